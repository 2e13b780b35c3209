"""Temperature logs: `marlin-temp log`, the headless logger (`command`); the log files it and `watch --log`
write and read back, CSV or JSON lines (`files`); `marlin-temp plot`, the figure drawn from a log (`plot`); and
the command lines of log and plot (`options`)."""
