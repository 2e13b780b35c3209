"""Serving a `SimulatedPrinter` on a pseudo-terminal or a TCP port, with asyncio.

The printer is sans-I/O; this module is the only place that knows about file descriptors, sockets and clocks.
It is callback-driven rather than task-driven: bytes from the host are handed to the printer in the reader
callback, and a single timer is kept pointing at the printer's `next_wakeup()`. An idle printer therefore costs
nothing between events, which matters when it runs beside a Raspberry Pi-class client being benchmarked.

Simulated time is `(loop.time() - start) * time_scale`. A caller can pass `clock` instead (simulated seconds
directly); then time moves only when the caller says so, and the server advances on received bytes and on
`poke()`, never on its own timer.

Only os, pty, tty and termios are used for the pseudo-terminal, never the serial package (the client's business).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import pty
import socket
import tty
from collections.abc import Callable
from types import TracebackType
from typing import Literal

from marlin_aio.simulator._printer import Faults, SimulatedPrinter, SimulatorConfig

__all__ = ["SimulatorServer", "serve_pty", "serve_tcp"]

_READ_CHUNK = 65536
# Output the host has not read yet, beyond what the kernel holds. A board's transmit path is not an endless
# queue either; past this, output is dropped rather than delivered stale minutes later.
_MAX_PENDING_OUTPUT = 4096


class SimulatorServer:
    """A simulated printer reachable at `url`; an async context manager (or call `start()` / `aclose()`).

    Create it with `serve_pty()` or `serve_tcp()`. `printer` (and `printer.faults`) can be inspected and changed
    at any time; after changing something from outside, call `poke()` so the server acts on it at once.
    """

    def __init__(
        self,
        config: SimulatorConfig | None,
        faults: Faults | None,
        *,
        kind: Literal["pty", "tcp"],
        host: str = "127.0.0.1",
        port: int = 0,
        time_scale: float = 1.0,
        clock: Callable[[], float] | None = None,
    ) -> None:
        """Prepare a server; nothing is opened until `start()`.

        Raises:
            ValueError: if `time_scale` is not a positive number.
        """
        if not time_scale > 0:
            raise ValueError(f"time_scale must be positive, got {time_scale!r}")
        self.printer = SimulatedPrinter(config, faults, now=0.0, boot=True)
        """The firmware being served."""
        self._kind = kind
        self._host = host
        self._port = port
        self._time_scale = time_scale
        self._clock = clock
        self._url: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._started_at = 0.0
        self._timer: asyncio.TimerHandle | None = None
        self._timer_due = 0.0
        self._paused = False
        self._closed = False
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._pending = bytearray()
        self._server: asyncio.Server | None = None
        self._transport: asyncio.Transport | None = None

    # --------------------------------------------------------------------------------------------- lifecycle

    @property
    def url(self) -> str:
        """What a client opens: the pty slave path (`/dev/pts/3`) or `socket://127.0.0.1:<port>`.

        Raises:
            RuntimeError: before `start()`.
        """
        if self._url is None:
            raise RuntimeError("the simulator is not started yet; use `async with` or await start()")
        return self._url

    @property
    def connected(self) -> bool:
        """Whether a host can currently exchange bytes: the pty is open, or a TCP client is connected."""
        return self._master_fd is not None if self._kind == "pty" else self._transport is not None

    async def start(self) -> None:
        """Open the pseudo-terminal or the listening socket and start serving.

        Raises:
            RuntimeError: if already started.
            OSError: if the pty or the socket cannot be opened.
        """
        if self._loop is not None:
            raise RuntimeError("the simulator was already started")
        self._loop = asyncio.get_running_loop()
        self._started_at = self._loop.time()
        if self._kind == "pty":
            self._open_pty()
        else:
            self._server = await self._loop.create_server(lambda: _Connection(self), self._host, self._port)
            port = self._server.sockets[0].getsockname()[1]
            self._url = f"socket://{self._host}:{port}"
        # On a pty the boot banner waits in the terminal, where a client that does not flush on open finds it;
        # on TCP nobody is listening yet, and each client gets a banner of its own when it connects.
        self._flush()
        self._reschedule()

    async def aclose(self) -> None:
        """Stop serving and release the pty or socket. Safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        self._cancel_timer()
        self._close_pty()
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    async def __aenter__(self) -> SimulatorServer:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.aclose()

    # --------------------------------------------------------------------------------------------- controls

    def now(self) -> float:
        """The simulated time, in seconds."""
        if self._clock is not None:
            return self._clock()
        if self._loop is None:
            return 0.0
        return (self._loop.time() - self._started_at) * self._time_scale

    def poke(self) -> None:
        """Advance the printer to `now()` at once and send what it printed (use after moving a manual clock,
        or after calling the printer's methods, such as `reset()`, from outside). Does nothing while paused."""
        if self._loop is None or self._closed or self._paused:
            return
        self.printer.advance(self.now())
        self._flush()
        self._reschedule()

    async def disconnect(self) -> None:
        """Pull the cable: close the pty master, or the TCP connection, so the client sees the link drop.

        A pty is gone for good afterwards (its path no longer works). The TCP port keeps listening, and the next
        client to connect finds the board reset, as when a USB cable is plugged back in.
        """
        if self._kind == "pty":
            self._close_pty()
        elif self._transport is not None:
            transport, self._transport = self._transport, None
            transport.close()

    def pause(self) -> None:
        """Freeze the board: nothing is read, run or written until `resume()` (the host's bytes wait)."""
        if self._paused:
            return
        self._paused = True
        self._cancel_timer()
        if self._loop is not None and self._master_fd is not None:
            self._loop.remove_reader(self._master_fd)
        if self._transport is not None:
            self._transport.pause_reading()

    def resume(self) -> None:
        """Undo `pause()`: the board catches up on the time that passed, then reads what the host sent."""
        if not self._paused:
            return
        self._paused = False
        if self._loop is not None and self._master_fd is not None:
            self._loop.add_reader(self._master_fd, self._on_pty_readable)
        if self._transport is not None:
            self._transport.resume_reading()
        self.poke()

    # ------------------------------------------------------------------------------------------ the printer

    def _feed(self, data: bytes) -> None:
        self.printer.receive(data, self.now())
        self._flush()
        self._reschedule()

    def _flush(self) -> None:
        data = self.printer.take_output()
        if not data:
            return
        if self._kind == "pty":
            self._write_pty(data)
        elif self._transport is not None:
            self._transport.write(data)
        # Otherwise the output goes nowhere, like a board talking to an unplugged cable.

    def _reschedule(self) -> None:
        if self._loop is None or self._closed or self._paused or self._clock is not None:
            return
        wake = self.printer.next_wakeup()
        if wake is None:
            self._cancel_timer()
            return
        if self._timer is not None:
            if self._timer_due == wake:
                return
            self._timer.cancel()
        self._timer_due = wake
        self._timer = self._loop.call_at(self._started_at + wake / self._time_scale, self._on_timer)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _on_timer(self) -> None:
        self._timer = None
        # The loop may run a timer a hair before its time; the printer is owed the moment it asked for.
        self.printer.advance(max(self.now(), self._timer_due))
        self._flush()
        self._reschedule()

    # -------------------------------------------------------------------------------------------------- pty

    def _open_pty(self) -> None:
        assert self._loop is not None
        master_fd, slave_fd = pty.openpty()
        # Raw at once: otherwise the line discipline echoes the host's bytes back and turns \n into \r\n.
        tty.setraw(slave_fd)
        os.set_blocking(master_fd, False)
        self._master_fd = master_fd
        # Held open for the server's life, so the master sees no hang-up while no client has the port open.
        self._slave_fd = slave_fd
        self._url = os.ttyname(slave_fd)
        self._loop.add_reader(master_fd, self._on_pty_readable)

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
        self._pending.clear()

    def _on_pty_readable(self) -> None:
        if self._master_fd is None:
            return
        try:
            data = os.read(self._master_fd, _READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            # EIO and friends: the terminal is gone; stop listening rather than spin on an error.
            self._close_pty()
            return
        if data:
            self._feed(data)

    def _write_pty(self, data: bytes) -> None:
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
            self._loop.add_writer(self._master_fd, self._on_pty_writable)

    def _queue_output(self, data: bytes) -> None:
        room = _MAX_PENDING_OUTPUT - len(self._pending)
        if room > 0:
            self._pending += data[:room]

    def _on_pty_writable(self) -> None:
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

    # -------------------------------------------------------------------------------------------------- tcp

    def _accept(self, transport: asyncio.Transport) -> bool:
        if self._transport is not None or self._closed:
            return False  # one client at a time, like a serial port
        self._transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self._paused:
            transport.pause_reading()
            return True
        # Opening the port resets the board (DTR), so each client starts from the banner.
        self.printer.reset(self.now())
        self._flush()
        self._reschedule()
        return True

    def _lost(self, transport: asyncio.Transport) -> None:
        if self._transport is transport:
            self._transport = None


class _Connection(asyncio.Protocol):
    def __init__(self, server: SimulatorServer) -> None:
        self._server = server
        self._transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        if self._server._accept(transport):
            self._transport = transport
        else:
            transport.close()

    def data_received(self, data: bytes) -> None:
        if self._transport is not None and self._server._transport is self._transport:
            self._server._feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._transport is not None:
            self._server._lost(self._transport)


def serve_pty(
    config: SimulatorConfig | None = None,
    faults: Faults | None = None,
    *,
    time_scale: float = 1.0,
    clock: Callable[[], float] | None = None,
) -> SimulatorServer:
    """A simulated printer on a new pseudo-terminal; open `url` (its slave path) with pyserial at any baud rate.

    Raises:
        ValueError: if `time_scale` is not positive.
    """
    return SimulatorServer(config, faults, kind="pty", time_scale=time_scale, clock=clock)


def serve_tcp(
    config: SimulatorConfig | None = None,
    faults: Faults | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    time_scale: float = 1.0,
    clock: Callable[[], float] | None = None,
) -> SimulatorServer:
    """A simulated printer on a TCP port (0 picks a free one); open `url`, `socket://HOST:PORT`.

    One client at a time; each new connection resets the board and gets its boot banner.

    Raises:
        ValueError: if `time_scale` is not positive.
    """
    return SimulatorServer(config, faults, kind="tcp", host=host, port=port, time_scale=time_scale, clock=clock)
