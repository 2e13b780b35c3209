"""The asyncio side of marlin_aio: the `Printer` an application awaits, the link that drives the sans-I/O core on
one port, opening ports, the temperature feed, the poller and prints in progress."""
