"""`marlin-temp`: the command-line front end of marlin_aio (installed as the `marlin_temp` package)."""
