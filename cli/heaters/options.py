"""The command line of `marlin-temp set`: its options and help; the targets are checked here, before `command`
opens the printer."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions, Exit
from ..common.options import checked_target, error_console, fail, run, with_connect_options

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
    )
)


@with_connect_options("hotend", "bed", "chamber")
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
    if tool is not None and hotend is None:
        fail("--tool says which hotend --hotend sets; give --hotend too", Exit.USAGE)
    if on_done is not None and not wait:
        fail("--on-done runs when a --wait ends; without --wait set ends at once: give --wait too", Exit.USAGE)
    if on_done is not None and not on_done.strip():
        fail("--on-done is empty: give a shell command", Exit.USAGE)
    limits = options.limits
    request = SetRequest(
        hotend=None if off else checked_target("hotend", hotend, limits.hotend),
        bed=None if off else checked_target("bed", bed, limits.bed),
        chamber=checked_target("chamber", chamber, limits.chamber),
        tool=tool,
        off=off,
        wait=wait,
        tolerance_c=tolerance,
        timeout_s=wait_timeout,
        cool_to_c=cool_to,
        on_done=on_done,
    )
    if not off and request.hotend is None and request.bed is None and request.chamber is None:
        fail("nothing to set: give --hotend, --bed, --chamber or --off", Exit.USAGE)
    code = run(set_printer_targets(options, request, Console(highlight=False, emoji=False), error_console()))
    raise typer.Exit(int(code))
