"""The terminal chart of heater temperatures over time, drawn by both `watch` (the last minute, up to "now") and
`plot --show` (a log's stretch of the past): one grid of characters, actual temperatures as dots and targets as
lines, a temperature axis of round numbers, a time axis labelled by the caller, and a legend.

A pure function from curves to a `rich.text.Text`, like the rest of the rendering. `flow`, the line breaking the
legend uses, lives here too: the watch view breaks its footer and key help the same way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from rich.cells import cell_len
from rich.text import Text

__all__ = ["Curve", "flow", "heater_colour", "legend", "plot_columns", "time_chart"]

_COLOURS = {"hotend": "red", "bed": "blue", "chamber": "green"}
# One colour per numbered hotend, so each curve can be told apart; none of them is the bed's or chamber's.
_HOTEND_COLOURS = ("red", "yellow", "bright_red", "orange3", "bright_yellow", "deep_pink3", "gold3", "dark_orange")
_AXIS_WIDTH = 6  # " 200 ┤" or "     │" before each row
_INDENT = " " * _AXIS_WIDTH


def plot_columns(width: int) -> int:
    """How many columns of time `time_chart` draws at `width` (the rest is the temperature axis)."""
    return max(width - _AXIS_WIDTH - 1, 10)  # a column spare: a line that fills the terminal may wrap


def heater_colour(name: str) -> str:
    """The colour of a heater by its name (`hotend`, `hotend 1`, `bed`, ...), the same in every view."""
    kind, _, number = name.partition(" ")
    if kind == "hotend" and number.isdigit():
        return _HOTEND_COLOURS[int(number) % len(_HOTEND_COLOURS)]
    return _COLOURS.get(name, "magenta")


@dataclass(frozen=True, slots=True)
class Curve:
    """One heater's readings: (time in s, actual C, target C) in time order; None where it was not read."""

    name: str
    points: Sequence[tuple[float, float | None, float | None]]

    @property
    def colour(self) -> str:
        """The heater's colour (`heater_colour`)."""
        return heater_colour(self.name)


def time_chart(
    curves: Sequence[Curve],
    start_s: float,
    end_s: float,
    *,
    width: int,
    height: int,
    time_labels: tuple[str, str],
    marks: Sequence[tuple[float, str]] = (),
) -> Text:
    """The readings from `start_s` to `end_s` on a grid `width` columns wide with `height` rows, then the time
    axis (`time_labels` at its left and right end), a row of `marks` (each label under its time, left out where it
    would touch another) if any, and the legend.

    Each column spans the lowest to the highest actual temperature that falls in it (so a column of hours shows
    how far it swung, not whichever reading came last), and a stretch without readings stays empty; each column's
    target is its last, drawn first so actual temperatures draw over it, and a target of 0 (off) is not drawn.
    """
    plot_width = plot_columns(width)
    span = max(end_s - start_s, 1e-9)

    def column_of(time_s: float) -> int:
        return min(max(int((time_s - start_s) / span * (plot_width - 1)), 0), plot_width - 1)

    top = 50.0
    for curve in curves:
        for _, actual, target in curve.points:
            top = max(top, actual or 0.0, target or 0.0)
    # A round top (50s below 100 C, 100s above) so the quarter-height labels are round numbers too.
    step = 50.0 if top * 1.05 <= 100 else 100.0
    top = math.ceil(top * 1.05 / step) * step

    def row_of(celsius: float) -> int:
        return height - 1 - min(max(round(celsius / top * (height - 1)), 0), height - 1)

    grid: list[list[tuple[str, str]]] = [[(" ", "")] * plot_width for _ in range(height)]
    for curve in curves:
        targets: dict[int, float] = {}
        lows: dict[int, float] = {}
        highs: dict[int, float] = {}
        for time_s, actual, target in curve.points:
            if time_s < start_s:
                continue
            column = column_of(time_s)
            if actual is not None:
                if column not in lows:
                    lows[column] = highs[column] = actual
                elif actual < lows[column]:
                    lows[column] = actual
                elif actual > highs[column]:
                    highs[column] = actual
            if target:
                targets[column] = target
        for column, target in targets.items():
            grid[row_of(target)][column] = ("─", f"dim {curve.colour}")
        for column, low in lows.items():
            # Rows grow downwards: the highest temperature is the top row.
            for grid_row in range(row_of(highs[column]), row_of(low) + 1):
                grid[grid_row][column] = ("•", f"bold {curve.colour}")

    # Label the rows that hold round values (quarters of a multiple of 50), not whatever each row happens to be.
    labels = {row_of(top * quarter / 4): top * quarter / 4 for quarter in range(5)}
    text = Text()
    for index, row in enumerate(grid):
        value = labels.get(index)
        text.append(f"{value:>4.0f} ┤" if value is not None else "     │", style="dim")
        for char, style in row:
            text.append(char, style=style)
        text.append("\n")
    left, right = time_labels
    text.append(_INDENT + left + right.rjust(max(plot_width - len(left), len(right) + 1)) + "\n", style="dim")
    if marks:
        row_of_marks = [" "] * plot_width
        for time_s, label in marks:
            column = min(column_of(time_s), plot_width - len(label))
            if all(mark == " " for mark in row_of_marks[max(column - 1, 0) : column + len(label)]):
                row_of_marks[column : column + len(label)] = list(label)
        text.append(_INDENT + "".join(row_of_marks).rstrip() + "\n", style="dim")
    text.append_text(legend(curves, width))
    return text


def legend(curves: Sequence[Curve], width: int) -> Text:
    """`• hotend  • bed  ─ target` in the curves' colours, broken into lines of `width` between its items."""
    items = [Text(f"• {curve.name}", style=curve.colour) for curve in curves]
    return flow([*items, Text("─ target", style="dim")], width, indent=_INDENT)


def flow(items: list[Text], width: int | None, indent: str = "", separator: str = "  ") -> Text:
    """`items` joined by `separator`, starting a new line (with `indent`) where the next would pass `width`.

    Items break only between each other, so "latency 0.3 ms median" or "• hotend 1" is never split across lines.
    """
    text = Text(indent)
    used = cell_len(indent)
    for index, item in enumerate(items):
        length = item.cell_len
        if index and width is not None and used + len(separator) + length > width:
            text.append("\n" + indent)
            used = cell_len(indent)
        elif index:
            text.append(separator)
            used += len(separator)
        text.append_text(item)
        used += length
    return text
