"""Motion as checked G-code: homing, moves, extrusion, motor power, and which commands may run long.

Pure functions over plain values, like `heaters`: each builds the commands of one `Printer` helper (`home`,
`move`, `extrude`, `disable_motors`) and checks every argument first, so a NaN, an unknown axis or a negative
feed rate raises `ValueError` before a byte is written. No I/O, no clock.

Modes. A move that trusts whatever mode the printer was left in moves somewhere else when someone typed `G91`
before it, so every move says its mode: an absolute move is `G90` then `G1`, a relative one `G91`, `G1`, `G90`,
and an extrusion `M83`, `G1 E`, `M82`. The printer is left in Marlin's power-on modes (absolute positions and
extrusion); note that Marlin's `G90` also makes extrusion absolute again.

Long commands. Marlin answers G28 only when homing is done. A board with HOST_KEEPALIVE_FEATURE says
`busy: processing` every couple of seconds meanwhile, which keeps any timeout alive; a board without it is silent
for as long as homing takes, so these commands get at least `LONG_COMMAND_TIMEOUT_S` (`command_timeout_s`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from marlin_aio.protocol.commands import command_code

__all__ = [
    "LONG_COMMANDS",
    "LONG_COMMAND_TIMEOUT_S",
    "MAX_DISTANCE_MM",
    "MAX_FEEDRATE_MM_MIN",
    "command_timeout_s",
    "disable_motors_command",
    "extrude_commands",
    "home_command",
    "move_commands",
]

#: Commands that run for a long time before their `ok` (homing, probing, levelling, gantry alignment).
LONG_COMMANDS = frozenset({"G28", "G29", "G33", "G34", "G35", "M48"})

#: The least time allowed for a long command's `ok`: a large printer homing slowly, with no keepalive, fits in it.
LONG_COMMAND_TIMEOUT_S = 180.0

#: No printer has an axis this long: a coordinate beyond it is a typo (or micrometres), not a place to go.
MAX_DISTANCE_MM = 10_000.0

#: Far above any printer's top speed (Marlin clamps to its own limits anyway); above it is a mistake.
MAX_FEEDRATE_MM_MIN = 100_000.0

_HOMING_AXES = "XYZ"
_MOTOR_AXES = "XYZE"


def command_timeout_s(command: str, default_s: float) -> float:
    """How long to wait for `command`'s `ok`: `default_s`, or at least `LONG_COMMAND_TIMEOUT_S` for a long one."""
    return max(default_s, LONG_COMMAND_TIMEOUT_S) if command_code(command) in LONG_COMMANDS else default_s


def home_command(axes: Iterable[str] = ()) -> str:
    """G28 for the axes given (`"x"`, `"Y"`, ...), or for all of them when none are.

    Raises:
        ValueError: an axis is not X, Y or Z.
    """
    letters = _check_axes(axes, _HOMING_AXES, "home")
    return " ".join(["G28", *letters])


def disable_motors_command(axes: Iterable[str] = ()) -> str:
    """M84 for the motors of the axes given (X, Y, Z, E), or for all of them when none are.

    Marlin waits for the moves already planned before it turns motors off, and homing is needed again afterwards.

    Raises:
        ValueError: an axis is not X, Y, Z or E.
    """
    letters = _check_axes(axes, _MOTOR_AXES, "disable")
    return " ".join(["M84", *letters])


def move_commands(
    *,
    x: float | None = None,
    y: float | None = None,
    z: float | None = None,
    feedrate_mm_min: float | None = None,
    relative: bool = False,
) -> list[str]:
    """The commands of one linear move: to (`x`, `y`, `z`) in millimetres, or by that much with `relative`.

    Axes left out do not move. `feedrate_mm_min` (G-code's `F`, millimetres a minute) also becomes the speed of
    later moves; without it the printer's current one is used.

    Raises:
        ValueError: no axis given; a coordinate is not a finite number or beyond `MAX_DISTANCE_MM`; the feed rate
            is not a positive finite number up to `MAX_FEEDRATE_MM_MIN`.
    """
    words = [
        f"{letter}{_format_mm(_check_distance(letter, value))}"
        for letter, value in (("X", x), ("Y", y), ("Z", z))
        if value is not None
    ]
    if not words:
        raise ValueError("nothing to move: give at least one of x, y, z")
    if feedrate_mm_min is not None:
        words.append(f"F{_format_mm(_check_feedrate(feedrate_mm_min))}")
    if not isinstance(relative, bool):
        raise ValueError(f"relative must be True or False, got {relative!r}")
    move = " ".join(["G1", *words])
    return ["G91", move, "G90"] if relative else ["G90", move]


def extrude_commands(length_mm: float, *, feedrate_mm_min: float) -> list[str]:
    """The commands that push `length_mm` of filament through the hotend (a negative length retracts).

    Marlin refuses to extrude below its EXTRUDE_MINTEMP (170 C by default) and says `cold extrusion prevented` in
    the reply, which is then the printer's answer, not an error.

    Raises:
        ValueError: the length is zero, not a finite number or beyond `MAX_DISTANCE_MM`; the feed rate is not a
            positive finite number up to `MAX_FEEDRATE_MM_MIN`.
    """
    length = _check_distance("E", length_mm)
    if length == 0:
        raise ValueError("nothing to extrude: the length is 0 mm")
    feedrate = _check_feedrate(feedrate_mm_min)
    return ["M83", f"G1 E{_format_mm(length)} F{_format_mm(feedrate)}", "M82"]


def _check_axes(axes: Iterable[str], allowed: str, verb: str) -> list[str]:
    if isinstance(axes, str):
        axes = [axes]  # one axis given as a bare string, not its letters one by one
    found = set()
    for axis in axes:
        letter = axis.strip().upper() if isinstance(axis, str) else None
        if letter is None or len(letter) != 1 or letter not in allowed:
            raise ValueError(f"cannot {verb} axis {axis!r}: use {', '.join(allowed)}")
        found.add(letter)
    return [letter for letter in allowed if letter in found]  # G-code's usual order, each once


def _check_number(what: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} must be a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an int too large for a float
        raise ValueError(f"{what} must be a finite number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return number


def _check_distance(letter: str, value: object) -> float:
    distance = _check_number(letter, value)
    if abs(distance) > MAX_DISTANCE_MM:
        raise ValueError(f"{letter} {distance:g} mm is beyond {MAX_DISTANCE_MM:g} mm")
    return distance


def _check_feedrate(value: object) -> float:
    feedrate = _check_number("feed rate", value)
    if feedrate <= 0:
        raise ValueError(f"feed rate must be positive, got {feedrate:g} mm/min")
    if feedrate > MAX_FEEDRATE_MM_MIN:
        raise ValueError(f"feed rate {feedrate:g} mm/min is above {MAX_FEEDRATE_MM_MIN:g} mm/min")
    return feedrate


def _format_mm(value: float) -> str:
    """`10`, `-2.5`, `0.125`: three decimals at most (micrometres), no exponent, no trailing zeros, no `-0`."""
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text
