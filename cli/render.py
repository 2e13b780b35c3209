"""Rendering: pure functions from the watch model to rich renderables and plain text.

Nothing here touches the printer or the terminal; tests render into `Console(record=True, width=...)`.
"""

from __future__ import annotations

import json
import math
import time

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from marlin_aio import TemperatureReading

from .model import HeaterStatus, LinkStats, WatchModel, heater_name

__all__ = ["chart", "footer", "heater_table", "json_line", "plain_line", "watch_view"]

_COLOURS = {"T": "red", "B": "blue", "C": "green"}
# One colour per hotend, so each curve in the chart can be told apart; none of them is the bed's or chamber's.
_HOTEND_COLOURS = ("red", "yellow", "bright_red", "orange3", "bright_yellow", "deep_pink3", "gold3", "dark_orange")
_STATE_STYLE = {"heating": "bold red", "cooling": "cyan", "holding": "green", "off": "dim"}


def _colour(key: str) -> str:
    if key[0] == "T" and key[1:].isdigit():
        return _HOTEND_COLOURS[int(key[1:]) % len(_HOTEND_COLOURS)]
    return _COLOURS.get(key, "magenta")


def _fmt(value: float | None, spec: str, unit: str = "") -> str:
    return "-" if value is None else f"{value:{spec}}{unit}"


def _eta(seconds: float | None, state: str) -> str:
    if state == "holding":
        return "at target"
    if seconds is None or math.isinf(seconds):
        return "-"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes}:{secs:02d}" if minutes else f"{secs} s"


def heater_table(statuses: list[HeaterStatus]) -> Table:
    """One row per heater: actual, target, power, rate, state, time to target."""
    table = Table(expand=False, box=None, padding=(0, 2), header_style="bold")
    for column, justify in [
        ("heater", "left"),
        ("actual", "right"),
        ("target", "right"),
        ("power", "right"),
        ("rate", "right"),
        ("state", "left"),
        ("to target", "right"),
    ]:
        table.add_column(column, justify=justify)  # type: ignore[arg-type]
    for status in statuses:
        table.add_row(
            Text(status.name, style=_colour(status.key)),
            _fmt(status.actual, ".1f", " °C"),
            "off" if not status.target else _fmt(status.target, ".0f", " °C"),
            _fmt(status.power_percent, ".0f", " %"),
            _fmt(status.rate_c_per_s, "+.2f", " °C/s"),
            Text(status.state, style=_STATE_STYLE.get(status.state, "")),
            _eta(status.eta_s, status.state),
        )
    return table


def chart(model: WatchModel, width: int = 72, height: int = 12, now: float | None = None) -> Text:
    """A chart of the last `model.window_s` seconds: actual (•) and target (─) of each hotend, the bed and chamber."""
    keys = [k for k in model.heater_keys() if k[0] in "TBC"]
    plot_width = max(width - 7, 10)
    end = now if now is not None else (model.latest_time or 0.0)
    start = end - model.window_s
    top = 50.0
    for key in keys:
        for _, actual, target in model.series[key]:
            top = max(top, actual, target or 0.0)
    # A round top (50s below 100 C, 100s above) so the quarter-height labels are round numbers too.
    step = 50.0 if top * 1.05 <= 100 else 100.0
    top = math.ceil(top * 1.05 / step) * step
    grid: list[list[tuple[str, str]]] = [[(" ", "")] * plot_width for _ in range(height)]

    def row_of(value: float) -> int:
        return height - 1 - min(max(round(value / top * (height - 1)), 0), height - 1)

    for key in keys:
        colour = _colour(key)
        # The last value in each column is what the column shows; targets first so actuals draw over them.
        targets: dict[int, float] = {}
        actuals: dict[int, float] = {}
        for time_s, actual, target in model.series[key]:
            if time_s < start:
                continue
            column = min(int((time_s - start) / model.window_s * (plot_width - 1)), plot_width - 1)
            actuals[column] = actual
            if target:
                targets[column] = target
        for column, target in targets.items():
            grid[row_of(target)][column] = ("─", f"dim {colour}")
        for column, actual in actuals.items():
            grid[row_of(actual)][column] = ("•", f"bold {colour}")

    # Label the rows that hold round values (quarters of a multiple of 50), not whatever each row happens to be.
    labels = {row_of(top * quarter / 4): top * quarter / 4 for quarter in range(5)}
    text = Text()
    for index, row in enumerate(grid):
        value = labels.get(index)
        label = f"{value:>4.0f} ┤" if value is not None else "     │"
        text.append(label, style="dim")
        for char, style in row:
            text.append(char, style=style)
        text.append("\n")
    axis = f"-{model.window_s:.0f} s".ljust(plot_width - 3) + "now"
    text.append("      " + axis, style="dim")
    legend = Text("      ")
    for key in keys:
        legend.append(f"• {heater_name(key)}  ", style=_colour(key))
    legend.append("─ target", style="dim")
    return Text("\n").join([text, legend])


def footer(port: str, firmware: str, link: LinkStats) -> Text:
    """The status line: port, firmware, polls per second, latency, and counts of timeouts and errors."""
    latency = (
        "-"
        if link.latency_median_ms is None
        else f"{link.latency_median_ms:.1f} ms median, {link.latency_worst_ms or 0:.1f} worst"
    )
    text = Text()
    text.append(f"{port}", style="bold")
    # "Marlin 2.1.2.4 (Jan  1 2024 12:00:00)": the build date only crowds the line.
    text.append(f"  {firmware.split(' (')[0]}  ", style="dim")
    text.append(f"{link.polls_per_s:.0f} polls/s  latency {latency}  ")
    style = "bold red" if link.timeouts or link.errors else "dim"
    text.append(f"{link.timeouts} timeouts  {link.errors} errors", style=style)
    text.append("  q quits", style="dim")
    return text


def watch_view(model: WatchModel, port: str, firmware: str, width: int = 80, chart_height: int = 12) -> Group:
    """The whole live view: heater table, chart, footer."""
    statuses = [model.status(key) for key in model.heater_keys()]
    parts: list[RenderableType] = [heater_table(statuses), Text(""), chart(model, width=width, height=chart_height)]
    parts += [Text(""), footer(port, firmware, model.link())]
    return Group(*parts)


def plain_line(model: WatchModel, wall_time_s: float | None = None) -> str:
    """One line per refresh for logs and pipes: `12:00:01 hotend 25.3/200 C 100% +3.30 C/s heating | bed ...`."""
    stamp = time.strftime("%H:%M:%S", time.localtime(wall_time_s if wall_time_s is not None else time.time()))
    parts = []
    for key in model.heater_keys():
        status = model.status(key)
        target = "off" if not status.target else f"{status.target:.0f}"
        power = "" if status.power_percent is None else f" {status.power_percent:.0f}%"
        rate = "" if status.rate_c_per_s is None else f" {status.rate_c_per_s:+.2f} C/s"
        parts.append(f"{status.name} {status.actual:.1f}/{target} C{power}{rate} {status.state}")
    link = model.link()
    return f"{stamp} " + " | ".join(parts) + f" | {link.polls_per_s:.0f} polls/s"


def json_line(reading: TemperatureReading) -> str:
    """One reading as a JSON object on one line (for `watch --json`)."""
    heaters = {
        key: {"actual": h.actual, "target": h.target, "power": h.power}
        for key, h in reading.temperatures.heaters.items()
    }
    return json.dumps({"time": reading.wall_time_s, "source": reading.source, "heaters": heaters})
