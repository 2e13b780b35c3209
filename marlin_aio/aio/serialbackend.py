"""A printer on a port of this process: `Printer`'s backend for a device path or a pyserial URL.

It drives small collaborators, each in its own module: `marlin_aio.aio.link.Link` (the port, the protocol core and
the callers' futures), `marlin_aio.aio.handshake` (the start-up sequence), `marlin_aio.aio.poller` (M105 on a
schedule) and `marlin_aio.aio.printhandle` (a print in progress). All protocol decisions live in
`marlin_aio.protocol.connection`. Loop-bound objects are made in `open()`, never in `__init__`. No user code runs
in the read path: what the link reads only resolves futures, updates state and queues readings and requests (the
`Listeners` and the `TemperatureFeed` call user code from the loop, right after).

Over 400 lines because it is the port's answer to each of `Printer`'s members (the link's life, commands,
readings, prints, the firmware's requests, the link's figures) in one place, as `marlin_aio.aio.served` is the
service's: side by side, a reader sees what each backend does for the same member.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import AsyncIterator, Generator, Iterable, Sequence
from pathlib import Path

from marlin_aio.aio.feed import TemperatureFeed
from marlin_aio.aio.gcodefile import job_from_path
from marlin_aio.aio.handshake import handshake, send_until_processed
from marlin_aio.aio.link import Link
from marlin_aio.aio.listeners import LinkEvent, Listeners
from marlin_aio.aio.poller import Poller
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.aio.wirelog import WireLog, WireSession
from marlin_aio.errors import ConnectionLostError, MarlinError
from marlin_aio.protocol.connection import Connection, Reply
from marlin_aio.protocol.events import BusyKeepalive, Capability, Event, FirmwareInfo, HostAction, Ok, Start
from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.protocol.hostrequests import (
    PRINT_CANCELS,
    PRINT_PAUSES,
    PRINT_RESUMES,
    HostRequest,
    HostRequests,
    Prompt,
)
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.printjob import PrintJob, gcode_commands
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.temperatures import ReadingSource, TemperatureReading
from marlin_aio.protocol.wire import Trace

__all__ = ["SerialBackend"]

_log = logging.getLogger("marlin_aio")


class SerialBackend:
    """The port `port`, its link and everything on it (see the module's docstring); `Printer`'s arguments."""

    def __init__(
        self,
        port: str,
        listeners: Listeners,
        *,
        baudrate: int,
        timeout_s: float,
        handshake: bool,
        numbered: bool,
        window: tuple[int, int],
        boot_quiet_s: float,
        limits: HeaterLimits,
        password: str | None,
        wire_log: WireLog | None,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self._listeners = listeners
        self._feed: TemperatureFeed = listeners.feed
        self._handshake_enabled = handshake
        self._numbered = numbered
        self._window = window
        self._boot_quiet_s = boot_quiet_s
        self._limits = limits
        self._password = password
        self._wire_log = wire_log
        self._wire: WireSession | None = None
        self.firmware: FirmwareInfo | None = None
        self.capabilities: dict[str, bool] = {}
        self._print_poll_interval_s = 1.0
        self._link = self._new_link()
        self._poller = Poller(self._link, timeout_s, self._poll_slow_down)
        self._print: PrintHandle | None = None
        self._reset_on_open = False
        self._requests = HostRequests()

    def set_limits(self, limits: HeaterLimits) -> None:
        """Check every command and print line against `limits` from now on."""
        self._limits = limits
        self._connection.limits = limits  # the connection is the gate every command and print line passes

    def _new_link(self) -> Link:
        connection = Connection(
            # Connecting from before the port opens: a boot banner read the moment it is open is the handshake's,
            # never a reset of a connected printer.
            connecting=self._handshake_enabled,
            numbered=self._numbered,
            max_in_flight=self._window[0],
            rx_buffer_bytes=self._window[1],
            limits=self._limits,
        )
        self._connection = connection
        return Link(
            self.port,
            self.baudrate,
            connection,
            on_event=self._on_event,
            on_failure=self._listeners.failed,
            after_results=self._after_results,
            after_read=self._feed.deliver,
        )

    # ------------------------------------------------------------------------------------------- lifecycle

    async def open(self) -> None:
        """Open the port and, unless disabled, run the handshake (see `Printer.open`).

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
        if self._wire_log is not None:
            self._end_wire("closed")  # a session of an earlier open that was never closed
            self._wire = self._wire_log.connection(self.port, self.baudrate)
            self._connection.trace.tap = self._wire.line
        self._listeners.loop = asyncio.get_running_loop()
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
            self._connection.handshake_done()
        _log.info("connected to %s: %s", self.port, self.firmware.name if self.firmware else "unknown firmware")
        firmware = self.firmware.name if self.firmware else "firmware unknown"
        self._listeners.link_event(LinkEvent("connected", f"{self.port} ({firmware})"))
        if self._reset_on_open:
            _log.warning("the board on %s reset when the port was opened; targets set earlier were cleared", self.port)

    @property
    def reset_on_open(self) -> bool:
        """True if the board reset as this connection opened the port."""
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

    async def send(self, command: str, *, timeout_s: float, numbered: bool | None) -> Reply:
        """Send one command on the link and return its reply (see `Printer.send`).

        Raises:
            ValueError, MarlinError: as `Printer.send`.
        """
        return await self._link.send(command, timeout_s=timeout_s, numbered=numbered)

    def emergency_stop(self) -> None:
        """Write M112 at once, ahead of anything queued.

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        self._link.emergency_stop()
        _log.warning("emergency stop (M112) sent to %s", self.port)

    def interrupt_wait(self) -> bool:
        """Write M108 at once if the firmware reads it during a wait; say whether it was written.

        Raises:
            ConnectionLostError: the port is closed or lost.
        """
        if not self.capabilities.get("EMERGENCY_PARSER", False):
            return False
        self._link.interrupt_wait()
        _log.info("M108 sent to %s to end a wait", self.port)
        return True

    # ------------------------------------------------------------------------------------------- temperatures

    async def read_temperatures(self) -> TemperatureReading:
        """Ask for the temperatures once (M105) and return the reading.

        Raises:
            MarlinError: as `send`; also if the printer's answer holds no temperatures.
        """
        reply = await self.send("M105", timeout_s=self.timeout_s, numbered=None)
        if reply.temperatures is None or not reply.temperatures.heaters:
            raise MarlinError(f"M105 was answered without temperatures: {reply.ok.payload!r}")
        # Built from this reply, not `latest`: an auto-report arriving in the same read may already have replaced it.
        return self._feed.reading(reply.temperatures, reply.answered_s, ReadingSource.POLL)

    def readings_ended(self) -> MarlinError | None:
        """Why the link's readings have ended (it was lost or closed), or None."""
        return self._link.lost

    @contextlib.asynccontextmanager
    async def poll_temperatures(self, interval_s: float, auto_report: bool) -> AsyncIterator[None]:
        """Poll M105 every `interval_s` while the block runs (and M155 S1 with `auto_report`, where the firmware
        has it)."""
        use_auto = auto_report and self.capabilities.get("AUTOREPORT_TEMP", False)
        if use_auto:
            await self.send("M155 S1", timeout_s=self.timeout_s, numbered=None)
        poller = self._poller
        poller.start(interval_s)
        try:
            yield
        finally:
            poller.stop(interval_s)
            if use_auto and self._link.lost is None and self._link.halted is None:
                with contextlib.suppress(MarlinError):
                    await self.send("M155 S0", timeout_s=self.timeout_s, numbered=None)

    def polled(self) -> bool:
        """True while readings come without asking (a poller runs)."""
        return self._poller.active

    def _poll_slow_down(self) -> float | None:
        return self._print_poll_interval_s if self._print is not None and not self._print.finished else None

    @property
    def print_poll_interval_s(self) -> float:
        """While a print streams, polls slow down to this interval."""
        return self._print_poll_interval_s

    @print_poll_interval_s.setter
    def print_poll_interval_s(self, interval_s: float) -> None:
        self._print_poll_interval_s = interval_s

    # ------------------------------------------------------------------------------------------- printing

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool,
        window_bytes: int | None,
        check: bool,
        timeout_s: float | None,
        name: str | None = None,
        stop_on_unknown: bool = False,
    ) -> PrintHandle:
        """Start streaming `source` on the link (see `Printer.start_print`).

        Raises:
            ValueError, OSError, RuntimeError, MarlinError: as `Printer.start_print`.
        """
        if self._print is not None and not self._print.finished:
            raise RuntimeError(f"a print is already running ({self._print.job.name})")
        link = self._link
        if isinstance(source, str | Path):
            # A file is read whole to be checked before its first line: millions of lines take seconds, which must
            # not stall the event loop (other printers, polls, a service's clients) meanwhile.
            job = await asyncio.to_thread(self._print_job, source, check)
        else:
            job = self._print_job(source, check)
        if name is not None:
            job.name = name  # what its messages call it (the file's name as its starter gave it)
        job.stop_on_unknown = stop_on_unknown
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
        limits = self._limits
        if isinstance(source, str | Path):
            return job_from_path(Path(source), check=check, limits=limits)
        if check and isinstance(source, Sequence):
            # Before the first line is sent, as for a file: a list over the limits is refused whole, and counted in
            # the same pass. (An iterator can be read only once: each of its lines is checked as it is fed, and a
            # bad one stops the print.)
            commands = sum(1 for _ in gcode_commands(source, limits))
            return PrintJob(source, lines_total=commands, limits=limits)
        return PrintJob(source, limits=limits)

    # ------------------------------------------------------------------------------------------- state

    @property
    def trace(self) -> Trace:
        """The last lines sent and received, with times on the event loop's clock."""
        return self._link.trace

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link's counters."""
        return self._link.stats()

    @property
    def round_trips(self) -> deque[tuple[float, float]]:
        """(answered at, round trip) of the latest replies (up to 8,192) on the loop's clock."""
        return self._link.round_trips

    @property
    def send_ahead_window_bytes(self) -> int:
        """How many unanswered bytes a send-ahead print keeps on the wire by default."""
        return self._link.send_ahead_window_bytes

    @contextlib.contextmanager
    def sending_ahead(self, max_in_flight: int) -> Generator[None]:
        """Let up to `max_in_flight` commands share the wire while the block runs.

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
        """Where the link stands, as the core's state machine says (CONNECTING while the handshake runs)."""
        return self._link.state

    @property
    def is_connected(self) -> bool:
        """True while the link is open and has not been lost."""
        return self._link.is_open

    def failure(self) -> MarlinError | None:
        """Why the printer can take no more commands (the link lost, the printer halted), or None."""
        return self._link.lost if self._link.lost is not None else self._link.halted

    # ------------------------------------------------------------------------------------------- firmware requests

    @property
    def prompt(self) -> Prompt | None:
        """The prompt the firmware shows for a person, or None."""
        return self._requests.prompt

    @property
    def waiting_for_user(self) -> bool:
        """True while a command waits for a person."""
        return self._requests.waiting_for_user

    @property
    def last_host_request(self) -> HostRequest | None:
        """The firmware's last pause, paused, resume, resumed, cancel or disconnect request, or None."""
        return self._requests.last

    async def answer_prompt(self, index: int) -> None:
        """Answer the open prompt with its button `index` (see `Printer.answer_prompt`).

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
            await self.send(command, timeout_s=self.timeout_s, numbered=None)
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
        self._listeners.host_request(request)

    def _disconnect_requested(self, request: HostRequest) -> None:
        self._poller.cancel()
        extra = f" ({request.argument})" if request.argument else ""
        self._link.drop(ConnectionLostError(f"the printer asked the host to disconnect (//action:disconnect{extra})"))

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
            case Start() if self._connection.state is not LinkState.CONNECTING:
                # The boot banner during the handshake is the handshake's; after it, the board restarted.
                message = "the printer reset (it printed 'start'); its targets were cleared"
                self._listeners.link_event(LinkEvent("reset", message))
                self._requests.clear()
                self._feed.on_event(event, now)
            case _:
                self._feed.on_event(event, now)

    def _after_results(self) -> None:
        if self._print is not None:
            self._print.check()
