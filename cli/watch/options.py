"""The command line of `marlin-temp watch`: its options and help, checked before `command` watches anything.

Its connect options are the shared ones, declared here rather than through `with_connect_options`: `--port` is
repeatable (a farm of printers), and watch's own options stand between the shared ones in `--help`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console

import marlin_aio
from marlin_aio.protocol import DEFAULT_LIMITS

from ..common.connect import ConnectOptions, Exit
from ..common.history import BUCKETS, LEVELS_S
from ..common.options import (
    AskPasswordOption,
    BaudOption,
    MaxBedOption,
    MaxHotendOption,
    PasswordFileOption,
    PasswordOption,
    SimOption,
    SimSpeedOption,
    TimeoutOption,
    WireLogOption,
    checked_log_path,
    connect_options,
    error_console,
    fail,
    run,
)
from ..common.presets import PresetsOption, load_presets_file

if TYPE_CHECKING:
    from marlin_aio.farm.supervisor import PrinterSpec

__all__ = ["WATCH_HELP", "watch"]

#: The longest window the history holds: its coarsest buckets (12 h).
MAX_WINDOW_S = LEVELS_S[-1] * BUCKETS

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
WATCH_HELP = "\n\n".join(
    (
        "Live view of every heater: table, chart of the last minute (w steps it to 10 min, 1 h, 6 h and back; "
        "--window sets where it starts), link statistics. q or Ctrl-C quits.",
        "Keys set targets while watching: h hotend and b bed (type the degrees, Enter; Esc cancels), o every "
        "heater off, + and - step the last one chosen by 5 C, 1-9 the presets in the presets file's order (by "
        "default 1 PLA 200/60 C, 2 PETG 240/80 C, 3 ABS 250/100 C, 4 cooldown; marlin-temp presets lists them), f "
        "the fan (percent), and : sends one G-code line, its reply shown under the chart. Targets are checked "
        "against --max-hotend and --max-bed as in set; one refused is shown in the view and nothing is sent. "
        "Narrow terminals (down to 40 columns) get a compact table; short ones lose the chart first, then the "
        "footer and the key help shorten (down to 30x12 the keys stay on screen).",
        "A prompt the printer opens (a filament change, a runout) is shown under the chart with its buttons; "
        "while it is open, its digit keys answer it (M876) instead of choosing a preset.",
        "On a printer of marlin-temp serve (--port serve:NAME), the service's print job is shown over the table "
        "(file, percent, state, who started it; once ended, how and the line to resume from): p pauses and "
        "resumes it, and c cancels it after a question only y answers (any other key keeps it printing).",
        "With two or more hotends each one (hotend 0, hotend 1, ...) has its own row with its actual, target and "
        "power, and its own curve in the chart, whichever tool is active. When stdout is not a terminal it prints "
        "one plain line per refresh instead (or JSON lines with --json), and q is the only key.",
        "The footer's latency is of the recent round trips, polls included: the median and the worst of the "
        "last 10 s, so a slow command (G28) stops being the worst 10 s after it.",
        "A target the printer does not report (Repetier-style reports, set by another program) shows as ?, and "
        "its heater as heating? while it draws power, else unknown: never off.",
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
            help="Seconds between M105 polls (default 0.01; with several printers 0.1 for each): every reading is "
            "shown and logged; --refresh paces the screen.",
            min=0.001,
            show_default=False,
        ),
    ] = None,
    refresh: Annotated[float, typer.Option("--refresh", help="Seconds between screen redraws.", min=0.05)] = 1.0,
    window: Annotated[
        float,
        typer.Option(
            "--window",
            help="Seconds of history the chart starts with (default 60; up to 43200, 12 h); the w key steps it "
            "through 1 min, 10 min, 1 h and 6 h.",
            min=5,
            max=MAX_WINDOW_S,
            show_default=False,
        ),
    ] = 60.0,
    tolerance: Annotated[
        float, typer.Option("--tolerance", help="Within this many C a heater is holding.", min=0)
    ] = 2.0,
    log: Annotated[
        Path | None, typer.Option("--log", help="Also record every reading to this CSV file (on disk within a second).")
    ] = None,
    json_lines: Annotated[bool, typer.Option("--json", help="Print JSON lines instead of the live view.")] = False,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds. Default: until q or Ctrl-C.")
    ] = None,
    reconnect: Annotated[
        bool,
        typer.Option("--reconnect", help="When the printer goes away, keep retrying (after 1 s, doubling up to 30 s)."),
    ] = False,
    max_hotend: MaxHotendOption = DEFAULT_LIMITS.hotend,
    max_bed: MaxBedOption = DEFAULT_LIMITS.bed,
    presets_file: PresetsOption = None,
    wire_log: WireLogOption = None,
) -> None:
    """Live view of every heater, with keys to set targets; the farm view for several printers (the help text
    is `WATCH_HELP`)."""
    ports = ports or []
    options = connect_options(
        port=_single_port(ports),
        baud=baud,
        sim=sim or sims == 1,
        sim_speed=sim_speed,
        timeout=timeout,
        password=password,
        password_file=password_file,
        ask_password=ask_password,
        max_hotend=max_hotend,
        max_bed=max_bed,
        wire_log=wire_log,
    )
    from .command import WatchSettings, watch_farm, watch_printer

    if sim and sims:
        fail("--sim is one simulated printer, --sims N is N of them: give one of the two", Exit.USAGE)
    farm_specs = _farm_specs(ports, sims + int(sim), options, interval) if len(ports) + sims + int(sim) > 1 else []
    if duration is not None and not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration:g}", Exit.USAGE)
    settings = WatchSettings(
        interval_s=interval or (0.1 if farm_specs else 0.01),
        refresh_s=refresh,
        window_s=window,
        tolerance_c=tolerance,
        log_path=None if log is None else checked_log_path(log, "--log"),
        json_lines=json_lines,
        duration_s=duration,
        reconnect=reconnect,
        # One printer's view only: the farm view's keys 1-9 choose a printer.
        presets=() if farm_specs else load_presets_file(presets_file).presets,
        wire_log=options.wire_log,
    )
    if farm_specs:
        if log is not None:
            fail("--log records one printer: watch it alone (one --port or --sim) to log it", Exit.USAGE)
        code = run(watch_farm(farm_specs, settings, Console(highlight=False, emoji=False), error_console()))
    else:
        code = run(watch_printer(options, settings, Console(highlight=False, emoji=False), error_console()))
    raise typer.Exit(int(code))


def _single_port(ports: list[str]) -> str | None:
    """The port of a single printer: the first --port, its name dropped if given as NAME=PORT (it is not used)."""
    if not ports:
        return None
    name, sep, after = ports[0].partition("=")
    return after if sep and "://" not in name else ports[0]


def _farm_specs(ports: list[str], sims: int, options: ConnectOptions, interval_s: float | None) -> list[PrinterSpec]:
    """The printers of the farm view (--port NAME=PORT given again, --sims N), each with the connect options of
    the command line: its timeout, password and heater limits.

    The farm keeps a printer's limits as the three numbers of its TOML file (`max_hotend_celsius` ...), so the
    one `HeaterLimits` of the options is spread into them here.
    """
    from dataclasses import replace

    from marlin_aio.farm.config import specs_from_options

    try:
        specs = specs_from_options(
            ports,
            sims,
            baud=options.baud or marlin_aio.DEFAULT_BAUDRATE,
            poll_interval_s=interval_s or 0.1,
            sim_speed=options.sim_speed,
        )
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    limits = options.limits
    from marlin_aio.service import service_holding

    for index, spec in enumerate(specs):
        served = service_holding(spec.port) if spec.port and not spec.port.startswith("serve:") else None
        if served is not None:
            # The service owns that port: watch it through the service (a `serve:` port is a served printer).
            error_console().print(f"{spec.port} is held by marlin-temp serve: using it ({served})", style="dim")
            specs[index] = replace(spec, port=served)
    return [
        replace(
            spec,
            timeout_s=options.timeout_s,
            password=options.password,
            max_hotend_celsius=limits.hotend,
            max_bed_celsius=limits.bed,
            max_chamber_celsius=limits.chamber,
        )
        for spec in specs
    ]
