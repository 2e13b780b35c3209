"""Heater targets and waits: the G-code that sets targets, the targets a wait watches, and when they are reached.

Pure functions over readings and limits, so `Printer.set_temperatures` and `Printer.wait_for_temperatures` stay
short and these rules can be tested without a printer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from marlin_aio.commands import check_target, command_code, format_celsius
from marlin_aio.temperatures import TemperatureReading, heater_name

__all__ = [
    "HeaterLimits",
    "check_gcode_targets",
    "check_tool",
    "describe_heaters",
    "target_commands",
    "targets_reached",
    "wanted_targets",
]

#: The commands that set a target, with the heater they set.
_TARGET_CODES = {"M104": "hotend", "M109": "hotend", "M140": "bed", "M190": "bed", "M141": "chamber", "M191": "chamber"}


@dataclass(frozen=True, slots=True)
class HeaterLimits:
    """The highest targets accepted, in degrees Celsius."""

    hotend: float
    bed: float
    chamber: float


def check_gcode_targets(
    command: str, *, max_hotend_celsius: float, max_bed_celsius: float, max_chamber_celsius: float
) -> None:
    """Check the target a raw G-code command sets (`M104 S300`, `M190 R70`) against the same limits as
    `set_temperatures`, so typed G-code cannot get around them; other commands pass.

    Raises:
        ValueError: the command sets a target that is not a number, negative or above its limit.
    """
    heater = _TARGET_CODES.get(command_code(command))  # cached: this runs for every command sent
    if heater is None:
        return
    words = command.split(";", 1)[0].split()
    if words[0][:1] in "Nn" and words[0][1:].isdigit():
        words = words[1:]
    limit = {"hotend": max_hotend_celsius, "bed": max_bed_celsius, "chamber": max_chamber_celsius}[heater]
    for word in words[1:]:
        if word[:1] in "SsRr":
            check_target(heater, word[1:], limit)


def check_tool(tool: int | None) -> None:
    """Raises ValueError unless `tool` is None or a non-negative integer."""
    if tool is not None and (isinstance(tool, bool) or not isinstance(tool, int) or tool < 0):
        raise ValueError(f"tool must be a non-negative integer, got {tool!r}")


def target_commands(
    limits: HeaterLimits, *, hotend: float | None, bed: float | None, chamber: float | None, tool: int | None
) -> list[str]:
    """M104/M140/M141 for the targets given, each checked first.

    Raises:
        ValueError: a target is not a number, negative or above its limit; `tool` is negative.
    """
    check_tool(tool)
    commands = []
    if hotend is not None:
        value = check_target("hotend", hotend, limits.hotend)
        commands.append(f"M104 {'' if tool is None else f'T{tool} '}S{format_celsius(value)}")
    if bed is not None:
        value = check_target("bed", bed, limits.bed)
        commands.append(f"M140 S{format_celsius(value)}")
    if chamber is not None:
        value = check_target("chamber", chamber, limits.chamber)
        commands.append(f"M141 S{format_celsius(value)}")
    return commands


def wanted_targets(
    limits: HeaterLimits, *, hotend: float | None, bed: float | None, chamber: float | None, tool: int | None
) -> dict[str, float]:
    """The report keys a wait watches, with their explicit targets (`T` is the active hotend, `T<n>` one hotend).

    Raises:
        ValueError: as `target_commands`.
    """
    check_tool(tool)
    wanted: dict[str, float] = {}
    if hotend is not None:
        wanted["T" if tool is None else f"T{tool}"] = check_target("hotend", hotend, limits.hotend)
    if bed is not None:
        wanted["B"] = check_target("bed", bed, limits.bed)
    if chamber is not None:
        wanted["C"] = check_target("chamber", chamber, limits.chamber)
    return wanted


def targets_reached(
    reading: TemperatureReading, wanted: dict[str, float], tool: int | None, tolerance_c: float
) -> bool:
    """Are the heaters of `wanted` within `tolerance_c` of their targets (or, with none given, every heater that
    has a target, among the active or named hotend, the bed and the chamber)?"""
    heaters = dict(reading.temperatures.heaters)
    if "T0" not in heaters and "T" in heaters:
        heaters["T0"] = heaters["T"]  # a single-hotend printer reports only `T`
    targets = dict(wanted)
    if not wanted:
        names = ("T" if tool is None else f"T{tool}", "B", "C")
        targets = {k: h.target for k, h in heaters.items() if h.target and k in names}
    return all(key in heaters and abs(heaters[key].actual - target) <= tolerance_c for key, target in targets.items())


def describe_heaters(reading: TemperatureReading) -> str:
    """The heaters of `reading` as "hotend 198.2/200 C, bed 60.0/60 C", for messages (named as everywhere else)."""
    parts = []
    heaters = reading.temperatures.heaters
    for key, heater in heaters.items():
        if key == "T" and "T0" in heaters:
            continue  # the active hotend appears again under its number
        if key[:1] in ("T", "B", "C") and heater.target is not None and not math.isnan(heater.actual):
            parts.append(f"{heater_name(key)} {heater.actual:.1f}/{heater.target:.0f} C")
    return ", ".join(parts) or "no heaters reported"
