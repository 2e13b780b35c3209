"""The asyncio client: `async with connect(url) as printer: await printer.send("G28")`.

`Printer` is a thin front over small collaborators, each in its own module: `marlin_aio.aio.link.Link` (the port, the
protocol core and the callers' futures), `marlin_aio.aio.handshake` (the start-up sequence), `marlin_aio.aio.feed`
(temperature readings to every subscriber), `marlin_aio.aio.poller` (M105 on a schedule) and
`marlin_aio.aio.printhandle` (a print in progress). All protocol decisions live in `marlin_aio.protocol.connection`.
Loop-bound objects are created in `open()`, never in `__init__`, so a `Printer` can be built outside a running
loop. No user code runs in the read path: what the link reads only resolves futures, updates state and queues
readings; `on_reading` callbacks run from the loop right after the read (see `marlin_aio.aio.feed`), and one that
raises is logged, never able to stop the link. (Over 400 lines because it is the API
reference: about a third of it is the docstrings of `Printer`'s public methods; the logic behind them lives in the
collaborators.)
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import AsyncGenerator, AsyncIterator, Callable, Generator, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import TracebackType
from typing import Literal, Self

from marlin_aio.aio.feed import TemperatureFeed
from marlin_aio.aio.gcodefile import job_from_path
from marlin_aio.aio.handshake import BAUD_RATES, handshake, send_until_processed
from marlin_aio.aio.link import Link
from marlin_aio.aio.poller import Poller
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.aio.wirelog import WireLog, WireSession
from marlin_aio.errors import ConnectionLostError, MarlinError, PrinterHaltedError, TemperatureTimeoutError
from marlin_aio.protocol.commands import (
    DEFAULT_MAX_BED_CELSIUS,
    DEFAULT_MAX_CHAMBER_CELSIUS,
    DEFAULT_MAX_HOTEND_CELSIUS,
)
from marlin_aio.protocol.connection import Connection, Reply
from marlin_aio.protocol.events import BusyKeepalive, Capability, Event, FirmwareInfo, HostAction, Ok, Start
from marlin_aio.protocol.heaters import (
    HeaterLimits,
    describe_heaters,
    target_commands,
    targets_reached,
    wanted_targets,
)
from marlin_aio.protocol.hostrequests import (
    PRINT_CANCELS,
    PRINT_PAUSES,
    PRINT_RESUMES,
    HostRequest,
    HostRequests,
    Prompt,
)
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.motion import (
    command_timeout_s,
    disable_motors_command,
    extrude_commands,
    home_command,
    move_commands,
)
from marlin_aio.protocol.parsing import parse_endstops, parse_position
from marlin_aio.protocol.printjob import PrintJob, PrintProgress, gcode_commands
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.temperatures import ReadingSource, TemperatureReading, heater_name
from marlin_aio.protocol.trace import Trace

__all__ = ["BAUD_RATES", "DEFAULT_BAUDRATE", "LinkEvent", "PrintHandle", "Printer", "connect"]


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """Something that happened to a printer's link, for `Printer.on_link_event`.

    `kind` is `connected` (the handshake is done), `reset` (the board restarted while connected: it printed
    `start`, and its targets and settings are gone), `halted` (a kill or emergency stop: it needs a reset; `error`
    says why) or `disconnected` (the port went away, or was closed, `close()` included; `error` says why).
    `message` says it for people.
    """

    kind: Literal["connected", "reset", "halted", "disconnected"]
    message: str
    error: MarlinError | None = None
    time_s: float = field(default_factory=time.time)
    """Wall-clock time (epoch seconds)."""


DEFAULT_BAUDRATE = BAUD_RATES[0]

#: A port that starts with this names a printer of `marlin-temp serve` (`serve:NAME`), not a device.
SERVE_PREFIX = "serve:"

_log = logging.getLogger("marlin_aio")


def _limit(name: str, celsius: float) -> float:
    """A heater limit as given, if it is a positive finite number of degrees.

    Raises:
        ValueError: it is not.
    """
    if isinstance(celsius, bool) or not isinstance(celsius, int | float) or not 0 < celsius < float("inf"):
        raise ValueError(f"{name} must be a positive number of degrees Celsius, got {celsius!r}")
    return float(celsius)


class Printer:
    """A connection to one Marlin printer: `async with connect(port, ...) as printer:` (or `Printer(port, ...)`).

    Any number of tasks may call its coroutines at once: commands go out in the order they were sent, and each
    resolves with its own reply. A printer that was closed can be opened again (`async with` once more).

    Args:
        port: a device path (`/dev/ttyUSB0`) or a pyserial URL (`socket://host:port`).
        baudrate: the port's speed.
        timeout_s: bounds each handshake step and, by default, the wait for each command's `ok` (busy keepalives
            extend it).
        handshake: run the start-up sequence (banner, sync, M110, M115) when the port opens.
        numbered: send every command with a line number and checksum, so corrupted lines are resent.
        max_in_flight: how many commands may be on the wire at once outside prints (1: ping-pong).
        rx_buffer_bytes: the printer's serial receive buffer; unanswered bytes never exceed it.
        boot_quiet_s: how long the line stream must be quiet before the boot banner is taken as over.
        max_hotend_celsius: the highest hotend target accepted (however the G-code spells it).
        max_bed_celsius: the highest bed target accepted.
        max_chamber_celsius: the highest chamber target accepted.
        password: unlocks a printer with Marlin's PASSWORD_FEATURE during the handshake (M511); without it, a
            locked printer fails the handshake with `PrinterLockedError`.
        wire_log: write every line sent and received, with times, to this log (`marlin_aio.aio.WireLog`), from
            the handshake on; passwords redacted. A `serve:NAME` printer's wire is the service's: nothing is
            written for it here.

    Attributes:
        firmware: the M115 identity line, once the handshake asked for it.
        capabilities: the M115 `Cap:` flags, e.g. {"AUTOREPORT_TEMP": True}.
        print_poll_interval_s: while a print streams, polls slow down to this interval.

    Raises:
        ValueError: `timeout_s` is not positive, or the password cannot travel in M511.
    """

    def __new__(cls, port: str, *args: object, **kwargs: object) -> Self:
        # `Printer("serve:NAME")` is a printer that a `marlin-temp serve` process owns: the same API, spoken to the
        # service over its socket (`marlin_aio.aio.served`), so every program written for a port works with it.
        if cls is Printer and isinstance(port, str) and port.startswith(SERVE_PREFIX):
            from marlin_aio.aio.served import ServedPrinter

            return ServedPrinter.__new__(ServedPrinter, port)  # type: ignore[return-value]
        return super().__new__(cls)

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
        wire_log: WireLog | None = None,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        if password is not None and (
            not password or not password.isascii() or any(c.isspace() or c in ";*" for c in password)
        ):
            # It travels as one word of `M511 P<password>`: no blanks, and no comment or checksum mark.
            raise ValueError("password must be one word of ASCII without ';' or '*'")
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self._heater_limits = HeaterLimits(
            _limit("max_hotend_celsius", max_hotend_celsius),
            _limit("max_bed_celsius", max_bed_celsius),
            _limit("max_chamber_celsius", max_chamber_celsius),
        )
        self._handshake_enabled = handshake
        self._boot_quiet_s = boot_quiet_s
        self._password = password
        self._window = (max_in_flight, rx_buffer_bytes)
        self._numbered = numbered
        self._wire_log = wire_log
        self._wire: WireSession | None = None
        self.firmware: FirmwareInfo | None = None
        self.capabilities: dict[str, bool] = {}
        self.print_poll_interval_s = 1.0
        self._feed = TemperatureFeed()
        self._link = self._new_link()
        self._poller = Poller(self._link, timeout_s, self._poll_slow_down)
        self._print: PrintHandle | None = None
        self._connecting = False  # the handshake is under way
        self._reset_on_open = False
        self._failure_waiters: list[asyncio.Future[MarlinError]] = []
        self._link_listeners: list[Callable[[LinkEvent], None]] = []
        self._requests = HostRequests()
        self._request_listeners: list[Callable[[HostRequest], None]] = []
        self._request_queues: list[asyncio.Queue[HostRequest | MarlinError]] = []  # of `host_requests()` readers

    @property
    def heater_limits(self) -> HeaterLimits:
        """The three limits below as one `HeaterLimits`: what every command and print line is checked against."""
        return self._heater_limits

    @property
    def max_hotend_celsius(self) -> float:
        """The highest hotend target any command may set (checked as the firmware reads each command)."""
        return self._heater_limits.hotend

    @max_hotend_celsius.setter
    def max_hotend_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, hotend=_limit("max_hotend_celsius", celsius)))

    @property
    def max_bed_celsius(self) -> float:
        """The highest bed target any command may set."""
        return self._heater_limits.bed

    @max_bed_celsius.setter
    def max_bed_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, bed=_limit("max_bed_celsius", celsius)))

    @property
    def max_chamber_celsius(self) -> float:
        """The highest chamber target any command may set."""
        return self._heater_limits.chamber

    @max_chamber_celsius.setter
    def max_chamber_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, chamber=_limit("max_chamber_celsius", celsius)))

    def _set_limits(self, limits: HeaterLimits) -> None:
        self._heater_limits = limits
        self._connection.limits = limits  # the connection is the gate every command and print line passes

    def _new_link(self) -> Link:
        connection = Connection(
            numbered=self._numbered,
            max_in_flight=self._window[0],
            rx_buffer_bytes=self._window[1],
            limits=self._heater_limits,
        )
        self._connection = connection
        return Link(
            self.port,
            self.baudrate,
            connection,
            on_event=self._on_event,
            on_failure=self._failed,
            after_results=self._after_results,
            after_read=self._feed.deliver,
        )

    def _failed(self, error: MarlinError) -> None:
        # The printer halted or the link went away: readers of temperatures and `wait_for_failure()` learn of it.
        self._feed.fail(error)
        waiters, self._failure_waiters = self._failure_waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(error)
        kind: Literal["halted", "disconnected"] = "halted" if isinstance(error, PrinterHaltedError) else "disconnected"
        self._link_event(LinkEvent(kind, str(error), error))
        for queue in self._request_queues:
            # After the requests already scheduled (a disconnect request comes before the loss it causes).
            self._link.loop.call_soon(queue.put_nowait, error)

    def on_link_event(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        """Call `callback` with each `LinkEvent` from now on (connected, reset, halted, disconnected); return the
        function that stops the calls.

        A supervisor learns of a board reset here as it happens, instead of polling `stats.resets`. It is called on
        the event loop, soon after the line that told (never inside the link's read handler); if it raises, the
        error is logged (logger "marlin_aio") and the link and the other listeners go on.
        """
        self._link_listeners.append(callback)

        def stop() -> None:
            if callback in self._link_listeners:
                self._link_listeners.remove(callback)

        return stop

    def _link_event(self, event: LinkEvent) -> None:
        if self._link_listeners:
            self._link.loop.call_soon(self._tell_link_listeners, event)

    def _tell_link_listeners(self, event: LinkEvent) -> None:
        for listener in list(self._link_listeners):
            try:
                listener(event)
            except Exception:  # a listener's bug must not reach the link
                _log.exception("a link event listener failed on %s", event.kind)

    # ------------------------------------------------------------------------------------------- lifecycle

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def open(self) -> None:
        """Open the port and, unless disabled, run the handshake. A closed printer opens afresh.

        Raises:
            RuntimeError: the printer is already open.
            ConnectError: the port could not be opened (its subclasses say why).
            HandshakeError: the printer did not answer the start-up sequence; `step` says where it stopped.
        """
        if self._link.is_open:
            raise RuntimeError(f"the printer on {self.port} is already open")
        if self._link.lost is not None:
            # Closed before: a fresh link, counters and all, on the same port.
            self._link = self._new_link()
            self._poller = Poller(self._link, self.timeout_s, self._poll_slow_down)
            self._print = None
            self._requests = HostRequests()
        # Connecting from before the port opens: a boot banner read the moment it is open is the handshake's, never
        # a reset of a connected printer.
        self._connecting = self._handshake_enabled
        if self._wire_log is not None:
            self._end_wire("closed")  # a session of an earlier open that was never closed
            self._wire = self._wire_log.connection(self.port, self.baudrate)
            self._connection.trace.tap = self._wire.line
        try:
            try:
                await self._link.open()
            except BaseException as exc:
                self._end_wire(f"not opened ({exc})")
                raise
            _log.info("opened %s at %d baud", self.port, self.baudrate)
            if not self._handshake_enabled:
                return
            try:
                self._reset_on_open = await handshake(
                    self._link, timeout_s=self.timeout_s, boot_quiet_s=self._boot_quiet_s, password=self._password
                )
            except BaseException as exc:
                self._end_wire(f"closed: the handshake failed ({exc})")
                await self.close()
                raise
        finally:
            self._connecting = False
        _log.info("connected to %s: %s", self.port, self.firmware.name if self.firmware else "unknown firmware")
        self._link_event(
            LinkEvent("connected", f"{self.port} ({self.firmware.name if self.firmware else 'firmware unknown'})")
        )
        if self._reset_on_open:
            _log.warning("the board on %s reset when the port was opened; targets set earlier were cleared", self.port)

    @property
    def reset_on_open(self) -> bool:
        """True if the board reset as this connection opened the port (it printed its boot banner): targets, fan
        and other settings made by an earlier connection are gone.

        Boards whose USB bridge wires DTR to reset do this on the first open after plugging in; later opens by
        this library leave DTR raised (HUPCL cleared) so they keep running, where the platform allows it.
        """
        return self._reset_on_open

    async def close(self) -> None:
        """Close the port. Commands still waiting fail with `ConnectionLostError`; safe to call twice."""
        self._poller.cancel()
        await self._link.close()
        lost = self._link.lost
        self._end_wire("closed" if lost is None or "was closed" in str(lost) else f"closed after: {lost}")

    def _end_wire(self, reason: str) -> None:
        wire, self._wire = self._wire, None
        if wire is not None:
            self._connection.trace.tap = None
            wire.end(reason)

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float | None = None, numbered: bool | None = None) -> Reply:
        """Send one command and return its reply (the lines that came with it and its `ok`).

        Busy keepalives and M109/M190 wait lines push the deadline out, so long commands only time out when the
        printer falls silent. If the caller is cancelled before the command was written, it is never written.

        Raises:
            ValueError: the command is malformed (line break, non-ASCII, over 95 bytes, empty), or it sets a
                target above the client's limits (`M104 S300` with `max_hotend_celsius=260`), as
                `set_temperatures` would refuse it.
            CommandTimeoutError: no `ok` within `timeout_s` (default: the client's) without a sign of life.
            PrinterHaltedError: the printer halted (ThermalRunawayError if its thermal protection tripped).
            PrinterResetError: the printer reset before answering.
            LostReplyError: the command ran, but its reply cannot be proven its own (an ok was lost).
            ConnectionLostError: the link went away.
        """
        return await self._link.send(
            command, timeout_s=self.timeout_s if timeout_s is None else timeout_s, numbered=numbered
        )

    def emergency_stop(self) -> None:
        """Write M112 at once, ahead of anything queued; the printer halts and needs a reset.

        Every command still waiting fails with `PrinterHaltedError` right away.

        Raises:
            ConnectionLostError: the port is closed or lost, so M112 cannot reach the printer (cut its power).
        """
        self._link.emergency_stop()
        _log.warning("emergency stop (M112) sent to %s", self.port)

    def interrupt_wait(self) -> bool:
        """End a heater wait (M109, M190, M191) or a pause (M0/M1) now, if the firmware can: write M108 at once,
        ahead of anything queued, and return True. Only Marlin's emergency parser (M115's `Cap:EMERGENCY_PARSER:1`)
        reads M108 while a wait blocks; without it nothing is written and this returns False (the wait runs to its
        end, and the M108 would only run after it).

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        if not self.capabilities.get("EMERGENCY_PARSER", False):
            return False
        self._link.interrupt_wait()
        _log.info("M108 sent to %s to end a wait", self.port)
        return True

    async def home(self, *axes: str, timeout_s: float | None = None) -> Reply:
        """Home the axes given (`home()` homes all, `home("x", "y")` two) with G28; return its reply.

        Homing is answered only when it is done, so unless `timeout_s` says otherwise the wait is at least
        `LONG_COMMAND_TIMEOUT_S` (3 minutes), for boards that stay silent meanwhile (see `marlin_aio.protocol.motion`).

        Raises:
            ValueError: an axis is not X, Y or Z.
            MarlinError: as `send`.
        """
        command = home_command(axes)
        if timeout_s is None:
            timeout_s = command_timeout_s(command, self.timeout_s)
        return await self.send(command, timeout_s=timeout_s)

    async def move(
        self,
        *,
        x: float | None = None,
        y: float | None = None,
        z: float | None = None,
        feedrate_mm_min: float | None = None,
        relative: bool = False,
        timeout_s: float | None = None,
    ) -> Reply:
        """Move in a straight line to (`x`, `y`, `z`) in millimetres, or by that much with `relative`; return the
        move's reply. Marlin answers once the move is planned, not when it is done (M400 waits for that).

        The mode is sent with the move (G90 or G91 before it) and the printer is left in absolute mode.
        `feedrate_mm_min` is G-code's `F`; without it the printer's current speed is used.

        Raises:
            ValueError: no axis given, a coordinate is not a finite number, the feed rate is not positive, ...
                (nothing is sent).
            MarlinError: as `send`.
        """
        commands = move_commands(x=x, y=y, z=z, feedrate_mm_min=feedrate_mm_min, relative=relative)
        return (await self._send_together(commands, timeout_s))[1]

    async def extrude(
        self, length_mm: float, *, feedrate_mm_min: float = 300.0, timeout_s: float | None = None
    ) -> Reply:
        """Push `length_mm` of filament through the hotend (negative retracts) at `feedrate_mm_min`; return the
        move's reply. Marlin refuses below its minimum extrusion temperature and says so in the reply's lines.

        Raises:
            ValueError: the length is 0 or not a finite number, the feed rate is not positive, ... (nothing is sent).
            MarlinError: as `send`.
        """
        commands = extrude_commands(length_mm, feedrate_mm_min=feedrate_mm_min)
        return (await self._send_together(commands, timeout_s))[1]

    async def disable_motors(self, *axes: str) -> Reply:
        """Turn the stepper motors of the axes given (X, Y, Z, E) off with M84, or all of them; return its reply.

        Marlin finishes the moves already planned first. The position is lost: home again before moving.

        Raises:
            ValueError: an axis is not X, Y, Z or E.
            MarlinError: as `send`.
        """
        return await self.send(disable_motors_command(axes))

    async def _send_together(self, commands: list[str], timeout_s: float | None) -> list[Reply]:
        # Each `send` queues its command before its first await, so gathering them queues these back to back: no
        # other task's command can land between a G91 and the move it is meant for.
        return await asyncio.gather(*(self.send(command, timeout_s=timeout_s) for command in commands))

    # ------------------------------------------------------------------------------------------- temperatures

    @property
    def latest(self) -> TemperatureReading | None:
        """The most recent temperature reading, whatever produced it (None before the first)."""
        return self._feed.latest

    async def read_temperatures(self) -> TemperatureReading:
        """Ask for the temperatures once (M105) and return the reading.

        Raises:
            MarlinError: as `send`; also if the printer's answer holds no temperatures.
        """
        reply = await self.send("M105")
        if reply.temperatures is None or not reply.temperatures.heaters:
            raise MarlinError(f"M105 was answered without temperatures: {reply.ok.payload!r}")
        # Built from this reply, not `latest`: an auto-report arriving in the same read may already have replaced it.
        return self._feed.reading(reply.temperatures, reply.answered_s, ReadingSource.POLL)

    async def temperatures(self) -> TemperatureReading:
        """The same as `read_temperatures()` (the older name)."""
        return await self.read_temperatures()

    def temperature_readings(self) -> AsyncGenerator[TemperatureReading, None]:
        """Yield every temperature report from now on, whatever produced it (polls, auto-report, wait lines).

        Each reader has its own queue of up to 1,000 readings; one that falls further behind loses its oldest
        readings (counted in `readings_dropped`), never the error that ends them.

        Raises:
            ConnectionLostError, PrinterHaltedError, PrinterResetError: when the link or printer goes away.
        """
        return self._feed.readings(self._link.lost)

    def on_reading(self, callback: Callable[[TemperatureReading], None]) -> Callable[[], None]:
        """Call `callback` with every temperature reading from now on; return the function that stops the calls
        (at once: no reading reaches it after that, not even one already read).

        It is called from the event loop soon after each read, outside the link's read handler: the readings of one
        read are handed over in one `loop.call_soon`, before a task awaiting the command that brought them resumes
        (no queue and no task wake-up per reading: the cheapest way to follow 100 Hz polling). It runs on the
        loop, so keep it short and do not block. If it raises, the error is logged once for this callback (logger
        "marlin_aio", WARNING, with its name and traceback) and then only counted in `callback_errors`; it stays
        subscribed, and neither the link, the polls nor the other callbacks and readers notice.
        """
        return self._feed.add_callback(callback)

    @property
    def callback_errors(self) -> int:
        """Exceptions raised by `on_reading` callbacks (each callback's first is logged, the rest only counted)."""
        return self._feed.callback_errors

    @property
    def readings_dropped(self) -> int:
        """Readings dropped because a reader of `temperature_readings()` fell more than 1,000 behind."""
        return self._feed.dropped

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
        poller = self._poller
        poller.start(interval_s)
        try:
            yield
        finally:
            poller.stop(interval_s)
            if use_auto and self._link.lost is None and self._link.halted is None:
                with contextlib.suppress(MarlinError):
                    await self.send("M155 S0")

    def _polled(self) -> bool:
        """True while readings come without asking (a poller runs)."""
        return self._poller.active

    def _poll_slow_down(self) -> float | None:
        return self.print_poll_interval_s if self._print is not None and not self._print.finished else None

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
        for command in target_commands(self._heater_limits, hotend=hotend, bed=bed, chamber=chamber, tool=tool):
            await self.send(command)

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
        wanted = wanted_targets(self._heater_limits, hotend=hotend, bed=bed, chamber=chamber, tool=tool)

        async def watch() -> TemperatureReading:
            readings = self.temperature_readings()
            try:
                # A reading from before the call may predate the targets just set: only trust it for explicit ones.
                latest = self.latest
                if wanted and latest is not None and targets_reached(latest, wanted, tool, tolerance_c):
                    return latest
                async for reading in readings:
                    if targets_reached(reading, wanted, tool, tolerance_c):
                        return reading
            finally:
                await readings.aclose()
            raise ConnectionLostError(f"the connection to {self.port} ended while waiting for temperatures")

        poller = self.poll_temperatures(poll_interval_s, auto_report=False) if not self._polled() else None
        async with contextlib.AsyncExitStack() as stack:
            if poller is not None:
                await stack.enter_async_context(poller)
            try:
                async with asyncio.timeout(timeout_s):
                    return await watch()
            except TimeoutError:
                latest = self.latest
                state = "no reading" if latest is None else describe_heaters(latest)
                waited_for = ", ".join(heater_name(key) for key in wanted) or "all heaters"
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
        link = self._link
        if isinstance(source, str | Path):
            # A file is read whole to be checked before its first line: millions of lines take seconds, which must
            # not stall the event loop (other printers, polls, a service's clients) meanwhile.
            job = await asyncio.to_thread(self._print_job, source, check)
        else:
            job = self._print_job(source, check)
        await send_until_processed(link, "M110 N0", timeout_s=self.timeout_s)  # the print's numbering starts fresh
        job.start_s = link.now()
        saved = link.window
        link.set_window(64 if send_ahead else 1, window_bytes or saved[1])
        handle = PrintHandle(link, job, self.timeout_s, saved)
        self._print = handle
        link.attach(job, timeout_s=self.timeout_s if timeout_s is None else timeout_s)
        _log.info("print of %s started (%s)", job.name, "send-ahead" if send_ahead else "ping-pong")
        return handle

    def _print_job(self, source: str | Path | Iterable[str], check: bool) -> PrintJob:
        """The job for `source`, checked whole first where it can be read twice (a path, a list of lines)."""
        limits = self._heater_limits
        if isinstance(source, str | Path):
            return job_from_path(Path(source), check=check, limits=limits)
        if check and isinstance(source, Sequence):
            # Before the first line is sent, as for a file: a list over the limits is refused whole, and counted in
            # the same pass. (An iterator can be read only once: each of its lines is checked as it is fed, and a
            # bad one stops the print.)
            commands = sum(1 for _ in gcode_commands(source, limits))
            return PrintJob(source, lines_total=commands, limits=limits)
        return PrintJob(source, limits=limits)

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
            MarlinError: as `start_print` and `PrintHandle.wait` raise them (and ValueError, OSError, RuntimeError
                from `start_print`).
        """
        handle = await self.start_print(
            source, send_ahead=send_ahead, window_bytes=window_bytes, check=check, timeout_s=timeout_s
        )
        return await handle.wait()

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
        return self._link.trace

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link's counters (commands answered and failed, timeouts, resends, resets, lost oks,
        bytes received), taken now; it does not change afterwards."""
        return self._link.stats()

    @property
    def round_trips(self) -> deque[tuple[float, float]]:
        """(answered at, round trip) of the latest replies (up to 8,192), polls included, on the loop's clock:
        latency figures."""
        return self._link.round_trips

    @property
    def send_ahead_window_bytes(self) -> int:
        """How many unanswered bytes a send-ahead print keeps on the wire by default: the printer's receive buffer
        less the room kept for a probe or a command of yours."""
        return self._link.send_ahead_window_bytes

    @contextlib.contextmanager
    def sending_ahead(self, max_in_flight: int) -> Generator[None]:
        """Let up to `max_in_flight` commands share the wire while the block runs (a benchmark's concurrent
        `send()`s); the window is restored afterwards. Commands whose answers could be confused still go one at a
        time (see `marlin_aio.protocol.matching`).

        Raises:
            ValueError: `max_in_flight` is below 1.
        """
        saved = self._link.window
        self._link.set_window(max_in_flight, saved[1])
        try:
            yield
        finally:
            self._link.set_window(*saved)

    @property
    def state(self) -> LinkState:
        """Where the link stands: CONNECTING, READY, LOCKED, STOPPED (M999 resumes), HALTED (needs a reset) or
        LOST (closed, or the port went away)."""
        state = self._link.state
        return LinkState.CONNECTING if self._connecting and state is not LinkState.LOST else state

    @property
    def is_connected(self) -> bool:
        """True while the link is open and has not been lost."""
        return self._link.is_open

    async def wait_for_failure(self) -> MarlinError:
        """Wait until the printer halts or the link is lost or closed, and return why (the error commands fail with
        from then on); at once if that has happened already. For a supervisor that keeps a printer connected: no
        task wakes up per reading while it waits.
        """
        failure = self._failure()
        if failure is not None:
            return failure
        waiter: asyncio.Future[MarlinError] = asyncio.get_running_loop().create_future()
        self._failure_waiters.append(waiter)
        try:
            return await waiter
        finally:
            if waiter in self._failure_waiters:
                self._failure_waiters.remove(waiter)

    def _failure(self) -> MarlinError | None:
        """Why the printer can take no more commands (the link lost, the printer halted), or None."""
        return self._link.lost if self._link.lost is not None else self._link.halted

    # ------------------------------------------------------------------------------------------- firmware requests

    @property
    def prompt(self) -> Prompt | None:
        """The prompt the firmware shows for a person (HOST_PROMPT_SUPPORT), with its buttons, or None.

        Answer it with `answer_prompt(index)`; the firmware closes it with `//action:prompt_end`.
        """
        return self._requests.prompt

    @property
    def waiting_for_user(self) -> bool:
        """True while a command waits for a person (`echo:busy: paused for user`: M600, M0/M1), until it ends."""
        return self._requests.waiting_for_user

    @property
    def last_host_request(self) -> HostRequest | None:
        """The firmware's last pause, paused, resume, resumed, cancel or disconnect request, or None."""
        return self._requests.last

    def on_host_request(self, callback: Callable[[HostRequest], None]) -> Callable[[], None]:
        """Call `callback` with each `HostRequest` from now on (prompts shown and closed, pause, resume, cancel,
        disconnect, `paused for user`); return the function that stops the calls.

        It is called on the event loop soon after the line that asked (never inside the link's read handler); if
        it raises, the error is logged (logger "marlin_aio") and the link and the other listeners go on.
        """
        self._request_listeners.append(callback)

        def stop() -> None:
            if callback in self._request_listeners:
                self._request_listeners.remove(callback)

        return stop

    async def host_requests(self) -> AsyncGenerator[HostRequest, None]:
        """Yield each `HostRequest` from now on (see `on_host_request`), until the link ends.

        Raises:
            MarlinError: the link was lost or closed, or the printer halted (at once if it already was).
        """
        queue: asyncio.Queue[HostRequest | MarlinError] = asyncio.Queue()
        stop = self.on_host_request(queue.put_nowait)
        self._request_queues.append(queue)
        try:
            failure = self._failure()
            if failure is not None:
                raise failure
            while True:
                item = await queue.get()
                if isinstance(item, MarlinError):
                    raise item
                yield item
        finally:
            stop()
            self._request_queues.remove(queue)

    async def answer_prompt(self, index: int) -> None:
        """Answer the open prompt with its button `index` (0 the first): `M876 S<index>`.

        With the firmware's EMERGENCY_PARSER (its M115 says so) it is written at once, ahead of anything queued,
        as a printer waiting for a person (M600) reads nothing else; without, it is sent like any command.

        Raises:
            ValueError: no prompt is open, or it has no button `index` (nothing is written).
            MarlinError: as `send`.
        """
        prompt = self._requests.prompt
        if prompt is None:
            raise ValueError("no prompt is open: there is nothing to answer")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(prompt.buttons):
            buttons = ", ".join(f"{number} {label}" for number, label in enumerate(prompt.buttons)) or "none"
            raise ValueError(f"the prompt {prompt.message!r} has no button {index!r} (its buttons: {buttons})")
        command = f"M876 S{index}"
        if self.capabilities.get("EMERGENCY_PARSER"):
            self._link.write_emergency(command)
        else:
            await self.send(command)
        self._requests.answered()

    def _host_request(self, request: HostRequest, now: float) -> None:
        """Act on a request of the firmware (in the read path: only state changes here, the rest is scheduled)."""
        _log.info("the printer asked: //action:%s %s", request.action, request.argument)
        handle = self._print
        if handle is not None and not handle.finished:
            job = handle.job
            if request.action in PRINT_PAUSES:
                job.pause(request.reason)
            elif request.action in PRINT_RESUMES:
                # Resuming writes the next line: from the loop, not from inside this read's step.
                self._link.loop.call_soon(handle.resume)
            elif request.action in PRINT_CANCELS:
                job.cancel(now, request.reason)
        if request.action == "disconnect":
            self._link.loop.call_soon(self._disconnect_requested, request)
        if self._request_listeners:
            self._link.loop.call_soon(self._tell_request_listeners, request)

    def _disconnect_requested(self, request: HostRequest) -> None:
        self._poller.cancel()
        extra = f" ({request.argument})" if request.argument else ""
        self._link.drop(ConnectionLostError(f"the printer asked the host to disconnect (//action:disconnect{extra})"))

    def _tell_request_listeners(self, request: HostRequest) -> None:
        for listener in list(self._request_listeners):
            try:
                listener(request)
            except Exception:  # a listener's bug must not reach the link
                _log.exception("a host request listener failed on %s", request.action)

    # ------------------------------------------------------------------------------------------- events

    def _on_event(self, event: Event, now: float) -> None:
        if type(event) is Ok:  # most events are oks (a hundred polls a second): no pattern to try first
            self._feed.on_event(event, now)
            if self._requests.waiting_for_user:
                self._requests.receive(event)
            return
        if isinstance(event, HostAction | BusyKeepalive):
            request = self._requests.receive(event)
            if request is not None:
                self._host_request(request, now)
        match event:
            case Capability(name=name, enabled=enabled):
                self.capabilities[name] = enabled
            case FirmwareInfo():
                self.firmware = event
            case Start() if not self._connecting:
                # The boot banner during the handshake is the handshake's; after it, the board restarted.
                self._link_event(LinkEvent("reset", "the printer reset (it printed 'start'); its targets were cleared"))
                self._requests.clear()
                self._feed.on_event(event, now)
            case _:
                self._feed.on_event(event, now)

    def _after_results(self) -> None:
        if self._print is not None:
            self._print.check()


#: `connect(port, ...)` makes a `Printer` with the same options (one definition of them: `Printer`'s); open it
#: with `async with`. `connect("serve:NAME")` gives the printer NAME of a running `marlin-temp serve`.
connect = Printer
