"""`marlin-temp serve`: own the printers' ports and share them with every other command and program
(`command`, over the library's `marlin_aio.service`; its command line in `options`)."""
