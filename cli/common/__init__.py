"""What every command shares: the shared options (--port, --baud, --sim, --max-hotend ...) made into one
`ConnectOptions`, and the way a command fails and runs (`options`); choosing and opening the printer, failures as
one line and an exit code (`connect`); the default heater limits (`limits`); the terminal as an input, keys and
stop signals (`keys`); and the watch model (`model`) with its pure rendering (`render`, `chart`), which both
`watch` and the farm view draw from."""
