"""Where a served simulator meets its host: a pseudo-terminal (`PtyEndpoint`) or a TCP port (`TcpEndpoint`).

`SimulatorServer` (`_serve`) owns one endpoint and talks to it through a small interface: `open()` and
`close()`, `connected`, `hang_up()` (pull the cable), `write()` and `set_reading()`. The endpoint reports back
through the server's `EndpointOwner` methods: bytes from the host, how much it may read now, a client that
opened the port (the board resets, as DTR makes it), and a link that dropped. The server itself never asks which
kind of endpoint it has.

Opening a port resets most boards (DTR), and each TCP client finds the board reset. A pty cannot see DTR, and the
endpoint holds the slave open, so it sees no open either; with `reset_on_open` it watches the terminal's settings
instead: the slave gets EXTPROC and the master packet mode (TIOCPKT), so every `tcsetattr()` on the slave reaches
the master as a TIOCPKT_IOCTL packet. pyserial's `open()` always sets the port up that way, and its reads and
flushes do not, so a client finds the board booting a moment after it opened the port, after the flush that
ends pyserial's `open()` (which would otherwise throw the banner away). This is Linux behaviour.

DTR is modelled as a real port has it: the first open raises it (the board resets), and closing drops it again
only while the terminal has HUPCL set, the default. A client that clears HUPCL (`stty -hupcl`, as marlin_aio
does) leaves DTR up, so the next open finds the board running, targets and all. The slave is held open here, so
its settings outlive each client, as a real port's do; an open resets the board when the setting seen before it
(how the last client left the port) had HUPCL set.

Only os, pty, tty and termios are used for the pseudo-terminal, never the serial package (the client's business).
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import pty
import socket
import struct
import termios
import tty
from typing import Protocol

__all__ = ["EndpointOwner", "PtyEndpoint", "TcpEndpoint"]

_READ_CHUNK = 65536
# Output the host has not read yet, beyond what the kernel holds. A board's transmit path is not an endless
# queue either; past this, output is dropped rather than delivered stale minutes later.
_MAX_PENDING_OUTPUT = 4096
# With reset_on_open: how long after the port's set-up the board prints its banner (a real one takes 1-3 s in
# its bootloader; this is short so a handshake is not slowed down, and long enough to come after pyserial's flush).
_OPEN_RESET_DELAY_S = 0.05
# Linux values; the termios module names neither.
_EXTPROC = 0o200000
_TIOCPKT_IOCTL = 0x40


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

    def _reset_on_connect(self) -> None:
        """A client opened the port: reset the board so it starts from its banner (unless paused or closed)."""


class PtyEndpoint:
    """A new pseudo-terminal; the client opens its slave path. The endpoint holds both ends open."""

    def __init__(self, owner: EndpointOwner, *, reset_on_open: bool) -> None:
        """An endpoint for `owner`; with `reset_on_open` (Linux) a client's port set-up resets the board."""
        self._owner = owner
        self._reset_on_open = reset_on_open
        self._loop: asyncio.AbstractEventLoop | None = None
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._pending = bytearray()
        self._open_reset: asyncio.TimerHandle | None = None
        self._dtr_raised = False  # DTR has been up since an open (and no close with HUPCL dropped it)
        self._hupcl_before = True  # HUPCL as last seen: a serial port starts with it set
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
        if self._reset_on_open:
            attributes = termios.tcgetattr(slave_fd)
            attributes[3] |= _EXTPROC  # lflag; in raw mode it changes nothing but the reporting
            # A serial port starts with HUPCL set (a pty without): closing drops DTR until a client clears it.
            attributes[2] |= termios.HUPCL
            termios.tcsetattr(slave_fd, termios.TCSANOW, attributes)
            fcntl.ioctl(master_fd, termios.TIOCPKT, struct.pack("i", 1))
        os.set_blocking(master_fd, False)
        self._master_fd = master_fd
        # Held open for the server's life, so the master sees no hang-up while no client has the port open.
        self._slave_fd = slave_fd
        url = os.ttyname(slave_fd)
        self.reading = False
        self._owner._update_reading()
        return url

    async def close(self) -> None:
        """Close the pty for good, and forget a reset still to come."""
        if self._open_reset is not None:
            self._open_reset.cancel()
            self._open_reset = None
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
        size = self._owner._read_size()
        if self._reset_on_open:
            size += 1  # room for the packet's status byte, so a read always makes progress
        try:
            data = os.read(self._master_fd, size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            # EIO and friends: the terminal is gone; stop listening rather than spin on an error.
            self._close_pty()
            return
        if data and self._reset_on_open:
            # Packet mode: a status byte first; 0 (TIOCPKT_DATA) means the host's bytes follow.
            status, data = data[0], data[1:]
            if status & _TIOCPKT_IOCTL:
                self._port_opened()
            if status:
                return
        if data:
            self._owner._receive_from_host(data)

    def _port_opened(self) -> None:
        """The client set the port up (opened it): the board resets, as DTR would make it, a moment later, unless
        DTR stayed up since the last session (HUPCL cleared)."""
        assert self._loop is not None
        # What matters is how the last session left the port: a close with HUPCL set dropped DTR. That is the
        # setting seen before this set-up, not now: the client may have cleared it since (packets coalesce, and the
        # setting is read when the packet is).
        dropped = not self._dtr_raised or self._hupcl_before
        if self._slave_fd is not None:
            with contextlib.suppress(termios.error, OSError):
                self._hupcl_before = bool(termios.tcgetattr(self._slave_fd)[2] & termios.HUPCL)
        if not dropped:
            return  # DTR never dropped: no reset (a reset already on its way from this open still comes)
        self._dtr_raised = True
        self._owner._clear_wires()  # what was on the wire belonged to the previous session
        if self._open_reset is not None:
            self._open_reset.cancel()
        self._open_reset = self._loop.call_later(_OPEN_RESET_DELAY_S, self._reset_after_open)

    def _reset_after_open(self) -> None:
        self._open_reset = None
        self._owner._reset_on_connect()

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


class TcpEndpoint:
    """A listening TCP socket; one client at a time, like a serial port, and each finds the board reset."""

    def __init__(self, owner: EndpointOwner, *, host: str, port: int) -> None:
        """An endpoint for `owner` that will listen on `host`:`port` (0 picks a free port)."""
        self._owner = owner
        self._host = host
        self._port = port
        self._server: asyncio.Server | None = None
        self._transport: asyncio.Transport | None = None
        self._closing = False
        self.reading = False
        """Whether the connected client's transport is reading."""

    @property
    def connected(self) -> bool:
        """Whether a client is connected."""
        return self._transport is not None

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
        self._closing = True
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    def hang_up(self) -> None:
        """Close the client's connection; the port keeps listening for the next one."""
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


class _Connection(asyncio.Protocol):
    def __init__(self, endpoint: TcpEndpoint) -> None:
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
