"""`marlin-temp print FILE`: stream a G-code file with a progress view, live temperatures and keys.

The file is read and checked whole before connecting (`printing.plan.plan_print`), so a bad file costs nothing; the view
is drawn by the pure functions of `printing.view`. On a terminal, p pauses (no new lines are sent; what the printer has
finishes, heaters stay on), r resumes, and ! sends M112 at once, with no question: an emergency stop must not wait
for a second key. Ctrl-C does not kill a print half way through a line: it asks (on a terminal) whether to cancel,
and a cancel stops feeding, lets the printer answer what it has, then turns the heaters and fan off (unless
--keep-heaters).

Over 400 lines (just) because the print's run, its keys and its Ctrl-C question share one printer and one view;
checking the file (`plan`) and drawing (`view`) are apart.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import time
from dataclasses import dataclass

from rich.console import Console
from rich.live import Live
from rich.text import Text

import marlin_aio
from marlin_aio.protocol import STOPPED_BY_SERVICE

from ..common.connect import ConnectOptions, Exit, UsageProblem, exit_code_for, open_printer
from ..common.keys import key_presses, on_stop_signals
from ..common.prompts import answer_index, prompt_text
from .plan import GcodePlan
from .view import (
    KEYS_HELP,
    PrintStatus,
    RateWindow,
    heaters_on_text,
    heating_text,
    plain_status,
    print_view,
    temperatures_text,
)

__all__ = ["PrintSettings", "print_gcode", "print_status"]

CANCEL_SCRIPT = marlin_aio.COOL_DOWN
_QUESTION = "cancel the print? y = yes, any other key = go on"
_ENDED_QUESTION = "the print has ended: press any key"
_FRESH_READING_S = 2.0  # a reading for the closing message: longer and the latest one says it as well
_M108_SENT = "M108 sent: the heat-up wait ended"
_M108_USER = "M108 sent: the printer's wait for the user ended"
_NO_EMERGENCY_PARSER_USER = "the printer waits for the user: answer on its screen, and the cancel takes effect"
_NO_EMERGENCY_PARSER = (
    "the firmware has no emergency parser (M108 cannot end the heat-up wait), so the cancel takes effect when "
    "the heat-up ends"
)


@dataclass(frozen=True)
class PrintSettings:
    """What `print` was asked to do: the checked file and how to send it."""

    plan: GcodePlan
    send_ahead: bool = False
    window_bytes: int | None = None
    keep_heaters: bool = False
    plain_every_s: float = 2.0  # between progress lines, when the output is not a terminal
    stop_on_unknown: bool = False  # stop at a command the firmware lacks instead of going on (Marlin skips it)


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
    note: str | None = None,
    prompt: str | None = None,
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
        message=plan.display_text(progress.last_source_line),
        note=note,
        paused_by=progress.paused_by,
        prompt=prompt,
    )


async def _answer(printer: marlin_aio.Printer, index: int) -> str:
    """Answer the printer's prompt with button `index`; what to tell the user."""
    prompt = printer.prompt
    try:
        await printer.answer_prompt(index)
    except (ValueError, marlin_aio.MarlinError) as exc:
        return f"the answer was not sent: {exc}"
    label = prompt.buttons[index] if prompt is not None else str(index + 1)
    return f"answered the printer: {label} (M876 S{index})"


def _say(console: Console, label: str, style: str, text: str) -> None:
    """One line: a styled label, then `text` exactly as it is (file and firmware text: no markup, no emoji)."""
    console.print(Text.assemble((label, style), " ", text), highlight=False, soft_wrap=True)


def _announce(plan: GcodePlan, errors: Console) -> None:
    """Say what the plan changed or skips, before the print starts."""
    for line, written, sent in plan.transliterated:
        _say(
            errors,
            "warning:",
            "yellow",
            f"line {line}: {written!r} is sent as {sent!r} (the printer takes ASCII only)",
        )
    if plan.transliterated_count > len(plan.transliterated):
        more = plan.transliterated_count - len(plan.transliterated)
        _say(errors, "warning:", "yellow", f"and {more} more lines with non-ASCII text, sent the same way")
    for danger in plan.resume_dangers:  # only there with --force: without it the plan was refused
        _say(errors, "warning:", "yellow", f"{danger} (resuming anyway: --force)")
    for note in plan.resume_notes:
        _say(errors, "note:", "dim", note)
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


def _job_hint(options: ConnectOptions) -> str:
    port = options.port or "serve:NAME"
    return f"follow it with: marlin-temp job attach --port {port}; cancel it with: marlin-temp job cancel --port {port}"


async def _refuse_if_served_job(printer: marlin_aio.Printer, label: str, options: ConnectOptions) -> None:
    """A printer of the service runs one job at a time, whoever started it: a second print is one line naming
    the running job (exit 4), refused before a byte of the file is sent.

    Raises:
        UsageProblem: a job is running there (`Exit.PORT_BUSY`).
    """
    call = getattr(printer, "call", None)
    if call is None:
        return  # a printer on a port: this command owns it
    from ..job.command import describe_job

    job = await call("job")
    if job is not None and job.get("active"):
        raise UsageProblem(
            f"a print is already running on {label}: {describe_job(job)} ({_job_hint(options)})", Exit.PORT_BUSY
        )


async def print_gcode(options: ConnectOptions, settings: PrintSettings, console: Console, errors: Console) -> Exit:
    """Stream the file; return the exit code (0 done, 130 cancelled, 7 after the emergency stop, or the code of
    the error that ended the print).

    A print that fails is reported here, not raised: its error line, then (where the printer may still be hot)
    which heaters are on and how to turn them off, which only this command can say.

    Raises:
        MarlinError: connecting failed (nothing was sent).
    """
    plan = settings.plan
    _announce(plan, errors)
    interrupted = asyncio.Event()
    with on_stop_signals(interrupted.set):
        async with open_printer(options, errors) as (printer, label), printer.poll_temperatures(1.0):
            await _refuse_if_served_job(printer, label, options)
            try:
                handle = await printer.start_print(
                    plan.lines(),
                    send_ahead=settings.send_ahead,
                    window_bytes=settings.window_bytes,
                    name=plan.path.name,
                    stop_on_unknown=settings.stop_on_unknown,
                )
            except RuntimeError as exc:  # the service's job, started by someone else since the check above
                raise UsageProblem(f"{exc} ({_job_hint(options)})", Exit.PORT_BUSY) from None
            mode = "send-ahead" if settings.send_ahead else "ping-pong"
            errors.print(f"printing {plan.path.name} on {label} ({mode}); Ctrl-C to cancel", style="dim")
            script = () if settings.keep_heaters else CANCEL_SCRIPT
            try:
                outcome = await _follow(
                    handle, printer, plan, console, errors, interrupted, script, settings.plain_every_s
                )
            except marlin_aio.MarlinError as exc:
                return await _failed(exc, handle, printer, plan, errors, script)
            final = handle.progress
            if outcome is _Outcome.STOPPED:
                errors.print(
                    f"[bold red]emergency stop:[/] M112 sent after line {final.last_source_line} "
                    f"({final.lines_acked} commands done); the printer is halted (Marlin turns its heaters off as "
                    "it halts): reset it (its reset button or power) before it prints again",
                    highlight=False,
                )
                return Exit.HALTED
            if (
                outcome is _Outcome.DONE
                and final.state is marlin_aio.PrintState.CANCELLED
                and (final.cancelled_by or "").startswith(STOPPED_BY_SERVICE)
            ):
                # The service running the print stopped: it ran the cancel script itself, and every line in flight
                # was answered, so the line after the last one acknowledged is exactly where to go on.
                errors.print(
                    f"{final.cancelled_by}: it cancelled the print after line {final.last_source_line} "
                    f"({final.lines_acked} commands done) and ran its cancel script; once it runs again, go on with: "
                    f"marlin-temp print {plan.path.name} --from-line {final.last_source_line + 1} (see --help)",
                    highlight=False,
                )
                return Exit.INTERRUPTED
            if outcome is _Outcome.DONE and final.state is marlin_aio.PrintState.CANCELLED:
                # The printer asked (//action:cancel, from its screen): a cancel like ours, the heaters with it.
                said = await _cool_down(printer, script)
                errors.print(
                    f"the printer cancelled the print after line {final.last_source_line} ({final.lines_acked} "
                    f"commands done; {final.cancelled_by}); {said}"
                )
                return Exit.INTERRUPTED
            if outcome is _Outcome.CANCELLED:
                done = f"cancelled after line {final.last_source_line} ({final.lines_acked} commands done)"
                if not settings.keep_heaters:
                    errors.print(f"{done}; heaters and fan turned off")
                else:
                    heaters = heaters_on_text(await _reading_now(printer))
                    errors.print(
                        f"{done}; heaters left as they were (--keep-heaters)" + ("" if heaters else ": none is on")
                    )
                    if heaters:
                        _heaters_on(errors, "heaters left on", heaters)
                return Exit.INTERRUPTED
            errors.print(
                f"done: {final.lines_acked} commands in {final.elapsed_s:.1f} s "
                f"({final.lines_per_s:.0f} lines/s on average, "
                f"{final.bytes_acked / max(final.elapsed_s, 1e-9):.0f} bytes/s, {final.resends} resends)"
            )
            _skipped_unknown(errors, final)
            heaters = heaters_on_text(await _reading_now(printer))
            if heaters:
                _heaters_on(errors, "the file ended with heaters on", heaters)
            return Exit.OK


def _skipped_unknown(errors: Console, final: marlin_aio.PrintProgress) -> None:
    """Say which commands of the file the firmware did not know: Marlin skipped them (the print went on)."""
    if final.unknown_codes:
        codes = ", ".join(final.unknown_codes)
        _say(
            errors,
            "warning:",
            "yellow",
            f"the printer does not know {codes}: Marlin skipped those lines and the print went on "
            "(--stop-on-unknown stops at such a line instead)",
        )


def _heaters_on(errors: Console, what: str, heaters: str) -> None:
    """The line every way out of a print that leaves a heater on ends with."""
    _say(errors, "warning:", "yellow", f"{what}: {heaters}; turn them off with: marlin-temp set --off")


async def _failed(
    exc: marlin_aio.MarlinError,
    handle: marlin_aio.PrintHandle,
    printer: marlin_aio.Printer,
    plan: GcodePlan,
    errors: Console,
    script: tuple[str, ...],
) -> Exit:
    """Report a print that failed: its error line (with where it got to), then what became of the heaters."""
    reached = handle.progress.last_source_line
    message = str(exc)
    heaters: str | None = None
    if isinstance(exc, marlin_aio.FileChangedError):
        # The printer is well and idle, but hot and standing on the part: end as a cancel would.
        message += f"; {await _cool_down(printer, script)}"
        if not script:
            heaters = heaters_on_text(await _reading_now(printer))
    elif isinstance(exc, marlin_aio.PrinterHaltedError | marlin_aio.PrinterResetError):
        # The one line a user reads after a failed print says how far it got; a halted or reset board has its
        # heaters off (Marlin's kill() and its start-up both turn them off).
        message += f"; the print reached line {reached} of {plan.path.name}; Marlin turned its heaters off"
    else:
        if isinstance(exc, marlin_aio.ConnectionLostError):
            # Lines sent and never answered may have run: going on after the last one acknowledged could run one
            # twice, so the resume starts after every line that may have run (a service bounds that by what it
            # told before it went away).
            may = max(handle.progress.may_have_run_through or 0, reached)
            if "surely ran" not in message:  # a served print's error says it already (`ServedPrintHandle.orphaned`)
                message += f"; line {reached} of {plan.path.name} surely ran"
                if may > reached:
                    message += f", lines up to {may} may have run"
            if may:
                message += (
                    f" (once the printer is checked, go on with: marlin-temp print {plan.path.name} "
                    f"--from-line {may + 1}; see --help)"
                )
        silent = isinstance(exc, marlin_aio.ConnectionLostError | TimeoutError)
        # Not turned off here: a failed print may be resumed (--from-line), with the bed kept hot meanwhile.
        heaters = heaters_on_text(printer.latest if silent else await _reading_now(printer))
    _say(errors, "error:", "bold red", message)
    if isinstance(exc, marlin_aio.PrintStalledError):
        errors.print("last lines sent (>>) and received (<<), seconds before the stall:", style="dim")
        errors.print(Text(exc.trace), highlight=False)
    if heaters:
        _heaters_on(errors, "heaters on when last read", heaters)
    return exit_code_for(exc)


async def _reading_now(printer: marlin_aio.Printer) -> marlin_aio.TemperatureReading | None:
    """A fresh reading where the printer answers within a moment, else the latest one (None: none yet)."""
    with contextlib.suppress(marlin_aio.MarlinError, TimeoutError):
        async with asyncio.timeout(_FRESH_READING_S):
            return await printer.read_temperatures()
    return printer.latest


async def _cool_down(printer: marlin_aio.Printer, script: tuple[str, ...]) -> str:
    """Send `script` (heaters and fan off, or nothing with --keep-heaters); say what became of the heaters."""
    if not script:
        return "heaters left on"
    try:
        for command in script:
            await printer.send(command)
    except marlin_aio.MarlinError as exc:
        return f"turning the heaters off failed ({exc}): turn them off on the printer or with marlin-temp set --off"
    return "heaters and fan turned off"


async def _follow(
    handle: marlin_aio.PrintHandle,
    printer: marlin_aio.Printer,
    plan: GcodePlan,
    console: Console,
    errors: Console,
    interrupted: asyncio.Event,
    script: tuple[str, ...],
    plain_every_s: float,
) -> _Outcome:
    """Show progress until the print ends; act on the keys and on Ctrl-C (cancelling with `script`).

    While the Ctrl-C question is up the print is paused (it goes on after "no", unless it was paused before), and
    keys are read until the answer comes, also when the print ends meanwhile: the key that answers is ours, never
    the shell's.

    Raises:
        MarlinError: what ended the print, unless it was cancelled or stopped here.
    """
    pressed: asyncio.Queue[str] = asyncio.Queue()
    rate = RateWindow()
    asking = cancelling = paused_to_ask = False
    note: str | None = None
    outcome = _Outcome.DONE
    done = asyncio.create_task(handle.wait())
    last_plain = -plain_every_s
    last_message: str | None = None
    last_said: tuple[str | None, str | None] = (None, None)  # the pause reason and prompt last printed plainly
    live = Live(console=console, auto_refresh=False) if console.is_terminal else None

    def frame(keys_help: str | None) -> PrintStatus:
        progress = handle.progress
        question = None
        if asking:
            question = _ENDED_QUESTION if ending.done() else _QUESTION
        status = print_status(
            progress,
            plan,
            printer.latest,
            rate.lines_per_s(),
            question=question,
            keys=keys_help,
            cancelling=cancelling,
            note=note,
            prompt=prompt_text(printer.prompt, printer.waiting_for_user),
        )
        if status.state == "printing":
            rate.add(time.monotonic(), progress.lines_acked)
        else:
            rate.clear()  # a pause or a wait for heat is not part of the printing rate
        return status

    def start_cancel() -> str | None:
        """Cancel the print; end a heater wait of the file the printer is in, where the firmware can. Returns
        what to tell the user about that wait."""
        progress = handle.progress
        if printer.waiting_for_user:
            # A filament change (M600, a runout) holds the line in flight until someone answers: M108 ends it, so
            # the cancel need not wait for a person.
            try:
                return _M108_USER if printer.interrupt_wait() else _NO_EMERGENCY_PARSER_USER
            except marlin_aio.MarlinError:
                return None
        wait = plan.heat_wait_running(progress.last_source_line, progress.lines_sent > progress.lines_acked)
        try:
            interrupted_wait = wait is not None and printer.interrupt_wait()
        except marlin_aio.MarlinError:
            interrupted_wait = False  # the link is gone: the print fails, and says so
        if wait is None:
            return None
        return _M108_SENT if interrupted_wait else _NO_EMERGENCY_PARSER

    # What ends the loop: the print, or once a cancel is under way, the cancel (which waits for what the printer
    # has, perhaps a long M109, then sends the script), and never a question without its answer. The loop goes on
    # meanwhile, so ! still works.
    ending: asyncio.Task[marlin_aio.PrintProgress] = done
    try:
        with (
            key_presses(pressed.put_nowait, discard_unread=True) as keys,
            live if live is not None else contextlib.nullcontext(),
        ):
            keys_help = KEYS_HELP if keys else None
            while asking or not ending.done():
                waiters = [asyncio.ensure_future(interrupted.wait()), asyncio.ensure_future(pressed.get())]
                if not ending.done():
                    waiters.append(ending)
                finished, _ = await asyncio.wait(waiters, timeout=0.25, return_when="FIRST_COMPLETED")
                for waiter in waiters[:2]:
                    if waiter not in finished:
                        waiter.cancel()
                signalled = waiters[0] in finished
                key = waiters[1].result() if waiters[1] in finished else None
                if key == "!" and not ending.done():
                    # First, before any question: an emergency stop waits for nothing.
                    printer.emergency_stop()
                    outcome = _Outcome.STOPPED
                    asking = False
                    break
                cancel = False
                was_asking = asking
                if signalled:
                    interrupted.clear()
                    if asking or not keys:
                        # A second Ctrl-C, or no terminal to ask on: cancel at once.
                        cancel = not cancelling
                    asking = not cancel and not cancelling and not ending.done()
                elif key is not None and asking:
                    asking = False
                    cancel = key == "y" and not ending.done()
                elif isinstance(key, str) and (index := answer_index(key, printer.prompt)) is not None:
                    note = await _answer(printer, index)
                elif key == "p" and not cancelling:
                    handle.pause()
                elif key == "r" and not cancelling:
                    handle.resume()
                if asking and not was_asking and handle.progress.state is marlin_aio.PrintState.RUNNING:
                    handle.pause()  # the print waits for the answer, not the answer for the print
                    paused_to_ask = True
                if was_asking and not asking and paused_to_ask:
                    paused_to_ask = False
                    if not cancel:
                        handle.resume()
                if cancel:
                    outcome, cancelling = _Outcome.CANCELLED, True
                    ending = asyncio.create_task(handle.cancel(script))
                    note = start_cancel()
                    if note is not None and live is None:
                        _say(errors, "note:", "yellow", note)
                status = frame(keys_help)
                if live is not None:
                    live.update(print_view(status), refresh=True)
                    continue
                if status.message is not None and status.message != last_message:
                    last_message = status.message
                    print(f"printer: {status.message}", flush=True)
                said = (status.paused_by if status.state == "paused" else None, status.prompt)
                if said != last_said:
                    last_said = said
                    for text in said:
                        if text is not None:
                            print(text if text is status.prompt else f"paused: {text}", flush=True)
                if status.question is not None and signalled:
                    print(status.question, flush=True)  # keys on a terminal, output to a pipe: ask plainly
                elif time.monotonic() - last_plain >= plain_every_s:
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
