"""`marlin-temp print FILE`: stream a G-code file with a progress bar and live temperatures.

Ctrl-C does not kill a print half way through a line: it asks (on a terminal) whether to cancel, and a cancel
stops feeding, lets the printer answer what it has, then turns the heaters and fan off (unless --keep-heaters).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console, Group
from rich.live import Live
from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn
from rich.text import Text

import marlin_aio

from .connect import ConnectOptions, Exit, open_printer
from .terminal import key_presses, on_stop_signals

__all__ = ["PrintSettings", "print_gcode"]

CANCEL_SCRIPT = marlin_aio.COOL_DOWN


@dataclass(frozen=True)
class PrintSettings:
    """What `print` was asked to do."""

    path: Path
    send_ahead: bool = False
    window_bytes: int | None = None
    keep_heaters: bool = False


def _temperatures(printer: marlin_aio.Printer) -> Text:
    reading = printer.latest
    text = Text("  ")
    if reading is None:
        return text.append("temperatures: waiting for a reading", style="dim")
    for key, style in (("T", "red"), ("B", "blue"), ("C", "green")):
        heater = reading.temperatures.heaters.get(key)
        if heater is not None:
            target = "off" if not heater.target else f"{heater.target:.0f}"
            text.append(f"{marlin_aio.heater_name(key)} ", style=style).append(f"{heater.actual:.1f}/{target} °C   ")
    return text


def _plain_progress(progress: marlin_aio.PrintProgress, printer: marlin_aio.Printer) -> str:
    fraction = progress.fraction
    percent = "?" if fraction is None else f"{fraction * 100:5.1f}%"
    total = "?" if progress.lines_total is None else str(progress.lines_total)
    eta = progress.eta_s
    line = f"{percent} {progress.lines_acked}/{total} lines {progress.lines_per_s:.0f} lines/s"
    line += f" ETA {'?' if eta is None else time.strftime('%H:%M:%S', time.gmtime(eta))}"
    return line + _temperatures(printer).plain.rstrip()


async def print_gcode(options: ConnectOptions, settings: PrintSettings, console: Console, errors: Console) -> Exit:
    """Stream the file; return the exit code (0 done, 130 cancelled).

    Raises:
        MarlinError: the print failed (a `PrintStalledError` carries the trace, printed before raising).
        ValueError: a line of the file is not a valid command (nothing was sent).
    """
    interrupted = asyncio.Event()
    with on_stop_signals(interrupted.set):
        async with open_printer(options, errors) as (printer, label), printer.poll_temperatures(1.0):
            handle = await printer.start_print(
                settings.path, send_ahead=settings.send_ahead, window_bytes=settings.window_bytes
            )
            mode = "send-ahead" if settings.send_ahead else "ping-pong"
            errors.print(f"printing {settings.path.name} on {label} ({mode}); Ctrl-C to cancel", style="dim")
            try:
                script = () if settings.keep_heaters else CANCEL_SCRIPT
                cancelled = await _follow(handle, printer, console, errors, interrupted, script)
            except marlin_aio.PrintStalledError as exc:
                errors.print(f"[bold red]error:[/] {exc}", highlight=False)
                errors.print("last lines sent (>>) and received (<<), seconds before the stall:", style="dim")
                errors.print(exc.trace, highlight=False, markup=False)
                raise
            final = handle.progress
            if cancelled:
                heaters = "heaters left on" if settings.keep_heaters else "heaters and fan turned off"
                errors.print(
                    f"cancelled after line {final.last_source_line} ({final.lines_acked} commands done); {heaters}"
                )
                return Exit.INTERRUPTED
            errors.print(
                f"done: {final.lines_acked} commands in {final.elapsed_s:.1f} s "
                f"({final.lines_per_s:.0f} lines/s, {final.bytes_acked / max(final.elapsed_s, 1e-9):.0f} bytes/s, "
                f"{final.resends} resends)"
            )
            return Exit.OK


async def _follow(
    handle: marlin_aio.PrintHandle,
    printer: marlin_aio.Printer,
    console: Console,
    errors: Console,
    interrupted: asyncio.Event,
    script: tuple[str, ...],
) -> bool:
    """Show progress until the print ends; handle Ctrl-C, cancelling with `script`. Return True if it was
    cancelled."""
    pressed: asyncio.Queue[str] = asyncio.Queue()
    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} lines  {task.fields[rate]:.0f} lines/s"),
        TimeRemainingColumn(),
        console=console,
        auto_refresh=False,
    )
    total = handle.job.lines_total or 0
    task = bar.add_task(handle.job.name, total=total or None, rate=0.0)
    asking = False
    cancelled = False
    done = asyncio.ensure_future(handle.wait())
    live = Live(Group(bar, Text("")), console=console, auto_refresh=False) if console.is_terminal else None
    last_plain = 0.0
    with key_presses(pressed.put_nowait) as keys, live if live is not None else contextlib.nullcontext():
        while not done.done():
            waiters = [done, asyncio.ensure_future(interrupted.wait()), asyncio.ensure_future(pressed.get())]
            finished, _ = await asyncio.wait(waiters, timeout=0.25, return_when="FIRST_COMPLETED")
            for waiter in waiters[1:]:
                if waiter not in finished:
                    waiter.cancel()
            if waiters[1] in finished:
                interrupted.clear()
                if asking or not keys:
                    # A second Ctrl-C, or no terminal to ask on: cancel at once.
                    cancelled = True
                    await handle.cancel(script)
                    break
                asking = True
            if waiters[2] in finished and asking:
                key = waiters[2].result()
                asking = False
                if key == "y":
                    cancelled = True
                    bar.update(task, description="cancelling...")
                    await handle.cancel(script)
                    break
            progress = handle.progress
            description = (
                "[bold yellow]cancel the print? y = yes, any other key = go on[/]" if asking else handle.job.name
            )
            bar.update(task, completed=progress.lines_acked, rate=progress.lines_per_s, description=description)
            if live is not None:
                live.update(Group(bar, _temperatures(printer)), refresh=True)
            elif time.monotonic() - last_plain >= 2.0:
                last_plain = time.monotonic()
                print(_plain_progress(progress, printer), flush=True)
        if not cancelled:
            done.result()  # raises what ended the print
        progress = handle.progress
        bar.update(task, completed=progress.lines_acked, rate=progress.lines_per_s)
        if live is not None:
            live.update(Group(bar, _temperatures(printer)), refresh=True)
    if not done.done():
        done.cancel()
    return cancelled
