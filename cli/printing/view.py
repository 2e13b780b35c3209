"""What `marlin-temp print` shows: pure functions from a `PrintStatus` to a rich renderable or a plain line.

No I/O and no clock: the command builds a status from the print's progress, the file's plan and the latest reading
(`print_status`), and the tests build statuses by hand and render them with `Console(record=True)`.

The rate is the rate of the last seconds (`RateWindow`), not an average since the start: a print that spent five
minutes in M190 would otherwise show a third of its real speed for the rest of the hour. While the printer waits
for a heater, the view says so ("heating hotend 187/200 C") instead of a rate of 0 and an ETA of hours.

Text that is not ours (the file's name, what the printer shows or echoes, firmware messages) goes into `Text`
objects, never into markup: `[bold]` and `:smile:` in it stay as they are.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from rich.console import Group, RenderableType
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

import marlin_aio
import marlin_aio.protocol

from .plan import HeatWait

__all__ = [
    "KEYS_HELP",
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


def heaters_on(reading: marlin_aio.TemperatureReading | None) -> list[str]:
    """The heaters of `reading` that have a target, each as "hotend 198.2/200 C" (none for no reading): what every
    command that ends with heaters on names (`heaters_on_text` here, `heaters.command.heaters_left_on`)."""
    if reading is None:
        return []
    heaters = reading.temperatures.heaters
    return [
        f"{marlin_aio.protocol.heater_name(key)} {heater.actual:.1f}/{heater.target:g} C"
        for key, heater in heaters.items()
        if heater.target and key[:1] in "TBC" and not (key == "T" and "T0" in heaters)  # T is one of T0, T1...
    ]


def heaters_on_text(reading: marlin_aio.TemperatureReading | None) -> str | None:
    """The heaters of `reading` that have a target, as "hotend 198.2/200 C, bed 60.0/60 C"; None if none has."""
    return ", ".join(heaters_on(reading)) or None


def temperatures_text(reading: marlin_aio.TemperatureReading | None) -> str:
    """Every heater of the reading as "hotend 187.2/200 °C   bed 60.0/60 °C" ("off" for no target)."""
    if reading is None:
        return "temperatures: waiting for a reading"
    heaters = reading.temperatures.heaters
    parts = []
    for key, heater in heaters.items():
        if key[:1] not in ("T", "B", "C") or (key == "T" and "T0" in heaters):
            continue  # the active hotend appears again under its number
        target = "off" if not heater.target else f"{heater.target:.0f}"
        parts.append(f"{marlin_aio.protocol.heater_name(key)} {heater.actual:.1f}/{target} °C")
    return "   ".join(parts)


def print_view(status: PrintStatus) -> RenderableType:
    """The live view: name, bar, percent, counts and rate (or what it waits for); temperatures; question or keys."""
    row = Table.grid(padding=(0, 1), expand=True)
    row.add_column(no_wrap=True)
    row.add_column(ratio=1)
    row.add_column(no_wrap=True, justify="right")
    row.add_column(no_wrap=True)
    row.add_column(no_wrap=True)
    style = "bold yellow" if status.heating is not None or status.state in ("paused", "cancelling") else ""
    row.add_row(
        Text(status.name),
        ProgressBar(total=max(status.lines_total, 1), completed=status.lines_done),
        f"{status.fraction * 100:5.1f}%",
        f"{status.lines_done}/{status.lines_total} lines",
        Text(_activity(status), style=style),
    )
    parts: list[RenderableType] = [
        row,
        Text(f"  {status.temperatures}", style="dim" if not status.temperatures else ""),
    ]
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
        parts.append(Text(status.keys, style="dim"))
    return Group(*parts)


def plain_status(status: PrintStatus) -> str:
    """One line for a log or a pipe: percent, counts, rate and ETA (or what it waits for), temperatures."""
    line = f"{status.fraction * 100:5.1f}% {status.lines_done}/{status.lines_total} lines {_activity(status)}"
    return f"{line}  {status.temperatures}" if status.temperatures else line
