"""What `marlin-temp print` shows: pure functions from a `PrintStatus` to a rich renderable or a plain line.

No I/O and no clock: the command builds a status from the print's progress, the file's plan and the latest reading
(`print_status`), and the tests build statuses by hand and render them with `Console(record=True)`.

The rate is the rate of the last seconds (`RateWindow`), not an average since the start: a print that spent five
minutes in M190 would otherwise show a third of its real speed for the rest of the hour. While the printer waits
for a heater, the view says so ("heating hotend 187/200 C") instead of a rate of 0 and an ETA of hours.

The view is laid out for the width it is drawn at: at 40 columns the percent and the ETA stay, and the rate, the
counts and the bar give way (`_progress_row`).

Text that is not ours (the file's name, what the printer shows or echoes, firmware messages) goes into `Text`
objects, never into markup: `[bold]` and `:smile:` in it stay as they are.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from rich.cells import cell_len
from rich.console import Console, ConsoleOptions, Group, RenderableType, RenderResult
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

import marlin_aio
import marlin_aio.protocol

from .plan import HeatWait

__all__ = [
    "KEYS_HELP",
    "KEYS_HELP_SHORTER",
    "PrintStatus",
    "RateWindow",
    "heaters_on_text",
    "heating_text",
    "plain_status",
    "print_view",
    "temperatures_text",
]

KEYS_HELP = "p pause  r resume  ! emergency stop (M112, no question asked)  Ctrl-C cancel"


class RateWindow:
    """Lines per second over the last `window_s` seconds, from (time, lines done) samples."""

    def __init__(self, window_s: float = 10.0) -> None:
        self.window_s = window_s
        self._samples: deque[tuple[float, int]] = deque()

    def add(self, now_s: float, lines_done: int) -> None:
        """Record how many lines were done at `now_s`; samples older than the window go."""
        self._samples.append((now_s, lines_done))
        while len(self._samples) > 2 and now_s - self._samples[1][0] >= self.window_s:
            self._samples.popleft()

    def clear(self) -> None:
        """Forget the samples: a wait for heat or a pause is not part of the printing rate."""
        self._samples.clear()

    def lines_per_s(self) -> float | None:
        """The rate over the window, or None until a second's worth of samples is in."""
        if len(self._samples) < 2:
            return None
        (start_s, start_lines), (end_s, end_lines) = self._samples[0], self._samples[-1]
        if end_s - start_s < 1.0:
            return None
        return (end_lines - start_lines) / (end_s - start_s)


@dataclass(frozen=True, slots=True)
class PrintStatus:
    """One frame of the print's view."""

    name: str
    lines_done: int
    lines_total: int
    state: str = "printing"  # "printing", "paused", "heating", "cancelling", "stopped", "done"
    lines_per_s: float | None = None
    heating: str | None = None  # "heating hotend 187/200 C" while the printer waits for a heater
    temperatures: str = ""
    question: str | None = None  # asked on a line of its own, never over the bar's label
    keys: str | None = None  # the keys help, when there is a terminal to press them in
    message: str | None = None  # the printer's text (M117/M118 of the file, firmware messages), shown verbatim
    note: str | None = None  # what the command did about the print ("M108 sent: the heat-up wait ended")
    paused_by: str | None = None  # the printer's own pause request ("printer asked: filament_runout 0")
    prompt: str | None = None  # the printer's prompt and the keys that answer it (`common.prompts.prompt_text`)

    @property
    def fraction(self) -> float:
        """Share of the commands done, 0.0-1.0."""
        return min(self.lines_done / self.lines_total, 1.0) if self.lines_total else 0.0

    @property
    def eta_s(self) -> float | None:
        """Seconds left at the recent rate; None while heating, paused or before the rate is known."""
        if self.state != "printing" or not self.lines_per_s:
            return None
        return max(self.lines_total - self.lines_done, 0) / self.lines_per_s


def _duration(seconds: float) -> str:
    whole = round(seconds)
    hours, rest = divmod(whole, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}"


def _activity(status: PrintStatus) -> str:
    """The part after the counts: the rate and ETA while printing, otherwise what the print is doing."""
    if status.heating is not None:
        return status.heating
    if status.state != "printing":
        return status.state
    if status.lines_per_s is None:
        return "-- lines/s  ETA --"
    eta = status.eta_s
    return f"{status.lines_per_s:.0f} lines/s  ETA {'--' if eta is None else _duration(eta)}"


def heating_text(wait: HeatWait, reading: marlin_aio.TemperatureReading | None) -> str:
    """ "heating hotend 187/200 C" for a heater wait, from the latest reading (the target from the command)."""
    heaters = reading.temperatures.heaters if reading is not None else {}
    heater = heaters.get(wait.heater) or (heaters.get("T") if wait.heater == "T0" else None)
    name = marlin_aio.protocol.heater_name("T" if wait.heater == "T0" and "T0" not in heaters else wait.heater)
    target = wait.target_celsius if wait.target_celsius is not None else (heater.target if heater else None)
    target_text = "?" if target is None else f"{target:.0f}"
    if heater is None:
        return f"waiting for {name} to reach {target_text} C"
    verb = "cooling" if target is not None and heater.actual > target + 1 else "heating"
    return f"{verb} {name} {heater.actual:.0f}/{target_text} C"


def _target_g(target: float | None) -> str:
    return "?" if target is None else f"{target:g}"


def heaters_on(reading: marlin_aio.TemperatureReading | None) -> list[str]:
    """The heaters of `reading` that have a target (or draw power with none reported), each as "hotend 198.2/200 C"
    (none for no reading): what every command that ends with heaters on names (`heaters_on_text` here,
    `heaters.command.heaters_left_on`)."""
    if reading is None:
        return []
    heaters = reading.temperatures.heaters
    return [
        f"{marlin_aio.protocol.heater_name(key)} {heater.actual:.1f}/{_target_g(heater.target)} C"
        for key, heater in heaters.items()
        # A target the report does not carry (Repetier style) is unknown, not off: a heater drawing power is on.
        if (heater.target or (heater.target is None and (heater.power or 0) > 0))
        and key[:1] in "TBC"
        and not (key == "T" and "T0" in heaters)  # T is one of T0, T1...
    ]


def heaters_on_text(reading: marlin_aio.TemperatureReading | None) -> str | None:
    """The heaters of `reading` that have a target, as "hotend 198.2/200 C, bed 60.0/60 C"; None if none has."""
    return ", ".join(heaters_on(reading)) or None


def temperatures_text(reading: marlin_aio.TemperatureReading | None) -> str:
    """Every heater of the reading as "hotend 187.2/200 °C   bed 60.0/60 °C" ("off" for a target of 0, "?" when the
    printer does not report it)."""
    if reading is None:
        return "temperatures: waiting for a reading"
    heaters = reading.temperatures.heaters
    parts = []
    for key, heater in heaters.items():
        if key[:1] not in ("T", "B", "C") or (key == "T" and "T0" in heaters):
            continue  # the active hotend appears again under its number
        target = "?" if heater.target is None else "off" if not heater.target else f"{heater.target:.0f}"
        parts.append(f"{marlin_aio.protocol.heater_name(key)} {heater.actual:.1f}/{target} °C")
    return "   ".join(parts)


#: Shorter forms of KEYS_HELP for narrow terminals, longest first; the view shows the first that fits.
KEYS_HELP_SHORTER = (
    "p pause  r resume  ! emergency stop  Ctrl-C cancel",
    "p pause  r resume  ! stop  ^C cancel",
)
_NAME_MIN = 8  # columns of a long file name kept before the bar, then the counts, give way
_BAR_MIN = 4  # rich's ProgressBar takes at least this many columns


class _Fitted:
    """A renderable laid out for the width it is drawn at: the live view's terminal may be any width, and resized
    between frames, so the layout is chosen when rich draws it, not when the frame is built."""

    __slots__ = ("_build",)

    def __init__(self, build: Callable[[int], RenderableType]) -> None:
        self._build = build

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield self._build(options.max_width)


def _activities(status: PrintStatus) -> list[str]:
    """What `_activity` says, then shorter forms of it: while printing the rate goes, the ETA stays."""
    full = _activity(status)
    if status.heating is None and status.state == "printing":
        return [full, full.split("  ")[-1]]  # "150 lines/s  ETA 0:09:36" -> "ETA 0:09:36"
    return [full]


def _progress_row(status: PrintStatus, width: int) -> RenderableType:
    """Name, bar, percent, counts and rate (or what it waits for), laid out for `width` columns.

    The percent and the ETA (or what the print waits for) are never cut. Narrower, the rate goes first, then the
    word "lines", then the counts, then the bar; the file's name is cut (with an ellipsis) to what is left.
    """
    percent = f"{status.fraction * 100:5.1f}%"
    counts = f"{status.lines_done}/{status.lines_total}"
    activities = _activities(status)
    short = activities[-1]
    candidates = [
        (f"{counts} lines", activities[0], True),
        (f"{counts} lines", short, True),
        (counts, short, True),
        ("", short, True),
        ("", short, False),
    ]
    name_min = min(cell_len(status.name), _NAME_MIN)
    for count_text, activity, bar in candidates:
        right_width = cell_len(" ".join(part for part in (percent, count_text, activity) if part))
        if name_min + 1 + (_BAR_MIN + 1 if bar else 0) + right_width <= width:
            break
    style = "bold yellow" if status.heating is not None or status.state in ("paused", "cancelling") else ""
    right = Text(percent.strip() if width < 60 else percent)
    if count_text:
        right.append(f" {count_text}")
    right.append(" ")
    right.append(activity, style=style)
    room = width - cell_len(right.plain) - 1 - (_BAR_MIN + 1 if bar else 0)
    row = Table.grid(padding=(0, 1), expand=True)
    cells: list[RenderableType] = []
    if room > 1:
        name = status.name if cell_len(status.name) <= room else status.name[: room - 1] + "…"
        row.add_column(no_wrap=True)
        cells.append(Text(name))  # Text: the file's name is not ours, and must not be read as markup
    if bar:
        row.add_column(ratio=1)
        cells.append(ProgressBar(total=max(status.lines_total, 1), completed=status.lines_done))
    row.add_column(no_wrap=True, justify="right")
    cells.append(right)
    row.add_row(*cells)
    return row


def _temperatures_line(temperatures: str, width: int) -> Text:
    """The temperatures under the bar, indented; narrower, in whole degrees and without "°C" (then wrapped)."""
    if not temperatures:
        return Text("  ", style="dim")
    forms = [f"  {temperatures}", temperatures.replace("   ", "  ")]
    whole = re.sub(r"(-?\d+\.\d)/", lambda m: f"{float(m.group(1)):.0f}/", forms[-1])
    forms += [whole, whole.replace(" °C", "")]
    return Text(next((form for form in forms if cell_len(form) <= width), forms[-1]))


def _keys_line(keys: str, width: int) -> str:
    if keys != KEYS_HELP or cell_len(keys) <= width:
        return keys
    return next((short for short in KEYS_HELP_SHORTER if cell_len(short) <= width), KEYS_HELP_SHORTER[-1])


def print_view(status: PrintStatus, width: int | None = None) -> RenderableType:
    """The live view: name, bar, percent, counts and rate (or what it waits for); temperatures; question or keys.

    Laid out for `width` columns, or (None) for the width it is drawn at. At 40 columns the percent and the ETA
    stay: the rate, the counts and the bar give way first, and the temperatures lose their decimals.
    """
    if width is None:
        return _Fitted(lambda drawn_width: print_view(status, drawn_width))
    parts: list[RenderableType] = [_progress_row(status, width), _temperatures_line(status.temperatures, width)]
    if status.message is not None:
        parts.append(Text.assemble(("  printer: ", "dim"), status.message))
    if status.note is not None:
        parts.append(Text(status.note, style="yellow"))
    if status.paused_by is not None and status.state == "paused":
        parts.append(Text(f"  paused: {status.paused_by}", style="bold yellow"))
    if status.prompt is not None:
        parts.append(Text(f"  {status.prompt}", style="bold yellow"))
    if status.question is not None:
        parts.append(Text(status.question, style="bold yellow"))
    elif status.keys is not None:
        parts.append(Text(_keys_line(status.keys, width), style="dim"))
    return Group(*parts)


def plain_status(status: PrintStatus) -> str:
    """One line for a log or a pipe: percent, counts, rate and ETA (or what it waits for), temperatures."""
    line = f"{status.fraction * 100:5.1f}% {status.lines_done}/{status.lines_total} lines {_activity(status)}"
    return f"{line}  {status.temperatures}" if status.temperatures else line
