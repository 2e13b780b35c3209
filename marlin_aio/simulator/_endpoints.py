"""Where a served simulator meets its host: a pseudo-terminal (`PtyEndpoint`), a TCP port (`TcpEndpoint`) or an
in-memory listener (`MemoryEndpoint`, a host in the same event loop opens `memory://sim-N`).

`SimulatorServer` (`_serve`) owns one endpoint and talks to it through a small interface: `open()` and
`close()`, `connected`, `hang_up()` (pull the cable), `write()` and `set_reading()`. The endpoint reports back
through the server's `EndpointOwner` methods: bytes from the host, how much it may read now, a client that
opened the port (the board resets, as DTR makes it), and a link that dropped. The server itself never asks which
kind of endpoint it has.

Opening a port resets most boards (DTR), and each TCP or memory client finds the board reset (the two share
`_ClientEndpoint`: one client at a time over an asyncio transport). A pty has no DTR, and the
endpoint holds the slave open (so its settings outlive each client, as a real port's do, and the master never
sees a hang-up), so the master sees no open either. With `reset_on_open` the endpoint watches the slave's path
with inotify (Linux), which reports every open and close of it by any process, and models DTR from those:

- DTR rises when a client opens the port while it is down: the board resets at that moment (the DTR edge) and
  sits in its bootloader for at least `OPEN_BOOT_S` of real time, so its banner comes after the flush that ends
  pyserial's `open()` (which would otherwise throw the banner away). The first open after the server started
  finds DTR down.
- DTR drops when the last client closes the port while the terminal has HUPCL set, a serial port's default. A
  client that clears HUPCL (`stty -hupcl`, as marlin_aio does) leaves DTR up, so the next open finds the board
  running, targets and all. The setting is read when the close is seen, normally at once.
- Nothing else resets the board: a client changing the baud rate, timeouts or any other setting of an open port,
  or flushing it, does what it does on a real port, nothing to the board. (An earlier version watched
  `tcsetattr()` calls instead, and rebooted the board when a host such as OctoPrint changed its port's settings
  in the middle of a print.)

An open is seen before any byte the client writes after it: the watch is read before each read of the host's
bytes.

Only os, pty, tty, termios and ctypes (for inotify, which the standard library does not wrap) are used here,
never the serial package (the client's business); and `marlin_aio.aio.memory`, the one module of the client the
simulator imports: a memory link's two ends are one pair of transports, so both sides use the same module.

Over 400 lines because the three endpoints are one interface, read side by side; most of the length is the pty's
open-watch (inotify through ctypes), which has no counterpart to share with the others.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import itertools
import os
import pty
import socket
import struct
import termios
import tty
from typing import Protocol

from marlin_aio.aio.memory import MemoryListener, listen

__all__ = ["OPEN_BOOT_S", "EndpointOwner", "MemoryEndpoint", "PtyEndpoint", "TcpEndpoint"]

_READ_CHUNK = 65536
# The names of memory endpoints, unique in this process: sim-1, sim-2, ...
_MEMORY_NAMES = itertools.count(1)
# Output the host has not read yet, beyond what the kernel holds. A board's transmit path is not an endless
# queue either; past this, output is dropped rather than delivered stale minutes later.
_MAX_PENDING_OUTPUT = 4096
OPEN_BOOT_S = 0.05
"""With `reset_on_open`: the shortest bootloader after an open, in real seconds (`SimulatorConfig.boot_delay_s`
may ask for longer). A real board takes 1-3 s; this is short so a handshake is not slowed down, and long enough
for the banner to come after the flush that ends pyserial's `open()`."""
# <sys/inotify.h>
_IN_OPEN = 0x20
_IN_CLOSE = 0x08 | 0x10  # IN_CLOSE_WRITE | IN_CLOSE_NOWRITE
_INOTIFY_EVENT = struct.Struct("iIII")  # wd, mask, cookie, len (a name of len bytes follows)


class EndpointOwner(Protocol):
    """What an endpoint tells the server that owns it (`SimulatorServer` implements it)."""

    def _receive_from_host(self, data: bytes) -> None:
        """Bytes the host wrote."""

    def _read_size(self) -> int:
        """How many bytes to read from the host at most, now."""

    def _update_reading(self) -> None:
        """Decide again whether to read from the host, and call the endpoint's `set_reading()` if that changed."""

    def _clear_wires(self) -> None:
        """Forget the bytes under way: they belonged to a session that ended."""

    def _reset_on_connect(self, *, min_boot_s: float = 0.0) -> None:
        """A client opened the port: reset the board so it starts from its banner (unless paused or closed), its
        bootloader taking at least `min_boot_s` of real time."""


class _OpenWatch:
    """Every open and close of one path, by any process (Linux inotify, called through libc)."""

    def __init__(self, path: str) -> None:
        """Watch `path`.

        Raises:
            OSError: if inotify is not available.
        """
        libc = ctypes.CDLL(None, use_errno=True)
        fd: int = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)  # IN_NONBLOCK, IN_CLOEXEC are these
        if fd < 0:
            error = ctypes.get_errno()
            raise OSError(error, f"inotify_init1: {os.strerror(error)}")
        if libc.inotify_add_watch(fd, os.fsencode(path), _IN_OPEN | _IN_CLOSE) < 0:
            error = ctypes.get_errno()
            os.close(fd)
            raise OSError(error, f"inotify_add_watch {path}: {os.strerror(error)}")
        self.fd = fd
        """The inotify descriptor, readable when something happened."""

    def events(self) -> list[bool]:
        """What happened since the last call, in order: True for an open, False for a close."""
        happened: list[bool] = []
        while True:
            try:
                data = os.read(self.fd, 4096)
            except OSError:  # nothing more (EAGAIN), or the watch is gone
                return happened
            offset = 0
            while offset + _INOTIFY_EVENT.size <= len(data):
                _, mask, _, name_size = _INOTIFY_EVENT.unpack_from(data, offset)
                offset += _INOTIFY_EVENT.size + name_size
                if mask & _IN_OPEN:
                    happened.append(True)
                elif mask & _IN_CLOSE:
                    happened.append(False)

    def close(self) -> None:
        """Stop watching."""
        os.close(self.fd)


class PtyEndpoint:
    """A new pseudo-terminal; the client opens its slave path. The endpoint holds both ends open."""

    def __init__(self, owner: EndpointOwner, *, reset_on_open: bool) -> None:
        """An endpoint for `owner`; with `reset_on_open` (Linux) a client's open resets the board as DTR does."""
        self._owner = owner
        self._reset_on_open = reset_on_open
        self._loop: asyncio.AbstractEventLoop | None = None
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._pending = bytearray()
        self._watch: _OpenWatch | None = None
        self._opens = 0  # clients that have the port open now (not counting the endpoint's own slave)
        self._dtr = False  # DTR is up: raised by an open, not dropped by a last close with HUPCL set
        self.reading = False
        """Whether the master is being read (its reader is registered)."""

    @property
    def connected(self) -> bool:
        """Whether the pty is open."""
        return self._master_fd is not None

    async def open(self, loop: asyncio.AbstractEventLoop) -> str:
        """Open the pseudo-terminal, start reading, and return its slave path (`/dev/pts/3`).

        Raises:
            OSError: if no pty can be opened.
        """
        self._loop = loop
        master_fd, slave_fd = pty.openpty()
        # Raw at once: otherwise the line discipline echoes the host's bytes back and turns \n into \r\n.
        tty.setraw(slave_fd)
        url = os.ttyname(slave_fd)
        if self._reset_on_open:
            attributes = termios.tcgetattr(slave_fd)
            # A serial port starts with HUPCL set (a pty without): closing drops DTR until a client clears it.
            attributes[2] |= termios.HUPCL
            termios.tcsetattr(slave_fd, termios.TCSANOW, attributes)
            try:
                self._watch = _OpenWatch(url)
            except OSError:
                os.close(master_fd)
                os.close(slave_fd)
                raise
            loop.add_reader(self._watch.fd, self._on_port_event)
        os.set_blocking(master_fd, False)
        self._master_fd = master_fd
        # Held open for the server's life, so the master sees no hang-up while no client has the port open.
        self._slave_fd = slave_fd
        self.reading = False
        self._owner._update_reading()
        return url

    async def close(self) -> None:
        """Close the pty for good."""
        self._close_pty()

    def hang_up(self) -> None:
        """Close the pty: the client sees the link drop, and the path no longer works."""
        self._close_pty()

    def write(self, data: bytes) -> None:
        """Send `data` to the host, holding back what the terminal cannot take yet (up to a limit)."""
        if self._master_fd is None:
            return
        if self._pending:
            self._queue_output(data)
            return
        try:
            written = os.write(self._master_fd, data)
        except (BlockingIOError, InterruptedError):
            written = 0
        except OSError:
            return
        if written < len(data):
            self._queue_output(data[written:])
            assert self._loop is not None
            self._loop.add_writer(self._master_fd, self._on_writable)

    def set_reading(self, want: bool) -> None:
        """Read from the host, or stop; nothing happens while the pty is closed."""
        if self._master_fd is None or self._loop is None:
            return
        if want:
            self._loop.add_reader(self._master_fd, self._on_readable)
        else:
            self._loop.remove_reader(self._master_fd)
        self.reading = want

    def _close_pty(self) -> None:
        if self._watch is not None:
            if self._loop is not None:
                self._loop.remove_reader(self._watch.fd)
            self._watch.close()
            self._watch = None
        if self._master_fd is not None:
            if self._loop is not None:
                self._loop.remove_reader(self._master_fd)
                self._loop.remove_writer(self._master_fd)
            os.close(self._master_fd)
            self._master_fd = None
        if self._slave_fd is not None:
            os.close(self._slave_fd)
            self._slave_fd = None
        self.reading = False
        self._pending.clear()
        self._owner._clear_wires()

    def _on_readable(self) -> None:
        if self._master_fd is None:
            return
        if self._watch is not None:
            self._on_port_event()  # an open comes before the bytes written after it
            if self._master_fd is None:
                return
        size = self._owner._read_size()
        try:
            data = os.read(self._master_fd, size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            # EIO and friends: the terminal is gone; stop listening rather than spin on an error.
            self._close_pty()
            return
        if data:
            self._owner._receive_from_host(data)

    def _on_port_event(self) -> None:
        """Opens and closes of the port by clients: DTR rises with an open, and drops with the last close while
        HUPCL is set; a rising DTR resets the board."""
        if self._watch is None:
            return
        for opened in self._watch.events():
            if opened:
                self._opens += 1
                if not self._dtr:
                    self._dtr = True
                    self._owner._clear_wires()  # what was on the wire belonged to the previous session
                    self._owner._reset_on_connect(min_boot_s=OPEN_BOOT_S)
                continue
            self._opens = max(self._opens - 1, 0)
            if self._opens == 0 and self._hupcl():
                self._dtr = False

    def _hupcl(self) -> bool:
        if self._slave_fd is None:
            return True
        try:
            return bool(termios.tcgetattr(self._slave_fd)[2] & termios.HUPCL)
        except (termios.error, OSError):
            return True

    def _queue_output(self, data: bytes) -> None:
        room = _MAX_PENDING_OUTPUT - len(self._pending)
        if room > 0:
            self._pending += data[:room]

    def _on_writable(self) -> None:
        if self._master_fd is None:
            return
        try:
            written = os.write(self._master_fd, self._pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            written = len(self._pending)
        del self._pending[:written]
        if not self._pending:
            assert self._loop is not None
            self._loop.remove_writer(self._master_fd)


class _ClientEndpoint:
    """What a TCP port and a memory listener share: one client at a time, like a serial port, over an asyncio
    transport, and each client finds the board reset. A subclass says how clients reach it (`open()`, `close()`)
    and hands each new transport to `_Connection`."""

    def __init__(self, owner: EndpointOwner) -> None:
        self._owner = owner
        self._transport: asyncio.Transport | None = None
        self._closing = False
        self.reading = False
        """Whether the connected client's transport is reading."""

    @property
    def connected(self) -> bool:
        """Whether a client is connected."""
        return self._transport is not None

    def hang_up(self) -> None:
        """Close the client's connection; the endpoint keeps listening for the next one."""
        if self._transport is not None:
            transport, self._transport = self._transport, None
            self.reading = False
            self._owner._clear_wires()
            transport.close()

    def write(self, data: bytes) -> None:
        """Send `data` to the client, if one is connected."""
        if self._transport is not None:
            self._transport.write(data)

    def set_reading(self, want: bool) -> None:
        """Read from the client, or stop; nothing happens while none is connected."""
        if self._transport is None:
            return
        if want:
            self._transport.resume_reading()
        else:
            self._transport.pause_reading()
        self.reading = want

    def _close_client(self) -> None:
        """Refuse every client from now on, and drop the one connected (the endpoint is closing)."""
        self._closing = True
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def _accept(self, transport: asyncio.Transport) -> bool:
        if self._transport is not None or self._closing:
            return False  # one client at a time, like a serial port
        self._transport = transport
        self.reading = True  # a new transport reads until told otherwise
        self._owner._clear_wires()
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._owner._update_reading()
        # Opening the port resets the board (DTR), so each client starts from the banner.
        self._owner._reset_on_connect()
        return True

    def _received(self, transport: asyncio.Transport, data: bytes) -> None:
        if self._transport is transport:
            self._owner._receive_from_host(data)

    def _lost(self, transport: asyncio.Transport) -> None:
        if self._transport is transport:
            self._transport = None
            self.reading = False
            self._owner._clear_wires()


class TcpEndpoint(_ClientEndpoint):
    """A listening TCP socket; one client at a time, like a serial port, and each finds the board reset."""

    def __init__(self, owner: EndpointOwner, *, host: str, port: int) -> None:
        """An endpoint for `owner` that will listen on `host`:`port` (0 picks a free port)."""
        super().__init__(owner)
        self._host = host
        self._port = port
        self._server: asyncio.Server | None = None

    async def open(self, loop: asyncio.AbstractEventLoop) -> str:
        """Start listening and return the URL to open, `socket://HOST:PORT`.

        Raises:
            OSError: if the socket cannot be opened.
        """
        self._server = await loop.create_server(lambda: _Connection(self), self._host, self._port)
        port = self._server.sockets[0].getsockname()[1]
        return f"socket://{self._host}:{port}"

    async def close(self) -> None:
        """Drop the client and stop listening."""
        self._close_client()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None


class MemoryEndpoint(_ClientEndpoint):
    """A listener at `memory://sim-N` (`marlin_aio.aio.memory`), reachable from this process and event loop only;
    one client at a time, like a serial port, and each finds the board reset, as on TCP."""

    def __init__(self, owner: EndpointOwner) -> None:
        """An endpoint for `owner`; its name is chosen when it opens, unique in this process."""
        super().__init__(owner)
        self._listener: MemoryListener | None = None

    async def open(self, loop: asyncio.AbstractEventLoop) -> str:
        """Start listening and return the URL to open, `memory://sim-N`."""
        self._listener = listen(f"sim-{next(_MEMORY_NAMES)}", lambda: _Connection(self))
        return self._listener.url

    async def close(self) -> None:
        """Drop the client and stop listening: the name is free, and opening it fails from now on."""
        self._close_client()
        if self._listener is not None:
            self._listener.close()
            self._listener = None


class _Connection(asyncio.Protocol):
    """One client's transport, handed to its endpoint."""

    def __init__(self, endpoint: _ClientEndpoint) -> None:
        self._endpoint = endpoint
        self._transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        if self._endpoint._accept(transport):
            self._transport = transport
        else:
            transport.close()

    def data_received(self, data: bytes) -> None:
        if self._transport is not None:
            self._endpoint._received(self._transport, data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._transport is not None:
            self._endpoint._lost(self._transport)
