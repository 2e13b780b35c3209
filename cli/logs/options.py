"""The command lines of `marlin-temp log` and `marlin-temp plot`: their options and help, checked before
`command` logs or `plot` draws anything."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions, Exit, UsageProblem
from ..common.options import checked_log_path, checked_target, error_console, fail, run, with_connect_options

__all__ = ["LOG_HELP", "log", "plot"]

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
LOG_HELP = "\n\n".join(
    (
        "Record temperatures to a file, headless, for long runs. Ctrl-C (or --duration) ends it with a summary.",
        "One row per --interval: the reading of the M105 poll; when polls are held up (G28, a wait for heat started "
        "from the printer's display), the auto-report or wait line that came instead. The source column says which: "
        "poll, auto or wait.",
        "Columns: time (ISO 8601, local time with its UTC offset), epoch_s, session (a new id for each run and each "
        "reconnect), session_elapsed_s (seconds since that session's first row: it starts again with each session), "
        "source, then for each heater (hotend, bed, chamber; hotend_0, hotend_1 with several hotends) actual_c, "
        "target_c, power_percent, and power_raw (Marlin's 0-127). --json (or --format jsonl) writes the same fields "
        "as JSON lines, heaters by name.",
        "An existing file is appended to when it is a log of this format with the same heaters. Anything else (a log "
        "of an older marlin-temp, the other format, another printer's heaters, not a log) is refused with one line "
        "before anything is sent to the printer: choose another --output. plot reads old and new logs alike.",
        "--hotend/--bed set targets first (checked as in marlin-temp set: not a number, negative, or above "
        "--max-hotend/--max-bed exits 2 before anything is sent) and the log starts with the first reading after "
        "them, so a heat-up is recorded from its start. They are sent once, not again after a reconnect.",
        "--reconnect keeps logging when the link is lost or the board resets: it retries after 1, 2, 4, 8, 16, then "
        "every 30 seconds, and each connection is a new session in the same file. Without it a lost link ends the "
        "log (exit 8).",
        "Every row reaches the disk within a second of its reading, also when no reading follows (a printer gone "
        "silent), so a crash loses at most the last second and the file always parses.",
    )
)


@with_connect_options("hotend", "bed")
def log(
    output: Annotated[Path, typer.Option("--output", "-o", help="File to write (appended to if it exists).")],
    interval: Annotated[
        float,
        typer.Option(
            "--interval",
            help="Seconds between rows, and between the M105 polls that make them (at least 0.005); not watch's "
            "--interval, which is the poll alone.",
        ),
    ] = 1.0,
    duration: Annotated[
        float | None,
        typer.Option(
            "--duration",
            help="Stop after this many seconds of rows (more than 0), counted from the first poll (its answer is the "
            "first row): connecting and --hotend/--bed come first. Default: until Ctrl-C.",
            show_default=False,
        ),
    ] = None,
    fmt: Annotated[
        str | None,
        typer.Option("--format", help="csv or jsonl. Default: csv, or jsonl with --json.", show_default=False),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Write JSON lines: the same as --format jsonl (--json as in watch, bench).")
    ] = False,
    hotend: Annotated[
        str | None, typer.Option("--hotend", help="Set this hotend target (C) first, then log the heat-up.")
    ] = None,
    bed: Annotated[str | None, typer.Option("--bed", help="Set this bed target (C) first, then log.")] = None,
    reconnect: Annotated[
        bool, typer.Option("--reconnect", help="When the printer goes away, keep retrying (a new session each time).")
    ] = False,
    *,
    options: ConnectOptions,
) -> None:
    """Record temperatures to a file (the help text is `LOG_HELP`)."""
    import math

    from .command import LogSettings, log_temperatures

    if fmt is None:
        fmt = "jsonl" if as_json else "csv"
    if fmt not in ("csv", "jsonl"):
        fail(f"unknown --format {fmt!r}: use csv or jsonl", Exit.USAGE)
    if as_json and fmt != "jsonl":
        fail(f"--json writes JSON lines, --format {fmt} asks otherwise: give one of them", Exit.USAGE)
    if not (math.isfinite(interval) and interval >= 0.005):
        fail(f"--interval must be at least 0.005 seconds, got {interval:g}", Exit.USAGE)
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        fail(f"--duration must be more than 0 seconds, got {duration:g}", Exit.USAGE)
    settings = LogSettings(
        output=checked_log_path(output, "--output"),
        fmt=fmt,
        interval_s=interval,
        duration_s=duration,
        hotend=checked_target("hotend", hotend, options.limits.hotend),
        bed=checked_target("bed", bed, options.limits.bed),
        reconnect=reconnect,
    )
    code = run(log_temperatures(options, settings, error_console()))
    raise typer.Exit(int(code))


def plot(
    logfile: Annotated[Path, typer.Argument(help="A log written by 'marlin-temp log' or 'watch --log'.")],
    output: Annotated[Path | None, typer.Option("--output", "-o", help="PNG file to write (needs matplotlib).")] = None,
    show: Annotated[bool, typer.Option("--show", help="Draw the curves in the terminal instead.")] = False,
    session: Annotated[
        str | None,
        typer.Option(
            "--session", help="Plot this session alone: its id, or its number (1 is the first).", show_default=False
        ),
    ] = None,
) -> None:
    """Plot actual and target curves from a log: a PNG with matplotlib, or --show in the terminal.

    The time axis is the clock time of each row. A file that several runs appended to (log, watch --log, each
    reconnect of log --reconnect) holds several sessions: they are drawn where they happened, each its own line,
    with the gaps between them; --show lists them, and --session draws one alone. Logs of older marlin-temp
    versions (time_utc, elapsed_s) are read too.
    """
    from .plot import plot_log

    if output is None and not show:
        fail("give --output FILE.png, or --show to draw in the terminal", Exit.USAGE)
    try:
        message = plot_log(logfile, output, show, Console(highlight=False, emoji=False), session)
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    except ValueError as exc:
        fail(str(exc))
    except OSError as exc:
        # In words, with the file: "No such file or directory: temps.csv", not "[Errno 2] ...".
        fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc), Exit.USAGE)
    if message:
        error_console().print(message)
