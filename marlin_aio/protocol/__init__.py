"""The sans-I/O core of marlin_aio: bytes and times in, bytes and results out.

Nothing in this folder opens a port, reads a clock or imports asyncio: `Connection` takes the bytes a driver read
and the time it read them, and gives back the bytes to write and each command's result. The asyncio client
(`marlin_aio.aio`) is one driver of it; the simulator's fault campaign is another.
"""
