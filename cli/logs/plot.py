"""`marlin-temp plot`: the tracking-curve figure from a log, as a PNG (matplotlib) or in the terminal.

Time is the rows' absolute time (`epoch_s`), never the elapsed column, which starts again with each session:
appended runs lie side by side on one clock, each session drawn as its own line, so no line runs back across
the chart and the span stated is the real one. `--session` draws one session alone. Files of the older format
(no sessions, `time_utc`) are read too: their runs are found where elapsed_s starts again.

The terminal chart is watch's (`common.chart.time_chart`); where watch shows the last minute up to "now", a log
is a stretch of the past, labelled with the clock times it covers and where each session began.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.text import Text

from ..common.chart import Curve, time_chart
from ..common.connect import UsageProblem
from .files import LogContents, LogSession, read_log

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "PlotData",
    "Segment",
    "describe_span",
    "plot_data",
    "plot_log",
    "png_figure",
    "session_table",
    "terminal_plot",
]

_FIGURE_COLOURS = {"hotend": "tab:red", "bed": "tab:blue", "chamber": "tab:green"}
_FIGURE_HOTENDS = ("tab:red", "tab:orange", "tab:brown", "tab:pink", "tab:olive", "tab:purple")


@dataclass(frozen=True)
class Segment:
    """One heater through one session: absolute times (epoch seconds) with actual and target in C."""

    session: str
    times_s: list[float]
    actual_c: list[float | None]
    target_c: list[float | None]

    def points(self) -> list[tuple[float, float | None, float | None]]:
        """(time, actual, target) of each reading, as a chart takes them."""
        return list(zip(self.times_s, self.actual_c, self.target_c, strict=True))


@dataclass(frozen=True)
class PlotData:
    """What a plot draws: the sessions chosen, and per heater (by name) one segment for each session."""

    sessions: list[LogSession]
    heaters: list[str]
    segments: dict[str, list[Segment]]

    @property
    def start_epoch_s(self) -> float:
        """The first row's time."""
        return self.sessions[0].start_epoch_s

    @property
    def end_epoch_s(self) -> float:
        """The last row's time."""
        return max(session.end_epoch_s for session in self.sessions)

    @property
    def rows(self) -> int:
        """Readings drawn."""
        return sum(len(session.rows) for session in self.sessions)

    def describe(self) -> str:
        """`120 readings in 2 sessions, 2026-11-23 17:30:01 to 17:40:01 (10 min 0 s)`."""
        sessions = "1 session" if len(self.sessions) == 1 else f"{len(self.sessions)} sessions"
        readings = "1 reading" if self.rows == 1 else f"{self.rows} readings"
        return f"{readings} in {sessions}, {describe_span(self.start_epoch_s, self.end_epoch_s)}"


def describe_span(start_epoch_s: float, end_epoch_s: float) -> str:
    """`2026-11-23 17:30:01 to 17:40:01 (10 min 0 s)`, in local time; the date again when the day changes."""
    start, end = datetime.fromtimestamp(start_epoch_s), datetime.fromtimestamp(end_epoch_s)
    end_text = f"{end:%H:%M:%S}" if end.date() == start.date() else f"{end:%Y-%m-%d %H:%M:%S}"
    return f"{start:%Y-%m-%d %H:%M:%S} to {end_text} ({_duration(end_epoch_s - start_epoch_s)})"


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes} min"


def _plotted_heaters(contents: LogContents) -> list[str]:
    """Hotends (each by number when the file has numbered ones, the active-tool copy then left out), bed, chamber."""
    names: list[str] = []
    for session in contents.sessions:
        for row in session.rows:
            names.extend(name for name in row.heaters if name not in names)
    numbered = sorted((n for n in names if n.startswith("hotend ")), key=lambda n: int(n.split()[1]))
    hotends = numbered or [n for n in names if n == "hotend"]
    return hotends + [n for n in ("bed", "chamber") if n in names]


def _choose(contents: LogContents, session: str | None, path: Path) -> list[LogSession]:
    if session is None:
        return contents.sessions
    for number, candidate in enumerate(contents.sessions, 1):
        if session in (candidate.id, str(number)):
            return [candidate]
    known = ", ".join(f"{number} ({s.id})" for number, s in enumerate(contents.sessions, 1))
    raise UsageProblem(f"{path} has no session {session!r}; its sessions: {known}")


def plot_data(contents: LogContents, path: Path, session: str | None = None) -> PlotData:
    """The segments to draw from a log read back; `session` (an id, or its number from 1) draws that one alone.

    Raises:
        UsageProblem: no such session.
        ValueError: the log has no readings of a hotend, bed or chamber.
    """
    if not contents.sessions:
        raise ValueError(f"{path} has no readings")
    chosen = _choose(contents, session, path)
    heaters = _plotted_heaters(LogContents(chosen))
    if not heaters:
        raise ValueError(f"{path} has no hotend, bed or chamber readings to plot")
    segments: dict[str, list[Segment]] = {}
    for name in heaters:
        for part in chosen:
            rows = [row for row in part.rows if name in row.heaters]
            if rows:
                segment = Segment(
                    part.id,
                    [row.epoch_s for row in rows],
                    [row.heaters[name].actual_c for row in rows],
                    [row.heaters[name].target_c for row in rows],
                )
                segments.setdefault(name, []).append(segment)
    return PlotData(chosen, heaters, segments)


def _clock(epoch_s: float, with_date: bool) -> str:
    return (
        f"{datetime.fromtimestamp(epoch_s):%m-%d %H:%M}" if with_date else f"{datetime.fromtimestamp(epoch_s):%H:%M:%S}"
    )


def terminal_plot(data: PlotData, width: int = 80, height: int = 16) -> Text:
    """The curves on a time axis labelled with clock times, a row marking where each session starts, a legend.

    Actual temperatures are dots, targets lines; each column shows the last reading that falls in it, so a gap
    between sessions stays empty.
    """
    curves = [
        Curve(name, [point for segment in data.segments.get(name, []) for point in segment.points()])
        for name in data.heaters
    ]
    start, end = data.start_epoch_s, data.end_epoch_s
    with_date = datetime.fromtimestamp(start).date() != datetime.fromtimestamp(end).date()
    # Each session's number where it starts, if there are several: the reader sees which stretch came from which run.
    sessions = data.sessions if len(data.sessions) > 1 else []
    marks = [(session.start_epoch_s, str(number)) for number, session in enumerate(sessions, 1)]
    return time_chart(
        curves,
        start,
        end,
        width=width,
        height=height,
        time_labels=(_clock(start, with_date), _clock(end, with_date)),
        marks=marks,
    )


def session_table(data: PlotData) -> Text:
    """One line per session: its number, id, the clock times it covers and its rows."""
    lines = Text("sessions (the numbers under the time axis mark where each starts):\n")
    for number, session in enumerate(data.sessions, 1):
        span = describe_span(session.start_epoch_s, session.end_epoch_s)
        lines.append(f"  {number:>2}  {session.id}  {span}  {len(session.rows)} readings\n")
    return lines


def plot_log(path: Path, output: Path | None, show: bool, console: Console, session: str | None = None) -> str:
    """Plot `path` (all sessions, or `session` alone); return a one-line message saying what was written.

    Raises:
        UsageProblem: matplotlib is missing and a PNG was asked for, or there is no such session.
        ValueError: the file is not a temperature log, or has nothing to plot.
        OSError: a file cannot be read or written.
    """
    data = plot_data(read_log(path), path, session)
    if show:
        # Lines of text are the terminal's to wrap; only the chart is sized to the width.
        console.print(f"{path.name}: {data.describe()}", soft_wrap=True)
        if len(data.sessions) > 1:
            console.print(session_table(data), end="", soft_wrap=True)
        console.print(terminal_plot(data, console.width))
    if output is None:
        return ""
    _write_png(data, path, output)
    return f"wrote {output} ({data.describe()})"


# matplotlib's dates are days since its epoch, read as the wall-clock time (local, as the axis is labelled).
_EPOCH = datetime(1970, 1, 1)


def _days(epoch_s: float) -> float:
    """A time as matplotlib plots dates: days since 1970-01-01 of the local wall clock."""
    return (datetime.fromtimestamp(epoch_s) - _EPOCH).total_seconds() / 86_400


def _write_png(data: PlotData, path: Path, output: Path) -> None:
    import matplotlib.pyplot as plt

    figure = png_figure(data, path)
    figure.savefig(output)
    plt.close(figure)


def png_figure(data: PlotData, path: Path) -> Figure:
    """The PNG's figure (matplotlib's Agg backend): actual (solid) and target (dashed) per heater and session.

    The legend stands outside the axes, to their right: inside (even at `loc="best"`) it covered the bed's curve,
    which runs low and flat across the whole width where the corners are. The caller closes the figure.

    Raises:
        UsageProblem: matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise UsageProblem(
            "matplotlib is not installed: pip install 'marlin-aio[plot]' (or use --show for a terminal plot)"
        ) from None
    figure, axes = plt.subplots(figsize=(11, 5.5), dpi=100)
    for index, name in enumerate(data.heaters):
        colour = _FIGURE_COLOURS.get(name, _FIGURE_HOTENDS[index % len(_FIGURE_HOTENDS)])
        for number, segment in enumerate(data.segments.get(name, [])):
            times = [_days(t) for t in segment.times_s]
            actual = [math.nan if a is None else a for a in segment.actual_c]
            target = [math.nan if t is None else t for t in segment.target_c]
            # One line per session, labelled once: no line joins the end of one run to the start of the next.
            axes.plot(times, actual, color=colour, label=f"{name} actual" if number == 0 else None)
            axes.plot(
                times, target, color=colour, linestyle="--", alpha=0.6, label=f"{name} target" if number == 0 else None
            )
    for session in data.sessions[1:]:
        axes.axvline(_days(session.start_epoch_s), color="grey", linestyle=":", linewidth=1)
    axes.xaxis_date()  # matplotlib's date ticks, labelled with the clock time
    axes.xaxis.set_major_formatter(lambda days, _position: f"{_EPOCH + timedelta(days=days):%H:%M:%S}")
    axes.set_xlabel(f"local time, {describe_span(data.start_epoch_s, data.end_epoch_s)}")
    axes.set_ylabel("temperature (°C)")
    sessions = "" if len(data.sessions) == 1 else f", {len(data.sessions)} sessions (dotted: where each starts)"
    axes.set_title(f"Temperature tracking: {path.name}{sessions}")
    axes.grid(True, alpha=0.3)
    # Outside the axes, right of them; tight_layout counts the legend in and narrows the axes to make room.
    axes.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    figure.autofmt_xdate()
    figure.tight_layout()
    return figure
