"""Rendering: pure functions from the watch model to rich renderables and plain text.

Nothing here touches the printer or the terminal; tests render into `Console(record=True, width=...)`.
Everything that can carry the printer's or the user's text (heater names, the firmware's name, the port, a
reply) is a `rich.text.Text`, which reads no markup and no emoji codes: `Cap:REPEAT:0` stays as it is.
Every part is laid out for the width it is given, from 30 columns up: the table takes the widest of its layouts
that fits, and the lines made of several parts (footer, legend, key help) break between parts, never inside one.
Given a height too, the view gives way in an order: the chart first, then the footer and the key help shorten,
so the key help (how to quit) is always on screen. A served printer's print job is a line of its own above the
table (`job_line`), and a part of each plain line (`plain_job`).

Over 400 lines because the parts of the view are laid out together: the rows the chart gets, and which form of
the footer and the key help fits, depend on what the table, the footer, a reply and the key help take at the same
width, so they are measured where they are drawn.
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

from .chart import Curve, flow, heater_colour, legend, plot_columns, time_chart
from .model import HeaterStatus, JobStatus, LinkHealth, WatchControls, WatchModel, heater_name, target_text

__all__ = [
    "chart",
    "controls_view",
    "footer",
    "heater_table",
    "job_line",
    "json_line",
    "plain_job",
    "plain_line",
    "table_lines",
    "watch_view",
    "window_label",
]

_STATE_STYLE = {
    "heating": "bold red",
    "cooling": "cyan",
    "holding": "green",
    "off": "dim",
    "heating?": "red",
    "unknown": "dim",
}


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
            "target": target_text(status.target) + (" °C" if status.target else ""),
            "power": _fmt(status.power_percent, ".0f", " %"),
            "rate": _fmt(status.rate_c_per_s, "+.2f", " °C/s"),
            "state": status.state,
            "eta": _eta(status.eta_s, status.state),
        }
    return {
        "heater": status.name,
        "actual": _fmt(status.actual, ".1f"),
        "target": target_text(status.target),
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


def window_label(window_s: float) -> str:
    """A chart's window as its time axis says it: `60 s`, `10 min`, `1 h`, `6 h`."""
    if window_s >= 3600 and window_s % 3600 == 0:
        return f"{window_s / 3600:g} h"
    if window_s >= 120 and window_s % 60 == 0:
        return f"{window_s / 60:g} min"
    return f"{window_s:g} s"


def chart(model: WatchModel, width: int = 72, height: int = 12, now: float | None = None) -> Text:
    """A chart of the last `model.window_s` seconds up to `now` (default: the latest reading): actual (•) and
    target (─) of each hotend, the bed and chamber. Longer windows draw from the downsampled history, each column
    spanning the range of its readings."""
    end = now if now is not None else (model.latest_time or 0.0)
    start = end - model.window_s
    column_s = model.window_s / plot_columns(width)
    curves = [Curve(heater_name(key), model.points(key, start, column_s)) for key in _chart_keys(model)]
    labels = (f"-{window_label(model.window_s)}", "now")
    return time_chart(curves, start, end, width=width, height=height, time_labels=labels)


def _chart_keys(model: WatchModel) -> list[str]:
    return [key for key in model.heater_keys() if key[0] in "TBC"]


def _curves(model: WatchModel) -> list[Curve]:
    """The chart's curves by name only (for the legend's size)."""
    return [Curve(heater_name(key), ()) for key in _chart_keys(model)]


def footer(
    port: str,
    firmware: str,
    link: LinkHealth,
    width: int | None = None,
    quit_hint: str = "q quits",
    *,
    compact: bool = False,
) -> Text:
    """The status line: port, firmware, polls per second, the latency of the recent round trips (median, and the
    worst of the last 10 s), and counts of timeouts and errors.

    Given a `width`, it breaks between its parts rather than inside one; `quit_hint` ends it (empty: left out,
    when the key help line below says how to quit). `compact` (a short terminal): polls per second, the median,
    and the timeouts and errors only if there are any.
    """
    style = "bold red" if link.timeouts or link.errors else "dim"
    median = "-" if link.latency_median_ms is None else f"{link.latency_median_ms:.1f} ms"
    if compact:
        parts = [Text(f"{link.polls_per_s:.0f} polls/s"), Text(f"latency {median}")]
        if link.timeouts or link.errors:
            parts.append(Text(f"{link.timeouts} timeouts  {link.errors} errors", style=style))
    else:
        parts = [
            Text(port, style="bold"),
            # "Marlin 2.1.2.4 (Jan  1 2024 12:00:00)": the build date only crowds the line.
            Text(firmware.split(" (")[0], style="dim"),
            Text(f"{link.polls_per_s:.0f} polls/s"),
            Text(f"latency {median} median" if link.latency_median_ms is not None else "latency -"),
        ]
        if link.latency_worst_ms is not None:
            # Its own part, so a narrow footer breaks before it; "of 10 s": a slow G28 is not the worst for ever.
            parts.append(Text(f"worst {link.latency_worst_ms:.1f} ms of {link.latency_window_s:g} s"))
        parts.append(Text(f"{link.timeouts} timeouts  {link.errors} errors", style=style))
    if quit_hint:
        parts.append(Text(quit_hint, style="dim"))
    return flow(parts, width)


_JOB_STATE_STYLE = {
    "starting": "yellow",
    "printing": "bold green",
    "paused": "bold yellow",
    "cancelling": "bold yellow",
    "done": "green",
    "cancelled": "bold red",
    "failed": "bold red",
    "interrupted": "bold red",
}
_BAR_CELLS = 12  # the whole line fits 80 columns with a starter of "socket client 12"
_BAR_FROM_WIDTH = 60  # narrower, the bar would take a line of its own: the percent says it


def _resume_parts(job: JobStatus) -> list[Text]:
    """Where an ended print stopped: the line surely run, the ones that may have run, and where to resume."""
    if not job.resumable:
        return []
    ran = f"ran line {job.surely_run_line}"
    if job.may_have_run_line > job.surely_run_line:
        ran += f" (maybe up to {job.may_have_run_line})"
    parts = [Text(ran, style="dim")]
    if job.resume_line is not None:
        parts.append(Text(f"resume with --from-line {job.resume_line}", style="bold"))
    return parts


def job_line(job: JobStatus, width: int | None = None) -> Text:
    """A served printer's print job, over the table: `print  part.gcode  42.0 %  ━━━━──  printing  started by
    socket client 3`; once ended, how (cancelled by whom, the error) and where it stopped, with the resume line.

    It breaks between its parts at `width`, never inside one; the file's name is shown as given (no markup read).
    """
    parts = [Text("print", style="bold"), Text(job.file, style="bold cyan")]
    if job.active:
        parts.append(Text("-" if job.percent is None else f"{job.percent:.1f} %", style="bold"))
        if width is None or width >= _BAR_FROM_WIDTH:
            done = 0 if job.percent is None else round(_BAR_CELLS * min(max(job.percent, 0.0), 100.0) / 100)
            bar = Text("━" * done, style="green")
            bar.append("─" * (_BAR_CELLS - done), style="dim")
            parts.append(bar)
    state = job.state + (f" by {job.cancelled_by}" if job.cancelled_by else "")
    parts.append(Text(state, style=_JOB_STATE_STYLE.get(job.state, "")))
    if job.active:
        parts.append(Text(f"started by {job.started_by}", style="dim"))
    else:
        if job.percent is not None and job.state != "done":
            parts.append(Text(f"at {job.percent:.1f} %"))
        if job.error:
            parts.append(Text(job.error, style="red"))
        parts += _resume_parts(job)
    return flow(parts, width)


def plain_job(job: JobStatus) -> str:
    """The job's part of a plain line: `job part.gcode printing 42.0%`, once ended with its resume line."""
    percent = "" if job.percent is None else f" {job.percent:.1f}%"
    text = f"job {job.file} {job.state}{percent}"
    if job.resumable and job.resume_line is not None:
        text += f" resume --from-line {job.resume_line}"
    return text


def controls_view(controls: WatchControls, width: int | None = None) -> Text:
    """Under the chart: the last action's outcome (a reply, or an error in red), the input line, the key help."""
    text = _notice_and_prompt(controls)
    text.append_text(_key_helps(controls, width)[0])
    return text


def _notice_and_prompt(controls: WatchControls, notice_lines: int | None = None) -> Text:
    """The last action's outcome and the open input line, each line ended; of a reply's lines, the last
    `notice_lines` only (None: all of them)."""
    text = Text()
    if controls.printer_prompt_text is not None:
        text.append(controls.printer_prompt_text + "\n", style="bold yellow")
    if controls.question is not None:
        text.append(controls.question + "\n", style="bold red")
    notice = controls.notice
    if notice is not None:
        style = "bold red" if notice.error else "bold"
        text.append(f"error: {notice.title}" if notice.error else notice.title, style=style)
        lines = notice.lines if notice_lines is None else notice.lines[max(len(notice.lines) - notice_lines, 0) :]
        for line in lines:
            text.append("\n  " + line)
        text.append("\n")
    if controls.prompt is not None:
        text.append(f"{controls.prompt}: ", style="bold cyan")
        text.append(controls.buffer)
        text.append("_", style="blink")  # a cursor: the terminal's own is hidden while the view is live
        text.append("\n")
    return text


def _key_helps(controls: WatchControls, width: int | None) -> list[Text]:
    """The key help, longest first: every item, broken into lines of `width`; the keys alone on one line
    (`h b o +/- 1-4 f : w  q quit`); then only how to leave (the input line's Enter and Esc, or q)."""
    items = controls.help_items()
    helps = [flow([_help_item(item) for item in items], width)]
    if controls.question is not None:
        return [*helps, _help_item(items[0])]  # at the least, the one key that cancels
    if controls.prompt is not None:
        helps.append(flow([_help_item(item) for item in items[:2]], width))
        return helps
    if controls.keys_enabled:
        helps.append(_keys_only(items, width))
    # "Ctrl-C quits (keys need a terminal on stdin)": its first words are what must stay.
    helps.append(_help_item(items[-1].split(" (")[0]))
    return helps


def _keys_only(items: list[str], width: int | None = None) -> Text:
    """The keys of `items` without their words, runs of digits as one range (1-2), the last item (q quit) whole;
    at `width`, q quit goes to a line of its own rather than be split (a print job's p and c make it longer)."""
    keys = [item.partition(" ")[0] for item in items[:-1]]
    merged: list[str] = []
    run: list[str] = []
    for key in [*keys, ""]:
        if key.isdigit() and len(key) == 1 and (not run or int(key) == int(run[-1]) + 1):
            run.append(key)
            continue
        if run:
            merged.append(run[0] if len(run) == 1 else f"{run[0]}-{run[-1]}")
            run = []
        if key.isdigit() and len(key) == 1:
            run.append(key)
        elif key:
            merged.append(key)
    return flow([Text(" ".join(merged), style="bold"), _help_item(items[-1])], width)


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

    Everything is laid out for `width` columns (30 and up). Given the terminal's `height`, the chart takes what
    the other parts leave (up to 30 rows) instead of `chart_height`, and none at all when fewer than 4 are left;
    on a terminal too short even for the rest, the footer and the key help shorten (`_SHORTENINGS`), so the keys
    and how to quit stay on screen (30x12 and up).
    """
    statuses = [model.status(key) for key in model.heater_keys()]
    job = None if controls is None or controls.job is None else job_line(controls.job, width)
    quit_hint = "q quits" if controls is None else ""
    link = model.link()
    footers: list[Text | None] = [
        footer(port, firmware, link, width, quit_hint=quit_hint),
        footer(port, firmware, link, width, quit_hint=quit_hint, compact=True),
        None,
    ]
    helps = _key_helps(controls, width) if controls is not None else []
    bottom, under = footers[0], controls_view(controls, width) if controls is not None else None
    if height is not None:
        # One line spare: the cursor's line after the view. Above the chart: the table and a blank line.
        room = height - 1 - table_lines(statuses, width) - 1 - (_lines(job, width) if job is not None else 0)
        for footer_index, help_index, notice_lines in _SHORTENINGS:
            bottom = footers[footer_index]
            under = None
            if controls is not None:
                under = _notice_and_prompt(controls, notice_lines)
                under.append_text(helps[min(help_index, len(helps) - 1)])
            left = room - (_lines(bottom, width) if bottom is not None else 0)
            left -= _lines(under, width) if under is not None else 0
            if left >= 0:
                break
        # The chart's own time axis and legend, and a blank line under it.
        left -= 2 + _lines(legend(_curves(model), width), width)
        chart_height = min(left, 30) if left >= 4 else 0
    parts: list[RenderableType] = [] if job is None else [job]
    parts += [heater_table(statuses, width), Text("")]
    if chart_height:
        parts += [chart(model, width=width, height=chart_height), Text("")]
    if bottom is not None:
        parts.append(bottom)
    if under is not None:
        parts.append(under)
    return Group(*parts)


# How the parts under the table give way on a short terminal, after the chart, one step at a time: (footer: full,
# compact, none; key help: full, keys only, how to quit; a reply's lines: all, the last 2, none). The key help
# goes last: without it the user is left not knowing how to get out.
_SHORTENINGS: tuple[tuple[int, int, int | None], ...] = (
    (0, 0, None),
    (1, 0, None),
    (1, 1, None),
    (2, 1, None),
    (2, 1, 2),
    (2, 2, 2),
    (2, 2, 0),
)


def plain_line(model: WatchModel, wall_time_s: float | None = None, job: JobStatus | None = None) -> str:
    """One line per refresh for logs and pipes: `12:00:01 hotend 25.3/200 C 100% +3.30 C/s heating | bed ...`,
    and a served printer's job last (`plain_job`)."""
    stamp = time.strftime("%H:%M:%S", time.localtime(wall_time_s if wall_time_s is not None else time.time()))
    parts = []
    for key in model.heater_keys():
        status = model.status(key)
        target = target_text(status.target)
        power = "" if status.power_percent is None else f" {status.power_percent:.0f}%"
        rate = "" if status.rate_c_per_s is None else f" {status.rate_c_per_s:+.2f} C/s"
        parts.append(f"{status.name} {status.actual:.1f}/{target} C{power}{rate} {status.state}")
    link = model.link()
    line = f"{stamp} " + " | ".join(parts) + f" | {link.polls_per_s:.0f} polls/s"
    return line if job is None else f"{line} | {plain_job(job)}"


def json_line(reading: TemperatureReading) -> str:
    """One reading as a JSON object on one line (for `watch --json`)."""
    heaters = {
        key: {"actual": h.actual, "target": h.target, "power": h.power}
        for key, h in reading.temperatures.heaters.items()
    }
    return json.dumps({"time": reading.wall_time_s, "source": reading.source, "heaters": heaters})
