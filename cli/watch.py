"""`marlin-temp watch`: readings arrive about every 10 ms, the screen redraws about once a second.

Readings go into the `WatchModel` as they arrive (cheap); rendering happens only at the refresh interval, so
CPU stays low on a Raspberry Pi. In a terminal the view is a rich `Live` on the alternate screen, restored on
exit; `q` or Ctrl-C leaves. Piped, it prints one plain line (or JSON line) per refresh.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.text import Text

import marlin_aio

from .connect import ConnectOptions, Exit, open_printer
from .logfile import TemperatureLog
from .model import WatchModel
from .render import plain_line, watch_view
from .terminal import key_presses, on_stop_signals

__all__ = ["WatchSettings", "watch_printer"]


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
    newest = since
    for answered_s, latency_s in printer.round_trips:
        if answered_s > since:
            model.add_latency(answered_s, latency_s)
            newest = answered_s
    return newest


def _json_status(model: WatchModel) -> str:
    link = model.link()
    heaters = {}
    for key in model.heater_keys():
        status = model.status(key)
        heaters[key] = {
            "actual": status.actual,
            "target": status.target,
            "power_percent": status.power_percent,
            "rate_c_per_s": status.rate_c_per_s,
            "state": status.state,
            "eta_s": status.eta_s,
        }
    return json.dumps(
        {
            "time": time.time(),
            "heaters": heaters,
            "polls_per_s": link.polls_per_s,
            "latency_median_ms": link.latency_median_ms,
            "timeouts": link.timeouts,
            "errors": link.errors,
        }
    )


async def _session(
    printer: marlin_aio.Printer,
    label: str,
    model: WatchModel,
    settings: WatchSettings,
    console: Console,
    log: TemperatureLog | None,
    stop: asyncio.Event,
    deadline: float | None,
) -> None:
    loop = asyncio.get_running_loop()
    live_view = console.is_terminal and not settings.json_lines
    firmware = printer.firmware.name if printer.firmware else "unknown firmware"

    first = asyncio.Event()  # the first reading is shown as soon as it is read, not a refresh period later

    async def consume() -> None:
        async for reading in printer.temperature_readings():
            model.add(reading)
            first.set()
            if log is not None:
                log.add(reading)

    def view() -> Text | object:
        if not model.series:
            return Text(f"{label}: waiting for the first reading...")
        chart_height = min(max(console.height - len(model.heater_keys()) - 10, 6), 30)
        return watch_view(model, label, firmware, width=console.width, chart_height=chart_height)

    since = 0.0
    baseline = _Baseline.now(model, printer)  # after the handshake: `open_printer` has run it
    async with printer.poll_temperatures(settings.interval_s):
        consumer = asyncio.create_task(consume(), name="marlin-temp readings")
        stopper = asyncio.create_task(stop.wait(), name="marlin-temp stop")
        first_reading: asyncio.Task[bool] | None = asyncio.create_task(first.wait(), name="marlin-temp first reading")
        live = Live(console=console, screen=True, auto_refresh=False, transient=True) if live_view else None
        try:
            with (
                live if live is not None else contextlib.nullcontext(),
                key_presses(lambda key: stop.set() if key == "q" else None),
            ):
                while True:
                    timeout = settings.refresh_s
                    if deadline is not None:
                        timeout = min(timeout, max(deadline - loop.time(), 0.0))
                    waiting = {consumer, stopper} if first_reading is None else {consumer, stopper, first_reading}
                    done, _ = await asyncio.wait(waiting, timeout=timeout, return_when="FIRST_COMPLETED")
                    if first_reading is not None and first_reading in done:
                        first_reading = None
                    if consumer in done:
                        consumer.result()  # raises what ended the readings (link lost, printer halted)
                    since = _update_link_stats(model, printer, since, baseline)
                    if live is not None:
                        live.update(view(), refresh=True)  # type: ignore[arg-type]
                    elif model.series:
                        print(_json_status(model) if settings.json_lines else plain_line(model), flush=True)
                    if stopper in done or (deadline is not None and loop.time() >= deadline):
                        return
        finally:
            tasks = [consumer, stopper] if first_reading is None else [consumer, stopper, first_reading]
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
    with on_stop_signals(stop.set):
        async with log if log is not None else contextlib.nullcontext():
            while True:
                try:
                    async with open_printer(options, errors) as (printer, label):
                        await _session(printer, label, model, settings, console, log, stop, deadline)
                        break
                except (marlin_aio.ConnectionLostError, marlin_aio.ConnectError, marlin_aio.HandshakeError) as exc:
                    if not settings.reconnect or stop.is_set():
                        if isinstance(exc, marlin_aio.ConnectionLostError):
                            raise marlin_aio.ConnectionLostError(
                                f"{exc} (unplugged? use --reconnect to keep retrying)"
                            ) from exc
                        raise
                    errors.print(f"{exc}; retrying in 2 s (Ctrl-C stops)", style="yellow")
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(stop.wait(), 2.0)
                    if stop.is_set():
                        break
    link = model.link()
    elapsed = loop.time() - started
    summary = f"watched {elapsed:.1f} s: {model.readings} readings, {link.timeouts} timeouts, {link.errors} errors"
    if log is not None:
        summary += f"; {log.summary.line()}"
    errors.print(summary, style="dim")
    return Exit.OK
