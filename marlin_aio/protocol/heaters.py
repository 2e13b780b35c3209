"""Heater targets and waits: the G-code that sets targets, the targets a wait watches, and when they are reached.

Pure functions over readings and limits, so `Printer.set_temperatures` and `Printer.wait_for_temperatures` stay
short and these rules can be tested without a printer.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from marlin_aio.protocol.commands import (
    DEFAULT_MAX_BED_CELSIUS,
    DEFAULT_MAX_CHAMBER_CELSIUS,
    DEFAULT_MAX_HOTEND_CELSIUS,
    check_target,
    format_celsius,
)
from marlin_aio.protocol.gcode import GCodeLine, command_code, parse_gcode, value_long
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.temperatures import TemperatureReading, heater_name

__all__ = [
    "DEFAULT_LIMITS",
    "HeaterLimits",
    "check_gcode_targets",
    "check_tool",
    "describe_heaters",
    "target_commands",
    "targets_reached",
    "wanted_targets",
]

#: The words that set a target, by command and letter, with the heater each sets: S and R for M104/M109,
#: M140/M190 and M141/M191; B, AUTOTEMP's upper target, for M104/M109; M145's material presets (H hotend, B bed),
#: which M104/M140 `I<n>` and the LCD's preheat use later. M303 (PID autotune) heats to its S (see `_m303_heater`).
_TARGET_WORDS: dict[str, dict[str, str]] = {
    "M104": {"S": "hotend", "R": "hotend", "B": "hotend"},
    "M109": {"S": "hotend", "R": "hotend", "B": "hotend"},
    "M140": {"S": "bed", "R": "bed"},
    "M190": {"S": "bed", "R": "bed"},
    "M141": {"S": "chamber", "R": "chamber"},
    "M191": {"S": "chamber", "R": "chamber"},
    "M145": {"H": "hotend", "B": "bed"},
    "M303": {"S": "hotend"},
}
_TARGET_NUMBERS = frozenset(int(code[1:]) for code in _TARGET_WORDS)
_M_WORD = re.compile(r"[Mm] *[0-9]")  # an M command word, as parser.cpp reads one
_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)")


@dataclass(frozen=True, slots=True)
class HeaterLimits:
    """The highest targets accepted, in degrees Celsius."""

    hotend: float
    bed: float
    chamber: float

    def of(self, heater: str) -> float:
        """The limit of "hotend", "bed" or "chamber"."""
        return {"hotend": self.hotend, "bed": self.bed, "chamber": self.chamber}[heater]


#: Marlin's own default clamps (see `commands.DEFAULT_MAX_HOTEND_CELSIUS`).
DEFAULT_LIMITS = HeaterLimits(DEFAULT_MAX_HOTEND_CELSIUS, DEFAULT_MAX_BED_CELSIUS, DEFAULT_MAX_CHAMBER_CELSIUS)


def check_gcode_targets(command: str, limits: HeaterLimits) -> None:
    """Check every target a G-code command sets against `limits`, reading it as Marlin does (`gcode`):
    `M104S280`, `m0104 s280`, `M104 S100 S280`, `M65640 S280` (M104 to a 16-bit parser) and `M104 B1000` (AUTOTEMP)
    are all read, so no spelling gets around the limits that `set_temperatures` applies. A command word carried as
    a parameter of another (`T0 M104 S1000`, which Marlin runs as T0) is checked as if it ran: the user meant it.
    Every word of a target letter must be a plain number from 0 to the limit; other commands pass.

    Raises:
        ValueError: a target is not a number, negative or above its limit; the message names heater and limit.
    """
    if _M_WORD.search(command) is None:
        return  # every target is set by an M word: most lines (moves) have none, and cost one search
    if command_code(command) not in _TARGET_WORDS and _M_WORD.search(command, 1) is None:
        return  # an M command that sets no target, with no other M word in it
    line = parse_gcode(command)
    codes = [line.code]
    for letter, value in line.words:
        if letter == "M" and value is not None and value_long(value) in _TARGET_NUMBERS:
            codes.append(f"M{value_long(value)}")
    for code in codes:
        targets = _TARGET_WORDS.get(code)
        if targets is None:
            continue
        for letter, value in line.words:
            heater = targets.get(letter)
            if heater is None:
                continue
            if code == "M303":
                heater = _m303_heater(line)
            limit = limits.of(heater)
            if value is None or _NUMBER.fullmatch(value) is None:
                shown = _word_after(line.args, letter) if value is None else value
                raise ValueError(
                    f"{heater} target must be a number of degrees Celsius, got {shown!r} in {redact(command)!r}"
                )
            check_target(heater, value, limit)


def _m303_heater(line: GCodeLine) -> str:
    """M303 E<n>: -1 is the bed, -2 the chamber, any other the hotend of that number."""
    heater = line.value("E")
    number = 0 if heater is None else value_long(heater)
    return {-1: "bed", -2: "chamber"}.get(number, "hotend")


def _word_after(args: str, letter: str) -> str:
    """What follows `letter` in `args` up to a space (`Sabc` gives `abc`), for the message."""
    at = args.upper().find(letter)
    return args[at + 1 :].split(" ", 1)[0] if at >= 0 else ""


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
