"""`marlin-temp watch`: readings arrive about every 10 ms, the screen redraws about once a second.

Readings go into the `WatchModel` as they arrive (cheap); rendering happens only at the refresh interval (and
when a key is pressed), so CPU stays low on a Raspberry Pi. In a terminal the view is a rich `Live` on the
alternate screen, restored on exit; `q` or Ctrl-C leaves. Piped, it prints one plain line (or JSON line) per
refresh, and only `q` (when stdin is a terminal) means anything.

In the live view, keys set targets, the fan, or send a G-code line (`WatchControls` decides what a key means and
checks targets; nothing it refuses is sent). One task performs those actions one after another, beside the
polling, and hands each outcome back to the view: the port is held by watch, so this is where `set` runs now.
An action the library refuses (a target above the limits typed on the `:` line) is one line in the view, never a
traceback; quitting while a target set by the keys is still on says so, in `set`'s words.

On a printer of `marlin-temp serve`, the service's print job is read about once a second (its `job` verb, cheap)
and shown over the table, in the plain lines and in the JSON lines; while it runs, p pauses or resumes it and c
cancels it after a y (the actions go through the same task, as the service's `pause`, `resume` and `cancel`). A
printer on a serial port has no job: none of it shows.

The printer's text (replies, its firmware name) reaches the view as `rich.text.Text`, and the lines printed on
stderr have markup and emoji codes off: nothing the printer or the user typed is read as rich markup.

Over 400 lines because it runs both views, one printer's and the farm's, which share the refresh loop, the
keys and the plain-line output; what is drawn is in `common.render`, what a key means in `common.model`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.text import Text

import marlin_aio
import marlin_aio.protocol
from marlin_aio.aio import WireLog
from marlin_aio.farm.presets import DEFAULT_PRESETS, Preset
from marlin_aio.farm.supervisor import Farm, FarmEvent, PrinterSpec

from ..common.connect import ConnectOptions, Exit, run_sessions
from ..common.keys import key_presses, on_stop_signals
from ..common.model import (
    Action,
    AnswerPrompt,
    CancelJob,
    JobStatus,
    Notice,
    PauseJob,
    Quit,
    ResumeJob,
    SendCommand,
    SetFan,
    SetTargets,
    TurnOff,
    WatchControls,
    WatchModel,
)
from ..common.prompts import prompt_text
from ..common.render import plain_line, watch_view
from ..farm.view import FarmKeys, detail_view, farm_row, farm_view, json_lines, plain_lines
from ..heaters.command import say_heaters_left_on
from ..job.command import describe_job
from ..logs.files import TemperatureLog

__all__ = ["WatchSettings", "watch_farm", "watch_printer"]


@dataclass(frozen=True)
class WatchSettings:
    """What `watch` was asked to do."""

    interval_s: float = 0.01
    refresh_s: float = 1.0
    window_s: float = 60.0
    tolerance_c: float = 2.0
    log_path: Path | None = None
    json_lines: bool = False
    duration_s: float | None = None
    reconnect: bool = False
    presets: tuple[Preset, ...] = DEFAULT_PRESETS
    """The presets file's presets: the keys 1-9 of one printer's view."""
    wire_log: WireLog | None = None
    """The farm view's wire log (--wire-log with several printers); one printer's is in its `ConnectOptions`."""


@dataclass(frozen=True)
class _Baseline:
    """The counters when a connection was established, so the footer counts only what happened after it.

    A board that resets when the port opens prints `start` while the handshake runs, failing the M105 in flight
    then, and a bootloader's silence times a few out: that is the board starting, not the link failing. With
    --reconnect the model keeps the counts of the earlier connections (`model_timeouts`, `model_errors`).
    """

    timeouts: int
    failed: int
    resets: int
    model_timeouts: int
    model_errors: int

    @classmethod
    def now(cls, model: WatchModel, printer: marlin_aio.Printer) -> _Baseline:
        """The baseline for `printer`, just connected."""
        stats = printer.stats
        return cls(stats.timeouts, stats.failed, stats.resets, model.timeouts, model.errors)


def _update_link_stats(model: WatchModel, printer: marlin_aio.Printer, since: float, baseline: _Baseline) -> float:
    """Copy counters and new round trips from the client into the model; return the newest round-trip time."""
    stats = printer.stats
    timeouts = stats.timeouts - baseline.timeouts
    failures = stats.failed - baseline.failed - timeouts
    resets = stats.resets - baseline.resets
    model.timeouts = baseline.model_timeouts + timeouts
    # watch has at most one command in flight (its poll), so a reset fails at most one. The larger count is what
    # went wrong without counting a reset twice, nor missing one that came between two polls.
    model.errors = baseline.model_errors + max(failures, resets)
    return _copy_round_trips(model, printer.round_trips, since)


def _copy_round_trips(model: WatchModel, round_trips: deque[tuple[float, float]], since: float) -> float:
    """Hand the round trips answered after `since` to the model, oldest first; return the newest one's time."""
    # Polls included, the deque holds up to 8,192 of them: read back only to the last one copied.
    fresh = []
    for answered_s, latency_s in reversed(round_trips):
        if answered_s <= since:
            break
        fresh.append((answered_s, latency_s))
    for answered_s, latency_s in reversed(fresh):
        model.add_latency(answered_s, latency_s)
    return fresh[0][0] if fresh else since


def _json_status(model: WatchModel, job: dict[str, Any] | None = None, served: bool = False) -> str:
    link = model.link()
    heaters = {}
    for key in model.heater_keys():
        status = model.status(key)
        # By name, as the screen and the log files say them ("hotend", "bed", "hotend 0").
        heaters[marlin_aio.protocol.heater_name(key)] = {
            "actual": status.actual,
            "target": status.target,
            "power_percent": status.power_percent,
            "rate_c_per_s": status.rate_c_per_s,
            "state": status.state,
            "eta_s": status.eta_s,
        }
    line: dict[str, object] = {
        "time": time.time(),
        "heaters": heaters,
        "polls_per_s": link.polls_per_s,
        "latency_median_ms": link.latency_median_ms,
        "timeouts": link.timeouts,
        "errors": link.errors,
    }
    if served:
        line["job"] = job  # the service's own shape (`marlin-temp job status --json`), null before the first
    return json.dumps(line)


_REPLY_LINES = 8  # of a G-code reply shown under the chart; M503 prints dozens


def _celsius(value: float) -> str:
    return "off" if value == 0 else f"{value:g} °C"


#: How often the served printer's job is read (at most; a key that changes it reads it at once).
JOB_EVERY_S = 1.0

JobCall = Callable[..., Awaitable[Any]]


def _job_call(printer: marlin_aio.Printer) -> JobCall | None:
    """The served printer's requests to its service (`ServedPrinter.call`), or None: a printer on a serial port has
    no job to read."""
    call: JobCall | None = getattr(printer, "call", None)
    return call


async def _perform_job(printer: marlin_aio.Printer, action: PauseJob | ResumeJob | CancelJob) -> Notice:
    """Pause, resume or cancel the served printer's job through the service's verbs.

    Raises:
        MarlinError: as the service raised it (the link went away).
    """
    call = _job_call(printer)
    if call is None:
        return Notice("this printer has no print job (not a printer of marlin-temp serve)", error=True)
    verb = {PauseJob: "pause", ResumeJob: "resume", CancelJob: "cancel"}[type(action)]
    try:
        value = await call(verb)
    except RuntimeError as exc:  # the service's refusal: none running, still starting
        return Notice(" ".join(str(exc).split()), error=True)
    job = value.get("job", value) if verb == "cancel" else value
    if verb == "pause":
        return Notice(f"paused {job['file']}: no new lines are sent; the heaters stay as they are (p resumes)")
    if verb == "resume":
        return Notice(f"resumed {job['file']}")
    return Notice(describe_job(job))


async def _perform(printer: marlin_aio.Printer, action: Action, model: WatchModel) -> Notice:
    """Do what a key asked; return what the view should say about it.

    Raises:
        ValueError: the library refused the command before sending it (a G-code line that is not ASCII, too long).
        MarlinError: as `Printer.send`.
    """
    if isinstance(action, SetTargets):
        await printer.set_temperatures(hotend=action.hotend, bed=action.bed)
        pairs = (("hotend", action.hotend), ("bed", action.bed))
        said = ", ".join(f"{name} target {_celsius(value)}" for name, value in pairs if value is not None)
        return Notice(f"{action.label}: {said}" if action.label else said)
    if isinstance(action, TurnOff):
        keys = model.heater_keys()
        hotends = [key for key in keys if key[0] == "T" and key[1:].isdigit()]
        # Every hotend by number when the printer reports several; otherwise the one there is.
        for key in hotends:
            await printer.set_temperatures(hotend=0, tool=int(key[1:]))
        await printer.set_temperatures(
            hotend=None if hotends else 0, bed=0 if "B" in keys else None, chamber=0 if "C" in keys else None
        )
        return Notice("every heater off")
    if isinstance(action, SetFan):
        await printer.set_fan(action.percent / 100)
        return Notice("fan off" if action.percent == 0 else f"fan {action.percent:g} %")
    if isinstance(action, AnswerPrompt):
        await printer.answer_prompt(action.index)
        return Notice(f"answered the printer: {action.label} (M876 S{action.index})")
    if isinstance(action, PauseJob | ResumeJob | CancelJob):
        return await _perform_job(printer, action)
    if isinstance(action, SendCommand):
        reply = await printer.send(action.text)
        lines = list(reply.lines)
        ok = f"ok {reply.ok.payload}".rstrip()
        shown = lines[-_REPLY_LINES:]
        if len(lines) > len(shown) or reply.lines_dropped:
            shown.insert(0, f"({len(lines) - len(shown) + reply.lines_dropped} earlier lines not shown)")
        return Notice(f"> {action.text}", (*shown, ok))
    raise AssertionError(f"not an action to perform: {action!r}")


async def _outcome(printer: marlin_aio.Printer, action: Action, model: WatchModel) -> Notice:
    """`_perform`, with what it raises as an error notice of one line (the view has room for no more, and a
    message may quote what was typed). A lost link or a halt also ends the readings, and watch with them; until
    then, it is said here."""
    try:
        return await _perform(printer, action, model)
    except (ValueError, marlin_aio.MarlinError) as exc:
        message = " ".join(str(exc).split())
        # The library refuses with ValueError before anything is written.
        return Notice(f"{message}; nothing sent" if isinstance(exc, ValueError) else message, error=True)


async def _session(
    printer: marlin_aio.Printer,
    label: str,
    model: WatchModel,
    settings: WatchSettings,
    console: Console,
    log: TemperatureLog | None,
    stop: asyncio.Event,
    deadline: float | None,
    controls: WatchControls,
) -> None:
    loop = asyncio.get_running_loop()
    live_view = console.is_terminal and not settings.json_lines
    firmware = printer.firmware.name if printer.firmware else "unknown firmware"
    actions: asyncio.Queue[Action] = asyncio.Queue()
    wake = asyncio.Event()  # a key was pressed or an action finished: redraw now, not at the next refresh

    first = asyncio.Event()  # the first reading is shown as soon as it is read, not a refresh period later
    call = _job_call(printer)
    read_job = asyncio.Event()  # a job key was acted on: read the job now, not at the next tick
    latest_job: dict[str, Any] | None = None
    controls.show_job(None)  # a job of an earlier connection (--reconnect) is not this one's

    async def follow_job(call: JobCall) -> None:
        """Read the job about once a second; piped, say it in a line of its own when it starts or changes state."""
        nonlocal latest_job
        said: tuple[object, object] | None = None
        while True:
            read_job.clear()
            try:
                value = await call("job")
            except marlin_aio.ConnectionLostError:
                return  # the readings end too, and say why
            except (marlin_aio.MarlinError, RuntimeError, ValueError, OSError) as exc:
                controls.notice = Notice(f"the service tells no print job: {' '.join(str(exc).split())}", error=True)
                wake.set()
                return
            latest_job = value  # whole, for the JSON lines
            job = None if value is None else JobStatus.from_json(value)
            if job != controls.job:
                controls.show_job(job)
                wake.set()
            piped = not live_view and not settings.json_lines
            if piped and value is not None and (value["id"], value["state"]) != said:
                said = (value["id"], value["state"])
                print(f"job: {describe_job(value)}", flush=True)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(read_job.wait(), min(settings.refresh_s, JOB_EVERY_S))

    async def consume() -> None:
        async for reading in printer.temperature_readings():
            model.add(reading)
            first.set()
            if log is not None:
                log.add(reading)

    async def perform() -> None:
        while True:
            action = await actions.get()
            if isinstance(action, SendCommand):
                # M109, G28 and the like take a while: say it went out rather than show nothing.
                controls.notice = Notice(f"> {action.text}", ("(waiting for the reply)",))
                wake.set()
            elif isinstance(action, CancelJob) and controls.job is not None:
                # The service stops feeding, waits for what is in flight and runs the cancel script: seconds.
                controls.notice = Notice(f"cancelling {controls.job.file}", ("(the service runs its cancel script)",))
                wake.set()
            notice = await _outcome(printer, action, model)
            controls.finished(action, notice)
            if isinstance(action, PauseJob | ResumeJob | CancelJob):
                read_job.set()
            wake.set()

    def on_key(key: str) -> None:
        if not live_view:
            if key.lower() == "q":  # piped: as before, q is the only key
                stop.set()
            return
        action = controls.press(key, model)
        if isinstance(action, Quit):
            stop.set()
        elif action is not None:
            actions.put_nowait(action)
        wake.set()

    def show_prompt() -> None:
        controls.printer_prompt = printer.prompt
        text = prompt_text(printer.prompt, printer.waiting_for_user)
        if text != controls.printer_prompt_text and text is not None and not live_view:
            print(text, flush=True)  # piped: the printer's question once, as it comes
        controls.printer_prompt_text = text

    def view() -> Text | object:
        if not model.series:
            return Text(f"{label}: waiting for the first reading...")
        return watch_view(model, label, firmware, width=console.width, height=console.height, controls=controls)

    since = 0.0
    baseline = _Baseline.now(model, printer)  # after the handshake: `open_printer` has run it
    stop_requests = printer.on_host_request(lambda _request: wake.set())  # a prompt shows at once
    async with printer.poll_temperatures(settings.interval_s):
        consumer = asyncio.create_task(consume(), name="marlin-temp readings")
        performer = asyncio.create_task(perform(), name="marlin-temp key actions")
        stopper = asyncio.create_task(stop.wait(), name="marlin-temp stop")
        waker = asyncio.create_task(wake.wait(), name="marlin-temp redraw")
        first_reading: asyncio.Task[bool] | None = asyncio.create_task(first.wait(), name="marlin-temp first reading")
        job_follower: asyncio.Task[None] | None = None
        if call is not None:
            job_follower = asyncio.create_task(follow_job(call), name="marlin-temp print job")
        live = Live(console=console, screen=True, auto_refresh=False, transient=True) if live_view else None
        try:
            with (
                live if live is not None else contextlib.nullcontext(),
                key_presses(on_key, raw=live_view) as keys_enabled,
            ):
                controls.keys_enabled = keys_enabled
                next_refresh = loop.time() + settings.refresh_s
                while True:
                    timeout = max(next_refresh - loop.time(), 0.0)
                    if deadline is not None:
                        timeout = min(timeout, max(deadline - loop.time(), 0.0))
                    waiting: set[asyncio.Task[object]] = {consumer, performer, stopper, waker}
                    if first_reading is not None:
                        waiting.add(first_reading)
                    if job_follower is not None:
                        waiting.add(job_follower)
                    done, _ = await asyncio.wait(waiting, timeout=timeout, return_when="FIRST_COMPLETED")
                    if consumer in done:
                        consumer.result()  # raises what ended the readings (link lost, printer halted)
                    if performer in done:
                        performer.result()  # it only ends by a bug: let it show
                    if job_follower is not None and job_follower in done:
                        job_follower.result()  # it ends when the link does (said by the readings), or by a bug
                        job_follower = None
                    if waker in done:
                        wake.clear()
                        waker = asyncio.create_task(wake.wait(), name="marlin-temp redraw")
                    # A key redraws the view at once but leaves the refresh schedule (and the piped lines) alone.
                    scheduled = loop.time() >= next_refresh or stopper in done
                    if first_reading is not None and first_reading in done:
                        first_reading = None
                        scheduled = True
                    if scheduled:
                        next_refresh = loop.time() + settings.refresh_s
                    since = _update_link_stats(model, printer, since, baseline)
                    show_prompt()
                    if live is not None:
                        live.update(view(), refresh=True)  # type: ignore[arg-type]
                    elif model.series and (scheduled or (deadline is not None and loop.time() >= deadline)):
                        line = (
                            _json_status(model, latest_job, served=call is not None)
                            if settings.json_lines
                            else plain_line(model, job=controls.job)
                        )
                        print(line, flush=True)
                    if stopper in done or (deadline is not None and loop.time() >= deadline):
                        return
        finally:
            tasks: list[asyncio.Task[object]] = [consumer, performer, stopper, waker]
            if first_reading is not None:
                tasks.append(first_reading)
            if job_follower is not None:
                tasks.append(job_follower)
            stop_requests()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)


async def watch_printer(options: ConnectOptions, settings: WatchSettings, console: Console, errors: Console) -> Exit:
    """Run `watch` until q, Ctrl-C or --duration; return the exit code.

    Raises:
        MarlinError: the printer could not be opened, halted, or went away (without --reconnect).
    """
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    model = WatchModel(settings.window_s, settings.tolerance_c)
    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s
    started = loop.time()
    log = TemperatureLog(settings.log_path) if settings.log_path is not None else None
    # One for the whole run: what the keys set is remembered across reconnects, for the word on the way out.
    controls = WatchControls(options.limits, presets=settings.presets)
    with on_stop_signals(stop.set):
        try:
            async with log if log is not None else contextlib.nullcontext():
                await _sessions(options, settings, model, console, errors, log, stop, deadline, controls)
        except BaseException as exc:
            if controls.heated:
                say_heaters_left_on(errors, model.latest, exc)
            raise
    link = model.link()
    elapsed = loop.time() - started
    summary = f"watched {elapsed:.1f} s: {model.readings} readings, {link.timeouts} timeouts, {link.errors} errors"
    if log is not None:
        summary += f"; {log.summary.line()}"
    errors.print(summary, style="dim", markup=False, emoji=False)
    if controls.heated:
        say_heaters_left_on(errors, model.latest)
    return Exit.OK


# What ends a session but not a --reconnect run: the link went away or cannot be made (yet).
_RETRIED = (marlin_aio.ConnectionLostError, marlin_aio.ConnectError, marlin_aio.HandshakeError)


async def _sessions(
    options: ConnectOptions,
    settings: WatchSettings,
    model: WatchModel,
    console: Console,
    errors: Console,
    log: TemperatureLog | None,
    stop: asyncio.Event,
    deadline: float | None,
    controls: WatchControls,
) -> None:
    """Connect and watch until the end; with --reconnect, again after each lost link (waits of 1 s doubling to
    30 s between attempts, from 1 s again once connected), until a stop or the deadline."""

    async def session(printer: marlin_aio.Printer, label: str) -> None:
        await _session(printer, label, model, settings, console, log, stop, deadline, controls)

    await run_sessions(
        options,
        errors,
        session,
        reconnect=settings.reconnect,
        retried=_RETRIED,
        goal="keep retrying",
        stop=stop,
        deadline=deadline,
    )


_FARM_EVENTS = 3  # the latest events shown under the farm table


async def watch_farm(specs: list[PrinterSpec], settings: WatchSettings, console: Console, errors: Console) -> Exit:
    """Watch several printers until q, Ctrl-C or --duration: the farm view (one row per printer; a digit, or the
    arrows and Enter, open one printer's detail); piped, one line per printer per refresh. Return the exit code.

    Each printer is kept connected by its own supervisor (`marlin_aio.farm`): one that goes away shows down and
    reconnecting while the others go on, so nothing here ends on a printer's error.
    """
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    wake = asyncio.Event()  # a key or an event: redraw now, not at the next refresh
    live_view = console.is_terminal and not settings.json_lines
    events: deque[str] = deque(maxlen=_FARM_EVENTS)

    def on_event(event: FarmEvent) -> None:
        # The kind first, as `marlin-temp farm` says it ("p2: connection lost: ..."), but "connected: connected".
        kind = "" if event.kind == "connected" else event.kind.replace("_", " ") + ": "
        line = f"{time.strftime('%H:%M:%S', time.localtime(event.time_s))} {event.printer}: {kind}{event.message}"
        if live_view:
            events.append(line)
            wake.set()
        else:
            errors.print(line, style="dim", markup=False, emoji=False)

    farm = Farm(specs, on_event)
    farm.wire_log = settings.wire_log
    printers = list(farm.printers.values())
    models = {name: WatchModel(settings.window_s, settings.tolerance_c) for name in farm.printers}
    for farm_printer in printers:
        farm_printer.reading_listeners.append(models[farm_printer.name].add)
    keys = FarmKeys(len(printers))

    def on_key(key: str) -> None:
        if keys.press(key if live_view else key.lower()):
            stop.set()
        wake.set()

    answered_since = dict.fromkeys(farm.printers, 0.0)

    def copy_round_trips() -> None:
        # For the detail view's latency figures: the replies each open printer got since the last redraw.
        for farm_printer in printers:
            if farm_printer.printer is not None:
                name = farm_printer.name
                answered_since[name] = _copy_round_trips(
                    models[name], farm_printer.printer.round_trips, answered_since[name]
                )

    def view(keys_enabled: bool) -> Group:
        copy_round_trips()
        rows = [farm_row(index + 1, p, models[p.name]) for index, p in enumerate(printers)]
        if keys.detail is not None:
            shown = printers[keys.detail]
            return detail_view(rows[keys.detail], models[shown.name], shown, width=console.width, height=console.height)
        return farm_view(rows, console.width, selected=keys.selected, events=list(events), keys_enabled=keys_enabled)

    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s
    started = loop.time()
    with on_stop_signals(stop.set):
        runner = asyncio.create_task(farm.run(), name="marlin-temp farm")
        stopper = asyncio.create_task(stop.wait(), name="marlin-temp stop")
        waker = asyncio.create_task(wake.wait(), name="marlin-temp redraw")
        live = Live(console=console, screen=True, auto_refresh=False, transient=True) if live_view else None
        try:
            with (
                live if live is not None else contextlib.nullcontext(),
                key_presses(on_key, raw=live_view) as keys_enabled,
            ):
                next_refresh = loop.time() + settings.refresh_s
                if live is not None:
                    live.update(view(keys_enabled), refresh=True)
                while True:
                    timeout = max(next_refresh - loop.time(), 0.0)
                    if deadline is not None:
                        timeout = min(timeout, max(deadline - loop.time(), 0.0))
                    done, _ = await asyncio.wait(
                        {runner, stopper, waker}, timeout=timeout, return_when="FIRST_COMPLETED"
                    )
                    if runner in done:
                        runner.result()  # the farm only ends by a bug: let it show
                    if waker in done:
                        wake.clear()
                        waker = asyncio.create_task(wake.wait(), name="marlin-temp redraw")
                    ending = stopper in done or (deadline is not None and loop.time() >= deadline)
                    scheduled = loop.time() >= next_refresh or ending
                    if scheduled:
                        next_refresh = loop.time() + settings.refresh_s
                    if live is not None:
                        live.update(view(keys_enabled), refresh=True)
                    elif scheduled:
                        rows = [farm_row(index + 1, p, models[p.name]) for index, p in enumerate(printers)]
                        lines = json_lines(rows) if settings.json_lines else plain_lines(rows)
                        print("\n".join(lines), flush=True)
                    if ending:
                        break
        finally:
            for task in (runner, stopper, waker):
                task.cancel()
            await asyncio.gather(runner, stopper, waker, return_exceptions=True)
    readings = sum(p.readings for p in printers)
    errors.print(
        f"watched {len(printers)} printers for {loop.time() - started:.1f} s: {readings} readings", style="dim"
    )
    return Exit.OK
