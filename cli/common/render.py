"""Rendering: pure functions from the watch model to rich renderables and plain text.

Nothing here touches the printer or the terminal; tests render into `Console(record=True, width=...)`.
Everything that can carry the printer's or the user's text (heater names, the firmware's name, the port, a
reply) is a `rich.text.Text`, which reads no markup and no emoji codes: `Cap:REPEAT:0` stays as it is.
Every part is laid out for the width it is given, from 40 columns up: the table takes the widest of its layouts
that fits, and the lines made of several parts (footer, legend, key help) break between parts, never inside one.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

from rich.cells import cell_len
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from marlin_aio import TemperatureReading

from .chart import Curve, flow, heater_colour, legend, time_chart
from .model import HeaterStatus, LinkHealth, WatchControls, WatchModel, heater_name

__all__ = [
    "chart",
    "controls_view",
    "footer",
    "heater_table",
    "json_line",
    "plain_line",
    "table_lines",
    "watch_view",
]

_STATE_STYLE = {"heating": "bold red", "cooling": "cyan", "holding": "green", "off": "dim"}


def _fmt(value: float | None, spec: str, unit: str = "") -> str:
    return "-" if value is None else f"{value:{spec}}{unit}"


def _lines(text: Text, width: int) -> int:
    """Lines `text` takes at `width` columns (a line longer than the width wraps)."""
    return sum(max(1, -(-cell_len(line) // max(width, 1))) for line in text.plain.split("\n"))


def _eta(seconds: float | None, state: str) -> str:
    if state == "holding":
        return "at target"
    if seconds is None or math.isinf(seconds):
        return "-"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes}:{secs:02d}" if minutes else f"{secs} s"


@dataclass(frozen=True, slots=True)
class _Layout:
    """One way to lay the table out; `heater_table` takes the first that fits the width."""

    units_in_cells: bool  # "189.9 °C" in each cell, or "189.9" under a two-line "actual / °C" header
    gap: int  # spaces between columns
    columns: tuple[str, ...]


_ALL_COLUMNS = ("heater", "actual", "target", "power", "rate", "state", "eta")
# Widest first. Below ~75 columns the units move into the header (a cell never wraps "°C" onto a line of its own),
# then the gaps shrink, then power and the time to target go: a name is never cut to "hote…".
_LAYOUTS = (
    _Layout(True, 4, _ALL_COLUMNS),
    _Layout(True, 2, _ALL_COLUMNS),
    _Layout(False, 2, _ALL_COLUMNS),
    _Layout(False, 1, _ALL_COLUMNS),
    _Layout(False, 1, ("heater", "actual", "target", "rate", "state", "eta")),
    _Layout(False, 1, ("heater", "actual", "target", "rate", "state")),
    _Layout(False, 1, ("heater", "actual", "target", "state")),
)
_HEADERS = {
    "heater": ("heater", ""),
    "actual": ("actual", "°C"),
    "target": ("target", "°C"),
    "power": ("power", "%"),
    "rate": ("rate", "°C/s"),
    "state": ("state", ""),
    "eta": ("to target", ""),
}
_RIGHT = {"actual", "target", "power", "rate", "eta"}


def _cells(status: HeaterStatus, units: bool) -> dict[str, str]:
    """The text of each column for one heater, with or without units."""
    if units:
        return {
            "heater": status.name,
            "actual": _fmt(status.actual, ".1f", " °C"),
            "target": "off" if not status.target else _fmt(status.target, ".0f", " °C"),
            "power": _fmt(status.power_percent, ".0f", " %"),
            "rate": _fmt(status.rate_c_per_s, "+.2f", " °C/s"),
            "state": status.state,
            "eta": _eta(status.eta_s, status.state),
        }
    return {
        "heater": status.name,
        "actual": _fmt(status.actual, ".1f"),
        "target": "off" if not status.target else _fmt(status.target, ".0f"),
        "power": _fmt(status.power_percent, ".0f"),
        "rate": _fmt(status.rate_c_per_s, "+.2f"),
        "state": status.state,
        # "holding" already says it is there; the short form keeps the column narrow.
        "eta": "-" if status.state == "holding" else _eta(status.eta_s, status.state),
    }


def _header(column: str, units: bool) -> str:
    name, unit = _HEADERS[column]
    if units:
        return name
    if column == "eta":
        return "to\ntarget"  # the header is two lines anyway, and "to target" is wider than any time
    return f"{name}\n{unit}" if unit else name


def _layout_width(layout: _Layout, rows: list[dict[str, str]]) -> int:
    widths = []
    for column in layout.columns:
        cells = [cell_len(row[column]) for row in rows]
        cells += [cell_len(part) for part in _header(column, layout.units_in_cells).split("\n")]
        widths.append(max(cells))
    edge = 2 if layout.gap == 4 else 0  # the widest layout keeps its indent of two spaces
    return sum(widths) + layout.gap * (len(widths) - 1) + 2 * edge


def _choose_layout(statuses: list[HeaterStatus], width: int | None) -> _Layout:
    if width is None:
        return _LAYOUTS[0]
    for layout in _LAYOUTS:
        rows = [_cells(status, layout.units_in_cells) for status in statuses]
        if _layout_width(layout, rows) <= width:
            return layout
    return _LAYOUTS[-1]


def table_lines(statuses: list[HeaterStatus], width: int | None = None) -> int:
    """How many lines `heater_table(statuses, width)` takes (its header is two lines once units move into it)."""
    return (1 if _choose_layout(statuses, width).units_in_cells else 2) + len(statuses)


def heater_table(statuses: list[HeaterStatus], width: int | None = None) -> Table:
    """One row per heater: actual, target, power, rate, state, time to target.

    Given the `width` it must fit, the table takes the widest layout that fits: below about 75 columns the units
    move into a second header line, and at 40 columns power and the time to target are left out; the heater names
    and the numbers are never cut.
    """
    layout = _choose_layout(statuses, width)
    if layout.gap == 4:
        table = Table(expand=False, box=None, padding=(0, 2), header_style="bold")
    else:
        # Each cell pads only its right side; pad_edge drops it after the last column.
        table = Table(expand=False, box=None, padding=(0, layout.gap, 0, 0), pad_edge=False, header_style="bold")
    for column in layout.columns:
        table.add_column(
            _header(column, layout.units_in_cells),
            justify="right" if column in _RIGHT else "left",
            no_wrap=True,
        )
    for status in statuses:
        cells = _cells(status, layout.units_in_cells)
        row: list[Text] = []
        for column in layout.columns:
            if column == "heater":
                row.append(Text(cells[column], style=heater_colour(status.name)))
            elif column == "state":
                row.append(Text(cells[column], style=_STATE_STYLE.get(status.state, "")))
            else:
                row.append(Text(cells[column]))  # Text, not str: a str cell would be read as markup
        table.add_row(*row)
    return table


def chart(model: WatchModel, width: int = 72, height: int = 12, now: float | None = None) -> Text:
    """A chart of the last `model.window_s` seconds up to `now` (default: the latest reading): actual (•) and
    target (─) of each hotend, the bed and chamber."""
    end = now if now is not None else (model.latest_time or 0.0)
    labels = (f"-{model.window_s:.0f} s", "now")
    return time_chart(_curves(model), end - model.window_s, end, width=width, height=height, time_labels=labels)


def _curves(model: WatchModel) -> list[Curve]:
    return [Curve(heater_name(key), model.series[key]) for key in model.heater_keys() if key[0] in "TBC"]


def footer(port: str, firmware: str, link: LinkHealth, width: int | None = None, quit_hint: str = "q quits") -> Text:
    """The status line: port, firmware, polls per second, latency, and counts of timeouts and errors.

    Given a `width`, it breaks between its parts rather than inside one; `quit_hint` ends it (empty: left out,
    when the key help line below says how to quit).
    """
    latency = (
        "-"
        if link.latency_median_ms is None
        else f"{link.latency_median_ms:.1f} ms median, {link.latency_worst_ms or 0:.1f} worst"
    )
    style = "bold red" if link.timeouts or link.errors else "dim"
    parts = [
        Text(port, style="bold"),
        # "Marlin 2.1.2.4 (Jan  1 2024 12:00:00)": the build date only crowds the line.
        Text(firmware.split(" (")[0], style="dim"),
        Text(f"{link.polls_per_s:.0f} polls/s"),
        Text(f"latency {latency}"),
        Text(f"{link.timeouts} timeouts  {link.errors} errors", style=style),
    ]
    if quit_hint:
        parts.append(Text(quit_hint, style="dim"))
    return flow(parts, width)


def controls_view(controls: WatchControls, width: int | None = None) -> Text:
    """Under the chart: the last action's outcome (a reply, or an error in red), the input line, the key help."""
    text = Text()
    if controls.printer_prompt_text is not None:
        text.append(controls.printer_prompt_text + "\n", style="bold yellow")
    notice = controls.notice
    if notice is not None:
        style = "bold red" if notice.error else "bold"
        text.append(f"error: {notice.title}" if notice.error else notice.title, style=style)
        for line in notice.lines:
            text.append("\n  " + line)
        text.append("\n")
    if controls.prompt is not None:
        text.append(f"{controls.prompt}: ", style="bold cyan")
        text.append(controls.buffer)
        text.append("_", style="blink")  # a cursor: the terminal's own is hidden while the view is live
        text.append("\n")
    text.append_text(flow([_help_item(item) for item in controls.help_items()], width))
    return text


def _help_item(item: str) -> Text:
    """`h hotend` with its key in bold, so the keys stand out of the line."""
    key, _, rest = item.partition(" ")
    text = Text(key, style="bold")
    if rest:
        text.append(" " + rest, style="dim")
    return text


def watch_view(
    model: WatchModel,
    port: str,
    firmware: str,
    width: int = 80,
    chart_height: int = 12,
    *,
    height: int | None = None,
    controls: WatchControls | None = None,
) -> Group:
    """The whole live view: heater table, chart, footer, and (with `controls`) the reply area and the key help.

    Everything is laid out for `width` columns (40 and up). Given the terminal's `height`, the chart takes what
    the other parts leave (up to 30 rows) instead of `chart_height`, and none at all when fewer than 4 are left.
    """
    statuses = [model.status(key) for key in model.heater_keys()]
    quit_hint = "q quits" if controls is None else ""
    bottom = footer(port, firmware, model.link(), width, quit_hint=quit_hint)
    under = controls_view(controls, width) if controls is not None else None
    if height is not None:
        # table, a blank line, (the chart,) its time axis and legend, a blank line, the footer
        used = table_lines(statuses, width) + 2 + _lines(legend(_curves(model), width), width)
        used += 1 + _lines(bottom, width)
        if under is not None:
            used += _lines(under, width)
        # One line spare: the cursor's line after the view. The chart gives way first: on a short terminal the
        # footer, a reply and the key help (how to quit) stay on screen and the chart goes.
        room = height - used - 1
        chart_height = min(room, 30) if room >= 4 else 0
    parts: list[RenderableType] = [heater_table(statuses, width), Text("")]
    if chart_height:
        parts += [chart(model, width=width, height=chart_height), Text("")]
    parts.append(bottom)
    if under is not None:
        parts.append(under)
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
