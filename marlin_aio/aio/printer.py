"""The asyncio client: `async with connect(url) as printer: await printer.send("G28")`.

`Printer` is the one public class, a front that hands each call to a backend chosen when it is made (bleak's
`BleakClient` shape; the seam is `marlin_aio.aio.backend.PrinterBackend`): a port of this process
(`marlin_aio.aio.serialbackend`: the link, the handshake, the poller, prints streamed from here) or a printer of
`marlin-temp serve` for a `serve:NAME` port (`marlin_aio.aio.served`: JSON-RPC to the service). What is built on
the backend (moves, homing, fans, heater limits, waits for temperatures, whole prints) is here, once for both.
Listeners of link events and the firmware's requests live in `marlin_aio.aio.listeners`, readings in
`marlin_aio.aio.feed`. A member a backend cannot serve raises `NotSupportedError` saying why; none does nothing.
Loop-bound objects are made in `open()`, never in `__init__`, so a `Printer` can be built outside a running loop.

(Over 400 lines because it is the API reference: most of it is the docstrings of `Printer`'s public members; the
logic behind them lives in the backends and their collaborators.)
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import AsyncGenerator, AsyncIterator, Callable, Iterable
from contextlib import AbstractContextManager
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Self

from marlin_aio.aio.backend import PrinterBackend
from marlin_aio.aio.feed import TemperatureFeed
from marlin_aio.aio.gcodecommands import GcodeCommands
from marlin_aio.aio.handshake import BAUD_RATES
from marlin_aio.aio.heatwait import wait_for_targets
from marlin_aio.aio.listeners import LinkEvent, Listeners
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.aio.serialbackend import SerialBackend
from marlin_aio.aio.servicepaths import SERVE_PREFIX
from marlin_aio.aio.wirelog import WireLog
from marlin_aio.errors import MarlinError
from marlin_aio.protocol.commands import (
    DEFAULT_MAX_BED_CELSIUS,
    DEFAULT_MAX_CHAMBER_CELSIUS,
    DEFAULT_MAX_HOTEND_CELSIUS,
)
from marlin_aio.protocol.connection import Reply
from marlin_aio.protocol.events import FirmwareInfo
from marlin_aio.protocol.heaters import HeaterLimits, wanted_targets
from marlin_aio.protocol.hostrequests import HostRequest, Prompt
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.printjob import PrintProgress
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.temperatures import TemperatureReading
from marlin_aio.protocol.wire import Trace

if TYPE_CHECKING:
    from marlin_aio.aio.served import ServedBackend

__all__ = ["BAUD_RATES", "DEFAULT_BAUDRATE", "LinkEvent", "PrintHandle", "Printer", "ServedPrinter", "connect"]

DEFAULT_BAUDRATE = BAUD_RATES[0]


class Printer(GcodeCommands):
    """A connection to one Marlin printer: `async with connect(port, ...) as printer:` (or `Printer(port, ...)`).

    Any number of tasks may call its coroutines at once: commands go out in the order they were sent, and each
    resolves with its own reply. A printer that was closed can be opened again (`async with` once more).

    Args:
        port: a device path (`/dev/ttyUSB0`), a pyserial URL (`socket://host:port`), or `serve:NAME` for the
            printer NAME of a running `marlin-temp serve` (see `marlin_aio.aio.served`: the same API, spoken to
            the service; what only the service can do raises `NotSupportedError`).
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

    (`baudrate`, `handshake`, `numbered`, the window and `password` are the service's business for `serve:NAME`.)

    Raises:
        ValueError: `timeout_s` is not positive, or the password cannot travel in M511.
    """

    def __new__(cls, port: str, *args: object, **kwargs: object) -> Self:
        # `Printer("serve:NAME")` is a `ServedPrinter`: the same class with the service's backend, and the few
        # members only a service has (`call`, `name`).
        if cls is Printer and isinstance(port, str) and port.startswith(SERVE_PREFIX):
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
        super().__init__(HeaterLimits(max_hotend_celsius, max_bed_celsius, max_chamber_celsius))
        self._feed = TemperatureFeed()
        self._listeners = Listeners(self._feed)
        self._backend: PrinterBackend
        if port.startswith(SERVE_PREFIX):
            # The service's client (its JSON-RPC socket) loads only for a `serve:` port.
            from marlin_aio.aio.served import ServedBackend

            self._backend = ServedBackend(port, self._listeners, timeout_s=timeout_s, limits=self.heater_limits)
        else:
            self._backend = SerialBackend(
                port,
                self._listeners,
                baudrate=baudrate,
                timeout_s=timeout_s,
                handshake=handshake,
                numbered=numbered,
                window=(max_in_flight, rx_buffer_bytes),
                boot_quiet_s=boot_quiet_s,
                limits=self.heater_limits,
                password=password,
                wire_log=wire_log,
            )

    @property
    def timeout_s(self) -> float:
        """The default wait for each command's `ok` (and each handshake step)."""
        return self._backend.timeout_s

    @timeout_s.setter
    def timeout_s(self, timeout_s: float) -> None:
        self._backend.timeout_s = timeout_s

    @property
    def firmware(self) -> FirmwareInfo | None:
        """The M115 identity line, once the handshake asked for it."""
        return self._backend.firmware

    @property
    def capabilities(self) -> dict[str, bool]:
        """The M115 `Cap:` flags, e.g. {"AUTOREPORT_TEMP": True}."""
        return self._backend.capabilities

    @property
    def print_poll_interval_s(self) -> float:
        """While a print streams, polls slow down to this interval (seconds; 1.0 unless set).

        Raises:
            NotSupportedError: a served printer: the service polls at its own rate (`marlin-temp serve --interval`).
        """
        return self._backend.print_poll_interval_s

    @print_poll_interval_s.setter
    def print_poll_interval_s(self, interval_s: float) -> None:
        self._backend.print_poll_interval_s = interval_s

    def _limits_changed(self, limits: HeaterLimits) -> None:
        self._backend.set_limits(limits)

    def on_link_event(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        """Call `callback` with each `LinkEvent` from now on (connected, reset, halted, disconnected); return the
        function that stops the calls.

        A supervisor learns of a board reset here as it happens, instead of polling `stats.resets`. It is called on
        the event loop, soon after the line that told (never inside the link's read handler); if it raises, the
        error is logged (logger "marlin_aio") and the link and the other listeners go on.
        """
        return self._listeners.on_link_event(callback)

    # ------------------------------------------------------------------------------------------- lifecycle

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def open(self) -> None:
        """Open the port and, unless disabled, run the handshake (a served printer: reach the service and its
        printer). A closed printer opens afresh.

        Raises:
            RuntimeError: the printer is already open.
            ConnectError: the port could not be opened (its subclasses say why); a served printer: the service's
                printer is not connected now.
            HandshakeError: the printer did not answer the start-up sequence; `step` says where it stopped.
        """
        await self._backend.open()

    @property
    def reset_on_open(self) -> bool:
        """True if the board reset as this connection opened the port (it printed its boot banner): targets, fan
        and other settings made by an earlier connection are gone. (Always False for a served printer: this
        connection opens no port.)

        Boards whose USB bridge wires DTR to reset do this on the first open after plugging in; later opens by
        this library leave DTR raised (HUPCL cleared) so they keep running, where the platform allows it.
        """
        return self._backend.reset_on_open

    async def close(self) -> None:
        """Close the port (a served printer: leave the service; a print started from here goes on there).
        Commands still waiting fail with `ConnectionLostError`; safe to call twice."""
        await self._backend.close()

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float | None = None, numbered: bool | None = None) -> Reply:
        """Send one command and return its reply (the lines that came with it and its `ok`).

        Busy keepalives and M109/M190 wait lines push the deadline out, so long commands only time out when the
        printer falls silent. If the caller is cancelled before the command was written, it is never written.
        (Served: commands of all clients go out in the order the service received them; `numbered` is its own.)

        Raises:
            ValueError: the command is malformed (line break, non-ASCII, over 95 bytes, empty), or it sets a
                target above the client's limits (`M104 S300` with `max_hotend_celsius=260`), as
                `set_temperatures` would refuse it.
            CommandTimeoutError: no `ok` within `timeout_s` (default: the client's) without a sign of life.
            PrinterHaltedError: the printer halted (ThermalRunawayError if its thermal protection tripped).
            PrinterResetError: the printer reset before answering.
            LostReplyError: the command ran, but its reply cannot be proven its own (an ok was lost).
            ConnectionLostError: the link (or the service) went away.
        """
        timeout = self.timeout_s if timeout_s is None else timeout_s
        return await self._backend.send(command, timeout_s=timeout, numbered=numbered)

    def emergency_stop(self) -> None:
        """Write M112 at once, ahead of anything queued; the printer halts and needs a reset.

        Every command still waiting fails with `PrinterHaltedError` right away.

        Raises:
            ConnectionLostError: the port is closed or lost, so M112 cannot reach the printer (cut its power).
        """
        self._backend.emergency_stop()

    def interrupt_wait(self) -> bool:
        """End a heater wait (M109, M190, M191) or a pause (M0/M1) now, if the firmware can: write M108 at once,
        ahead of anything queued, and return True. Only Marlin's emergency parser (M115's `Cap:EMERGENCY_PARSER:1`)
        reads M108 while a wait blocks; without it nothing is written and this returns False (the wait runs to its
        end, and the M108 would only run after it).

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        return self._backend.interrupt_wait()

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
        return await self._backend.read_temperatures()

    async def temperatures(self) -> TemperatureReading:
        """The same as `read_temperatures()` (the older name)."""
        return await self.read_temperatures()

    def temperature_readings(self) -> AsyncGenerator[TemperatureReading, None]:
        """Yield every temperature report from now on, whatever produced it (polls, auto-report, wait lines; a
        served printer: the service's polls).

        Each reader has its own queue of up to 1,000 readings; one that falls further behind loses its oldest
        readings (counted in `readings_dropped`), never the error that ends them.

        Raises:
            ConnectionLostError, PrinterHaltedError, PrinterResetError: when the link or printer goes away.
        """
        return self._feed.readings(self._backend.readings_ended())

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
        A served printer asks for nothing more: the service polls at its own rate for all its clients.

        Raises:
            ValueError: `interval_s` is not positive.
        """
        if not interval_s > 0:
            raise ValueError(f"interval_s must be positive, got {interval_s}")
        async with self._backend.poll_temperatures(interval_s, auto_report):
            yield

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
        wanted = wanted_targets(self.heater_limits, hotend=hotend, bed=bed, chamber=chamber, tool=tool)

        poller = self.poll_temperatures(poll_interval_s, auto_report=False) if not self._backend.polled() else None
        return await wait_for_targets(
            self.temperature_readings,
            lambda: self.latest,
            wanted,
            tool=tool,
            tolerance_c=tolerance_c,
            timeout_s=timeout_s,
            poller=poller,
            where=self.port,
        )

    # ------------------------------------------------------------------------------------------- printing

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool = False,
        window_bytes: int | None = None,
        check: bool = True,
        timeout_s: float | None = None,
        name: str | None = None,
        stop_on_unknown: bool = False,
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
        A served printer's print runs inside the service (a file it can read, or lines sent to it first) and goes
        on if this client leaves. `name` is what the print is called (default: the file's name): a print of lines
        made from `part.gcode` is `part.gcode` in every message and, served, to every client.
        A command the firmware does not know (`Unknown command` echoing it exactly as sent: a build without `M73`,
        which slicers write near the top) is skipped by Marlin; the print goes on, with one warning per command
        and the codes in `PrintProgress.unknown_codes`, as OctoPrint and Pronterface do. `stop_on_unknown` stops
        the print at such a line instead. (A line that arrived damaged is told apart: its echo differs from what
        was sent, and it goes again or stops the print, never skipped.)

        Raises:
            ValueError: with `check`, a line of the file is not a valid command (nothing is sent).
            OSError: the file cannot be read.
            RuntimeError: a print is already running.
            MarlinError: as `send` (for the M110 that starts the print).
        """
        if window_bytes is not None and not 16 < window_bytes <= 65536:
            raise ValueError(f"window_bytes must be between 17 and 65536, got {window_bytes}")
        return await self._backend.start_print(
            source,
            send_ahead=send_ahead,
            window_bytes=window_bytes,
            check=check,
            timeout_s=timeout_s,
            name=name,
            stop_on_unknown=stop_on_unknown,
        )

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

    # ------------------------------------------------------------------------------------------- state

    @property
    def trace(self) -> Trace:
        """The last lines sent and received, with times on the event loop's clock.

        Raises:
            NotSupportedError: a served printer: its wire is the service's (`marlin-temp serve --wire-log`).
        """
        return self._backend.trace

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link's counters (commands answered and failed, timeouts, resends, resets, lost oks,
        bytes received), taken now; it does not change afterwards. A served printer's are the service's link's
        (every client's commands and its polls), fetched once a second."""
        return self._backend.stats

    @property
    def round_trips(self) -> deque[tuple[float, float]]:
        """(answered at, round trip) of the latest replies (up to 8,192), polls included, on the loop's clock:
        latency figures. A served printer's are the service's link's, fetched once a second."""
        return self._backend.round_trips

    @property
    def send_ahead_window_bytes(self) -> int:
        """How many unanswered bytes a send-ahead print keeps on the wire by default: the printer's receive buffer
        less the room kept for a probe or a command of yours.

        Raises:
            NotSupportedError: a served printer: the service sets the window of its prints.
        """
        return self._backend.send_ahead_window_bytes

    def sending_ahead(self, max_in_flight: int) -> AbstractContextManager[None]:
        """Let up to `max_in_flight` commands share the wire while the block runs (a benchmark's concurrent
        `send()`s); the window is restored afterwards. Commands whose answers could be confused still go one at a
        time (see `marlin_aio.protocol.matching`).

        Raises:
            ValueError: `max_in_flight` is below 1.
            NotSupportedError: a served printer: the service's wire carries every client's commands.
        """
        return self._backend.sending_ahead(max_in_flight)

    @property
    def state(self) -> LinkState:
        """Where the link stands: CONNECTING, READY, LOCKED, STOPPED (M999 resumes), HALTED (needs a reset) or
        LOST (closed, or the port went away). A served printer is READY or LOST."""
        return self._backend.state

    @property
    def is_connected(self) -> bool:
        """True while the link is open and has not been lost."""
        return self._backend.is_connected

    async def wait_for_failure(self) -> MarlinError:
        """Wait until the printer halts or the link is lost or closed, and return why (the error commands fail with
        from then on); at once if that has happened already. For a supervisor that keeps a printer connected: no
        task wakes up per reading while it waits.
        """
        return await self._listeners.wait_for_failure(self._backend.failure())

    # ------------------------------------------------------------------------------------------- firmware requests

    @property
    def prompt(self) -> Prompt | None:
        """The prompt the firmware shows for a person (HOST_PROMPT_SUPPORT), with its buttons, or None.

        Answer it with `answer_prompt(index)`; the firmware closes it with `//action:prompt_end`.
        """
        return self._backend.prompt

    @property
    def waiting_for_user(self) -> bool:
        """True while a command waits for a person (`echo:busy: paused for user`: M600, M0/M1), until it ends."""
        return self._backend.waiting_for_user

    @property
    def last_host_request(self) -> HostRequest | None:
        """The firmware's last pause, paused, resume, resumed, cancel or disconnect request, or None."""
        return self._backend.last_host_request

    def on_host_request(self, callback: Callable[[HostRequest], None]) -> Callable[[], None]:
        """Call `callback` with each `HostRequest` from now on (prompts shown and closed, pause, resume, cancel,
        disconnect, `paused for user`); return the function that stops the calls.

        It is called on the event loop soon after the line that asked (never inside the link's read handler); if
        it raises, the error is logged (logger "marlin_aio") and the link and the other listeners go on.
        """
        return self._listeners.on_host_request(callback)

    def host_requests(self) -> AsyncGenerator[HostRequest, None]:
        """Yield each `HostRequest` from now on (see `on_host_request`), until the link ends.

        Raises:
            MarlinError: the link was lost or closed, or the printer halted (at once if it already was).
        """
        return self._listeners.host_requests(self._backend.failure)

    async def answer_prompt(self, index: int) -> None:
        """Answer the open prompt with its button `index` (0 the first): `M876 S<index>`.

        With the firmware's EMERGENCY_PARSER (its M115 says so) it is written at once, ahead of anything queued,
        as a printer waiting for a person (M600) reads nothing else; without, it is sent like any command. (A
        served printer: the service checks `index` against the prompt open there, and writes it.)

        Raises:
            ValueError: no prompt is open, or it has no button `index` (nothing is written).
            MarlinError: as `send`.
        """
        await self._backend.answer_prompt(index)


class ServedPrinter(Printer):
    """A `Printer` of `marlin-temp serve` (what `Printer("serve:NAME")` makes): the same members, on the service's
    backend (`marlin_aio.aio.served`), and what only a service has: `name` and `call`."""

    _backend: ServedBackend

    def __init__(self, port: str, **options: Any) -> None:
        if not port.startswith(SERVE_PREFIX):
            raise ValueError(f"not a served printer: {port!r} (expected serve:NAME)")
        super().__init__(port, **options)

    @property
    def name(self) -> str | None:
        """The service's name of the printer (None before `open()` for `serve:` alone: the service's only one)."""
        return self._backend.name

    async def call(self, method: str, **params: Any) -> Any:
        """Send the service a request about this printer (`method` and its parameters, as `marlin_aio.protocol.rpc`
        lists them) and return its result: for what `Printer`'s API has no name for.

        Raises:
            ConnectionLostError: not open, or the service went away.
            MarlinError, ValueError, RuntimeError, OSError: as the service raised them.
        """
        return await self._backend.call(method, **params)


#: `connect(port, ...)` makes a `Printer` with the same options (one definition of them: `Printer`'s); open it
#: with `async with`. `connect("serve:NAME")` gives the printer NAME of a running `marlin-temp serve`.
connect = Printer
