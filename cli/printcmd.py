"""`marlin-temp print FILE`: stream a G-code file with a progress view, live temperatures and keys.

The file is read and checked whole before connecting (`printfile.plan_print`), so a bad file costs nothing; the view
is drawn by the pure functions of `printview`. On a terminal, p pauses (no new lines are sent; what the printer has
finishes, heaters stay on), r resumes, and ! sends M112 at once, with no question: an emergency stop must not wait
for a second key. Ctrl-C does not kill a print half way through a line: it asks (on a terminal) whether to cancel,
and a cancel stops feeding, lets the printer answer what it has, then turns the heaters and fan off (unless
--keep-heaters).
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import time
from dataclasses import dataclass

from rich.console import Console
from rich.live import Live
from rich.markup import escape

import marlin_aio

from .connect import ConnectOptions, Exit, open_printer
from .printfile import GcodePlan
from .printview import KEYS_HELP, PrintStatus, RateWindow, heating_text, plain_status, print_view, temperatures_text
from .terminal import key_presses, on_stop_signals

__all__ = ["PrintSettings", "print_gcode", "print_status"]

CANCEL_SCRIPT = marlin_aio.COOL_DOWN
_QUESTION = "cancel the print? y = yes, any other key = go on"
_PLAIN_EVERY_S = 2.0


@dataclass(frozen=True)
class PrintSettings:
    """What `print` was asked to do: the checked file and how to send it."""

    plan: GcodePlan
    send_ahead: bool = False
    window_bytes: int | None = None
    keep_heaters: bool = False


class _Outcome(enum.Enum):
    DONE = "done"
    CANCELLED = "cancelled"
    STOPPED = "stopped"  # the emergency stop


def print_status(
    progress: marlin_aio.PrintProgress,
    plan: GcodePlan,
    reading: marlin_aio.TemperatureReading | None,
    lines_per_s: float | None,
    *,
    question: str | None = None,
    keys: str | None = None,
    cancelling: bool = False,
) -> PrintStatus:
    """One frame of the view from the print's progress, the file's plan and the latest reading."""
    in_flight = progress.lines_sent > progress.lines_acked
    wait = plan.heat_wait_running(progress.last_source_line, in_flight)
    state = "printing"
    if cancelling:
        state = "cancelling"
    elif progress.state is marlin_aio.PrintState.PAUSED:
        state = "paused"
    elif wait is not None:
        state = "heating"
    return PrintStatus(
        name=plan.path.name,
        lines_done=progress.lines_acked,
        lines_total=plan.commands,
        state=state,
        lines_per_s=lines_per_s,
        heating=heating_text(wait, reading) if wait is not None and state == "heating" else None,
        temperatures=temperatures_text(reading),
        question=question,
        keys=keys,
    )


def _announce(plan: GcodePlan, errors: Console) -> None:
    """Say what the plan changed or skips, before the print starts."""
    for line, written, sent in plan.transliterated:
        errors.print(
            f"[yellow]warning:[/] line {line}: {escape(repr(written))} is sent as {escape(repr(sent))} "
            "(the printer takes ASCII only)",
            highlight=False,
        )
    if plan.transliterated_count > len(plan.transliterated):
        more = plan.transliterated_count - len(plan.transliterated)
        errors.print(f"[yellow]warning:[/] and {more} more lines with non-ASCII text, sent the same way")
    if plan.extrusion_warning is not None:
        errors.print(f"[yellow]warning:[/] {escape(plan.extrusion_warning)}", highlight=False)
    if plan.from_line is not None and plan.first_move_line is not None:
        if plan.from_line <= plan.first_move_line:
            errors.print(
                f"--from-line {plan.from_line} is not past the first move (line {plan.first_move_line}): "
                "the whole file runs"
            )
        else:
            errors.print(
                f"resuming: the {plan.header_lines} header commands before the first move (line "
                f"{plan.first_move_line}) run first, then line {plan.from_line} on"
            )


async def print_gcode(options: ConnectOptions, settings: PrintSettings, console: Console, errors: Console) -> Exit:
    """Stream the file; return the exit code (0 done, 130 cancelled, 7 after the emergency stop).

    Raises:
        MarlinError: the print failed (a `PrintStalledError` carries the trace, printed before raising; after a
            `FileChangedError` the heaters and fan are turned off first, as on a cancel).
    """
    plan = settings.plan
    _announce(plan, errors)
    interrupted = asyncio.Event()
    with on_stop_signals(interrupted.set):
        async with open_printer(options, errors) as (printer, label), printer.poll_temperatures(1.0):
            handle = await printer.start_print(
                plan.lines(), send_ahead=settings.send_ahead, window_bytes=settings.window_bytes
            )
            mode = "send-ahead" if settings.send_ahead else "ping-pong"
            errors.print(f"printing {plan.path.name} on {label} ({mode}); Ctrl-C to cancel", style="dim")
            script = () if settings.keep_heaters else CANCEL_SCRIPT
            try:
                outcome = await _follow(handle, printer, plan, console, interrupted, script)
            except marlin_aio.FileChangedError as exc:
                # The printer is well and idle, but hot and standing on the part: end as a cancel would.
                raise marlin_aio.FileChangedError(
                    f"{exc}; {await _cool_down(printer, script)}", path=exc.path, line=exc.line
                ) from exc
            except marlin_aio.PrintStalledError as exc:
                errors.print(f"[bold red]error:[/] {exc}", highlight=False)
                errors.print("last lines sent (>>) and received (<<), seconds before the stall:", style="dim")
                errors.print(exc.trace, highlight=False, markup=False)
                raise
            except (marlin_aio.ConnectionLostError, marlin_aio.PrinterHaltedError) as exc:
                # The one line a user reads after a failed print says how far it got and how to go on from there.
                reached = handle.progress.last_source_line
                where = f"; the print reached line {reached} of {plan.path.name}"
                if isinstance(exc, marlin_aio.ConnectionLostError) and reached:
                    where += (
                        f" (once the printer is checked, go on with: marlin-temp print {plan.path.name} "
                        f"--from-line {reached + 1}; see --help)"
                    )
                raise type(exc)(f"{exc}{where}") from exc
            final = handle.progress
            if outcome is _Outcome.STOPPED:
                errors.print(
                    f"[bold red]emergency stop:[/] M112 sent after line {final.last_source_line} "
                    f"({final.lines_acked} commands done); the printer is halted: reset it (its reset button or "
                    "power) before it prints again",
                    highlight=False,
                )
                return Exit.HALTED
            if outcome is _Outcome.CANCELLED:
                heaters = "heaters left on" if settings.keep_heaters else "heaters and fan turned off"
                errors.print(
                    f"cancelled after line {final.last_source_line} ({final.lines_acked} commands done); {heaters}"
                )
                return Exit.INTERRUPTED
            errors.print(
                f"done: {final.lines_acked} commands in {final.elapsed_s:.1f} s "
                f"({final.lines_per_s:.0f} lines/s on average, "
                f"{final.bytes_acked / max(final.elapsed_s, 1e-9):.0f} bytes/s, {final.resends} resends)"
            )
            return Exit.OK


async def _cool_down(printer: marlin_aio.Printer, script: tuple[str, ...]) -> str:
    """Send `script` (heaters and fan off, or nothing with --keep-heaters); say what became of the heaters."""
    if not script:
        return "heaters left on"
    try:
        for command in script:
            await printer.send(command)
    except marlin_aio.MarlinError as exc:
        return f"turning the heaters off failed ({exc}): turn them off on the printer"
    return "heaters and fan turned off"


async def _follow(
    handle: marlin_aio.PrintHandle,
    printer: marlin_aio.Printer,
    plan: GcodePlan,
    console: Console,
    interrupted: asyncio.Event,
    script: tuple[str, ...],
) -> _Outcome:
    """Show progress until the print ends; act on the keys and on Ctrl-C (cancelling with `script`).

    Raises:
        MarlinError: what ended the print, unless it was cancelled or stopped here.
    """
    pressed: asyncio.Queue[str] = asyncio.Queue()
    rate = RateWindow()
    asking = cancelling = False
    outcome = _Outcome.DONE
    done = asyncio.create_task(handle.wait())
    last_plain = -_PLAIN_EVERY_S
    live = Live(console=console, auto_refresh=False) if console.is_terminal else None

    def frame(keys_help: str | None) -> PrintStatus:
        progress = handle.progress
        status = print_status(
            progress,
            plan,
            printer.latest,
            rate.lines_per_s(),
            question=_QUESTION if asking else None,
            keys=keys_help,
            cancelling=cancelling,
        )
        if status.state == "printing":
            rate.add(time.monotonic(), progress.lines_acked)
        else:
            rate.clear()  # a pause or a wait for heat is not part of the printing rate
        return status

    # What ends the loop: the print, or once a cancel is under way, the cancel (which waits for what the printer
    # has, perhaps a long M109, then sends the script). The loop goes on meanwhile, so ! still works.
    ending: asyncio.Task[marlin_aio.PrintProgress] = done
    try:
        with key_presses(pressed.put_nowait) as keys, live if live is not None else contextlib.nullcontext():
            keys_help = KEYS_HELP if keys else None
            while not ending.done():
                waiters = [ending, asyncio.ensure_future(interrupted.wait()), asyncio.ensure_future(pressed.get())]
                finished, _ = await asyncio.wait(waiters, timeout=0.25, return_when="FIRST_COMPLETED")
                for waiter in waiters[1:]:
                    if waiter not in finished:
                        waiter.cancel()
                key = waiters[2].result() if waiters[2] in finished else None
                if key == "!":
                    # First, before any question: an emergency stop waits for nothing.
                    printer.emergency_stop()
                    outcome = _Outcome.STOPPED
                    break
                start_cancel = False
                if waiters[1] in finished:
                    interrupted.clear()
                    if asking or not keys:
                        # A second Ctrl-C, or no terminal to ask on: cancel at once.
                        start_cancel = not cancelling
                    asking = not start_cancel and not cancelling
                elif key is not None and asking:
                    asking = False
                    start_cancel = key == "y"
                elif key == "p" and not cancelling:
                    handle.pause()
                elif key == "r" and not cancelling:
                    handle.resume()
                if start_cancel:
                    outcome, cancelling = _Outcome.CANCELLED, True
                    ending = asyncio.create_task(handle.cancel(script))
                status = frame(keys_help)
                if live is not None:
                    live.update(print_view(status), refresh=True)
                elif status.question is not None and waiters[1] in finished:
                    print(status.question, flush=True)  # keys on a terminal, output to a pipe: ask plainly
                elif time.monotonic() - last_plain >= _PLAIN_EVERY_S:
                    last_plain = time.monotonic()
                    print(plain_status(status), flush=True)
            if live is not None:
                live.update(print_view(frame(None)), refresh=True)
        if outcome is _Outcome.STOPPED:
            with contextlib.suppress(marlin_aio.PrinterHaltedError):
                await ending
        else:
            ending.result()  # raises what ended the print (or the cancel)
    finally:
        for future in {done, ending}:
            if not future.done():
                future.cancel()
    return outcome
