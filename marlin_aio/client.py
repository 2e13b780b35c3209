"""The asyncio client: `async with connect(url) as printer: await printer.send("G28")`.

A thin layer over `marlin_aio.connection.Connection` (all protocol decisions live there): it owns the transport,
turns bytes into `Connection.receive_data` calls, resolves one future per command, arms one timer for the oldest
command's deadline, and fans temperature readings out to subscribers. Loop-bound objects are created in
`__aenter__`, never in `__init__`, so a `Printer` can be built outside a running loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import time
from collections import deque
from collections.abc import AsyncGenerator, AsyncIterator, Generator, Iterable
from pathlib import Path
from types import TracebackType
from typing import Self

from marlin_aio import _serial
from marlin_aio.commands import (
    DEFAULT_MAX_BED_CELSIUS,
    DEFAULT_MAX_CHAMBER_CELSIUS,
    DEFAULT_MAX_HOTEND_CELSIUS,
    check_target,
    format_celsius,
)
from marlin_aio.connection import Command, Connection, Reply
from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandTimeoutError,
    ConnectionLostError,
    HandshakeError,
    HandshakeTimeoutError,
    LostReplyError,
    MarlinError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
    TemperatureTimeoutError,
)
from marlin_aio.events import (
    Capability,
    Event,
    FirmwareInfo,
    Ok,
    TargetTemperature,
    TemperatureReport,
)
from marlin_aio.linkstate import LinkState
from marlin_aio.parsing import parse_endstops, parse_position
from marlin_aio.printjob import PrintJob, PrintProgress, PrintState
from marlin_aio.stats import LinkStats
from marlin_aio.temperatures import TemperatureReading, Temperatures
from marlin_aio.trace import Trace

__all__ = ["DEFAULT_BAUDRATE", "PrintHandle", "Printer", "connect"]

DEFAULT_BAUDRATE = 250_000


class _LinkProtocol(asyncio.Protocol):
    """Hands the transport's callbacks to the printer; holds no state of its own."""

    def __init__(self, printer: Printer) -> None:
        self._printer = printer

    def data_received(self, data: bytes) -> None:
        self._printer._on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._printer._on_connection_lost(exc)


class PrintHandle:
    """A print in progress: watch `progress`, `pause()`, `resume()`, `cancel()`, and await it for the outcome."""

    def __init__(self, printer: Printer, job: PrintJob, done: asyncio.Future[PrintProgress]) -> None:
        self._printer = printer
        self.job = job
        self._done = done

    @property
    def progress(self) -> PrintProgress:
        """Lines and bytes sent and acknowledged, elapsed time, rate, estimate of what remains."""
        return self.job.progress(self._printer._running_loop().time())

    @property
    def finished(self) -> bool:
        """True once the print ended (done, cancelled or failed)."""
        return self._done.done()

    def pause(self) -> None:
        """Stop feeding lines (what is in flight completes); heaters and fans stay as they are."""
        self.job.pause()

    def resume(self) -> None:
        """Feed lines again."""
        self.job.resume(self._printer._running_loop().time())
        self._printer._flush()
        self._printer._check_print()

    async def cancel(self, script: list[str] | tuple[str, ...] = ()) -> PrintProgress:
        """Stop feeding for good, wait for what is in flight, then send `script` (e.g. heaters off).

        Raises:
            MarlinError: the print failed before it could be cancelled, or the script failed.
        """
        self.job.cancel(self._printer._running_loop().time())
        self._printer._check_print()
        progress = await self.wait()
        for command in script:
            await self._printer.send(command)
        return progress

    async def wait(self) -> PrintProgress:
        """Wait for the print to end; return its final progress.

        Raises:
            PrintStalledError: the printer stopped answering (the message says where and who was silent).
            PrinterHaltedError, PrinterResetError, ConnectionLostError: the printer or link failed mid-print.
            ResendLimitError: the link was too noisy.
            MarlinError: a line of the file could not be sent.
        """
        return await asyncio.shield(self._done)

    def __await__(self) -> Generator[object, None, PrintProgress]:
        return self.wait().__await__()


class Printer:
    """A connection to one Marlin printer. Create it with `connect()` and use it as an async context manager.

    Any number of tasks may call its coroutines at once: commands go out in the order they were sent, and each
    resolves with its own reply.

    Attributes:
        latest: the most recent temperature reading, whatever produced it (None before the first).
        firmware: the M115 identity line, once the handshake asked for it.
        capabilities: the M115 `Cap:` flags, e.g. {"AUTOREPORT_TEMP": True}.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        timeout_s: float = 10.0,
        handshake: bool = True,
        numbered: bool = True,
        max_in_flight: int = 1,
        rx_buffer_bytes: int = 128,
        boot_quiet_s: float = 0.3,
        max_hotend_celsius: float = DEFAULT_MAX_HOTEND_CELSIUS,
        max_bed_celsius: float = DEFAULT_MAX_BED_CELSIUS,
        max_chamber_celsius: float = DEFAULT_MAX_CHAMBER_CELSIUS,
        password: str | None = None,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.max_hotend_celsius = max_hotend_celsius
        self.max_bed_celsius = max_bed_celsius
        self.max_chamber_celsius = max_chamber_celsius
        self._handshake_enabled = handshake
        self._boot_quiet_s = boot_quiet_s
        if password is not None and (
            not password or not password.isascii() or any(c.isspace() or c in ";*" for c in password)
        ):
            # It travels as one word of `M511 P<password>`: no blanks, and no comment or checksum mark.
            raise ValueError("password must be one word of ASCII without ';' or '*'")
        self._password = password
        self._conn = Connection(numbered=numbered, max_in_flight=max_in_flight, rx_buffer_bytes=rx_buffer_bytes)
        self.latest: TemperatureReading | None = None
        self.firmware: FirmwareInfo | None = None
        self.capabilities: dict[str, bool] = {}
        self._targets: dict[str, float] = {}  # from Repetier-style target lines, for reports that lack targets
        #: (answered at, round trip) of the latest replies, on the loop's clock: for latency figures.
        self.round_trips: deque[tuple[float, float]] = deque(maxlen=8192)
        self._transport: asyncio.Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiters: dict[int, asyncio.Future[Reply]] = {}
        self._subscribers: list[asyncio.Queue[TemperatureReading | MarlinError]] = []
        self._timer: asyncio.TimerHandle | None = None
        self._closed: asyncio.Future[None] | None = None
        self._lost: MarlinError | None = None
        self._line_seen: asyncio.Event | None = None
        self._poll_intervals: list[float] = []  # one per active poll_temperatures(); the shortest wins
        self._poll_timer: asyncio.Handle | None = None
        self._poll_pending: Command | None = None  # the poller's M105 on its way; never more than one
        self._next_poll = 0.0
        self._halt_notified: PrinterHaltedError | None = None
        self._print: PrintHandle | None = None
        self._saved_window: tuple[int, int] | None = None
        self._connecting = False  # the handshake is under way
        #: While a print streams, polls slow down to this interval so they do not compete with the stream.
        self.print_poll_interval_s = 1.0

    # ------------------------------------------------------------------------------------------- lifecycle

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def open(self) -> None:
        """Open the port and, unless disabled, run the handshake (boot banner, sync, M115).

        Raises:
            ConnectError: the port could not be opened (its subclasses say why).
            HandshakeError: the printer did not answer the start-up sequence; `step` says where it stopped.
        """
        self._loop = asyncio.get_running_loop()
        self._closed = self._loop.create_future()
        transport, _ = await _serial.open_link(self.port, self.baudrate, lambda: _LinkProtocol(self))
        self._transport = transport
        if self._handshake_enabled:
            self._connecting = True
            try:
                await self._handshake()
            except BaseException:
                await self.close()
                raise
            finally:
                self._connecting = False

    async def close(self) -> None:
        """Close the port. Commands still waiting fail with `ConnectionLostError`; safe to call twice."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._poll_timer is not None:
            self._poll_timer.cancel()
            self._poll_timer = None
        if self._lost is None:
            self._lost = ConnectionLostError(f"the connection to {self.port} was closed")
            self._conn.fail_all(self._lost)
            self._deliver_results()
            self._notify_subscribers(self._lost)
        transport, self._transport = self._transport, None
        if transport is not None and not transport.is_closing():
            transport.close()
        if self._closed is not None and transport is not None:
            # pyserial-asyncio-fast closes the port in an executor and then calls connection_lost.
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self._closed), 2.0)

    # ------------------------------------------------------------------------------------------- handshake

    async def _handshake(self) -> None:
        loop = self._running_loop()
        # Set by every read while the banner passes; dropped afterwards so reads stop paying for it.
        line_seen = self._line_seen = asyncio.Event()
        # 1. Let the boot banner pass: many boards reset when the port opens and print for a moment. Wait until
        #    the line stream has been quiet for a short while; a board that does not reset prints nothing.
        boot_deadline = loop.time() + self.timeout_s
        while loop.time() < boot_deadline:
            line_seen.clear()
            try:
                await asyncio.wait_for(line_seen.wait(), self._boot_quiet_s)
            except TimeoutError:
                break
        self._line_seen = None
        # Flush: whatever is left of the banner (half a line, noise from the reset) must not prefix the first reply.
        if self._transport is not None:
            _serial.flush_input(self._transport)
        self._conn.discard_partial_input()
        # 2. Synchronise: M105 until one is answered (commands written during a reset are lost, so retry),
        #    then set the line counter with M110 N0. A late answer to an earlier probe is recognised as stray.
        sync_deadline = loop.time() + self.timeout_s
        while True:
            remaining = sync_deadline - loop.time()
            if remaining <= 0:
                raise HandshakeTimeoutError(self._silence_explanation(), step="sync")
            try:
                if self._conn.requires_numbers:
                    # This firmware runs only numbered lines; M110 is the one numbered line it accepts whatever
                    # its line counter says, and it sets the counter for what follows.
                    await self.send("M110 N0", timeout_s=min(1.0, remaining))
                else:
                    await self.send("M105", timeout_s=min(1.0, remaining), numbered=False)
                break
            except (CommandTimeoutError, PrinterResetError, ChecksumRequiredError):
                continue
            except PrinterLockedError:
                await self._unlock()
                continue
            except PrinterHaltedError as exc:
                raise HandshakeError(f"{exc}; reset the printer (power cycle or reset button)", step="sync") from exc
        try:
            await self._send_until_processed("M110 N0")
        except PrinterLockedError:
            await self._unlock()
            await self._send_until_processed("M110 N0")
        except CommandTimeoutError as exc:
            raise HandshakeTimeoutError(f"the printer did not answer M110 N0: {exc}", step="sync") from exc
        # 3. Identify: M115 gives the firmware name and capabilities (collected from events as they arrive).
        try:
            await self._send_until_processed("M115")
        except CommandTimeoutError as exc:
            raise HandshakeTimeoutError(f"the printer did not answer M115: {exc}", step="identify") from exc

    async def _send_until_processed(self, command: str) -> None:
        """Send a command that is harmless to run twice and whose reply lines nobody needs (M110 N0, M115), and
        return once the printer has shown that it processed it: a lost ok costs a probe, not the connection or
        the print.

        An answer to a later command proves it ran (Marlin answers in order; the connection then fails it with
        `LostReplyError`). Without one, it times out after a short wait and an M105 is written behind it: if that
        is answered, the command ran. Otherwise it is written again, until `timeout_s` has passed.

        Raises:
            CommandTimeoutError: the printer answered nothing for `timeout_s`.
        """
        loop = self._running_loop()
        deadline = loop.time() + self.timeout_s
        while True:
            step = max(min(2.0, self.timeout_s / 4, deadline - loop.time()), 0.05)
            try:
                await self.send(command, timeout_s=step)
                return
            except LostReplyError:
                return
            except CommandTimeoutError:
                if loop.time() >= deadline:
                    raise
            try:
                # Unnumbered, so a line counter the command may not have set cannot get it rejected.
                probe_timeout = max(min(2.0, self.timeout_s / 4, deadline - loop.time()), 0.05)
                await self.send("M105", timeout_s=probe_timeout, numbered=self._conn.requires_numbers)
                return  # answered behind it: the command was processed, only its ok was lost
            except (CommandTimeoutError, LostReplyError) as exc:
                if loop.time() >= deadline:
                    raise CommandTimeoutError(
                        f"no answer to {command!r} within {self.timeout_s:g} s: {exc}", command=command
                    ) from exc

    async def _unlock(self) -> None:
        """Unlock a PASSWORD_FEATURE printer with the password given to `connect()`, or fail clearly."""
        if self._password is None:
            raise PrinterLockedError(
                f"the printer on {self.port} is locked (it said 'Printer locked! (Unlock with M511 or LCD)'): "
                "connect with password=... (marlin-temp --password) to send M511 P<password>, "
                "or unlock it on its screen"
            )
        reply = await self.send(f"M511 P{self._password}", timeout_s=self.timeout_s)
        if any("incorrect" in line.lower() for line in reply.lines):
            raise PrinterLockedError(
                f"the printer on {self.port} refused the password ({' '.join(reply.lines)}); it stays locked"
            )

    def _silence_explanation(self) -> str:
        stats = self._conn.stats()
        if stats.bytes_received == 0:
            return (
                f"no answer from {self.port} within {self.timeout_s:g} s: nothing was received "
                "(is this the printer's port, and is it powered?)"
            )
        if stats.garbage_lines:
            other = 115_200 if self.baudrate != 115_200 else 250_000
            return (
                f"no answer from {self.port} within {self.timeout_s:g} s: {stats.bytes_received} bytes of garbage "
                f"received; wrong baud rate? {self.baudrate} is set, try {other}"
            )
        said = [entry.text for entry in self._conn.trace.entries() if entry.direction == "received"][-3:]
        quoted = "; it said: " + " | ".join(repr(line) for line in said) if said else ""
        return (
            f"no 'ok' from {self.port} within {self.timeout_s:g} s, though it sent {stats.bytes_received} bytes{quoted}"
        )

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float | None = None, numbered: bool | None = None) -> Reply:
        """Send one command and return its reply (the lines that came with it and its `ok`).

        Busy keepalives and M109/M190 wait lines push the deadline out, so long commands only time out when the
        printer falls silent. If the caller is cancelled before the command was written, it is never written.

        Raises:
            ValueError: the command is malformed (line break, non-ASCII, over 95 bytes, empty).
            CommandTimeoutError: no `ok` within `timeout_s` (default: the client's) without a sign of life.
            PrinterHaltedError: the printer halted (ThermalRunawayError if its thermal protection tripped).
            PrinterResetError: the printer reset before answering.
            ConnectionLostError: the link went away.
        """
        loop = self._running_loop()
        if self._lost is not None:
            raise self._lost
        entry = self._conn.submit(
            command, timeout_s=self.timeout_s if timeout_s is None else timeout_s, now=loop.time(), numbered=numbered
        )
        future: asyncio.Future[Reply] = loop.create_future()
        self._waiters[entry.id] = future
        self._flush()
        try:
            return await future
        except asyncio.CancelledError:
            self._conn.cancel(entry)
            raise
        finally:
            self._waiters.pop(entry.id, None)

    def emergency_stop(self) -> None:
        """Write M112 at once, ahead of anything queued; the printer halts and needs a reset.

        Every command still waiting fails with `PrinterHaltedError` right away.

        Raises:
            ConnectionLostError: the port is closed or lost, so M112 cannot reach the printer (cut its power).
        """
        if self._transport is None or self._lost is not None:
            reason = str(self._lost) if self._lost is not None else f"{self.port} is not open"
            raise ConnectionLostError(f"cannot send the emergency stop (M112): {reason}")
        self._transport.write(self._conn.emergency_stop(self._running_loop().time()))
        self._deliver_results()

    # ------------------------------------------------------------------------------------------- temperatures

    async def temperatures(self) -> TemperatureReading:
        """Ask for the temperatures once (M105) and return the reading.

        Raises:
            MarlinError: as `send`; also if the printer's answer holds no temperatures.
        """
        reply = await self.send("M105")
        if reply.temperatures is None or not reply.temperatures.heaters:
            raise MarlinError(f"M105 was answered without temperatures: {reply.ok.payload!r}")
        # Built from this reply, not `latest`: an auto-report arriving in the same read may already have replaced it.
        return self._reading(reply.temperatures, reply.answered_s, "poll")

    async def temperature_readings(self) -> AsyncGenerator[TemperatureReading, None]:
        """Yield every temperature report from now on, whatever produced it (polls, auto-report, wait lines).

        Nothing is dropped: each subscriber has its own unbounded queue, so keep up or stop iterating.

        Raises:
            ConnectionLostError, PrinterHaltedError, PrinterResetError: when the link or printer goes away.
        """
        queue: asyncio.Queue[TemperatureReading | MarlinError] = asyncio.Queue()
        self._subscribers.append(queue)
        try:
            if self._lost is not None:
                raise self._lost
            while True:
                item = await queue.get()
                if isinstance(item, MarlinError):
                    raise item
                yield item
        finally:
            self._subscribers.remove(queue)

    @contextlib.asynccontextmanager
    async def poll_temperatures(self, interval_s: float = 0.01, *, auto_report: bool = True) -> AsyncIterator[None]:
        """Poll M105 every `interval_s` while the block runs; read the readings with `temperature_readings()`.

        At most one M105 is in flight, the schedule is deadline-based (no drift), and a poll that falls behind a
        long command is not repeated to catch up. With `auto_report` and a firmware that has it (Cap
        AUTOREPORT_TEMP), M155 S1 is turned on as well so readings keep coming while G28/M109/M190 block the queue.

        Raises:
            ValueError: `interval_s` is not positive.
        """
        if not interval_s > 0:
            raise ValueError(f"interval_s must be positive, got {interval_s}")
        use_auto = auto_report and self.capabilities.get("AUTOREPORT_TEMP", False)
        if use_auto:
            await self.send("M155 S1")
        loop = self._running_loop()
        self._poll_intervals.append(interval_s)
        if self._poll_timer is None:
            self._next_poll = loop.time()
            self._poll_timer = loop.call_soon(self._poll_tick)
        try:
            yield
        finally:
            self._poll_intervals.remove(interval_s)
            if not self._poll_intervals and self._poll_timer is not None:
                self._poll_timer.cancel()
                self._poll_timer = None
            if use_auto and self._lost is None and self._conn.halted is None:
                with contextlib.suppress(MarlinError):
                    await self.send("M155 S0")

    def _poll_tick(self) -> None:
        """One slot of the poll schedule: send an M105 unless the last one is still unanswered.

        Driven by one timer callback rather than a task awaiting each reply: no future, no task switch and no
        sleep per poll, which halves the event-loop work at 100 Hz (it matters on a Raspberry Pi).
        """
        self._poll_timer = None
        if not self._poll_intervals or self._lost is not None:
            return
        loop = self._running_loop()
        now = loop.time()
        if self._poll_pending is None and self._conn.halted is None:
            self._poll_pending = self._conn.submit("M105", timeout_s=self.timeout_s, now=now, checked=False)
            self._flush()
        interval = min(self._poll_intervals)
        if self._print is not None and not self._print.finished:
            interval = max(interval, self.print_poll_interval_s)
        # Deadline-based, so the rate does not drift; slots missed behind a long command are skipped, not repeated.
        self._next_poll += interval
        if self._next_poll <= now:
            self._next_poll = now + interval
        self._poll_timer = loop.call_at(self._next_poll, self._poll_tick)

    async def set_temperatures(
        self,
        *,
        hotend: float | None = None,
        bed: float | None = None,
        chamber: float | None = None,
        tool: int | None = None,
    ) -> None:
        """Set heater targets (M104, M140, M141) without waiting. 0 turns a heater off.

        Every target is checked before anything is written.

        Raises:
            ValueError: a target is not a number, negative, or above the client's limit; `tool` is negative.
            MarlinError: as `send`.
        """
        commands = self._target_commands(hotend=hotend, bed=bed, chamber=chamber, tool=tool)
        for command in commands:
            await self.send(command)

    def _target_commands(
        self, *, hotend: float | None, bed: float | None, chamber: float | None, tool: int | None
    ) -> list[str]:
        _check_tool(tool)
        commands = []
        if hotend is not None:
            value = check_target("hotend", hotend, self.max_hotend_celsius)
            commands.append(f"M104 {'' if tool is None else f'T{tool} '}S{format_celsius(value)}")
        if bed is not None:
            value = check_target("bed", bed, self.max_bed_celsius)
            commands.append(f"M140 S{format_celsius(value)}")
        if chamber is not None:
            value = check_target("chamber", chamber, self.max_chamber_celsius)
            commands.append(f"M141 S{format_celsius(value)}")
        return commands

    async def wait_for_temperatures(
        self,
        *,
        hotend: float | None = None,
        bed: float | None = None,
        chamber: float | None = None,
        tool: int | None = None,
        tolerance_c: float = 2.0,
        timeout_s: float | None = None,
        poll_interval_s: float = 0.5,
    ) -> TemperatureReading:
        """Wait until heaters are within `tolerance_c` of their targets, watching readings (the queue stays free).

        Targets not given are taken from readings that arrive after the call (heaters whose target is 0 are not
        waited for). `tool` waits on that hotend (`T1:` in the reports) instead of the active one. If no poller is
        running, one polls every `poll_interval_s` while waiting.

        Raises:
            ValueError: `tolerance_c` is negative or a target is invalid.
            TemperatureTimeoutError: not reached within `timeout_s` (None waits as long as it takes).
            MarlinError: the link or the printer failed meanwhile.
        """
        if not tolerance_c >= 0:
            raise ValueError(f"tolerance_c must not be negative, got {tolerance_c}")
        _check_tool(tool)
        # `T` is whichever hotend is active; `T<n>` names one hotend (a single-hotend printer reports only `T`).
        hotend_key = "T" if tool is None else f"T{tool}"
        wanted: dict[str, float] = {}
        if hotend is not None:
            wanted[hotend_key] = check_target("hotend", hotend, self.max_hotend_celsius)
        if bed is not None:
            wanted["B"] = check_target("bed", bed, self.max_bed_celsius)
        if chamber is not None:
            wanted["C"] = check_target("chamber", chamber, self.max_chamber_celsius)

        def reached(reading: TemperatureReading) -> bool:
            heaters = dict(reading.temperatures.heaters)
            if "T0" not in heaters and "T" in heaters:
                heaters["T0"] = heaters["T"]
            targets = dict(wanted)
            if not wanted:
                names = ("T" if tool is None else hotend_key, "B", "C")
                targets = {k: h.target for k, h in heaters.items() if h.target and k in names}
            return all(
                key in heaters and abs(heaters[key].actual - target) <= tolerance_c for key, target in targets.items()
            )

        async def watch() -> TemperatureReading:
            readings = self.temperature_readings()
            try:
                # A reading from before the call may predate the targets just set: only trust it for explicit ones.
                if wanted and self.latest is not None and reached(self.latest):
                    return self.latest
                async for reading in readings:
                    if reached(reading):
                        return reading
            finally:
                await readings.aclose()
            raise ConnectionLostError(f"the connection to {self.port} ended while waiting for temperatures")

        poller = self.poll_temperatures(poll_interval_s, auto_report=False) if not self._poll_intervals else None
        async with contextlib.AsyncExitStack() as stack:
            if poller is not None:
                await stack.enter_async_context(poller)
            try:
                async with asyncio.timeout(timeout_s):
                    return await watch()
            except TimeoutError:
                latest = self.latest
                state = "no reading" if latest is None else _describe_heaters(latest)
                waited_for = ", ".join(_HEATER_NAMES.get(key, f"hotend {key[1:]}") for key in wanted) or "all heaters"
                raise TemperatureTimeoutError(
                    f"{waited_for} did not reach the target within {timeout_s:g} s ({state})"
                ) from None
        raise AssertionError("unreachable")  # pragma: no cover  (mypy cannot see that `async with` returns)

    # ------------------------------------------------------------------------------------------- printing

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool = False,
        window_bytes: int | None = None,
        check: bool = True,
        timeout_s: float | None = None,
    ) -> PrintHandle:
        """Start streaming G-code: a file path, or any iterable of lines (read lazily, so any size streams).

        Every line is numbered with a checksum (after an `M110 N0`), comments and blank lines are dropped, and lines
        the printer rejects are resent. By default one line at a time (ping-pong): each line is written after the
        ok of the one before, so no fault of the link can make a line run twice or out of place. With `send_ahead`
        several lines are in flight, never more unanswered bytes than `window_bytes` (default: the printer's
        receive buffer): faster on a clean link. After a line error it writes one line at a time again until the
        link has been clean for a while; but Marlin throws away its receive buffer when it rejects a line, and if
        that cuts the next line in two, the firmware may run the rest of it on its own. No host can prevent that
        with lines on the wire; the print then stops with a `RemoteProtocolError` that says so.
        Polls and `send()` keep working meanwhile; polls slow to `print_poll_interval_s`.

        Raises:
            ValueError: with `check`, a line of the file is not a valid command (nothing is sent).
            OSError: the file cannot be read.
            RuntimeError: a print is already running.
            MarlinError: as `send` (for the M110 that starts the print).
        """
        if self._print is not None and not self._print.finished:
            raise RuntimeError(f"a print is already running ({self._print.job.name})")
        if window_bytes is not None and not 16 < window_bytes <= 65536:
            raise ValueError(f"window_bytes must be between 17 and 65536, got {window_bytes}")
        loop = self._running_loop()
        job = PrintJob.from_path(Path(source), check=check) if isinstance(source, str | Path) else PrintJob(source)
        await self._send_until_processed("M110 N0")  # the print's numbering starts fresh
        job.start_s = loop.time()
        self._saved_window = self._conn.window
        self._conn.set_window(64 if send_ahead else 1, window_bytes or self._conn.rx_buffer_bytes)
        self._conn.attach(job, timeout_s=self.timeout_s if timeout_s is None else timeout_s)
        handle = PrintHandle(self, job, loop.create_future())
        self._print = handle
        self._flush()
        return handle

    async def print_file(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool = False,
        window_bytes: int | None = None,
        check: bool = True,
        timeout_s: float | None = None,
    ) -> PrintProgress:
        """Stream G-code to the end (see `start_print`) and return the final progress.

        Raises:
            The errors of `start_print` and `PrintHandle.wait`.
        """
        handle = await self.start_print(
            source, send_ahead=send_ahead, window_bytes=window_bytes, check=check, timeout_s=timeout_s
        )
        return await handle.wait()

    def _check_print(self) -> None:
        """Resolve the print's future once its job has ended, and give the window back."""
        handle = self._print
        if handle is None or handle._done.done() or not handle.job.finished:
            return
        if self._saved_window is not None:
            self._conn.set_window(*self._saved_window)
            self._saved_window = None
        job = handle.job
        if job.state is PrintState.FAILED and job.error is not None:
            handle._done.set_exception(job.error)
            handle._done.exception()  # a print nobody awaits must not log "exception never retrieved"
        else:
            handle._done.set_result(job.progress(self._running_loop().time()))

    # ------------------------------------------------------------------------------------------- other helpers

    async def endstops(self) -> dict[str, bool]:
        """Read the endstops (M119): {"x_min": False, "z_min": True, ...}, True meaning triggered.

        Raises:
            MarlinError: as `send`.
        """
        return parse_endstops((await self.send("M119")).lines)

    async def position(self) -> dict[str, float]:
        """Read the current position in millimetres (M114): {"X": 10.0, "Y": 20.0, "Z": 5.0, "E": 0.0}.

        Raises:
            MarlinError: as `send`; also if the reply holds no position.
        """
        reply = await self.send("M114")
        # Some firmwares answer on the ok line itself (`ok X:10.00 Y:0.00 ...`).
        position = parse_position(reply.lines) or parse_position((reply.ok.payload,))
        if position is None:
            raise MarlinError(f"M114 was answered without a position: {reply.lines!r}")
        return position

    async def set_fan(self, fraction: float, *, fan: int = 0) -> None:
        """Set a part-cooling fan's speed, from 0.0 (off, M107) to 1.0 (full, M106 S255).

        Raises:
            ValueError: `fraction` is not between 0 and 1, or `fan` is negative.
            MarlinError: as `send`.
        """
        if not (isinstance(fraction, int | float) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"fan speed must be a fraction from 0.0 to 1.0, got {fraction!r}")
        if isinstance(fan, bool) or not isinstance(fan, int) or fan < 0:
            raise ValueError(f"fan must be a non-negative integer, got {fan!r}")
        index = f" P{fan}" if fan else ""
        if fraction == 0:
            await self.send(f"M107{index}")
        else:
            await self.send(f"M106{index} S{round(fraction * 255)}")

    # ------------------------------------------------------------------------------------------- state

    @property
    def trace(self) -> Trace:
        """The last lines sent and received, with times on the event loop's clock."""
        return self._conn.trace

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link's counters (commands answered and failed, timeouts, resends, resets, lost oks,
        bytes received), taken now; it does not change afterwards."""
        return self._conn.stats()

    @property
    def send_ahead_window_bytes(self) -> int:
        """How many unanswered bytes a send-ahead print keeps on the wire by default: the printer's receive buffer
        less the room kept for a probe or a command of yours."""
        return self._conn.rx_buffer_bytes - self._conn.probe_reserve_bytes

    @contextlib.contextmanager
    def sending_ahead(self, max_in_flight: int) -> Generator[None]:
        """Let up to `max_in_flight` commands share the wire while the block runs (a benchmark's concurrent
        `send()`s); the window is restored afterwards. Commands whose answers could be confused still go one at a
        time (see `marlin_aio.connection`).

        Raises:
            ValueError: `max_in_flight` is below 1.
        """
        saved = self._conn.window
        self._conn.set_window(max_in_flight, saved[1])
        try:
            yield
        finally:
            self._conn.set_window(*saved)

    @property
    def state(self) -> LinkState:
        """Where the link stands: CONNECTING, READY, LOCKED, STOPPED (M999 resumes), HALTED (needs a reset) or
        LOST (closed, or the port went away)."""
        if self._transport is None or self._lost is not None:
            return LinkState.LOST
        if self._connecting:
            return LinkState.CONNECTING
        return self._conn.state

    @property
    def is_connected(self) -> bool:
        """True while the link is open and has not been lost."""
        return self._transport is not None and self._lost is None

    # ------------------------------------------------------------------------------------------- I/O plumbing

    def _running_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise RuntimeError("the printer is not open: use 'async with connect(...) as printer'")
        return self._loop

    def _on_data(self, data: bytes) -> None:
        loop = self._running_loop()
        now = loop.time()
        events = self._conn.receive_data(data, now)
        if events:
            if self._line_seen is not None:
                self._line_seen.set()
            for event in events:
                self._on_event(event, now)
        self._deliver_results()
        self._flush()

    def _on_event(self, event: Event, now: float) -> None:
        kind = type(event)
        if kind is Ok:
            assert isinstance(event, Ok)
            if event.temperatures is not None:
                self._publish(self._reading(event.temperatures, now, "poll"))
        elif kind is TemperatureReport:
            assert isinstance(event, TemperatureReport)
            source = "wait" if event.temperatures.waiting else "auto"
            self._publish(self._reading(event.temperatures, now, source))
        elif kind is TargetTemperature:
            assert isinstance(event, TargetTemperature)
            self._targets[event.heater] = event.celsius
        elif kind is Capability:
            assert isinstance(event, Capability)
            self.capabilities[event.name] = event.enabled
        elif kind is FirmwareInfo:
            assert isinstance(event, FirmwareInfo)
            self.firmware = event

    def _reading(self, temperatures: Temperatures, now: float, source: str) -> TemperatureReading:
        """A reading of `temperatures`, with the targets of Repetier-style `TargetExtr0:` lines filled in where the
        report itself carries none."""
        if self._targets:
            heaters = temperatures.heaters
            if any(heater.target is None for heater in heaters.values()):
                filled = {}
                for key, heater in heaters.items():
                    # `T` is the active hotend; these firmwares name hotends by number only.
                    target = self._targets.get(key, self._targets.get("T0") if key == "T" else None)
                    if heater.target is None and target is not None:
                        heater = dataclasses.replace(heater, target=target)
                    filled[key] = heater
                temperatures = Temperatures(filled, temperatures.waiting, temperatures.wait_remaining_s)
        return TemperatureReading(temperatures, now, time.time(), source)

    def _publish(self, reading: TemperatureReading) -> None:
        self.latest = reading
        for queue in self._subscribers:
            queue.put_nowait(reading)

    def _notify_subscribers(self, error: MarlinError) -> None:
        for queue in self._subscribers:
            queue.put_nowait(error)

    def _deliver_results(self) -> None:
        results = self._conn.take_results()
        for command, outcome in results:
            if command is self._poll_pending:
                self._poll_pending = None  # answered, timed out or failed: the next slot may poll again
                continue
            future = self._waiters.get(command.id)
            if future is None or future.done():
                continue
            if isinstance(outcome, Reply):
                self.round_trips.append((outcome.answered_s, outcome.latency_s))
                future.set_result(outcome)
            else:
                future.set_exception(outcome)
        if self._print is not None:
            self._check_print()
        halted = self._conn.halted
        if halted is not None and halted is not self._halt_notified:
            # Readers of temperatures learn of a halt even when no command was waiting for an answer.
            self._halt_notified = halted
            self._notify_subscribers(halted)
        self._arm_timer()

    def _flush(self) -> None:
        if self._transport is None or self._lost is not None or not self._conn.has_data_to_send:
            return
        data = self._conn.data_to_send(self._running_loop().time())
        if data:
            self._transport.write(data)
            self._arm_timer()

    def _arm_timer(self) -> None:
        deadline = self._conn.next_deadline()
        if deadline is None:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            return
        # Keep an earlier timer: when it fires it re-arms for the real deadline. That makes the common case (the
        # deadline moving later with every answer) free of timer churn.
        if self._timer is not None and self._timer.when() <= deadline:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self._running_loop().call_at(deadline, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        self._conn.check_timeouts(self._running_loop().time())
        self._deliver_results()
        self._flush()

    def _on_connection_lost(self, exc: Exception | None) -> None:
        if self._lost is None:
            reason = f": {exc}" if exc is not None else ""
            self._lost = ConnectionLostError(f"the connection to {self.port} was lost{reason}")
            self._conn.fail_all(self._lost)
            self._deliver_results()
            self._notify_subscribers(self._lost)
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._transport = None
        if self._closed is not None and not self._closed.done():
            self._closed.set_result(None)


def _check_tool(tool: int | None) -> None:
    if tool is not None and (isinstance(tool, bool) or not isinstance(tool, int) or tool < 0):
        raise ValueError(f"tool must be a non-negative integer, got {tool!r}")


#: Names for the heaters a wait can name; hotends by number are "hotend <n>".
_HEATER_NAMES = {"T": "hotend", "B": "bed", "C": "chamber"}


def _describe_heaters(reading: TemperatureReading) -> str:
    parts = []
    heaters = reading.temperatures.heaters
    for key, heater in heaters.items():
        if key == "T" and "T0" in heaters:
            continue  # the active hotend appears again under its number
        if key[:1] in ("T", "B", "C") and heater.target is not None and not math.isnan(heater.actual):
            parts.append(f"{key} {heater.actual:.1f}/{heater.target:.0f} C")
    return ", ".join(parts) or "no heaters reported"


def connect(
    port: str,
    *,
    baudrate: int = DEFAULT_BAUDRATE,
    timeout_s: float = 10.0,
    handshake: bool = True,
    numbered: bool = True,
    max_in_flight: int = 1,
    rx_buffer_bytes: int = 128,
    max_hotend_celsius: float = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed_celsius: float = DEFAULT_MAX_BED_CELSIUS,
    max_chamber_celsius: float = DEFAULT_MAX_CHAMBER_CELSIUS,
    password: str | None = None,
) -> Printer:
    """Return a `Printer` for `port` (a device path or a pyserial URL); open it with `async with`.

    `timeout_s` bounds each handshake step and, by default, the wait for each command's `ok` (busy keepalives
    extend it). `numbered` sends every command with a line number and checksum, so corrupted lines are resent.
    `password` unlocks a printer with Marlin's PASSWORD_FEATURE during the handshake (M511); without it, a locked
    printer fails the handshake with `PrinterLockedError`.
    """
    return Printer(
        port,
        baudrate=baudrate,
        timeout_s=timeout_s,
        handshake=handshake,
        numbered=numbered,
        max_in_flight=max_in_flight,
        rx_buffer_bytes=rx_buffer_bytes,
        max_hotend_celsius=max_hotend_celsius,
        max_bed_celsius=max_bed_celsius,
        max_chamber_celsius=max_chamber_celsius,
        password=password,
    )
