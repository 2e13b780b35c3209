"""The asyncio side of one serial link: the transport, the protocol core, and the futures of waiting callers.

`Link` is the thin layer the sans-I/O `Connection` needs: it writes what the core says to write, feeds it what the
port reads, arms one timer for the core's next deadline, and resolves each caller's future with its own result.
Everything above it (the handshake, the poller, the temperature feed, prints) uses its public methods only.

Its listeners (`on_event`, `on_failure`, `after_results`, `submit_quietly`'s `done`) are called inside the read
handler, between reading a step's events and writing its bytes, resolving its futures and re-arming its timer: one
that raised would leave that step half done and the link hung. So they are the client's own bookkeeping only
(resolve a future, update state, queue a reading), never user code. `after_read` is the exception: it runs once a
read's step is wholly done (bytes written, futures resolved, timer armed), so the feed hands that read's readings
to user callbacks there, each guarded, with no loop turn of its own (at 100 Hz a turn a reading is a cost a
Raspberry Pi notices).

Over 400 lines because the link's three duties (writing what the core says, resolving each caller's future, the
one deadline timer) share the read handler's single step, and splitting them would put a call between them on
the 100 Hz path.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
from collections import deque
from collections.abc import Callable

from marlin_aio.aio import _serial
from marlin_aio.errors import ConnectionLostError, MarlinError, PrinterHaltedError
from marlin_aio.protocol.connection import Command, Connection, Output, Reply
from marlin_aio.protocol.events import Event
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.printjob import PrintJob
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.wire import Trace

__all__ = ["Link"]

#: What the link tells its owner: each event received (with its time), and each failure of the whole link.
EventListener = Callable[[Event, float], None]
FailureListener = Callable[[MarlinError], None]


class _Protocol(asyncio.Protocol):
    """Hands the transport's callbacks to the link; holds no state of its own."""

    def __init__(self, link: Link) -> None:
        self._link = link

    def data_received(self, data: bytes) -> None:
        self._link.data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._link.connection_lost(exc)


class Link:
    """One open port and its protocol state.

    Args:
        port: a device path or a pyserial URL.
        baudrate: the port's speed.
        connection: the protocol core to drive.
        on_event: called with every event received and its time on the loop's clock.
        on_failure: called once when the printer halts (each halt) or the link is lost.
        after_results: called after every batch of finished commands was delivered (a print may have ended).
        after_read: called after each read's step was carried out in full (see the module's docstring).

    The listeners run inside the read handler and must not raise (see the module's docstring).
    """

    def __init__(
        self,
        port: str,
        baudrate: int,
        connection: Connection,
        *,
        on_event: EventListener,
        on_failure: FailureListener,
        after_results: Callable[[], None],
        after_read: Callable[[], None] | None = None,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self._conn = connection
        self._on_event = on_event
        self._on_failure = on_failure
        self._after_results = after_results
        self._after_read = after_read
        self._transport: asyncio.Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed: asyncio.Future[None] | None = None
        self._lost: MarlinError | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._waiters: dict[int, asyncio.Future[Reply]] = {}
        self._callbacks: dict[int, Callable[[Reply | MarlinError], None]] = {}
        self._halt_notified: PrinterHaltedError | None = None
        #: Set by every batch of lines received while it is not None (the handshake waits for the banner to end).
        self.line_seen: asyncio.Event | None = None
        #: (answered at, round trip) of the latest replies, the poller's included, on the loop's clock: for latency
        #: figures.
        self.round_trips: deque[tuple[float, float]] = deque(maxlen=8192)

    # ------------------------------------------------------------------------------------------- lifecycle

    async def open(self) -> None:
        """Open the port.

        Raises:
            ConnectError: the port could not be opened (its subclasses say why).
        """
        self._loop = asyncio.get_running_loop()
        self._closed = self._loop.create_future()
        self._lost = None
        transport, _ = await _serial.open_link(self.port, self.baudrate, lambda: _Protocol(self))
        self._transport = transport

    async def close(self) -> None:
        """Close the port; commands still waiting fail with `ConnectionLostError`. Safe to call twice."""
        self._cancel_timer()
        if self._lost is None:
            self._fail(ConnectionLostError(f"the connection to {self.port} was closed"))
        transport, self._transport = self._transport, None
        if transport is not None and not transport.is_closing():
            transport.close()
        if self._closed is not None and transport is not None:
            # pyserial-asyncio-fast closes the port in an executor and then calls connection_lost.
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self._closed), 2.0)

    @property
    def lost(self) -> MarlinError | None:
        """Why the link ended (closed or lost), or None while it is open (or not opened yet)."""
        return self._lost

    @property
    def is_open(self) -> bool:
        """True while the port is open and the link has not been lost."""
        return self._transport is not None and self._lost is None

    @property
    def state(self) -> LinkState:
        """The core's state, or LOST while the port is not open."""
        return self._conn.state if self.is_open else LinkState.LOST

    # ------------------------------------------------------------------------------------------- reading state

    def now(self) -> float:
        """The event loop's clock, which every time on this link is measured by.

        Raises:
            RuntimeError: the link was never opened.
        """
        if self._loop is None:
            raise RuntimeError("the printer is not open: use 'async with connect(...) as printer'")
        return self._loop.time()

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The event loop the link runs on.

        Raises:
            RuntimeError: the link was never opened.
        """
        if self._loop is None:
            raise RuntimeError("the printer is not open: use 'async with connect(...) as printer'")
        return self._loop

    @property
    def trace(self) -> Trace:
        """The last lines sent and received."""
        return self._conn.trace

    def stats(self) -> LinkStats:
        """A snapshot of the counters."""
        return self._conn.stats()

    @property
    def halted(self) -> PrinterHaltedError | None:
        """Why the printer halted, or None while it runs."""
        return self._conn.halted

    @property
    def requires_numbers(self) -> bool:
        """The printer runs only numbered lines."""
        return self._conn.requires_numbers

    @property
    def window(self) -> tuple[int, int]:
        """(max_in_flight, rx_buffer_bytes) of the core."""
        return self._conn.window

    def set_window(self, max_in_flight: int, rx_buffer_bytes: int) -> None:
        """Change the core's window (see `Connection.set_window`)."""
        self._conn.set_window(max_in_flight, rx_buffer_bytes)

    @property
    def send_ahead_window_bytes(self) -> int:
        """Unanswered bytes a streaming print may keep on the wire: the buffer less the probe's room."""
        return self._conn.rx_buffer_bytes - self._conn.probe_reserve_bytes

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float, numbered: bool | None = None) -> Reply:
        """Send one command and return its reply; if the caller is cancelled before it was written, it never is.

        Raises:
            ValueError: the command is malformed.
            MarlinError: its own failure (timeout, halt, reset, lost link, lost reply).
        """
        now = self.now()
        if self._lost is not None:
            raise self._lost
        entry = self._submit(command, timeout_s, now, numbered=numbered, checked=True)
        future: asyncio.Future[Reply] = self.loop.create_future()
        self._waiters[entry.id] = future
        try:
            return await future
        except asyncio.CancelledError:
            self._conn.cancel(entry)
            raise
        finally:
            self._waiters.pop(entry.id, None)

    def submit_quietly(self, command: str, *, timeout_s: float, done: Callable[[Reply | MarlinError], None]) -> bool:
        """Queue a command nobody awaits (the poller's M105, built by the caller and known valid); `done` gets its
        outcome, inside the read handler (so it must not raise). Return False (nothing queued) while the printer is
        halted or the link is down."""
        if self._lost is not None or self._conn.halted is not None:
            return False
        entry = self._submit(command, timeout_s, self.now(), numbered=None, checked=False)
        self._callbacks[entry.id] = done
        return True

    def _submit(self, text: str, timeout_s: float, now: float, *, numbered: bool | None, checked: bool) -> Command:
        """Hand a command to the core and carry out what it says. On an idle link (the usual case: a poll, a
        caller's command between others) it is written at once without a whole step of the core: no results can
        come of it, only its deadline to arm."""
        conn = self._conn
        entry = conn.submit_and_write(text, timeout_s=timeout_s, now=now, numbered=numbered, checked=checked)
        if entry is None:
            entry = conn.submit(text, timeout_s=timeout_s, now=now, numbered=numbered, checked=checked)
            self.flush()
        elif self._transport is not None:
            self._transport.write(entry.wire)
            self._arm_timer(conn.next_deadline())
        return entry

    def emergency_stop(self) -> None:
        """Write M112 at once; everything waiting fails with `PrinterHaltedError`.

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        if self._transport is None or self._lost is not None:
            reason = str(self._lost) if self._lost is not None else f"{self.port} is not open"
            raise ConnectionLostError(f"cannot send the emergency stop (M112): {reason}")
        self._transport.write(self._conn.emergency_stop(self.now()))
        self.flush()

    def interrupt_wait(self) -> None:
        """Write M108 at once, ahead of anything queued: Marlin's emergency parser ends a heater wait (M109, M190,
        M191) or an M0/M1 with it. The wait's own command is then answered normally, and the M108 by its own `ok`
        after it, in order (its place in the FIFO is taken as it is written: see `Connection.emergency`).

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        if self._transport is None or self._lost is not None:
            reason = str(self._lost) if self._lost is not None else f"{self.port} is not open"
            raise ConnectionLostError(f"cannot send M108: {reason}")
        self._transport.write(self._conn.emergency("M108", now=self.now()))
        self.flush()  # its ok is now due too, and a probe may follow it (`Connection.emergency`)

    def write_emergency(self, text: str) -> None:
        """Write an emergency command (`M876 S1`) at once, ahead of anything queued; it takes its place in the
        FIFO as it is written, so its own `ok` lands on it and on no caller's command (see `Connection.emergency`).

        Raises:
            ValueError: it is not an emergency command.
            ConnectionLostError: the port is closed or lost.
        """
        if self._transport is None or self._lost is not None:
            reason = str(self._lost) if self._lost is not None else f"{self.port} is not open"
            raise ConnectionLostError(f"cannot send {text}: {reason}")
        self._transport.write(self._conn.emergency(text, now=self.now()))
        self.flush()  # its ok is now due too, and a probe may follow it (`Connection.emergency`)

    def drop(self, error: MarlinError) -> None:
        """End the link now with `error` (everything waiting fails with it) and close the port, without waiting
        for it to close (`close()` still waits, if called)."""
        self._cancel_timer()
        if self._lost is None:
            self._fail(error)
        transport = self._transport
        if transport is not None and not transport.is_closing():
            transport.close()

    def attach(self, job: PrintJob, *, timeout_s: float) -> None:
        """Stream `job` (see `Connection.attach`)."""
        self._conn.attach(job, timeout_s=timeout_s)
        self.flush()

    def flush_input(self) -> None:
        """Throw away whatever the port has read and not yet handed over, and any half line."""
        if self._transport is not None:
            _serial.flush_input(self._transport)
        self._conn.discard_partial_input()

    # ------------------------------------------------------------------------------------------- plumbing

    def data_received(self, data: bytes) -> None:
        """Feed bytes read from the port to the core, and act on what they brought."""
        now = self.now()
        output = self._conn.receive(data, now)
        if output.events and self.line_seen is not None:
            self.line_seen.set()
        self._act(output, now)
        if output.events and self._after_read is not None:
            self._after_read()

    def flush(self) -> None:
        """Let the core act now (a command was submitted, a print resumed) and carry out what it says."""
        if self._loop is not None:
            now = self._loop.time()
            self._act(self._conn.tick(now), now)

    def _act(self, output: Output, now: float) -> None:
        """One `Output` of the core (of a step at `now`), handled in its order: events, bytes, finished commands,
        the next deadline."""
        if output.events:
            for event in output.events:
                self._on_event(event, now)
        if output.data and self._transport is not None and self._lost is None:
            self._transport.write(output.data)
        for command, outcome in output.finished:
            callback = self._callbacks.pop(command.id, None)
            if callback is not None:
                # The poller's M105s come this way: recorded too, or the latency figures would only ever show the
                # handshake and the callers' commands (watch's footer did). Inline, not `latency_s`: 100 Hz path.
                if isinstance(outcome, Reply):
                    self.round_trips.append((outcome.answered_s, outcome.answered_s - outcome.sent_s))
                callback(outcome)
                continue
            future = self._waiters.get(command.id)
            if future is None or future.done():
                continue
            if isinstance(outcome, Reply):
                self.round_trips.append((outcome.answered_s, outcome.answered_s - outcome.sent_s))
                future.set_result(outcome)
            else:
                future.set_exception(outcome)
        self._after_results()
        halted = self._conn.halted
        if halted is not None and halted is not self._halt_notified:
            # Readers of temperatures learn of a halt even when no command was waiting for an answer.
            self._halt_notified = halted
            self._on_failure(halted)
        self._arm_timer(output.deadline)

    def _arm_timer(self, deadline: float | None) -> None:
        # Keep a timer already armed, whether it is earlier than the deadline or nothing waits at all: when it
        # fires it only ticks the core, which re-arms for the real deadline. So a poll answered before the next one
        # is sent (no deadline between them) costs no timer cancelled and no timer armed: one every timeout.
        if deadline is None or (self._timer is not None and self._timer.when() <= deadline):
            return
        self._cancel_timer()
        self._timer = self.loop.call_at(deadline, self._on_timer)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _on_timer(self) -> None:
        self._timer = None
        self.flush()

    def connection_lost(self, exc: Exception | None) -> None:
        """The transport went away (or finished closing)."""
        if self._lost is None:
            self._fail(ConnectionLostError(f"the connection to {self.port} was lost{_why_lost(exc)}"))
        self._cancel_timer()
        self._transport = None
        if self._closed is not None and not self._closed.done():
            self._closed.set_result(None)

    def _fail(self, error: MarlinError) -> None:
        self._lost = error
        self._conn.lose(error)
        self.flush()
        self._on_failure(error)


def _why_lost(exc: Exception | None) -> str:
    """What a transport's error says about a lost link, in words a user can act on (pyserial's own text for a
    vanished device is "device reports readiness to read but returned no data (device disconnected or multiple
    access on port?)")."""
    if exc is None:
        return ""
    gone = (errno.EIO, errno.ENXIO, errno.ENODEV)
    # pyserial wraps the OSError of a failed write in a SerialException that keeps only its text ("write failed:
    # [Errno 5] Input/output error"), so the error number is looked for in the text and in the cause too.
    causes = [exc, exc.__cause__, exc.__context__]
    text = str(exc)
    if (
        "returned no data" in text
        or any(getattr(cause, "errno", None) in gone for cause in causes if cause is not None)
        or any(f"[Errno {number}]" in text for number in gone)
    ):
        return ": the port went away (the printer was unplugged or switched off, or its USB bridge reset)"
    return f": {exc}"
