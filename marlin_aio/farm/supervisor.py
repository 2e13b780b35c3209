"""A print farm in one process: N printers on one event loop, each kept connected by a supervisor of its own.

Each printer gets its own `marlin_aio.Printer`, polled at its own rate, and a supervisor task that reconnects it
with backoff (1 s doubling to 30 s) when it is unplugged, halts or never answered; one printer's failure never
reaches another's task. What the farm knows of each printer (`FarmPrinter`: link up or down, firmware, the latest
reading, the last error) is read by whoever shows or forwards it (the MQTT bridge, a farm view), and what happens
to it (`FarmEvent`: connected, connection lost, halted, reset, thermal runaway) goes to one callback, in order.

Nothing here knows about MQTT: the bridge (`marlin_aio.farm.bridge`) reads this state at its own rate, so a slow or
absent broker never slows a serial loop.

Secrets: a printer's password (`password` in the config, sent as `M511 P<password>`) never reaches an event, the
last error or a log line: every event's message is redacted (`redact`) where it is made, in `Farm.emit`, and the
bridge redacts whatever else it publishes (`redact_payload`); `PrinterSpec`'s repr leaves the password out.

Over 400 lines because `FarmPrinter` (what is known of a printer) and `Farm` (the only code that writes it: the
supervisor, the prints, the firmware's requests and answers) are read together: every field's writer is here.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import marlin_aio
import marlin_aio.protocol
from marlin_aio.aio import Backoff, Retry, WireLog, keep_connected
from marlin_aio.aio.printhandle import FEED_GUARD, FeedGuard
from marlin_aio.farm.job import DEFAULT_END_SCRIPT, Job, JobState, cancel_script_for

if TYPE_CHECKING:
    from marlin_aio.simulator import SimulatorServer

__all__ = [
    "BACKOFF_MAX_S",
    "BACKOFF_START_S",
    "REQUEST_EVENTS",
    "RESERVED_NAMES",
    "SIM_RECORD_LIMIT",
    "Farm",
    "FarmEvent",
    "FarmPrinter",
    "PrinterSpec",
    "one_line",
    "redact",
    "redact_payload",
]

_log = logging.getLogger("marlin_aio.farm.supervisor")

BACKOFF_START_S = 1.0
BACKOFF_MAX_S = 30.0

#: The library's redaction (an M511's password blanked as `M511 ****`), re-exported for the bridge.
redact = marlin_aio.redact

#: Names a printer cannot have: `bridge` is the bridge's own topic level (`PREFIX/bridge/availability`).
RESERVED_NAMES = frozenset({"bridge"})

#: Commands an in-process simulated printer remembers (it counts all): enough to look back on, small enough that
#: twenty of them polled at 10 Hz for days stay at the same size.
SIM_RECORD_LIMIT = 1_000

#: The farm event each request of the firmware becomes (those not here, a notification, make none: the
#: printer's `Printer.on_host_request` still has them, and a disconnect becomes the connection_lost it causes).
REQUEST_EVENTS = {
    "prompt": "prompt_opened",
    "prompt_closed": "prompt_closed",
    "pause": "paused_by_printer",
    "paused": "paused_by_printer",
    "resume": "resumed_by_printer",
    "resumed": "resumed_by_printer",
    "cancel": "cancelled_by_printer",
}

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def one_line(text: str) -> str:
    """`text` with every control character (a newline, an escape, ...) written as its escape, so that a file name or
    an error quoting one stays on the one line an event is printed and logged on."""
    return _CONTROL.sub(lambda match: repr(match.group())[1:-1], text)


def redact_payload(value: Any) -> Any:
    """`value` (a JSON-able payload: dicts, lists, strings, numbers) with every string in it redacted."""
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, dict):
        return {key: redact_payload(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [redact_payload(item) for item in value]
    return value


@dataclass(frozen=True)
class PrinterSpec:
    """One printer of the farm, as configured: a name (used in topics), where it is, and how to poll it."""

    name: str
    port: str | None
    """A device path or pyserial URL; None with `sim`."""
    baud: int = marlin_aio.DEFAULT_BAUDRATE
    poll_interval_s: float = 0.1
    timeout_s: float = 10.0
    max_hotend_celsius: float = marlin_aio.DEFAULT_MAX_HOTEND_CELSIUS
    max_bed_celsius: float = marlin_aio.DEFAULT_MAX_BED_CELSIUS
    max_chamber_celsius: float = marlin_aio.DEFAULT_MAX_CHAMBER_CELSIUS
    password: str | None = field(default=None, repr=False)
    """PASSWORD_FEATURE's password, sent as `M511 P<password>`; never printed, logged or published."""
    sim: bool = False
    """Serve a simulated printer for it in this process (on a pty) instead of opening `port`."""
    sim_speed: float = 1.0

    @property
    def limits(self) -> marlin_aio.HeaterLimits:
        """The three `max_*_celsius` settings (the TOML file's words) as the one `HeaterLimits` checks take."""
        return marlin_aio.HeaterLimits(self.max_hotend_celsius, self.max_bed_celsius, self.max_chamber_celsius)


@dataclass(frozen=True)
class FarmEvent:
    """Something that happened to one printer: `kind` is one of connected, connection_lost, connect_failed,
    halted, thermal_runaway, reset, print_started, print_finished, print_cancelled, print_failed, or one of the
    firmware's requests (`REQUEST_EVENTS`: prompt_opened, prompt_closed, paused_by_printer, resumed_by_printer,
    cancelled_by_printer); `message` says it for people."""

    printer: str
    kind: str
    message: str
    time_s: float = field(default_factory=time.time)


@dataclass
class FarmPrinter:
    """What the farm knows about one printer now. Written by its supervisor only; read by anyone."""

    spec: PrinterSpec
    link_up: bool = False
    firmware: str | None = None
    last_error: str | None = None
    latest: marlin_aio.TemperatureReading | None = None
    readings: int = 0
    """Readings taken since the farm started (all connections)."""
    connections: int = 0
    printer: marlin_aio.Printer | None = None
    """The open printer while the link is up (to send it commands), else None."""
    url: str | None = None
    """Where it is reached: the port, or the simulator's pty."""
    job: Job | None = None
    """The printer's print job: the one running, or the last one (ended), or None. Written by the farm only."""
    machine: str | None = None
    """The board's MACHINE_TYPE from M115, if it says."""
    reconnect_at_s: float | None = None
    """While the supervisor waits to reconnect: when it tries again (`time.monotonic()`), else None."""
    closed_on_request: bool = False
    """Its port was closed on request (`Farm.disconnect`) and stays closed until `Farm.connect`."""
    reading_listeners: list[Callable[[marlin_aio.TemperatureReading], None]] = field(default_factory=list)
    """Called with every reading after it is kept (a farm view keeps each printer's history with one)."""
    request_listeners: list[Callable[[marlin_aio.HostRequest], None]] = field(default_factory=list)
    """Called with every request of the firmware (`Printer.on_host_request`), after the farm's event for it."""

    @property
    def prompt(self) -> marlin_aio.protocol.Prompt | None:
        """The prompt the printer shows for a person now (see `Printer.prompt`), or None (also while it is down)."""
        return self.printer.prompt if self.printer is not None and self.link_up else None

    @property
    def waiting_for_user(self) -> bool:
        """True while a command of the printer waits for a person (M600: `Printer.waiting_for_user`)."""
        return self.printer is not None and self.link_up and self.printer.waiting_for_user

    @property
    def print_handle(self) -> marlin_aio.PrintHandle | None:
        """The job's print in progress (or ended), if it got as far as starting."""
        return None if self.job is None else self.job.handle

    @property
    def print_file(self) -> str | None:
        """The job's file name as its starter gave it."""
        return None if self.job is None else self.job.file

    def print_status(self) -> dict[str, object] | None:
        """The print's progress for the state topic, or None when no print was started."""
        job = self.job
        if job is None or job.handle is None:
            return None
        handle = job.handle
        progress = handle.progress
        failure = handle.job.error if progress.state is marlin_aio.PrintState.FAILED else None
        # Read from the job itself, so the state is never "failed" without why, even before the follower ran.
        error = None if failure is None else one_line(redact(f"{_print_failure(failure)}: {failure}"))
        total = progress.source_bytes_total
        percent = round(100 * progress.source_bytes_acked / total, 1) if total else None
        return {
            "file": job.file,
            "state": progress.state.value,
            "job_state": job.state.value,
            "percent": percent,
            "lines_acked": progress.lines_acked,
            "last_file_line": progress.last_source_line,
            "started_by": job.started_by,
            "error": error or job.error,
        }

    @property
    def name(self) -> str:
        """The printer's name."""
        return self.spec.name

    def on_reading(self, reading: marlin_aio.TemperatureReading) -> None:
        """Keep the newest reading: called for every reading, so it only stores it."""
        self.latest = reading
        self.readings += 1
        for listener in self.reading_listeners:
            listener(reading)


def _print_failure(exc: BaseException) -> str:
    """How a print ended, in a word or two, from the error that ended it."""
    for kind, words in (
        (marlin_aio.ThermalRunawayError, "thermal runaway"),
        (marlin_aio.PrinterHaltedError, "halted"),
        (marlin_aio.PrinterResetError, "reset"),
        (marlin_aio.ConnectionLostError, "link lost"),
        (marlin_aio.PrintStalledError, "stalled"),
    ):
        if isinstance(exc, kind):
            return words
    return "failed"


class Farm:
    """Runs every printer of `specs` until cancelled; `on_event` gets each `FarmEvent` as it happens.

    Args:
        specs: the printers; names must be unique.
        on_event: called on the event loop with each event, in order.
        backoff_start_s: how long a supervisor waits before its first reconnection attempt; the wait doubles after
            each failed attempt.
        backoff_max_s: the longest wait between attempts.
    """

    def __init__(
        self,
        specs: list[PrinterSpec],
        on_event: Callable[[FarmEvent], None],
        *,
        backoff_start_s: float = BACKOFF_START_S,
        backoff_max_s: float = BACKOFF_MAX_S,
    ) -> None:
        names = [spec.name for spec in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"printer names must be unique: {', '.join(names)}")
        reserved = RESERVED_NAMES.intersection(names)
        if reserved:
            raise ValueError(f"a printer cannot be named {sorted(reserved)[0]!r}: the name is the bridge's own")
        self.printers = {spec.name: FarmPrinter(spec) for spec in specs}
        self._on_event = on_event
        self._backoff_start_s = backoff_start_s
        self._backoff_max_s = backoff_max_s
        self.sims: dict[str, SimulatorServer] = {}
        """The simulated printers' servers, by printer name (tests reach in to unplug one)."""
        self.wire_log: WireLog | None = None
        """Where every printer's wire goes, each line with the printer's name (set before `run`), or None."""
        self._group: asyncio.TaskGroup | None = None
        self._supervisors: dict[str, asyncio.Task[None]] = {}  # by printer: the task that keeps it connected
        # --- issue 33 life cycle hook: the service bounds each print's feed by its record (service.lifecycle)
        self.feed_guard: Callable[[FarmPrinter, Path], FeedGuard] | None = None
        """Makes the guard of each print started (None: prints are not bounded)."""

    async def run(self) -> None:
        """Supervise every printer until cancelled; one task each, named after its printer. The simulated
        printers it served are stopped when it ends."""
        try:
            async with asyncio.TaskGroup() as group:
                self._group = group  # prints run here, next to their printer's supervisor
                for farm_printer in self.printers.values():
                    self.connect(farm_printer)
                # Until cancelled, whether or not a printer is connected: a printer disconnected on request
                # (`disconnect`) must not end the farm with its supervisor.
                await asyncio.Event().wait()
        finally:
            self._group = None
            self._supervisors.clear()
            for server in self.sims.values():
                await server.aclose()

    def connect(self, farm_printer: FarmPrinter) -> None:
        """Keep the printer connected (again, after `disconnect`): open its port, and reopen it whenever it is lost.

        Raises:
            RuntimeError: the farm is not running.
        """
        if farm_printer.name in self._supervisors:
            return  # connected, or trying to be
        if self._group is None:
            raise RuntimeError("the farm is not running")
        farm_printer.closed_on_request = False
        task = self._group.create_task(self._supervise(farm_printer), name=f"printer {farm_printer.name}")
        self._supervisors[farm_printer.name] = task

    async def disconnect(self, farm_printer: FarmPrinter) -> None:
        """Close the printer's port and keep it closed until `connect` (heaters are left as they are, as
        OctoPrint's disconnect leaves them).

        Raises:
            RuntimeError: a print is running (cancel it first).
        """
        job = farm_printer.job
        if job is not None and job.active:
            raise RuntimeError(f"a print is running: {job.describe()}; cancel it before disconnecting")
        task = self._supervisors.pop(farm_printer.name, None)
        if task is None:
            return
        task.cancel()
        await asyncio.wait([task])  # its port closed (the printer's context ends as the task does)
        farm_printer.closed_on_request = True
        farm_printer.reconnect_at_s = None
        self.emit(farm_printer, "disconnected", "its port was closed on request; connect to open it again")

    async def start_print(
        self,
        farm_printer: FarmPrinter,
        path: Path,
        *,
        send_ahead: bool = False,
        timeout_s: float | None = None,
        window_bytes: int | None = None,
        name: str | None = None,
        stop_on_unknown: bool = False,
        started_by: str = "the farm",
        cancel_script: tuple[str, ...] | None = None,
        end_script: tuple[str, ...] = DEFAULT_END_SCRIPT,
        remove_file: bool = False,
    ) -> Job:
        """Start printing `path` on `farm_printer` as a new `Job` and follow it in a task of the farm's own.

        However the print ends (done, cancelled, halted, a reset, the link lost, a stall) becomes one `print_*`
        event and the job's state: an ending that is an error is that printer's news only, never an exception in
        whoever started it, so the farm and the other printers go on. `name` is the file's name as its starter
        knows it (default: the path's); `stop_on_unknown` as `Printer.start_print`; `cancel_script` runs once
        when it is cancelled (default: every heater and the fan off, `cancel_script_for`); `end_script` after it
        ended by itself; with `remove_file` the file is the service's own copy and is removed when the job ends.

        Raises:
            RuntimeError: the farm is not running, the printer is not connected, or a job is already running (the
                message names it).
            ValueError, OSError, MarlinError: as `Printer.start_print` (nothing of the file was sent).
        """
        printer = farm_printer.printer
        if self._group is None:
            raise RuntimeError("the farm is not running")
        if printer is None or not farm_printer.link_up:
            raise RuntimeError(f"printer {farm_printer.name!r} is not connected")
        running = farm_printer.job
        if running is not None and running.active:
            raise RuntimeError(f"a print is already running: {running.describe()}; cancel it first")
        script = cancel_script_for(farm_printer.latest) if cancel_script is None else cancel_script
        # The job holds the printer from before the first await: two print commands back to back (a double press,
        # a redelivered message) must not both pass the check above while the first one's M110 is on its way.
        options: dict[str, Any] = {
            "send_ahead": send_ahead,
            "timeout_s": timeout_s,
            "window_bytes": window_bytes,
            "stop_on_unknown": stop_on_unknown,
        }
        job = Job(
            farm_printer.name,
            name or path.name,
            path,
            started_by,
            cancel_script=script,
            end_script=end_script,
            options=options,
            remove_file=remove_file,
        )
        farm_printer.job = job
        # --- issue 33 life cycle hook: the guard is found by the print's handle before its first line is fed
        guard = FEED_GUARD.set(None if self.feed_guard is None else self.feed_guard(farm_printer, path))
        try:
            job.handle = await printer.start_print(path, **options)
        except BaseException as exc:
            job.ended(one_line(redact(str(exc))) or type(exc).__name__)
            raise
        finally:
            FEED_GUARD.reset(guard)
        self._group.create_task(self._follow_print(farm_printer, job), name=f"print on {farm_printer.name}")
        self.emit(farm_printer, "print_started", f"printing {job.file} (started by {started_by})")
        return job

    def running_job(self, farm_printer: FarmPrinter) -> Job:
        """The job running on `farm_printer`.

        Raises:
            RuntimeError: none is running (the message says what the last one did).
        """
        job = farm_printer.job
        if job is None or not job.active:
            last = "" if job is None else f" (the last: {job.describe()})"
            raise RuntimeError(f"no print is running on {farm_printer.name}{last}")
        return job

    def _started_job(self, farm_printer: FarmPrinter, what: str) -> tuple[Job, marlin_aio.PrintHandle]:
        """The running job and its print, for `what` (pause, resume, cancel) to act on.

        Raises:
            RuntimeError: no print is running, or it is still starting (its M110 on the way).
        """
        job = self.running_job(farm_printer)
        if job.handle is None:
            raise RuntimeError(f"{job.file} is still starting: {what} it in a moment")
        return job, job.handle

    def pause_print(self, farm_printer: FarmPrinter) -> Job:
        """Stop feeding the running job's lines (what is in flight completes; heaters stay as they are).

        Raises:
            RuntimeError: no print is running, or it is still starting.
        """
        job, handle = self._started_job(farm_printer, "pause")
        handle.pause()
        return job

    def resume_print(self, farm_printer: FarmPrinter) -> Job:
        """Feed the running job's lines again.

        Raises:
            RuntimeError: no print is running, or it is still starting.
        """
        job, handle = self._started_job(farm_printer, "resume")
        handle.resume()
        return job

    async def cancel_print(self, farm_printer: FarmPrinter, by: str) -> Job:
        """Cancel the running job: stop feeding, wait for what is in flight, run its cancel script (once, however
        many ask), and return it ended. A second cancel while one is under way waits for the first; a caller
        that leaves does not stop the script (it runs in the farm's task).

        Raises:
            RuntimeError: no print is running.
            MarlinError: the printer failed meanwhile (the job says so too).
        """
        job = farm_printer.job
        if job is None or job.cancel_task is None or job.cancel_task.done():
            job, _ = self._started_job(farm_printer, "cancel")
            job.cancelling(by)
            job.cancel_task = asyncio.ensure_future(self._cancel(farm_printer, job))
        await asyncio.shield(job.cancel_task)
        return job

    async def restart_print(self, farm_printer: FarmPrinter, by: str) -> Job:
        """Print the paused job's file again from its first line (OctoPrint's restart): the paused job ends without
        its cancel script (the heaters stay on: the print that starts again wants them), and a new job begins with
        the same file, name, options and scripts. Return the new job.

        Raises:
            RuntimeError: no print is paused (one running or still starting is not restarted: pause it first).
            ValueError, OSError, MarlinError: as `start_print` (the old job has ended then).
        """
        job, _ = self._started_job(farm_printer, "restart")
        if job.state is not JobState.PAUSED or job.cancel_task is not None:
            raise RuntimeError(f"only a paused print can be restarted: {job.describe()}")
        script, remove_file = job.cancel_script, job.remove_file
        job.cancel_script, job.remove_file = (), False  # the new job owns the file, and the heaters stay on
        job.cancelling(f"a restart by {by}")
        job.cancel_task = asyncio.ensure_future(self._cancel(farm_printer, job))
        await asyncio.shield(job.cancel_task)
        return await self.start_print(
            farm_printer,
            job.path,
            name=job.file,
            started_by=by,
            cancel_script=script,
            end_script=job.end_script,
            remove_file=remove_file,
            **job.options,
        )

    async def _cancel(self, farm_printer: FarmPrinter, job: Job) -> None:
        assert job.handle is not None  # `_started_job` refuses a job still starting
        try:
            await job.handle.cancel(job.cancel_script)
        finally:
            job.ended()  # the asker hears it ended (`_follow_print` says how, in its event)
        self.emit(farm_printer, "cancel_script", f"{job.file}: ran {'; '.join(job.cancel_script) or 'nothing'}")

    async def answer_prompt(self, farm_printer: FarmPrinter, index: int) -> None:
        """Answer `farm_printer`'s open prompt with button `index` (`Printer.answer_prompt`), and say so with a
        prompt_closed event (the printer's own `prompt_end` after an answer closes nothing left open).

        Raises:
            RuntimeError: the printer is not connected.
            ValueError: no prompt is open, or it has no button `index` (nothing is written).
            MarlinError: as `Printer.answer_prompt`.
        """
        printer = farm_printer.printer
        if printer is None or not farm_printer.link_up:
            raise RuntimeError(f"printer {farm_printer.name!r} is not connected")
        prompt = printer.prompt
        await printer.answer_prompt(index)
        label = prompt.buttons[index] if prompt is not None else str(index)
        self.emit(farm_printer, "prompt_closed", f"answered {label} (M876 S{index})")

    async def _follow_print(self, farm_printer: FarmPrinter, job: Job) -> None:
        """Wait for a print to end and say how, then run its end script; never raise (but when cancelled)."""
        assert job.handle is not None
        try:
            progress = await job.handle.wait()
        except Exception as exc:  # every ending is news of this printer, never a crash of the farm
            where = job.handle.progress.last_source_line
            reason = _print_failure(exc)
            message = f"{job.file}: {reason} at file line {where}: {exc}"
            job.ended(one_line(redact(message)))
            self.emit(farm_printer, "print_failed", message)
            return
        if job.cancel_task is not None:
            with contextlib.suppress(Exception):  # the cancel's own caller hears how its script went
                await asyncio.shield(job.cancel_task)
        elif progress.state is marlin_aio.PrintState.CANCELLED and farm_printer.printer is not None:
            # The printer itself cancelled it (//action:cancel): the same cancel script as any door's cancel.
            job.cancelling(progress.cancelled_by or "the printer")
            try:
                for command in job.cancel_script:
                    await farm_printer.printer.send(command)
            except (marlin_aio.MarlinError, ValueError) as exc:
                self.emit(farm_printer, "print_failed", f"{job.file}: its cancel script failed: {exc}")
        elif progress.state is marlin_aio.PrintState.DONE and job.end_script and farm_printer.printer is not None:
            try:
                for command in job.end_script:
                    await farm_printer.printer.send(command)
            except (marlin_aio.MarlinError, ValueError) as exc:
                self.emit(farm_printer, "print_failed", f"{job.file}: its end script failed: {exc}")
        job.ended()
        kind = "print_finished" if progress.state is marlin_aio.PrintState.DONE else "print_cancelled"
        by = f" by {job.cancelled_by}" if kind == "print_cancelled" and job.cancelled_by else ""
        at_line = f"at file line {progress.last_source_line}"
        self.emit(farm_printer, kind, f"{job.file}: {progress.state.value}{by} {at_line}")

    def emit(self, farm_printer: FarmPrinter, kind: str, message: str) -> None:
        """Tell the listener that `kind` happened to `farm_printer` (also for events from outside: a print).

        The message is redacted here, once for the event, the last error and whatever prints or publishes them: it
        is often an error's text, which may quote an `M511 P<password>` from the library or from a user's G-code.
        """
        message = one_line(redact(message))
        if kind in ("connection_lost", "halted", "thermal_runaway", "connect_failed", "print_failed"):
            farm_printer.last_error = message
        try:
            self._on_event(FarmEvent(farm_printer.name, kind, message))
        except Exception:  # a listener's bug must not stop a printer's supervisor
            _log.exception("event listener failed on %s %s", farm_printer.name, kind)

    async def _supervise(self, farm_printer: FarmPrinter) -> None:
        def on_retry(retry: Retry) -> None:
            exc = retry.error
            if retry.connected:
                kind = (
                    "thermal_runaway"
                    if isinstance(exc, marlin_aio.ThermalRunawayError)
                    else ("halted" if isinstance(exc, marlin_aio.PrinterHaltedError) else "connection_lost")
                )
                self.emit(farm_printer, kind, str(exc))
            elif retry.attempt == 1:
                self.emit(farm_printer, "connect_failed", str(exc))  # said once per outage, not at every retry
            _log.info("%s: reconnecting in %g s", farm_printer.name, retry.delay_s)
            farm_printer.reconnect_at_s = time.monotonic() + retry.delay_s

        await keep_connected(
            lambda: self._connected(farm_printer),
            lambda printer: self._watch(farm_printer, printer),
            backoff=Backoff(self._backoff_start_s, self._backoff_max_s),
            on_retry=on_retry,
        )

    @contextlib.asynccontextmanager
    async def _connected(self, farm_printer: FarmPrinter) -> AsyncIterator[marlin_aio.Printer]:
        spec = farm_printer.spec
        farm_printer.reconnect_at_s = None  # trying now
        async with contextlib.AsyncExitStack() as stack:
            url = spec.port
            if spec.sim:
                server = self.sims.get(spec.name)
                if server is None:
                    from marlin_aio.simulator import SimulatorConfig, serve_pty

                    # The simulated printer lives as long as the farm: a reconnect finds it as it was left. Its record
                    # of commands is small: a farm runs for days.
                    config = SimulatorConfig(seed=len(self.sims), record_limit=SIM_RECORD_LIMIT)
                    server = serve_pty(config, time_scale=spec.sim_speed)
                    await server.start()
                    self.sims[spec.name] = server
                url = server.url
            assert url is not None
            farm_printer.url = url
            printer = marlin_aio.Printer(
                url,
                baudrate=spec.baud,
                timeout_s=spec.timeout_s,
                max_hotend_celsius=spec.max_hotend_celsius,
                max_bed_celsius=spec.max_bed_celsius,
                max_chamber_celsius=spec.max_chamber_celsius,
                password=spec.password,
                wire_log=None if self.wire_log is None else self.wire_log.named(spec.name),
            )
            await stack.enter_async_context(printer)
            farm_printer.printer = printer
            try:
                yield printer
            finally:
                farm_printer.link_up = False
                farm_printer.printer = None

    async def _watch(self, farm_printer: FarmPrinter, printer: marlin_aio.Printer) -> None:
        """Poll a connected printer until its link fails; raise that failure."""
        farm_printer.link_up = True
        farm_printer.connections += 1
        farm_printer.firmware = printer.firmware.name if printer.firmware is not None else None
        farm_printer.machine = printer.firmware.fields.get("MACHINE_TYPE") if printer.firmware is not None else None
        farm_printer.last_error = None
        self.emit(
            farm_printer,
            "connected",
            f"{farm_printer.url} ({farm_printer.firmware or 'firmware unknown'})",
        )
        if printer.reset_on_open:
            self.emit(
                farm_printer, "reset", "the board reset when the port was opened; targets set earlier were cleared"
            )
        stop = printer.on_reading(farm_printer.on_reading)

        def on_link_event(event: marlin_aio.LinkEvent) -> None:
            # A reset while connected is told by the printer as it happens (no polling of its counters).
            if event.kind == "reset":
                self.emit(farm_printer, "reset", event.message)

        stop_link_events = printer.on_link_event(on_link_event)
        stop_requests = printer.on_host_request(lambda request: self._host_request(farm_printer, request))
        try:
            async with printer.poll_temperatures(farm_printer.spec.poll_interval_s):
                raise await printer.wait_for_failure()
        finally:
            stop_requests()
            stop_link_events()
            stop()

    def _host_request(self, farm_printer: FarmPrinter, request: marlin_aio.HostRequest) -> None:
        """A request of the firmware: its event (a prompt with its buttons, a pause with its reason), then the
        printer's request listeners (the service tells its clients)."""
        kind = REQUEST_EVENTS.get(request.action)
        if kind is not None:
            if request.prompt is not None:
                buttons = ", ".join(request.prompt.buttons)
                message = request.prompt.message + (f" (buttons: {buttons})" if buttons else "")
            elif kind == "prompt_closed":
                message = "the printer closed its prompt"
            else:
                message = request.reason
            self.emit(farm_printer, kind, message)
        for listener in list(farm_printer.request_listeners):
            try:
                listener(request)
            except Exception:  # a listener's bug must not stop the printer's other listeners
                _log.exception("request listener failed on %s %s", farm_printer.name, request.action)
