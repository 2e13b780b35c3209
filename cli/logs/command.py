"""`marlin-temp log`: a headless logger for long runs.

Opening the printer and recording are apart: `record_temperatures` takes an open printer and an open log, so a
test can watch the same log object while the printer misbehaves.

The order of a run is what keeps it honest. The log file is checked first (an older or foreign file is refused
before the port is even opened); then one M105 names the printer's heaters, so a file with other heaters is
refused while nothing has been sent that changes anything; only then are `--hotend`/`--bed` set, and the
readings are followed from before the first poll goes out, so a heat-up is recorded from its first reading
with its target already in the row. With `--reconnect` each connection is a new session of the same file, and
targets are not sent again: a board that reset has turned its heaters off, and re-heating a printer nobody is
watching is not this command's call. The reconnecting is the library's (`marlin_aio.aio.keep_connected`); what is
here is which failures it may retry.

`--duration` counts from the first session's recording, not from the command's start: a handshake that took
seconds (a board that resets when opened) no longer shortens the log. Until then it bounds the wait for a
printer, so a `--reconnect` run that never finds one still ends.

A log the file system stops (disk full, the file size limit) ends the run at once with one line, the rows on
disk counted in it, and exit code 1: logging is all this command does.

A run that set targets says, however it ends (Ctrl-C, --duration, a lost link, an error), which heaters are still
on and how to turn them off, in `set`'s words (`heaters.command.heaters_left_on`), from the last reading it had. Lines
that carry a file name, a port or an error's text are printed with markup and emoji codes off.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

import marlin_aio

from ..common.connect import ConnectOptions, Exit, run_sessions
from ..common.keys import on_stop_signals
from ..heaters.command import say_heaters_left_on
from .files import LogFormat, LogWriteError, TemperatureLog

__all__ = ["LogSettings", "log_temperatures", "record_temperatures"]

# What ends a session but not a --reconnect run: the link went away, the board restarted, or it does not answer
# (yet). A halted printer (M112, thermal runaway) is not among them: it needs a person.
_RECONNECTABLE = (
    marlin_aio.ConnectionLostError,
    marlin_aio.ConnectError,
    marlin_aio.HandshakeError,
    marlin_aio.PrinterResetError,
)


@dataclass(frozen=True)
class LogSettings:
    """What `log` was asked to do (targets already checked against the limits)."""

    output: Path
    fmt: LogFormat = "csv"
    interval_s: float = 1.0
    duration_s: float | None = None
    hotend: float | None = None
    bed: float | None = None
    reconnect: bool = False


async def record_temperatures(
    printer: marlin_aio.Printer,
    log: TemperatureLog,
    interval_s: float,
    duration_s: float | None,
    stop: asyncio.Event,
) -> None:
    """Poll every `interval_s` and add readings to `log` until `stop` is set or `duration_s` has passed.

    The log's sampler (if it has one) keeps one reading per interval; the readings are followed from before the
    first poll is sent, so the first row is the first reading.

    Raises:
        MarlinError: the printer halted or went away (the log keeps what was recorded).
        ValueError: the log file holds other heaters than this printer reports.
        LogWriteError: the file system refused the rows (disk full, ...); the file keeps its whole rows.
    """

    async def record() -> None:
        async for reading in printer.temperature_readings():
            log.add(reading)

    # Created before the polls start: the task subscribes on its first step, before any answer can arrive.
    recorder = asyncio.create_task(record(), name="marlin-temp log")
    stopper = asyncio.create_task(stop.wait(), name="marlin-temp stop")
    failed = asyncio.create_task(log.wait_for_failure(), name="marlin-temp log failure")
    tasks = (recorder, stopper, failed)
    try:
        async with printer.poll_temperatures(interval_s):
            done, _ = await asyncio.wait(tasks, timeout=duration_s, return_when="FIRST_COMPLETED")
            if recorder in done:
                recorder.result()
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        log.flush()
    if log.failure is not None:
        raise log.failure


def _targets_line(settings: LogSettings) -> str:
    wanted = (("hotend", settings.hotend), ("bed", settings.bed))
    return ", ".join(f"{name} target {value:g} C" for name, value in wanted if value is not None)


@dataclass
class _Run:
    """What carries over from one connection to the next."""

    targets_pending: bool
    targets_sent: bool = False
    latest: marlin_aio.TemperatureReading | None = None  # the last reading of the last session: what is on
    deadline: float | None = None
    """When --duration ends the run (the event loop's time): counted from the start of the first session's
    recording; until then, from the command's start, so a --reconnect run that never reaches a printer still ends."""
    recording: bool = False
    """Whether a session has started recording (and so moved the deadline)."""


async def _log_session(
    printer: marlin_aio.Printer,
    label: str,
    settings: LogSettings,
    log: TemperatureLog,
    stop: asyncio.Event,
    run: _Run,
    errors: Console,
) -> None:
    first = await printer.read_temperatures()
    log.check_heaters(first.temperatures.heaters)  # refuse a file with other heaters before setting anything
    if run.targets_pending:
        run.targets_pending = False
        run.targets_sent = True  # from here on, the user must hear what stays on (a failed set may have set one)
        await printer.set_temperatures(hotend=settings.hotend, bed=settings.bed)
        errors.print(f"set {_targets_line(settings)}; logging from the first reading", style="dim")
    errors.print(
        f"logging {label} to {settings.output} every {settings.interval_s:g} s, session {log.session}; Ctrl-C stops",
        style="dim",
        markup=False,
        emoji=False,
    )
    now = asyncio.get_running_loop().time()
    if not run.recording and settings.duration_s is not None:
        # --duration counts from here, not from the command's start: opening the port, the handshake (seconds on
        # a board that resets when opened) and the targets took part of it, and the rows spanned less (issue 25).
        run.deadline = now + settings.duration_s
    run.recording = True
    remaining_s = None if run.deadline is None else max(run.deadline - now, 0.0)
    await record_temperatures(printer, log, settings.interval_s, remaining_s, stop)


async def log_temperatures(options: ConnectOptions, settings: LogSettings, errors: Console) -> Exit:
    """Log until Ctrl-C, SIGTERM or the duration: set the targets, then one row per interval; return the exit code.

    Raises:
        MarlinError: the printer could not be opened, halted, or went away without --reconnect (the file keeps
            what was logged).
        ValueError: the output file is not a log of this format, or holds other heaters than this printer has.
        OSError: the file cannot be opened.
        LogWriteError: the file system refused the rows (disk full, ...); the file keeps its whole rows, and the
            message counts them.
    """
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    run = _Run(targets_pending=settings.hotend is not None or settings.bed is not None)
    if settings.duration_s is not None:
        run.deadline = loop.time() + settings.duration_s  # until the first session records (see _Run.deadline)
    with on_stop_signals(stop.set):
        try:
            await _log_until_done(options, settings, stop, run, errors)
        except BaseException as exc:
            if run.targets_sent:
                say_heaters_left_on(errors, run.latest, exc)
            raise
    if run.targets_sent:
        say_heaters_left_on(errors, run.latest)
    return Exit.OK


async def _log_until_done(
    options: ConnectOptions,
    settings: LogSettings,
    stop: asyncio.Event,
    run: _Run,
    errors: Console,
) -> None:
    """The sessions of one run, into one file, and its summary line (see `log_temperatures`)."""
    async with TemperatureLog(settings.output, settings.fmt, interval_s=settings.interval_s) as log:
        try:
            await _keep_logging(options, settings, log, stop, run, errors)
        except LogWriteError:
            raise  # its one line counts the rows on disk
        except BaseException:
            if log.summary.rows:  # what the file holds; a run refused before its first row has one line only
                errors.print(log.summary.line(), markup=False, emoji=False)
            raise
    if log.failure is not None:
        raise log.failure  # met by the last rows, as the file was closed
    errors.print(log.summary.line(), markup=False, emoji=False)


async def _keep_logging(
    options: ConnectOptions,
    settings: LogSettings,
    log: TemperatureLog,
    stop: asyncio.Event,
    run: _Run,
    errors: Console,
) -> None:
    """One session; with --reconnect, one for each connection (waits of 1 s doubling to 30 s between attempts,
    from 1 s again once connected) until a stop or the deadline."""
    rows_before = log.summary.rows

    async def session(printer: marlin_aio.Printer, label: str) -> None:
        try:
            await _log_session(printer, label, settings, log, stop, run, errors)
        finally:
            run.latest = printer.latest

    def new_session() -> None:
        nonlocal rows_before
        if log.summary.rows > rows_before:
            rows_before = log.summary.rows
            log.new_session()  # the next connection's rows are a session of their own, whatever the printer did

    loop = asyncio.get_running_loop()
    while True:
        deadline = run.deadline
        await run_sessions(
            options,
            errors,
            session,
            reconnect=settings.reconnect,
            retried=_RECONNECTABLE,
            goal="keep logging",
            stop=stop,
            deadline=deadline,
            before_wait=new_session,
        )
        # The reconnecting gives up at the deadline it was given; the first session may have moved the run's
        # later since (it counts from the first poll), and then a lost link is retried until that one.
        if stop.is_set() or run.deadline is None or run.deadline == deadline or loop.time() >= run.deadline:
            return
