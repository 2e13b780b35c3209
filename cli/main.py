"""The `marlin-temp` command: watch, set and log the temperatures of a Marlin printer.

Typer has no async commands, so each command parses and checks its options, then calls `asyncio.run` on an
async function the tests can call too. Every failure ends as one line on stderr and an exit code from
`connect.Exit`; nothing is sent to the printer before the options are known to be good.
"""

from __future__ import annotations

import asyncio
import importlib.util
import os
import sys
from collections.abc import Coroutine, Sequence
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from typer.core import TyperGroup

import marlin_aio
from marlin_aio import DEFAULT_MAX_BED_CELSIUS, DEFAULT_MAX_CHAMBER_CELSIUS, DEFAULT_MAX_HOTEND_CELSIUS
from marlin_aio.protocol import check_target

from .common.connect import (
    EXIT_CODES_HELP,
    PASSWORD_ENV,
    ConnectOptions,
    Exit,
    UsageProblem,
    exit_code_for,
    printer_password,
)

__all__ = ["app"]


class _Commands(TyperGroup):
    """The command group, showing on/off options as bare flags in `--help` (typer lists `--sim <bool>` otherwise,
    which reads as if a value were needed)."""

    def get_params(self, ctx: Any) -> Any:
        params = super().get_params(ctx)
        for param in params:  # the group's own (--version, --help)
            if getattr(param, "is_flag", False) and getattr(param, "metavar", "") is None:
                param.metavar = ""
        return params

    def get_command(self, ctx: Any, cmd_name: str) -> Any:  # Any: click's types differ between typer releases
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            for param in command.get_params(ctx):
                if getattr(param, "is_flag", False) and getattr(param, "metavar", "") is None:
                    param.metavar = ""
        return command

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        """Run the command line; a usage error (a bad value, an unknown option) is one line on stderr, exit 2."""
        kwargs = {"args": args, "prog_name": prog_name, "complete_var": complete_var} | extra
        kwargs["windows_expand_args"] = windows_expand_args
        if not standalone_mode:
            return super().main(standalone_mode=False, **kwargs)
        try:
            outcome = super().main(standalone_mode=False, **kwargs)
        except _CLICK_EXCEPTION as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":
                exc.show()  # type: ignore[attr-defined]  # `marlin-temp` alone shows the help
            else:
                ctx = getattr(exc, "ctx", None)
                listed = "commands" if "No such command" in str(exc) else "options"
                where = f" ({ctx.command_path} --help lists the {listed})" if ctx is not None else ""
                message = exc.format_message()  # type: ignore[attr-defined]
                _stderr().print(f"[bold red]error:[/] {escape(message)}{escape(where)}", markup=True)
            sys.exit(getattr(exc, "exit_code", 2))
        except typer.Abort:
            _stderr().print("aborted")
            sys.exit(1)
        sys.exit(outcome if isinstance(outcome, int) else 0)


# typer 0.29 carries its own copy of click and older releases use click itself: its ClickException either way.
_CLICK_EXCEPTION: type[Exception] = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")


app = typer.Typer(
    cls=_Commands,
    name="marlin-temp",
    help="Watch, set and log the temperatures of a Marlin 3D printer. Try it with --sim: no printer needed.",
    epilog=EXIT_CODES_HELP,
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
)

_T = TypeVar("_T")


def _stderr() -> Console:
    return Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)


def fail(message: str, code: int = Exit.ERROR) -> NoReturn:
    """Print `error: message` as one line on stderr and exit with `code`."""
    _stderr().print(f"[bold red]error:[/] {escape(message)}", markup=True)
    raise typer.Exit(int(code))


def run(main: Coroutine[Any, Any, _T]) -> _T:
    """Run an async command body; map errors to one line and an exit code, Ctrl-C to 130."""
    try:
        return asyncio.run(main)
    except BrokenPipeError:
        # The reader went away (`marlin-temp watch | head`): not an error. Point stdout at /dev/null so the flush at
        # exit does not fail on the closed pipe again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        raise typer.Exit(int(Exit.OK)) from None
    except KeyboardInterrupt:
        _stderr().print("interrupted", style="dim")
        raise typer.Exit(int(Exit.INTERRUPTED)) from None
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    except marlin_aio.MarlinError as exc:
        fail(str(exc), exit_code_for(exc))
    except ValueError as exc:
        # Our own checks raise ValueError for bad input found late (e.g. a log file with other columns).
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))


# ------------------------------------------------------------------------------------------- shared options

PortOption = Annotated[
    str | None,
    typer.Option(
        "--port",
        "-p",
        help="Device path (/dev/ttyUSB0) or pyserial URL (socket://host:port). Default: the one printer-like port.",
        show_default=False,
    ),
]


def _check_baud(value: int | None) -> int | None:
    if value is not None and value <= 0:
        raise typer.BadParameter(f"must be a positive number of bits per second, such as 250000 or 115200, got {value}")
    return value


BaudOption = Annotated[
    int | None,
    typer.Option(
        "--baud",
        "-b",
        help="Baud rate. Default 250000, falling back to 115200 when auto-detecting.",
        callback=_check_baud,
    ),
]
SimOption = Annotated[bool, typer.Option("--sim", help="Use the built-in simulated printer (no hardware needed).")]
SimSpeedOption = Annotated[
    float, typer.Option("--sim-speed", help="With --sim: simulated seconds per real second.", min=0.01)
]
TimeoutOption = Annotated[
    float, typer.Option("--timeout", help="Seconds to wait for each answer from the printer.", min=0.1)
]
# The printer's password (Marlin's PASSWORD_FEATURE, M511) never comes from the command line, where `ps` shows it
# to every user of the machine: `--password VALUE` is refused with a line that says where to put it instead.
PasswordOption = Annotated[str | None, typer.Option("--password", hidden=True, show_default=False)]
PasswordFileOption = Annotated[
    Path | None,
    typer.Option(
        "--password-file",
        help=f"Unlock a printer with Marlin's PASSWORD_FEATURE (M511) when it connects, with the password in this "
        f"file (or in ${PASSWORD_ENV}).",
        show_default=False,
    ),
]
AskPasswordOption = Annotated[
    bool, typer.Option("--ask-password", help="Ask for the printer's password (M511) on the terminal.")
]
# In `set`, --timeout bounds the wait for the targets (as users expect there); the answer timeout moves aside.
MaxHotendOption = Annotated[
    float, typer.Option("--max-hotend", help="Highest hotend target allowed (C).", min=1, max=1000)
]
MaxBedOption = Annotated[float, typer.Option("--max-bed", help="Highest bed target allowed (C).", min=1, max=1000)]
MaxChamberOption = Annotated[
    float, typer.Option("--max-chamber", help="Highest chamber target allowed (C).", min=1, max=1000)
]


def _limits(max_hotend: float, max_bed: float) -> marlin_aio.HeaterLimits:
    """The heater limits of --max-hotend and --max-bed (the chamber's stays the library's default)."""
    return marlin_aio.HeaterLimits(max_hotend, max_bed, DEFAULT_MAX_CHAMBER_CELSIUS)


def _printer_password(on_argv: str | None, password_file: Path | None, ask: bool) -> str | None:
    """The printer password from --password-file, --ask-password or the environment; --password refused."""
    try:
        return printer_password(on_argv, password_file, ask=ask)
    except UsageProblem as exc:
        fail(str(exc), exc.code)


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"marlin-temp {marlin_aio.__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Watch, set and log the temperatures of a Marlin 3D printer. Try it with --sim: no printer needed."""


# ------------------------------------------------------------------------------------------- watch


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_WATCH_HELP = "\n\n".join(
    (
        "Live view of every heater: table, chart of the last minute, link statistics. q or Ctrl-C quits.",
        "Keys set targets while watching: h hotend and b bed (type the degrees, Enter; Esc cancels), o every "
        "heater off, + and - step the last one chosen by 5 C, 1 PLA (200/60 C), 2 PETG (240/80 C), f the fan "
        "(percent), and : sends one G-code line, its reply shown under the chart. Targets are checked against "
        "--max-hotend and --max-bed as in set; one refused is shown in the view and nothing is sent. Narrow "
        "terminals (down to 40 columns) get a compact table.",
        "With two or more hotends each one (hotend 0, hotend 1, ...) has its own row with its actual, target and "
        "power, and its own curve in the chart, whichever tool is active. When stdout is not a terminal it prints "
        "one plain line per refresh instead (or JSON lines with --json), and q is the only key.",
        "The footer counts timeouts and errors (failed commands, board resets) from the moment the connection is "
        "established: a board that resets when the port opens, printing 'start' and its banner during the "
        "handshake, is starting up, not failing.",
        "Several printers (--port given more than once, as NAME=PORT or PORT, and/or --sims N simulated ones) "
        "get the farm view: one row per printer with each heater's actual/target, its state and its link (up, or "
        "down and when it reconnects, with the last error). Each printer reconnects by itself, so one "
        "unplugged shows down while the others go on. 1-9, or the arrows and Enter, open one printer's detail "
        "(the single-printer view, without the keys that set targets); Esc or Backspace goes back; q quits. "
        "Piped, it prints one line per printer per refresh.",
    )
)


@app.command(help=_WATCH_HELP, epilog=EXIT_CODES_HELP)
def watch(
    ports: Annotated[
        list[str] | None,
        typer.Option(
            "--port",
            "-p",
            help="Device path (/dev/ttyUSB0) or pyserial URL (socket://host:port); give it again for each printer "
            "of a farm, as NAME=PORT. Default: the one printer-like port.",
            show_default=False,
            metavar="[NAME=]PORT",
        ),
    ] = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sims: Annotated[
        int,
        typer.Option(
            "--sims", help="Watch N simulated printers (sim1, sim2, ...) in the farm view.", min=0, metavar="N"
        ),
    ] = 0,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    interval: Annotated[
        float | None,
        typer.Option(
            "--interval",
            help="Seconds between M105 polls (default 0.01; with several printers 0.1 for each).",
            min=0.001,
            show_default=False,
        ),
    ] = None,
    refresh: Annotated[float, typer.Option("--refresh", help="Seconds between screen redraws.", min=0.05)] = 1.0,
    window: Annotated[float, typer.Option("--window", help="Seconds of history in the chart.", min=5)] = 60.0,
    tolerance: Annotated[
        float, typer.Option("--tolerance", help="Within this many C a heater is holding.", min=0)
    ] = 2.0,
    log: Annotated[
        Path | None, typer.Option("--log", help="Also record every reading to this CSV file (on disk within a second).")
    ] = None,
    json_lines: Annotated[bool, typer.Option("--json", help="Print JSON lines instead of the live view.")] = False,
    duration: Annotated[float | None, typer.Option("--duration", help="Stop after this many seconds.")] = None,
    reconnect: Annotated[
        bool,
        typer.Option("--reconnect", help="When the printer goes away, keep retrying (after 1 s, doubling up to 30 s)."),
    ] = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
) -> None:
    """Live view of every heater, with keys to set targets; the farm view for several printers (the help text
    is `_WATCH_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .watch.command import WatchSettings, watch_farm, watch_printer

    ports = ports or []
    farm_specs = []
    if sim and sims:
        fail("--sim is one simulated printer, --sims N is N of them: give one of the two", Exit.USAGE)
    if len(ports) + sims + int(sim) > 1:
        from dataclasses import replace

        from marlin_aio.farm.config import specs_from_options

        try:
            farm_specs = specs_from_options(
                ports,
                sims + int(sim),
                baud=baud or marlin_aio.DEFAULT_BAUDRATE,
                poll_interval_s=interval or 0.1,
                sim_speed=sim_speed,
            )
        except ValueError as exc:
            fail(str(exc), Exit.USAGE)
        farm_specs = [
            replace(spec, timeout_s=timeout, password=password, max_hotend_celsius=max_hotend, max_bed_celsius=max_bed)
            for spec in farm_specs
        ]
    port = ports[0] if ports else None
    if port is not None:
        name, sep, after = port.partition("=")
        port = after if sep and "://" not in name else port  # one printer given as NAME=PORT: its name is not used
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim or sims == 1,
        sim_speed=sim_speed,
        timeout_s=timeout,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
        password=password,
    )
    if duration is not None and not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration:g}", Exit.USAGE)
    settings = WatchSettings(
        interval_s=interval or (0.1 if farm_specs else 0.01),
        refresh_s=refresh,
        window_s=window,
        tolerance_c=tolerance,
        log_path=log,
        json_lines=json_lines,
        duration_s=duration,
        reconnect=reconnect,
    )
    if farm_specs:
        if log is not None:
            fail("--log records one printer: watch it alone (one --port or --sim) to log it", Exit.USAGE)
        code = run(watch_farm(farm_specs, settings, Console(highlight=False, emoji=False), _stderr()))
    else:
        code = run(watch_printer(options, settings, Console(highlight=False, emoji=False), _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- set


def _target(name: str, raw: str | None, limit: float) -> float | None:
    if raw is None:
        return None
    try:
        return check_target(name, raw, limit)
    except ValueError as exc:
        hint = f" (raise the limit with --max-{name})" if "above the limit" in str(exc) else ""
        fail(f"{exc}{hint}", Exit.USAGE)


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_SET_HELP = "\n\n".join(
    (
        "Set heater targets and print what the printer confirmed; --wait heats up with a progress bar per heater.",
        "Targets are checked before anything is sent: not a number, negative or above the limit (hotend 260 C, "
        "bed 140 C, chamber 60 C by default: Marlin's own clamps) exits with code 2 and one line saying why, as "
        "does a heater the printer does not have (--tool 1 on a one-hotend printer, --chamber with no chamber).",
        "What is printed is the target the printer confirmed, which can differ from the one asked for: Marlin "
        "keeps whole degrees and caps a target at its own maximum; the line says so, and --wait waits for the "
        "confirmed target. --off turns off every hotend, the bed and the chamber; --off --wait waits until each "
        "is below --cool-to (50 C: safe to touch).",
    )
)


@app.command("set", help=_SET_HELP, epilog=EXIT_CODES_HELP)
def set_targets(
    hotend: Annotated[str | None, typer.Option("--hotend", help="Hotend target in C (0 turns it off).")] = None,
    bed: Annotated[str | None, typer.Option("--bed", help="Bed target in C (0 turns it off).")] = None,
    chamber: Annotated[str | None, typer.Option("--chamber", help="Chamber target in C.")] = None,
    tool: Annotated[
        int | None, typer.Option("--tool", help="Which hotend --hotend sets (default: active).", min=0)
    ] = None,
    off: Annotated[bool, typer.Option("--off", help="Turn every heater off (every hotend, bed, chamber).")] = False,
    wait: Annotated[
        bool,
        typer.Option(
            "--wait", help="Wait until the targets are reached, with progress; with --off, until cool (--cool-to)."
        ),
    ] = False,
    tolerance: Annotated[float, typer.Option("--tolerance", help="With --wait: how close counts (C).", min=0)] = 2.0,
    wait_timeout: Annotated[
        float | None, typer.Option("--wait-timeout", help="With --wait: give up after this many seconds.", min=0.1)
    ] = None,
    cool_to: Annotated[
        float,
        typer.Option("--cool-to", help="With --off --wait (or a target of 0): wait until below this (C).", min=0),
    ] = 50.0,
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
    max_chamber: MaxChamberOption = DEFAULT_MAX_CHAMBER_CELSIUS,
) -> None:
    """Set heater targets, print what the printer confirmed, wait if asked (the help text is `_SET_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .heaters.command import SetRequest, set_printer_targets

    if off and (hotend or bed or chamber):
        fail("--off turns every heater off; do not combine it with targets", Exit.USAGE)
    if tool is not None and hotend is None:
        fail("--tool says which hotend --hotend sets; give --hotend too", Exit.USAGE)
    request = SetRequest(
        hotend=None if off else _target("hotend", hotend, max_hotend),
        bed=None if off else _target("bed", bed, max_bed),
        chamber=_target("chamber", chamber, max_chamber),
        tool=tool,
        off=off,
        wait=wait,
        tolerance_c=tolerance,
        timeout_s=wait_timeout,
        cool_to_c=cool_to,
    )
    if not off and request.hotend is None and request.bed is None and request.chamber is None:
        fail("nothing to set: give --hotend, --bed, --chamber or --off", Exit.USAGE)
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
        max_chamber_celsius=max_chamber,
        password=password,
    )
    code = run(set_printer_targets(options, request, Console(highlight=False, emoji=False), _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- log


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_LOG_HELP = "\n\n".join(
    (
        "Record temperatures to a file, headless, for long runs. Ctrl-C (or --duration) ends it with a summary.",
        "One row per --interval: the reading of the M105 poll; when polls are held up (G28, a wait for heat started "
        "from the printer's display), the auto-report or wait line that came instead. The source column says which: "
        "poll, auto or wait.",
        "Columns: time (ISO 8601, local time with its UTC offset), epoch_s, session (a new id for each run and each "
        "reconnect), session_elapsed_s (seconds since that session's first row: it starts again with each session), "
        "source, then for each heater (hotend, bed, chamber; hotend_0, hotend_1 with several hotends) actual_c, "
        "target_c, power_percent, and power_raw (Marlin's 0-127). --format jsonl writes the same fields, heaters by "
        "name.",
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


@app.command(help=_LOG_HELP, epilog=EXIT_CODES_HELP)
def log(
    output: Annotated[Path, typer.Option("--output", "-o", help="File to write (appended to if it exists).")],
    interval: Annotated[float, typer.Option("--interval", help="Seconds between rows (at least 0.005).")] = 1.0,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds (more than 0).")
    ] = None,
    fmt: Annotated[str, typer.Option("--format", help="csv or jsonl.")] = "csv",
    hotend: Annotated[
        str | None, typer.Option("--hotend", help="Set this hotend target (C) first, then log the heat-up.")
    ] = None,
    bed: Annotated[str | None, typer.Option("--bed", help="Set this bed target (C) first, then log.")] = None,
    reconnect: Annotated[
        bool, typer.Option("--reconnect", help="When the printer goes away, keep retrying (a new session each time).")
    ] = False,
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
) -> None:
    """Record temperatures to a file (the help text is `_LOG_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    import math

    from .logs.command import LogSettings, log_temperatures

    if fmt not in ("csv", "jsonl"):
        fail(f"unknown --format {fmt!r}: use csv or jsonl", Exit.USAGE)
    if not (math.isfinite(interval) and interval >= 0.005):
        fail(f"--interval must be at least 0.005 seconds, got {interval:g}", Exit.USAGE)
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        fail(f"--duration must be more than 0 seconds, got {duration:g}", Exit.USAGE)
    settings = LogSettings(
        output=output,
        fmt=fmt,
        interval_s=interval,
        duration_s=duration,
        hotend=_target("hotend", hotend, max_hotend),
        bed=_target("bed", bed, max_bed),
        reconnect=reconnect,
    )
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        password=password,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
    )
    code = run(log_temperatures(options, settings, _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- print


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_PRINT_HELP = "\n\n".join(
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


@app.command("print", help=_PRINT_HELP, epilog=EXIT_CODES_HELP)
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
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
) -> None:
    """Stream a G-code file with a progress view, keys and --from-line (the help text is `_PRINT_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .printing.command import PrintSettings, print_gcode
    from .printing.plan import plan_print

    if path.is_dir():
        fail(f"{path} is a directory: give a G-code file", Exit.USAGE)
    if not path.exists():
        fail(f"no such file: {path}", Exit.USAGE)
    if send_ahead is False and window is not None:
        fail("--ping-pong sends one line at a time; do not combine it with --window", Exit.USAGE)
    try:
        plan = plan_print(path, from_line, force=force, limits=_limits(max_hotend, max_bed))
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"cannot read {path}: {exc.strerror or exc}", Exit.USAGE)
    ahead = window is not None if send_ahead is None else send_ahead
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        password=password,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
    )
    settings = PrintSettings(plan=plan, send_ahead=ahead, window_bytes=window, keep_heaters=keep_heaters)
    code = run(print_gcode(options, settings, Console(highlight=False, emoji=False), _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- send


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_SEND_HELP = "\n\n".join(
    (
        "Send G-code commands in order and print each reply (its lines, then ok).",
        "Every command is checked first: a line break, non-ASCII, an empty command, one too long for Marlin, or a "
        "heater target above --max-hotend or --max-bed however it is spelt (M104S280, m0104 s280, M104 B1000) exits "
        "with code 2 and nothing is sent. The first failure (timeout, halt, lost link) ends the run with its exit "
        "code; a command the printer does not know exits 1 after the others ran.",
        "Homing and probing (G28, G29, ...) get at least 3 minutes. M112 is the emergency stop: sent at once, the "
        "printer halts.",
    )
)


@app.command("send", help=_SEND_HELP, epilog=EXIT_CODES_HELP)
def send(
    commands: Annotated[
        list[str] | None,
        typer.Argument(help='G-code commands, one per argument: send "G28" "G1 X10 F3000".', show_default=False),
    ] = None,
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
) -> None:
    """Send G-code commands in order and print each reply (the help text is `_SEND_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .console.send import check_commands, send_commands

    try:
        checked = check_commands(commands or [], limits=_limits(max_hotend, max_bed))
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        password=password,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
    )
    code = run(send_commands(options, checked, Console(highlight=False, emoji=False, soft_wrap=True), _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- terminal


_TERMINAL_HELP = "\n\n".join(
    (
        "Interactive G-code console: type commands, read replies; temperatures in the bottom bar.",
        "Tab completes the common G and M codes (with what each does); Up/Down and Ctrl-R reach the history of "
        "earlier sessions. Replies are printed as they come, and you can type on while a long command runs. Ctrl-C "
        "clears the line, Ctrl-D quits.",
        "F12 sends the emergency stop at once, ahead of anything queued: the printer halts and needs a reset (the "
        "exit code is then 7). M112 (or !) and Enter asks first. M112 is never completed or kept in the history.",
        "Every command is read as Marlin reads it and checked against --max-hotend and --max-bed (M104S280, "
        "m0104 s280 and M104 B1000 are all heater targets); one refused, or a malformed one, is one error line and "
        "nothing is sent.",
        "Needs a terminal: from scripts use send.",
    )
)


@app.command("terminal", help=_TERMINAL_HELP, epilog=EXIT_CODES_HELP)
def terminal(
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_MAX_HOTEND_CELSIUS,
    max_bed: MaxBedOption = DEFAULT_MAX_BED_CELSIUS,
    interval: Annotated[
        float, typer.Option("--interval", help="Seconds between the (hidden) temperature polls.", min=0.05)
    ] = 1.0,
    temperatures_every: Annotated[
        float,
        typer.Option(
            "--temperatures-every",
            help="Add a temperature line to the scrollback at most this often, when they changed (0: never).",
            min=0,
        ),
    ] = 30.0,
    history: Annotated[
        Path | None,
        typer.Option(
            "--history",
            help="History file. Default: $XDG_STATE_HOME/marlin-temp/history (~/.local/state/marlin-temp/history).",
            show_default=False,
        ),
    ] = None,
    no_history: Annotated[bool, typer.Option("--no-history", help="Keep no history after this session.")] = False,
) -> None:
    """The interactive G-code console (the help text is `_TERMINAL_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .console.terminal import ConsoleSettings, default_history_path, run_console

    if not (sys.stdin.isatty() and sys.stdout.isatty()):
        fail('terminal needs an interactive terminal; from a script use: marlin-temp send "G28" "M114"', Exit.USAGE)
    settings = ConsoleSettings(
        poll_interval_s=interval,
        temperature_every_s=temperatures_every,
        history_path=None if no_history else history or default_history_path(),
    )
    options = ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        password=password,
        max_hotend_celsius=max_hotend,
        max_bed_celsius=max_bed,
    )
    code = run(run_console(options, settings, _stderr()))
    raise typer.Exit(int(code))


# ------------------------------------------------------------------------------------------- bench


# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
_BENCH_HELP = "\n\n".join(
    (
        "Check the link to your printer (cable, USB bridge, baud rate, firmware): latency, order, throughput.",
        "Read-only: sends only M105, M118 (an echo) and G4 P0 (a dwell of 0 ms); nothing moves or heats.",
        "Latency: --count M105 round trips, one at a time. median, p99 and max are the time from writing the line "
        "to reading its ok (half, 99 % and all of them took no longer); round trips/s is how many were answered "
        "per second.",
        "Order check: --lines numbered 'M118 E1 bench <n>' lines with checksums, several in flight (send-ahead). "
        "Each reply must carry its own echo and come after the earlier ones: 'oks in order' should equal 'lines "
        "sent', and 'out of order' be 0. A lost ok is not reordering and is counted apart: 'oks lost' counts the "
        "oks that never came, which the library proved lost by a later answer and recovered from, and 'replies "
        "withheld' the lines that ran but whose reply it could not prove to be their own, so gave them none. "
        "Without ADVANCED_OK in the firmware only an M105's ok names its command, so each line gets an M105 behind "
        "it and lines go one at a time. 'resends' counts the lines the printer rejected (corrupted on the way) and "
        "asked for again; 'timeouts' the commands that got no ok within --timeout.",
        "Throughput: --lines G4 P0 lines streamed as 'marlin-temp print' streams a file (send-ahead in the "
        "printer's 128-byte buffer). 'stream lines/s' and 'stream bytes/s' (as on the wire, with line numbers and "
        "checksums) are compared with the wire limit of the baud rate, baud/10 bytes per second ('wire use'). The "
        "built-in --sim is not paced, so the limit does not apply there: run 'marlin-sim --baud 250000' and give "
        "its device as --port to see the ratio.",
        "Exits 1 with one line when an ok came back out of order, a line got no answer or a command timed out. "
        "Lost oks that the library recovered are not a failure of the link's order: they give a warning line "
        "('3 oks lost (recovered), 0 out of order') and exit 0.",
    )
)


# ------------------------------------------------------------------------------------------- farm

_FARM_HELP = (
    "Run many printers in one process and publish them to an MQTT broker, with Home Assistant discovery."
    "\n\n"
    "Give the printers as --port NAME=PORT (repeatable), --config FILE (TOML: a \\[defaults] table and "
    "\\[\\[printer]] tables with name, port, baud, poll_interval_s, max_hotend_celsius, ...), or --sims N for N "
    "simulated printers. Each printer reconnects on its own, with backoff, when it is unplugged, halts or does not "
    "answer; the others go on."
    "\n\n"
    "Per printer NAME it publishes PREFIX/NAME/telemetry (each heater's actual, target and power in percent, at "
    "--rate), PREFIX/NAME/state (retained JSON), PREFIX/NAME/events (QoS 1, queued while the broker is away) and "
    "PREFIX/NAME/availability (retained); and PREFIX/bridge/availability with a Last Will, so a crashed bridge "
    "shows offline. The broker password comes from $MARLIN_MQTT_PASSWORD or --password-file, never from the "
    "command line."
    "\n\n"
    "Try it: install Mosquitto (apt install mosquitto mosquitto-clients), run 'marlin-temp farm --sims 5', and "
    "watch with: mosquitto_sub -v -t 'marlin/#'"
)


@app.command("farm", help=_FARM_HELP, epilog=EXIT_CODES_HELP)
def farm(
    ports: Annotated[
        list[str] | None, typer.Option("--port", "-p", help="A printer as NAME=PORT (or just PORT); repeatable.")
    ] = None,
    config: Annotated[Path | None, typer.Option("--config", help="TOML file listing the printers.")] = None,
    sims: Annotated[
        int, typer.Option("--sims", help="Add N simulated printers (sim1, sim2, ...).", min=0, metavar="N")
    ] = 0,
    sim_speed: SimSpeedOption = 1.0,
    baud: BaudOption = None,
    interval: Annotated[
        float, typer.Option("--interval", help="Seconds between M105 polls of each printer.", min=0.005)
    ] = 0.1,
    broker: Annotated[str, typer.Option("--broker", help="MQTT broker as HOST[:PORT].")] = "127.0.0.1:1883",
    username: Annotated[str | None, typer.Option("--username", help="Broker user name.")] = None,
    password_file: Annotated[
        Path | None, typer.Option("--password-file", help="File with the broker password (or $MARLIN_MQTT_PASSWORD).")
    ] = None,
    client_id: Annotated[str | None, typer.Option("--client-id", help="MQTT client id (default: a random one).")] = (
        None
    ),
    tls_ca: Annotated[Path | None, typer.Option("--tls-ca", help="CA certificate: connect with TLS (port 8883).")] = (
        None
    ),
    tls_cert: Annotated[Path | None, typer.Option("--tls-cert", help="Client certificate for TLS.")] = None,
    tls_key: Annotated[Path | None, typer.Option("--tls-key", help="Client certificate's key.")] = None,
    prefix: Annotated[str, typer.Option("--prefix", help="Topic prefix.")] = "marlin",
    bridge_name: Annotated[
        str,
        typer.Option(
            "--bridge-name",
            help="The bridge's own topic level (PREFIX/NAME/availability); give each bridge sharing a broker and "
            "prefix its own.",
        ),
    ] = "bridge",
    rate: Annotated[
        float,
        typer.Option(
            "--rate",
            help="Telemetry messages per second and printer (at most the poll rate). The default, one every 5 s, "
            "keeps Home Assistant's recorder small; dashboards may want 1 or 2.",
        ),
    ] = 0.2,
    discovery: Annotated[
        bool, typer.Option("--discovery/--no-discovery", help="Publish Home Assistant MQTT discovery.")
    ] = True,
    discovery_prefix: Annotated[str, typer.Option("--discovery-prefix", help="Home Assistant's prefix.")] = (
        "homeassistant"
    ),
    allow_commands: Annotated[
        bool,
        typer.Option(
            "--allow-commands",
            help="Take commands on PREFIX/NAME/command (set targets, G-code, prints, emergency stop); off by default.",
        ),
    ] = False,
    allowed_dir: Annotated[
        Path | None,
        typer.Option("--allowed-dir", help="With --allow-commands: prints may be started from files in this folder."),
    ] = None,
    duration: Annotated[float | None, typer.Option("--duration", help="Stop after this many seconds.")] = None,
) -> None:
    if importlib.util.find_spec("aiomqtt") is None:
        fail("marlin-temp farm needs aiomqtt, which is not installed: pip install 'marlin-aio[farm]'")
    from marlin_aio.farm.bridge import BridgeSettings
    from marlin_aio.farm.config import check_unique, load_config, specs_from_options

    from .farm.command import FarmOptions, broker_settings, run_farm

    if duration is not None and not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration:g}", Exit.USAGE)
    if not (rate > 0 and rate <= 1 / interval):
        fail(f"--rate must be above 0 and at most the poll rate ({1 / interval:g}/s), got {rate:g}", Exit.USAGE)
    for name, value in (("--prefix", prefix), ("--discovery-prefix", discovery_prefix)):
        if not value or any(c in value for c in "#+ ") or value.startswith("/") or value.endswith("/"):
            fail(f"{name} {value!r}: a topic prefix without '#', '+', spaces or a leading or trailing '/'", Exit.USAGE)
    from marlin_aio.farm.config import NAME_PATTERN, NAME_RULE

    if not NAME_PATTERN.fullmatch(bridge_name):
        fail(f"--bridge-name {bridge_name!r} must be {NAME_RULE}", Exit.USAGE)
    try:
        specs = load_config(config) if config is not None else []
        if ports or sims or not specs:
            options_specs = specs_from_options(
                ports or [],
                sims,
                baud=baud or marlin_aio.DEFAULT_BAUDRATE,
                poll_interval_s=interval,
                sim_speed=sim_speed,
            )
            specs = check_unique(specs + options_specs)
        broker_at = broker_settings(
            broker,
            username=username,
            password_file=password_file,
            client_id=client_id,
            tls_ca=tls_ca,
            tls_cert=tls_cert,
            tls_key=tls_key,
        )
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{config}: {exc.strerror or exc}", Exit.USAGE)
    if any(spec.name == bridge_name for spec in specs):
        fail(f"printer name {bridge_name!r} is the bridge's own (--bridge-name); choose another", Exit.USAGE)
    if allowed_dir is not None and not allow_commands:
        fail(f"--allowed-dir {allowed_dir} is for prints over MQTT: give --allow-commands too", Exit.USAGE)
    if allowed_dir is not None and not allowed_dir.is_dir():
        fail(f"--allowed-dir {allowed_dir}: no such folder", Exit.USAGE)
    settings = BridgeSettings(
        prefix=prefix,
        name=bridge_name,
        rate_hz=rate,
        discovery=discovery,
        discovery_prefix=discovery_prefix,
        allow_commands=allow_commands,
        allowed_dir=allowed_dir,
    )
    bridge = run(run_farm(specs, broker_at, settings, FarmOptions(duration_s=duration), _stderr()))
    if bridge.connections == 0:
        fail(f"never reached the MQTT broker at {broker_at.address}: is it running (and the address right)?")


@app.command("bench", help=_BENCH_HELP, epilog=EXIT_CODES_HELP)
def bench(
    count: Annotated[int, typer.Option("--count", "-n", help="M105 round trips in the latency run.", min=1)] = 500,
    lines: Annotated[
        int, typer.Option("--lines", help="Lines in the order check and in the throughput stream.", min=1)
    ] = 1000,
    duration: Annotated[
        float | None,
        typer.Option("--duration", help="Run each of the three parts this many seconds instead.", min=0.01),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object instead of the table.")] = False,
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
) -> None:
    """Measure latency, order and throughput of the link to the printer (the help text is `_BENCH_HELP`)."""
    password = _printer_password(password, password_file, ask_password)
    from .bench.command import BenchSettings, bench_printer, show_result

    options = ConnectOptions(port=port, baud=baud, sim=sim, sim_speed=sim_speed, timeout_s=timeout, password=password)
    settings = BenchSettings(round_trips=count, lines=lines, duration_s=duration)
    result = run(bench_printer(options, settings, _stderr()))
    show_result(result, Console(highlight=False, emoji=False), as_json=json_output)
    if result.problem is not None:
        fail(result.problem)
    if result.warning is not None:
        _stderr().print(f"[yellow]warning:[/] {escape(result.warning)}", markup=True)


# ------------------------------------------------------------------------------------------- plot


@app.command(epilog=EXIT_CODES_HELP)
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
    from .logs.plot import plot_log

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
        _stderr().print(message)


# ------------------------------------------------------------------------------------------- ports


@app.command()
def ports() -> None:
    """List serial ports, marking the USB bridges printer boards use (CH340, CP2102, FTDI, STM32, Mega)."""
    from rich.table import Table

    found = marlin_aio.list_ports()
    console = Console(highlight=False, emoji=False)
    if not found:
        console.print("no serial ports found")
        return
    table = Table(box=None, header_style="bold")
    for column in ("port", "description", "usb id", "printer bridge"):
        table.add_column(column)
    for info in found:
        style = "bold" if info.likely_printer else "dim"
        table.add_row(info.device, info.description, info.usb_id or "-", info.bridge or "-", style=style)
    console.print(table)


# ------------------------------------------------------------------------------------------- sim


@app.command(
    "sim",
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []},
    add_help_option=False,
)
def simulate(ctx: typer.Context) -> None:
    """Run the simulated printer on a pseudo-terminal (or TCP) and print its address; Ctrl-C stops it.

    Takes every marlin-sim option (marlin-temp sim --help lists them): one definition serves both commands. Open
    the printed device path (or socket:// URL) with any host program, e.g. marlin-temp watch --port PATH.
    """
    from marlin_aio.simulator.__main__ import main as simulator_main

    # --sim-speed, as in every other command (the older --speed and --time-scale are still accepted).
    raise typer.Exit(simulator_main(ctx.args, prog="marlin-temp sim"))
