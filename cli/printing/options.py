"""The command line of `marlin-temp print`: its options and help; the file is checked whole (`plan`) before
`command` opens the printer."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions, Exit
from ..common.options import error_console, fail, run, with_connect_options

__all__ = ["PRINT_HELP", "print_file"]

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
PRINT_HELP = "\n\n".join(
    (
        "Stream a G-code file with line numbers, checksums and resends, with a progress bar and live temperatures.",
        "The whole file is checked before anything is sent: a line Marlin cannot take, a heater target above "
        "--max-hotend or --max-bed, or a file that is not text exits with code 2 and its line number. "
        "Display text (M117, M118, M0/M1) with letters beyond ASCII is sent transliterated (café as "
        "cafe), with a warning. While the printer waits for a heater (M109, M190 in the file) the view says so "
        "instead of a rate.",
        "While Ctrl-C's question is on screen the print is paused; a cancel during the file's heat-up ends the wait "
        "at once with M108 where the firmware has the emergency parser. Whenever print exits with heaters on, it "
        "says which, and how to turn them off (marlin-temp set --off).",
        "Keys on a terminal: p pauses (no new lines are sent; the moves the printer has finish, heaters stay on), "
        "r resumes, ! is the emergency stop: M112 at once, with no question asked; the printer halts and needs a "
        "reset (exit code 7). Ctrl-C asks whether to cancel; a cancel lets the printer finish what it has, then "
        "turns the heaters and fan off. If the printer stops answering, the print fails with a diagnosis of who "
        "went silent.",
        "The printer's own requests (Marlin's host actions): a filament runout or //action:pause pauses the print "
        "and the view says why; //action:resume resumes it, //action:cancel cancels it. A prompt the printer opens "
        "(a filament change: 'load filament, then press 1 Continue') is shown with its buttons; the digit keys "
        "1-9 answer it (M876, sent at once). Without a terminal, answer on the printer's screen.",
        "--from-line N: when a print stops, the message gives the last line the printer answered. Before resuming, "
        "check: the part is still stuck to the bed (keep the bed hot meanwhile); homing in the header (G28) will "
        "not hit the part (printers that home Z on the bed bring the nozzle down on it: raise Z or edit the "
        "header); line N starts a layer (its Z move; slicers mark layers with comments such as ;LAYER:), as moves "
        "the printer had buffered may not have run; and with absolute extrusion (M82) E goes on from where it "
        "was: the header's G92 E0 resets it, so the layer must set E itself (G92 E...) or you add that line (a "
        "warning names the line to add when it finds the jump). A resume the check calls dangerous (such as a jump "
        "in E that would push out a long length of filament at once) is refused unless --force.",
    )
)


@with_connect_options("hotend", "bed")
def print_file(
    path: Annotated[Path, typer.Argument(help="The G-code file to print.", show_default=False)],
    send_ahead: Annotated[
        bool | None,
        typer.Option(
            "--send-ahead/--ping-pong",
            help="Send-ahead keeps several lines on the wire (faster on a clean link); ping-pong, the default, writes "
            "one line at a time, each after the ok of the one before, which no link fault can make run a line twice "
            "or out of place.",
            show_default=False,
        ),
    ] = None,
    window: Annotated[
        int | None,
        typer.Option(
            "--window",
            help="Send-ahead (implied): bytes of unanswered lines allowed (default: the 128-byte buffer).",
            min=17,
        ),
    ] = None,
    keep_heaters: Annotated[
        bool, typer.Option("--keep-heaters", help="On cancel, leave heaters and fan as they are.")
    ] = False,
    stop_on_unknown: Annotated[
        bool,
        typer.Option(
            "--stop-on-unknown",
            help="Stop the print at a command the firmware does not know (Marlin answers 'Unknown command' with it "
            "as sent). Default: Marlin skips such a line and the print goes on, with one warning per command (a "
            "build without M73, which slicers write near the top, would otherwise stop every print there).",
        ),
    ] = False,
    from_line: Annotated[
        int | None,
        typer.Option(
            "--from-line",
            help="Resume a failed print at line N of the file: the header (every command before the first move) "
            "runs, then line N on. Check what the description above says first.",
            min=1,
            show_default=False,
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force",
            help="With --from-line: resume even though the checks found that the resume would do harm (absolute "
            "extrusion resumed from the header's E, pushing out the skipped layers' filament at once; an extrusion "
            "mode or a heater the skipped part set and the header does not). The reasons are still printed as "
            "warnings.",
        ),
    ] = False,
    refresh: Annotated[
        float,
        typer.Option(
            "--refresh",
            help="Seconds between progress lines when the output is not a terminal (the live view on a terminal "
            "redraws four times a second).",
            min=0.05,
        ),
    ] = 2.0,
    on_done: Annotated[
        str | None,
        typer.Option(
            "--on-done",
            metavar="CMD",
            help="Run CMD through sh -c when the print ends (done, cancelled, failed, halted), with the outcome in "
            "$MARLIN_TEMP_OUTCOME, $MARLIN_TEMP_MESSAGE, $MARLIN_TEMP_FILE ... (see the README); waited for up to "
            "60 s. Default: none.",
            show_default=False,
        ),
    ] = None,
    *,
    options: ConnectOptions,
) -> None:
    """Stream a G-code file with a progress view, keys and --from-line (the help text is `PRINT_HELP`)."""
    from ..common.hooks import with_on_done
    from .command import PrintSettings, print_gcode
    from .done import print_done
    from .plan import plan_print

    if path.is_dir():
        fail(f"{path} is a directory: give a G-code file", Exit.USAGE)
    if not path.exists():
        fail(f"no such file: {path}", Exit.USAGE)
    if send_ahead is False and window is not None:
        fail("--ping-pong sends one line at a time; do not combine it with --window", Exit.USAGE)
    try:
        plan = plan_print(path, from_line, force=force, limits=options.limits)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"cannot read {path}: {exc.strerror or exc}", Exit.USAGE)
    ahead = window is not None if send_ahead is None else send_ahead
    settings = PrintSettings(
        plan=plan,
        send_ahead=ahead,
        window_bytes=window,
        keep_heaters=keep_heaters,
        plain_every_s=refresh,
        stop_on_unknown=stop_on_unknown,
    )
    if on_done is not None and not on_done.strip():
        fail("--on-done is empty: give a shell command", Exit.USAGE)
    errors = error_console()
    body = print_gcode(options, settings, Console(highlight=False, emoji=False), errors)
    code = run(with_on_done(body, on_done, errors, functools.partial(print_done, path)))
    raise typer.Exit(int(code))
