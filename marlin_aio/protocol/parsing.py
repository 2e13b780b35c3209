"""Parsing the bodies of a few replies: M119's endstops and M114's position.

(Lines from the printer are read into events by `wire.classify_line`.)
"""

from __future__ import annotations

import re

__all__ = ["parse_endstops", "parse_position"]

_ENDSTOP = re.compile(r"^\s*([A-Za-z0-9_ ]+?)\s*:\s*(open|TRIGGERED)\s*$")
_POSITION = re.compile(r"([XYZE]):\s*(-?\d+(?:\.\d+)?)")


def parse_endstops(lines: list[str] | tuple[str, ...]) -> dict[str, bool]:
    """Parse M119's reply lines into {name: triggered}, e.g. {"x_min": False, "z_probe": True}."""
    states: dict[str, bool] = {}
    for line in lines:
        match = _ENDSTOP.match(line)
        if match is not None:
            states[match[1]] = match[2] == "TRIGGERED"
    return states


def parse_position(lines: list[str] | tuple[str, ...]) -> dict[str, float] | None:
    """Parse an M114 line (`X:10.00 Y:20.00 Z:5.00 E:0.00 Count X:800 ...`) into {"X": 10.0, ...}.

    Only the part before `Count` is used: those are millimetres, what follows are stepper counts.
    """
    for line in lines:
        position_part = line.split("Count", 1)[0]
        found = {axis: float(value) for axis, value in _POSITION.findall(position_part)}
        if "X" in found and "Y" in found:
            return found
    return None
