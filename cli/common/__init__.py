"""What every command shares: choosing and opening the printer, failures as one line and an exit code
(`connect`); the terminal as an input, keys and stop signals (`keys`); and the watch model (`model`) with its
pure rendering (`render`), which both `watch` and the farm view draw from."""
