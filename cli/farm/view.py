"""The farm view of `marlin-temp watch` with several printers: one compact row per printer, and what each key means.

Pure, like `render.py`: a `FarmRow` is built from what the farm knows of a printer (`FarmPrinter`: link, last
error, when it reconnects, print) and that printer's `WatchModel` (readings, heater states); rows are rendered for
the width given and the tests render them into `Console(record=True, width=...)`. The detail view of one printer
is the single-printer view (`common.render.watch_view`) of its model, so both views read the same numbers.

Every cell is a `rich.text.Text`, never a str rich would read as markup: a printer named `[b]p1` or an error quoting
`Cap:REPEAT:0` is shown as it is.

A row keeps its number, heaters and state whole; the link column (the last one, where an error can be long) is
shortened, with an ellipsis, to what the width leaves. At 40 columns and less a long name is cut, then the link and
the print progress fold into the state, and the key line takes a shorter form that still says how to quit. A
printer whose link is down shows no temperatures: its last ones would read as if they were current.

Over 400 lines because the rows, the ways the table fits a width, the key lines and the keys' meaning are read
together: what the narrow table folds into the state and what the key line keeps both answer "what is left at 40
columns", and the keys the help names are the ones `FarmKeys` handles; the tests render and press them side by side.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass

from rich.cells import cell_len
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from marlin_aio.farm.supervisor import FarmPrinter

from ..common.model import WatchModel, heater_name, target_text
from ..common.render import watch_view

__all__ = [
    "DETAIL_KEYS_HELP",
    "FARM_KEYS_HELP",
    "FarmKeys",
    "FarmRow",
    "HeaterCell",
    "detail_view",
    "farm_row",
    "farm_table",
    "farm_view",
    "json_lines",
    "link_text",
    "plain_lines",
]

_STATE_STYLE = {
    "heating": "bold red",
    "heating?": "red",
    "cooling": "cyan",
    "holding": "green",
    "idle": "dim",
    "printing": "bold",
    "paused": "yellow",
    "-": "dim",
}
_ERROR_CHARS = 60  # of the last error in a plain line; the live view cuts it to the width left


@dataclass(frozen=True, slots=True)
class HeaterCell:
    """One heater of a row: its key (T, B, T0...), the name shown, actual and target (0: off; None: unknown)."""

    key: str
    name: str
    actual: float
    target: float | None

    def text(self, decimals: int = 1) -> str:
        """`204.6/210`, `25.0/off` with a target of 0, `25.0/?` when the printer does not report its target
        (`205/210` and `25/off` with no decimals)."""
        return f"{self.actual:.{decimals}f}/{target_text(self.target)}"


@dataclass(frozen=True, slots=True)
class FarmRow:
    """What the farm view shows of one printer."""

    number: int
    """1-based: the digit that opens its detail view (1 to 9)."""
    name: str
    link_up: bool
    link: str
    """`up`, `connecting`, or `down, reconnecting in 4 s: the last error`."""
    heaters: tuple[HeaterCell, ...]
    """Empty while the link is down or before the first reading."""
    state: str
    """`heating`, `cooling`, `holding`, `idle`, `printing`, `paused`, or `-` (link down, no reading yet)."""
    progress: str | None
    """`42%`, `done`, `cancelled`, `failed`; None when no print was started."""
    asks: str | None = None
    """The message of the prompt the printer shows for a person (`Load Filament`), or None: the state cell says
    `asks: Load Filament` instead of its state, as that is what needs the user now."""


def _short_error(message: str) -> str:
    """The first clause of an error: the part before its explanation in parentheses or after a semicolon."""
    for mark in (" (", "; "):
        head, found, _ = message.partition(mark)
        if found and head:
            message = head
    return message.strip()


def link_text(farm_printer: FarmPrinter, now_s: float | None = None) -> str:
    """`up`; `connecting` before the first connection; else `down`, when it tries again, and the last error.

    `now_s` is on `time.monotonic()`'s clock, as `FarmPrinter.reconnect_at_s`.
    """
    if farm_printer.link_up:
        return "up"
    error = _short_error(farm_printer.last_error) if farm_printer.last_error else None
    if farm_printer.reconnect_at_s is not None:
        now = time.monotonic() if now_s is None else now_s
        # Rounded up: "in 0 s" would read as "now" for the second before it happens.
        seconds = max(int(-(-(farm_printer.reconnect_at_s - now) // 1)), 1)
        text = f"down, reconnecting in {seconds} s"
    elif error is not None or farm_printer.connections:
        text = "down, reconnecting now"
    else:
        return "connecting"
    return f"{text}: {error}" if error else text


def _progress(farm_printer: FarmPrinter) -> tuple[str | None, str | None]:
    """(the print column, the state a running or paused print gives the printer)."""
    status = farm_printer.print_status()
    if status is None:
        return None, None
    state = str(status["state"])
    percent = status["percent"]
    shown = f"{percent:.0f}%" if isinstance(percent, float | int) else "?"
    if state == "running":
        return shown, "printing"
    if state == "paused":
        return shown, "paused"
    return state, None  # done, cancelled, failed: the heaters say what the printer does now


def farm_row(number: int, farm_printer: FarmPrinter, model: WatchModel, now_s: float | None = None) -> FarmRow:
    """The row of `farm_printer`, the `number`th of the farm; `model` holds its readings."""
    progress, print_state = _progress(farm_printer)
    heaters: tuple[HeaterCell, ...] = ()
    state = "-"
    if farm_printer.link_up and model.series:
        statuses = [model.status(key) for key in model.heater_keys()]
        heaters = tuple(HeaterCell(s.key, s.name, s.actual, s.target) for s in statuses)
        states = {s.state for s in statuses}
        # The state that asks most of the user's attention names the printer.
        # "heating?" (no target reported, power on) is not idle: a printer of Repetier-style reports heats unseen.
        attention = ("heating", "heating?", "cooling", "holding")
        state = next((name for name in attention if name in states), "idle")
        if print_state is not None:
            state = print_state
    return FarmRow(
        number=number,
        name=farm_printer.name,
        link_up=farm_printer.link_up,
        link=link_text(farm_printer, now_s),
        heaters=heaters,
        state=state,
        progress=progress,
        asks=None if farm_printer.prompt is None else farm_printer.prompt.message,
    )


def _heater_order(key: str) -> tuple[int, int]:
    if key[0] == "T":
        return (0, int(key[1:]) if key[1:].isdigit() else -1)
    return ({"B": 1, "C": 2}.get(key, 3), 0)


def _heater_keys(rows: Sequence[FarmRow]) -> list[str]:
    """Every heater any printer reports, hotends first, then bed, chamber and the rest."""
    seen: dict[str, None] = {}
    for row in rows:
        for cell in row.heaters:
            seen.setdefault(cell.key, None)
    return sorted(seen, key=_heater_order)


def _compact_link(link: str) -> str:
    """The link for a narrow table: when it reconnects kept, in fewer words, so the error keeps what room is left."""
    link = re.sub(r"^down, reconnecting in (\d+) s", r"down, retry \1 s", link)
    return link.replace("down, reconnecting now", "down, retrying", 1)


def _fit_link(link: str, width: int) -> str:
    """`link` in `width` columns: the error after `: ` is cut first, then dropped; what it says of the link last."""
    if cell_len(link) <= width:
        return link
    head, sep, _ = link.partition(": ")
    if sep and cell_len(head) + 3 < width:
        return _cut(link, width)  # "down, retry 8 s: connection l…"
    return _cut(head, width)


def _cut(text: str, width: int) -> str:
    if cell_len(text) <= width:
        return text
    return text[: max(width - 1, 0)] + "…"


@dataclass(frozen=True, slots=True)
class _TableFit:
    """One way to fit the farm table: `farm_table` takes the first that fits the width."""

    link: bool  # the link column; without it a row whose link is down says so in its state
    print: bool  # the print column; without it a printing row's state is its percent
    name_min: int  # the fewest columns a long printer name is cut to (with an ellipsis)


# Widest first: the whole name, then a cut name, then the link folded into the state, then the print progress.
# The number (the key that opens a printer), the heaters and the state are never cut.
_FITS = (_TableFit(True, True, 1_000), _TableFit(True, True, 6), _TableFit(False, True, 6), _TableFit(False, False, 4))


def _state_cell(row: FarmRow, fit: _TableFit) -> str:
    state = row.state
    if not fit.link and not row.link_up:
        state = "connecting" if row.link == "connecting" else "down"
    elif row.asks is not None:
        return f"asks: {row.asks}"
    if not fit.print and row.progress is not None and row.state in ("printing", "paused"):
        state = row.progress if row.state == "printing" else f"paused {row.progress}"
    return state


def farm_table(rows: Sequence[FarmRow], width: int | None = None, selected: int | None = None) -> Table:
    """One row per printer: number, name, each heater's actual/target, state, print progress (when any), link.

    Given the `width` to fit, the link column gets what the others leave (at least 4 columns) and a long error
    in it ends in an ellipsis. Below 80 columns the gaps are one space, temperatures whole degrees without "°C" in
    the headers, and the link says "retry 8 s" for "reconnecting in 8 s". Narrower still (40 columns, 30), a long
    printer name is cut, then the link column goes (a row whose link is down says "down" as its state), then the
    print column (a printing row's state is its percent); the number, the heaters and the state are never cut.
    `selected` (an index into `rows`) is shown in reverse video.
    """
    narrow = width is not None and width < 80
    keys = _heater_keys(rows)
    names = {key: heater_name(key) for key in keys}
    any_print = any(row.progress is not None for row in rows)
    gap = 1 if narrow else 2
    fit, name_width, link_width = _FITS[0], None, None
    for fit in _FITS:
        fit_print = any_print and fit.print
        headers = ["#", "printer", *(names[key] if narrow else f"{names[key]} °C" for key in keys), "state"]
        headers += ["print"] if fit_print else []
        cells = [
            [
                str(row.number),
                row.name,
                *(_heater_text(row, key, narrow) for key in keys),
                _state_cell(row, fit),
                *([row.progress or "-"] if fit_print else []),
            ]
            for row in rows
        ]
        widths = [max([cell_len(h)] + [cell_len(line[i]) for line in cells]) for i, h in enumerate(headers)]
        if width is None:
            break
        others = sum(widths) - widths[1] + gap * (len(headers) - (0 if fit.link else 1)) + (4 if fit.link else 0)
        name_width = min(widths[1], max(width - others, min(fit.name_min, widths[1])))
        # The link takes what is left (its 4 columns are counted in `others`); a long error in it is cut.
        link_width = width - others - name_width + 4 if fit.link else None
        if others + name_width <= width:
            break
    fit_print = any_print and fit.print
    table = Table(box=None, padding=(0, gap, 0, 0), pad_edge=False, header_style="bold", expand=False)
    for header in headers:
        right = header not in ("printer", "state")
        table.add_column(Text(header), justify="right" if right else "left", no_wrap=True)
    if fit.link:
        table.add_column("link", no_wrap=True)
    state_index = len(headers) - (2 if fit_print else 1)
    for index, (row, line) in enumerate(zip(rows, cells, strict=True)):
        rendered: list[Text] = []  # Text, not str: a printer's name or a heater's must not be read as markup
        for position, cell in enumerate(line):
            if position == state_index:
                rendered.append(Text(cell, style=_STATE_STYLE.get(row.state, "")))
            elif position == 1:
                rendered.append(Text(cell if name_width is None else _cut(cell, name_width), style="bold"))
            else:
                rendered.append(Text(cell))
        if fit.link:
            link = row.link
            if link_width is not None:
                link = _fit_link(_compact_link(link) if narrow else link, link_width)
            rendered.append(Text(link, style="green" if row.link_up else "bold red"))
        table.add_row(*rendered, style="reverse" if index == selected else None)
    return table


def _heater_text(row: FarmRow, key: str, narrow: bool) -> str:
    for cell in row.heaters:
        if cell.key == key:
            return cell.text(0 if narrow else 1)
    return "-"


#: The key help of the farm and of a printer's detail, longest first: the first that fits is shown, so the way to
#: quit is never cut off.
FARM_KEYS_HELP = (
    "1-9 or ↑/↓ and Enter: one printer's details   q quits",
    "1-9 ↑↓ Enter: details  q quits",
    "1-9 details  q quit",
    "q quit",
)
DETAIL_KEYS_HELP = (
    "Esc or Backspace: back to the farm   1-9 another printer   q quits",
    "Esc: back to the farm  1-9 another  q quits",
    "Esc back  1-9 another  q quit",
    "Esc back  q quit",
    "q quit",
)


def _fit_help(variants: Sequence[str], width: int | None) -> str:
    """The longest of `variants` that fits `width` (the shortest, cut, if none does)."""
    if width is None:
        return variants[0]
    return next((text for text in variants if cell_len(text) <= width), _cut(variants[-1], width))


def farm_view(
    rows: Sequence[FarmRow],
    width: int | None = None,
    *,
    selected: int | None = None,
    events: Sequence[str] = (),
    keys_enabled: bool = True,
) -> Group:
    """The whole farm view: a title, the table, the latest events, and the key help."""
    up = sum(row.link_up for row in rows)
    title = Text(f"farm: {len(rows)} printers, {up} up", style="bold")
    parts: list[RenderableType] = [title, farm_table(rows, width, selected if keys_enabled else None)]
    if events:
        parts.append(Text(""))
        parts += [Text(_cut(event, width) if width else event, style="dim") for event in events]
    parts.append(Text(""))
    no_keys = "Ctrl-C quits (keys need a terminal on stdin)"
    help_text = _fit_help(FARM_KEYS_HELP, width) if keys_enabled else no_keys
    parts.append(Text(_cut(help_text, width) if width else help_text, style="dim"))
    return Group(*parts)


def detail_view(
    row: FarmRow,
    model: WatchModel,
    farm_printer: FarmPrinter,
    width: int = 80,
    height: int | None = None,
) -> Group:
    """One printer's detail: its name and link, then the single-printer view of its readings, then the keys.

    Before the first reading there is no chart to show: the link line says why (connecting, or the error).
    """
    head = Text(f"{row.name} ({row.number})", style="bold")
    head.append("  ")
    head.append(row.link, style="green" if row.link_up else "bold red")
    if row.progress is not None:
        head.append(f"  print {row.progress}")
    keys = Text(_fit_help(DETAIL_KEYS_HELP, width), style="dim")
    if not model.series:
        return Group(head, Text(""), Text("waiting for the first reading...", style="dim"), Text(""), keys)
    firmware = farm_printer.firmware or "unknown firmware"
    where = farm_printer.url or farm_printer.spec.port or "simulated"
    inner_height = None if height is None else height - 3  # the link line, a blank line, the key line
    body = watch_view(model, where, firmware, width=width, height=inner_height)
    return Group(head, Text(""), body, keys)


def plain_lines(rows: Sequence[FarmRow], wall_time_s: float | None = None) -> list[str]:
    """One line per printer, for logs and pipes: `12:00:01 sim1: up | hotend 204.6/210 C | heating | print 42%`."""
    stamp = time.strftime("%H:%M:%S", time.localtime(wall_time_s if wall_time_s is not None else time.time()))
    lines = []
    for row in rows:
        parts = [_cut(row.link, _ERROR_CHARS)]
        parts += [f"{cell.name} {cell.text()} C" for cell in row.heaters]
        if row.heaters:
            parts.append(row.state)
        if row.progress is not None:
            parts.append(f"print {row.progress}")
        lines.append(f"{stamp} {row.name}: " + " | ".join(parts))
    return lines


def json_lines(rows: Sequence[FarmRow], wall_time_s: float | None = None) -> list[str]:
    """One JSON object per printer (`watch --json` with several printers): heaters by name, as the screen says."""
    stamp = wall_time_s if wall_time_s is not None else time.time()
    return [
        json.dumps(
            {
                "time": stamp,
                "printer": row.name,
                "link_up": row.link_up,
                "link": row.link,
                "state": row.state,
                "heaters": {cell.name: {"actual": cell.actual, "target": cell.target} for cell in row.heaters},
                "print": row.progress,
            }
        )
        for row in rows
    ]


_UP = ("\x1b[A", "\x1bOA", "k")
_DOWN = ("\x1b[B", "\x1bOB", "j")
_ENTER = ("\r", "\n")
_BACK = ("\x1b", "\x7f", "\x08")


class FarmKeys:
    """The keys of the farm view as a small state machine: `press(key)` moves, opens, goes back, or quits.

    In the farm: a digit opens that printer, up/down (or k/j) choose one and Enter opens it. In a printer's
    detail: Esc or Backspace goes back, a digit opens another, up/down step to the one before or after.
    q quits in both.

    Args:
        count: how many printers the farm has.
    """

    def __init__(self, count: int) -> None:
        self.count = count
        self.selected = 0
        self.detail: int | None = None
        """The index of the printer whose detail is shown, or None for the farm."""

    def press(self, key: str) -> bool:
        """Handle one key (a character, or an escape sequence whole); return True when it asks to quit."""
        if key in ("q", "Q"):
            return True
        if len(key) == 1 and key.isdigit() and 1 <= int(key) <= min(self.count, 9):
            self.selected = int(key) - 1
            self.detail = self.selected
        elif key in _UP or key in _DOWN:
            step = -1 if key in _UP else 1
            self.selected = min(max(self.selected + step, 0), self.count - 1)
            if self.detail is not None:
                self.detail = self.selected
        elif key in _ENTER and self.detail is None:
            self.detail = self.selected
        elif key in _BACK:
            self.detail = None
        return False
