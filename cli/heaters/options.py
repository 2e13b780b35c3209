"""The command line of `marlin-temp set`: its options and help; the targets are checked here, before `command`
opens the printer."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from marlin_aio.farm.presets import find_preset
from marlin_aio.protocol import HeaterLimits, check_target

from ..common.connect import ConnectOptions, Exit
from ..common.options import checked_target, error_console, fail, run, with_connect_options
from ..common.presets import PresetsOption, load_presets_file

__all__ = ["SET_HELP", "set_targets"]

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
SET_HELP = "\n\n".join(
    (
        "Set heater targets and print what the printer confirmed; --wait heats up with a progress bar per heater.",
        "Targets are checked before anything is sent: not a number, negative or above the limit (hotend 260 C, "
        "bed 140 C, chamber 60 C by default: Marlin's own clamps) exits with code 2 and one line saying why, as "
        "does a heater the printer does not have (--tool 1 on a one-hotend printer, --chamber with no chamber).",
        "What is printed is the target the printer confirmed, which can differ from the one asked for: Marlin "
        "keeps whole degrees and caps a target at its own maximum; the line says so, and --wait waits for the "
        "confirmed target. --off turns off every hotend, the bed and the chamber; --off --wait waits until each "
        "is below --cool-to (50 C: safe to touch).",
        "--preset NAME sets a preset's targets (marlin-temp presets lists them, with their file; the name in any "
        "case): set --preset PETG --wait. --hotend or --bed given with it replaces that heater's target of the "
        "preset (--preset PLA --hotend 215). An unknown name, a bad presets file or a preset above the limits "
        "exits with code 2 before anything is sent.",
    )
)


@with_connect_options("hotend", "bed", "chamber")
def set_targets(
    hotend: Annotated[str | None, typer.Option("--hotend", help="Hotend target in C (0 turns it off).")] = None,
    bed: Annotated[str | None, typer.Option("--bed", help="Bed target in C (0 turns it off).")] = None,
    chamber: Annotated[str | None, typer.Option("--chamber", help="Chamber target in C.")] = None,
    preset: Annotated[
        str | None,
        typer.Option(
            "--preset",
            help="Set this preset's targets (marlin-temp presets lists them); --hotend or --bed replaces its own.",
            show_default=False,
            metavar="NAME",
        ),
    ] = None,
    presets_file: PresetsOption = None,
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
        float | None,
        typer.Option(
            "--wait-timeout", help="With --wait: give up after this many seconds. Default: no limit.", min=0.1
        ),
    ] = None,
    cool_to: Annotated[
        float,
        typer.Option("--cool-to", help="With --off --wait (or a target of 0): wait until below this (C).", min=0),
    ] = 50.0,
    on_done: Annotated[
        str | None,
        typer.Option(
            "--on-done",
            metavar="CMD",
            help="With --wait: run CMD through sh -c when the wait ends (reached, timed out, failed), with the outcome "
            "in $MARLIN_TEMP_OUTCOME, $MARLIN_TEMP_MESSAGE, $MARLIN_TEMP_EXIT ... (see the README); waited for up to "
            "60 s. Default: none.",
            show_default=False,
        ),
    ] = None,
    *,
    options: ConnectOptions,
) -> None:
    """Set heater targets, print what the printer confirmed, wait if asked (the help text is `SET_HELP`)."""
    from .command import SetRequest, set_printer_targets

    if off and (hotend or bed or chamber):
        fail("--off turns every heater off; do not combine it with targets", Exit.USAGE)
    if off and preset is not None:
        fail("--off turns every heater off; do not combine it with --preset", Exit.USAGE)
    if on_done is not None and not wait:
        fail("--on-done runs when a --wait ends; without --wait set ends at once: give --wait too", Exit.USAGE)
    if on_done is not None and not on_done.strip():
        fail("--on-done is empty: give a shell command", Exit.USAGE)
    limits = options.limits
    # The preset's targets, less those --hotend or --bed replaces.
    given = {"hotend": checked_target("hotend", hotend, limits.hotend), "bed": checked_target("bed", bed, limits.bed)}
    replaced = {heater for heater, celsius in given.items() if celsius is not None}
    preset_name, from_preset = (None, {}) if preset is None else _preset_targets(preset, presets_file, limits, replaced)
    wanted = {heater: from_preset.get(heater) if celsius is None else celsius for heater, celsius in given.items()}
    if tool is not None and wanted["hotend"] is None:
        fail("--tool says which hotend --hotend sets; give --hotend too", Exit.USAGE)
    request = SetRequest(
        hotend=None if off else wanted["hotend"],
        bed=None if off else wanted["bed"],
        chamber=checked_target("chamber", chamber, limits.chamber),
        tool=tool,
        off=off,
        wait=wait,
        tolerance_c=tolerance,
        timeout_s=wait_timeout,
        cool_to_c=cool_to,
        preset=preset_name,
        on_done=on_done,
    )
    if not off and request.hotend is None and request.bed is None and request.chamber is None:
        fail("nothing to set: give --hotend, --bed, --chamber, --preset or --off", Exit.USAGE)
    code = run(set_printer_targets(options, request, Console(highlight=False, emoji=False), error_console()))
    raise typer.Exit(int(code))


def _preset_targets(
    name: str, presets_file: Path | None, limits: HeaterLimits, replaced: set[str]
) -> tuple[str, dict[str, float]]:
    """The preset called `name` (any case) in the presets file in use: its name as the file spells it, and its
    targets but those `replaced` (by --hotend, --bed), each checked against `limits`; an unknown name or a target
    above its limit fails with one line naming the file and the preset (exit code 2)."""
    loaded = load_presets_file(presets_file)
    try:
        found = find_preset(loaded.presets, name)
    except ValueError as exc:
        fail(f"{loaded.source}: {exc}", Exit.USAGE)
    targets = {heater: celsius for heater, celsius in found.targets().items() if heater not in replaced}
    for heater, celsius in targets.items():
        try:
            check_target(heater, celsius, limits.of(heater))
        except ValueError as exc:
            fail(f"{loaded.source}: preset {found.name!r}: {exc} (raise the limit with --max-{heater})", Exit.USAGE)
    return found.name, targets
