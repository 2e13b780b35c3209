"""Serving a `SimulatedPrinter` on a pseudo-terminal, a TCP port or an in-memory link, with asyncio.

The printer is sans-I/O; this module (with `_endpoints` for the file descriptors and sockets) is the only place
that knows about I/O and clocks.
It is callback-driven rather than task-driven: bytes from the host are handed to the printer in the reader
callback, and a single timer is kept pointing at the printer's `next_wakeup()`. An idle printer therefore costs
nothing between events, which matters when it runs beside a Raspberry Pi-class client being benchmarked.

Simulated time is `(loop.time() - start) * time_scale`. A caller can pass `clock` instead (simulated seconds
directly); then time moves only when the caller says so, and the server advances on received bytes and on
`poke()`, never on its own timer.

With `baud_rate`, both directions run at the speed of a UART (`_wire.Wire`, 10 bits a byte): the host's bytes
reach the printer's receive buffer, and the printer's replies reach the host, no faster than the wire carries
them. The wire runs on the loop's real clock whatever `time_scale` or `clock` say, since it is the cable and
not the firmware. Bytes are handed over in batches from one timer, at most about every millisecond while a
wire is busy and the moment a burst ends, so a 250000-baud stream costs one or two thousand wakeups a second,
not 25000. (On asyncio's default epoll loop timers wake in whole milliseconds, so there a short reply can
come up to a millisecond late, about what a USB-serial bridge adds with its 1 ms USB frames; `marlin-sim`
runs on a select() loop, which keeps time to the microsecond.) About 10 ms of the host's bytes are read ahead
of the wire; the rest wait in the pty or socket, where a host that writes too much finds its writes
blocking, as with a real serial port (on a memory link they wait in its transport, paused, without a bound).

The pseudo-terminal, the TCP port and the in-memory listener are endpoints (`_endpoints.PtyEndpoint`,
`TcpEndpoint`, `MemoryEndpoint`) behind one small interface, so nothing here depends on which one serves; each
client that opens the port finds the board reset, as DTR resets a real one (on a pty with `reset_on_open`, see
`_endpoints`), after its bootloader's `SimulatorConfig.boot_delay_s`. (A little over 400 lines: the two wires,
the timers and the pause/resume of reading belong together, and a fifth of the module is this text.)
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Callable
from types import TracebackType
from typing import Literal

from marlin_aio.simulator._config import Faults, SimulatorConfig
from marlin_aio.simulator._endpoints import MemoryEndpoint, PtyEndpoint, TcpEndpoint
from marlin_aio.simulator._printer import SimulatedPrinter
from marlin_aio.simulator._wire import Wire

__all__ = ["SimulatorServer", "serve_memory", "serve_pty", "serve_tcp"]

_READ_CHUNK = 65536
# With a baud rate: output still waiting for the wire beyond this is dropped. A board's transmit path is not an
# endless queue either; past this, output is lost rather than delivered stale minutes later.
_MAX_WIRE_OUTPUT = 16384
# With a baud rate: how often at most a busy wire hands over what has arrived.
_WIRE_TICK_S = 0.001
# With a baud rate: how far ahead of the wire the host's bytes are read (then reading pauses until half of it
# has gone on), so they mostly wait in the pty or socket and a flood is held back there.
_READ_AHEAD_S = 0.01
_MIN_READ_AHEAD = 32


class SimulatorServer:
    """A simulated printer reachable at `url`; an async context manager (or call `start()` / `aclose()`).

    Create it with `serve_pty()`, `serve_tcp()` or `serve_memory()`. `printer` (and `printer.faults`) can be
    inspected and changed at any time; after changing something from outside, call `poke()` so the server acts on
    it at once.
    """

    def __init__(
        self,
        config: SimulatorConfig | None,
        faults: Faults | None,
        *,
        kind: Literal["pty", "tcp", "memory"],
        host: str = "127.0.0.1",
        port: int = 0,
        time_scale: float = 1.0,
        clock: Callable[[], float] | None = None,
        baud_rate: int | None = None,
        reset_on_open: bool = False,
    ) -> None:
        """Prepare a server; nothing is opened until `start()`.

        Raises:
            ValueError: if `time_scale` or `baud_rate` is not a positive number, or `reset_on_open` is asked of
                a TCP or memory server (which always resets on connect) or off Linux.
        """
        if not time_scale > 0:
            raise ValueError(f"time_scale must be positive, got {time_scale!r}")
        if baud_rate is not None and baud_rate <= 0:
            raise ValueError(f"baud_rate must be positive, got {baud_rate!r}")
        if reset_on_open and (kind != "pty" or not sys.platform.startswith("linux")):
            raise ValueError(
                "reset_on_open is for a pty on Linux; a TCP or memory server resets on every connect anyway"
            )
        # The one place that looks at the kind: everything after talks to the endpoint.
        self._endpoint: PtyEndpoint | TcpEndpoint | MemoryEndpoint
        if kind == "pty":
            self._endpoint = PtyEndpoint(self, reset_on_open=reset_on_open)
        elif kind == "tcp":
            self._endpoint = TcpEndpoint(self, host=host, port=port)
        else:
            self._endpoint = MemoryEndpoint(self)
        self.printer = SimulatedPrinter(config, faults, now=0.0, boot=True)
        """The firmware being served."""
        self._time_scale = time_scale
        self._clock = clock
        self._url: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._started_at = 0.0
        self._timer: asyncio.TimerHandle | None = None
        self._timer_due = 0.0
        self._paused = False
        self._closed = False
        self._baud_rate = baud_rate
        self._rx_wire = Wire(baud_rate) if baud_rate is not None else None
        self._tx_wire = Wire(baud_rate) if baud_rate is not None else None
        self._read_ahead = 0 if baud_rate is None else max(_MIN_READ_AHEAD, int(baud_rate / 10 * _READ_AHEAD_S))
        self._wire_timer: asyncio.TimerHandle | None = None
        self._wire_due = 0.0
        self._paused_at: float | None = None  # loop time of pause(), once the loop is known

    # --------------------------------------------------------------------------------------------- lifecycle

    @property
    def url(self) -> str:
        """What a client opens: the pty slave path (`/dev/pts/3`), `socket://127.0.0.1:<port>` or `memory://sim-N`.

        Raises:
            RuntimeError: before `start()`.
        """
        if self._url is None:
            raise RuntimeError("the simulator is not started yet; use `async with` or await start()")
        return self._url

    @property
    def baud_rate(self) -> int | None:
        """The simulated UART's speed in bits per second, or None when bytes pass as fast as they can."""
        return self._baud_rate

    @property
    def connected(self) -> bool:
        """Whether a host can currently exchange bytes: the pty is open, or a TCP or memory client is connected."""
        return self._endpoint.connected

    async def start(self) -> None:
        """Open the pseudo-terminal, the listening socket or the memory listener, and start serving.

        Raises:
            RuntimeError: if already started.
            OSError: if the pty or the socket cannot be opened.
        """
        if self._loop is not None:
            raise RuntimeError("the simulator was already started")
        self._loop = asyncio.get_running_loop()
        self._started_at = self._loop.time()
        if self._paused:
            self._paused_at = self._started_at
        self._url = await self._endpoint.open(self._loop)
        # On a pty the boot banner waits in the terminal, where a client that does not flush on open finds it;
        # on TCP (and memory) nobody is listening yet, and each client gets a banner of its own when it connects.
        self._flush()
        self._reschedule()

    async def aclose(self) -> None:
        """Stop serving and release the pty, socket or memory listener. Safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        self._cancel_timer()
        self._cancel_wire_timer()
        await self._endpoint.close()

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
        """Pull the cable: close the pty master, or the TCP or memory connection, so the client sees the link drop.

        A pty is gone for good afterwards (its path no longer works). The TCP port and the memory listener keep
        listening, and the next client to connect finds the board reset, as when a USB cable is plugged back in.
        """
        self._endpoint.hang_up()

    def pause(self) -> None:
        """Freeze the board: nothing is read, run or written until `resume()` (the host's bytes wait)."""
        if self._paused:
            return
        self._paused = True
        self._cancel_timer()
        self._cancel_wire_timer()
        self._paused_at = self._loop.time() if self._loop is not None else None
        self._update_reading()

    def resume(self) -> None:
        """Undo `pause()`: the board catches up on the time that passed, then reads what the host sent."""
        if not self._paused:
            return
        self._paused = False
        if self._loop is not None and self._paused_at is not None:
            # The wire stood still too: what was under way arrives as much later as the pause lasted.
            stood_s = self._loop.time() - self._paused_at
            for wire in (self._rx_wire, self._tx_wire):
                if wire is not None:
                    wire.delay(stood_s)
        self._paused_at = None
        self._update_reading()
        self.poke()
        self._schedule_wire()

    # ------------------------------------------------------------------------------------------ the printer

    def _receive_from_host(self, data: bytes) -> None:
        """Bytes read from the pty, socket or memory link: straight to the printer, or onto the wire."""
        wire = self._rx_wire
        if wire is None:
            self._feed(data)
            return
        assert self._loop is not None
        wire.put(data, self._loop.time())
        self._update_reading()
        self._schedule_wire()

    def _feed(self, data: bytes) -> None:
        self.printer.receive(data, self.now())
        self._flush()
        self._reschedule()

    def _flush(self) -> None:
        data = self.printer.take_output()
        if not data or not self.connected:
            return  # output to nobody goes nowhere, like a board talking to an unplugged cable
        wire = self._tx_wire
        if wire is None:
            self._send_to_host(data)
            return
        if wire.pending >= _MAX_WIRE_OUTPUT:
            return
        assert self._loop is not None
        wire.put(data, self._loop.time())
        self._schedule_wire()

    def _send_to_host(self, data: bytes) -> None:
        self._endpoint.write(data)

    def _reset_on_connect(self, *, min_boot_s: float = 0.0) -> None:
        """A client opened the port: the board resets (DTR), so it starts from the banner; not while paused.

        Its bootloader takes `SimulatorConfig.boot_delay_s`, and at least `min_boot_s` of real time (simulated
        seconds scale with `time_scale`; a manual clock has no real time to stretch, so there it is left out).
        """
        if self._closed or self._paused:
            return
        boot_s = self.printer.config.boot_delay_s
        if min_boot_s > 0.0 and self._clock is None:
            boot_s = max(boot_s, min_boot_s * self._time_scale)
        self.printer.reset(self.now(), boot_delay_s=boot_s)
        self._flush()
        self._reschedule()

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

    # ------------------------------------------------------------------------------------------------ wire

    def _schedule_wire(self) -> None:
        """Keep the wire timer pointing at the next moment either direction has bytes to hand over."""
        if self._loop is None or self._closed or self._paused:
            return
        now = self._loop.time()
        due: float | None = None
        for wire in (self._rx_wire, self._tx_wire):
            if wire is not None and (wire_due := wire.due(now, _WIRE_TICK_S)) is not None:
                due = wire_due if due is None else min(due, wire_due)
        if due is None:
            self._cancel_wire_timer()
            return
        if self._wire_timer is not None:
            if self._wire_due <= due:
                return  # that earlier wakeup reschedules anyway
            self._wire_timer.cancel()
        self._wire_due = due
        self._wire_timer = self._loop.call_at(due, self._on_wire_timer)

    def _cancel_wire_timer(self) -> None:
        if self._wire_timer is not None:
            self._wire_timer.cancel()
            self._wire_timer = None

    def _on_wire_timer(self) -> None:
        self._wire_timer = None
        assert self._loop is not None
        now = max(self._loop.time(), self._wire_due)
        if self._rx_wire is not None:
            arrived = self._rx_wire.take(now)
            if arrived:
                self._feed(arrived)
            self._update_reading()
        if self._tx_wire is not None:
            arrived = self._tx_wire.take(now)
            if arrived:
                self._send_to_host(arrived)
        self._schedule_wire()

    def _clear_wires(self) -> None:
        for wire in (self._rx_wire, self._tx_wire):
            if wire is not None:
                wire.clear()
        self._cancel_wire_timer()

    def _update_reading(self) -> None:
        """Read from the host unless paused or, with a baud rate, far enough ahead of the wire."""
        want = not self._paused and not self._closed
        if want and self._rx_wire is not None:
            # Hysteresis: stop at the full read-ahead, go on once half of it has been handed over.
            limit = self._read_ahead if self._endpoint.reading else self._read_ahead // 2
            want = self._rx_wire.pending < limit
        if want != self._endpoint.reading:
            self._endpoint.set_reading(want)

    def _read_size(self) -> int:
        """How many bytes to read from the host at most: with a baud rate, no more than the read-ahead allows."""
        if self._rx_wire is None:
            return _READ_CHUNK
        return max(1, self._read_ahead - self._rx_wire.pending)


def serve_pty(
    config: SimulatorConfig | None = None,
    faults: Faults | None = None,
    *,
    time_scale: float = 1.0,
    clock: Callable[[], float] | None = None,
    baud_rate: int | None = None,
    reset_on_open: bool = False,
) -> SimulatorServer:
    """A simulated printer on a new pseudo-terminal; open `url` (its slave path) with pyserial at any baud rate.

    With `baud_rate` (bits per second, 10 a byte), bytes in both directions go no faster than a UART at that
    speed, in real time whatever the `time_scale`; without it they pass as fast as the pty carries them. The
    rate the client opens the port with does not matter either way.

    With `reset_on_open` (Linux), a client's open of the port resets the board, as the rising DTR of an open
    resets a real one: when DTR was down, that is on the first open and on an open after the last client closed
    the port with HUPCL set (the default; marlin_aio clears it, so its next open finds the board running). The
    board then spends `SimulatorConfig.boot_delay_s` in its bootloader, but at least 0.05 s of real time, so the
    client reads `start` and the boot banner after its `open()` has returned, during its handshake. Changing
    the settings of the open port (baud rate, timeouts) or flushing it resets nothing. With a manual `clock`
    the bootloader takes `boot_delay_s` of that clock, and its banner comes on the `poke()` after it. Without
    `reset_on_open`, the banner printed when the server starts waits in the terminal, and pyserial's `open()`
    throws it away.

    Raises:
        ValueError: if `time_scale` or `baud_rate` is not positive, or `reset_on_open` is asked off Linux.
    """
    return SimulatorServer(
        config,
        faults,
        kind="pty",
        time_scale=time_scale,
        clock=clock,
        baud_rate=baud_rate,
        reset_on_open=reset_on_open,
    )


def serve_tcp(
    config: SimulatorConfig | None = None,
    faults: Faults | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    time_scale: float = 1.0,
    clock: Callable[[], float] | None = None,
    baud_rate: int | None = None,
) -> SimulatorServer:
    """A simulated printer on a TCP port (0 picks a free one); open `url`, `socket://HOST:PORT`.

    One client at a time; each new connection resets the board and gets its boot banner. `baud_rate` paces
    both directions as for `serve_pty()`.

    Raises:
        ValueError: if `time_scale` or `baud_rate` is not positive.
    """
    return SimulatorServer(
        config, faults, kind="tcp", host=host, port=port, time_scale=time_scale, clock=clock, baud_rate=baud_rate
    )


def serve_memory(
    config: SimulatorConfig | None = None,
    faults: Faults | None = None,
    *,
    time_scale: float = 1.0,
    clock: Callable[[], float] | None = None,
    baud_rate: int | None = None,
) -> SimulatorServer:
    """A simulated printer in this process, on an in-memory link; open `url`, `memory://sim-N`, from the same
    event loop (`marlin_aio.connect(server.url)`).

    No pty, socket or thread: the client's bytes reach the printer, and its replies the client, on the loop's
    next turn (`marlin_aio.aio.memory`). For tests of a client that a real port adds nothing to, and for many
    simulated printers in one process. As on TCP, one client at a time, and each connect resets the board and
    gets its boot banner. `baud_rate` paces both directions as for `serve_pty()`. Another process cannot open it:
    `marlin-sim` offers the pty and TCP only.

    Raises:
        ValueError: if `time_scale` or `baud_rate` is not positive.
    """
    return SimulatorServer(config, faults, kind="memory", time_scale=time_scale, clock=clock, baud_rate=baud_rate)
