"""`marlin-temp set`: send heater targets, report what the printer confirmed and optionally wait
(`command`), with its command line (`options`); also says which heaters are left on when another command
ends."""
