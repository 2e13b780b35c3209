"""The G-code file `marlin-temp print` sends: checked whole before anything is written, then read again lazily.

`plan_print` reads the file once and decides everything a print needs to know up front: that it holds commands at
all, which lines go (all of them, or with `--from-line N` the header up to the first move and then line N on),
which display messages carry letters Marlin cannot take (sent transliterated, with a warning, rather than losing
the print to a `M117 café`), and where the file waits for a heater (so the progress view can say "heating"
instead of showing a rate of 0 lines/s). `GcodePlan.lines()` then yields the same selection again, one line at a
time, so a file of any size streams in constant memory.

Skipped lines are yielded as empty lines rather than left out, so the library's source line numbers stay the
file's line numbers: "cancelled after line 8123" is a line the user can find and resume from.

The second reading is of the file as it was checked: the plan keeps its size, modification time and number of
lines, and `lines()` reads through `marlin_aio.PrintJob.file_lines`, which stops with `FileChangedError` once the
file is found cut short, rewritten or appended to (also between the check and the print), so a file saved again
under a running print fails it, naming the line reached, instead of ending it as done half way.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import marlin_aio

__all__ = ["GcodePlan", "HeatWait", "plan_print", "transliterate"]

# Commands whose argument is free text for people (the display, the host's console, a pause prompt): the only
# ones where replacing a letter by its closest ASCII form changes nothing the printer does.
_TEXT_COMMANDS = frozenset({"M117", "M118", "M0", "M1"})
_MOVES = frozenset({"G0", "G1", "G2", "G3", "G5"})
_HEAT_WAITS = {"M109": "T", "M190": "B", "M191": "C"}
_CODE = re.compile(r"\s*([A-Za-z])\s*0*(\d+)")
_PARAMETER = re.compile(r"([A-Za-z])\s*(-?\d+(?:\.\d*)?|-?\.\d+)")
# Letters NFKD does not decompose into a base letter and an accent.
_SPELLED = str.maketrans(
    {"ß": "ss", "æ": "ae", "Æ": "AE", "ø": "o", "Ø": "O", "œ": "oe", "Œ": "OE", "ł": "l", "Ł": "L", "đ": "d"}
    | {"Đ": "D", "þ": "th", "°": "", "\u2018": "'", "\u2019": "'", "\u201c": '"', "\u201d": '"', "\u2013": "-"}
    | {"\u2014": "-"}
)


def transliterate(text: str) -> str:
    """`text` in ASCII: accents dropped (`café` gives `cafe`), a few letters spelled out, anything else `?`."""
    decomposed = unicodedata.normalize("NFKD", text.translate(_SPELLED))
    kept = "".join(c for c in decomposed if not unicodedata.combining(c))
    return kept.encode("ascii", errors="replace").decode("ascii")


def _code(command: str) -> str:
    """The command word, normalised: `g01 x1` and `G1X1` both give `G1`; `""` for anything else."""
    match = _CODE.match(command)
    return f"{match.group(1).upper()}{int(match.group(2))}" if match else ""


@dataclass(frozen=True, slots=True)
class HeatWait:
    """A command of the file that holds the print until a heater reaches its target (M109, M190, M191)."""

    line: int  # its line in the file
    heater: str  # the report key it waits on: "T" (the active hotend), "T1", "B" or "C"
    target_celsius: float | None  # its S or R value


@dataclass(frozen=True, slots=True)
class GcodePlan:
    """What a print will send, found by reading the file once before connecting."""

    path: Path
    commands: int
    from_line: int | None = None
    header_lines: int = 0  # with from_line: how many header commands (before the first move) run first
    first_move_line: int | None = None
    transliterated: tuple[tuple[int, str, str], ...] = ()  # (line, as written, as sent): the first few
    transliterated_count: int = 0
    # The heater waits, keyed by the file line of the command sent just before each (0: it is the first), which is
    # what a print's progress reports as the last line answered while the wait runs.
    heat_waits: dict[int, HeatWait] = field(default_factory=dict)
    extrusion_warning: str | None = None  # with from_line: the resumed part would extrude from the header's E
    # The file as it was checked (None: not known, for a plan made by hand): a print stops if it differs.
    size_bytes: int | None = None
    mtime_ns: int | None = None
    file_lines: int | None = None  # comments and blank lines included

    def lines(self) -> Iterator[str]:
        """The file's lines as they are to be sent: selected, transliterated, skipped ones empty.

        Raises:
            OSError: the file cannot be read.
            marlin_aio.FileChangedError: (while iterating) the file is no longer the one checked.
        """
        source = marlin_aio.PrintJob.file_lines(
            self.path, size_bytes=self.size_bytes, mtime_ns=self.mtime_ns, lines_total=self.file_lines
        )
        for number, raw in enumerate(source, 1):
            command = marlin_aio.strip_comment(raw)
            if not command or not self._selected(number):
                yield "\n"
            elif command.isascii():
                yield command + "\n"
            else:
                yield transliterate(command) + "\n"

    def _selected(self, number: int) -> bool:
        if self.from_line is None or self.first_move_line is None:
            return True
        return number < self.first_move_line or number >= self.from_line

    def heat_wait_running(self, last_line_answered: int, in_flight: bool) -> HeatWait | None:
        """The heater wait the printer is in, if the command after the last one answered is one and it was sent."""
        return self.heat_waits.get(last_line_answered) if in_flight else None


def plan_print(path: Path, from_line: int | None = None) -> GcodePlan:
    """Read and check `path` before printing it.

    Raises:
        ValueError: the file holds no commands, a command is invalid (the message names its line, nothing has been
            sent), or `from_line` lies past the last command or there is no move to resume at.
        OSError: the file cannot be read.
    """
    stamp = path.stat()  # before the file is read: a change while it is checked is a change too
    first_move = _first_move(path) if from_line is not None else None
    if from_line is not None and first_move is None:
        raise ValueError(f"{path}: --from-line needs a file with moves (G0/G1/G2/G3); this one has none")
    plan = GcodePlan(path, 0, from_line, first_move_line=first_move)
    commands = header = 0
    previous = 0
    last_command_line = 0
    changed: list[tuple[int, str, str]] = []
    changed_count = 0
    waits: dict[int, HeatWait] = {}
    extrusion = _Extrusion(from_line, first_move) if from_line is not None and first_move is not None else None
    number = 0
    with path.open(encoding="utf-8", errors="replace") as source:
        for number, raw in enumerate(source, 1):
            command = marlin_aio.strip_comment(raw)
            if not command:
                continue
            last_command_line = number
            code = _code(command)
            if extrusion is not None:
                extrusion.follow(number, code, command)
            if not plan._selected(number):
                continue
            if not command.isascii():
                if code not in _TEXT_COMMANDS:
                    raise ValueError(
                        f"{path}: line {number}: non-ASCII characters in a {code or 'G-code'} command: {command!r}"
                    )
                sent = transliterate(command)
                changed_count += 1
                if len(changed) < 3:
                    changed.append((number, command, sent))
                command = sent
            try:
                marlin_aio.encode_command(command)
            except ValueError as exc:
                raise ValueError(f"{path}: line {number}: {exc}") from None
            if code in _HEAT_WAITS:
                waits[previous] = _heat_wait(number, code, command)
            commands += 1
            if first_move is not None and number < first_move:
                header += 1
            previous = number
    if from_line is not None and from_line > last_command_line:
        raise ValueError(f"{path}: --from-line {from_line} is past the last command (line {last_command_line})")
    if not commands:
        raise ValueError(f"{path}: no G-code commands in it (only comments or blank lines); nothing to print")
    return GcodePlan(
        path,
        commands,
        from_line,
        header,
        first_move,
        tuple(changed),
        changed_count,
        waits,
        extrusion.warning if extrusion is not None else None,
        stamp.st_size,
        stamp.st_mtime_ns,
        number,
    )


class _Extrusion:
    """Follows E through the file, to warn when `--from-line` would resume absolute extrusion from the header's E.

    Resuming at a layer of a file with absolute E (M82) goes wrong quietly: the header's `G92 E0` sets E to 0, and
    the layer's first extruding move then pushes out all the filament of the layers skipped. A layer that sets E
    itself (`G92 E...`) is fine.
    """

    def __init__(self, from_line: int, first_move: int) -> None:
        self.from_line = from_line
        self.first_move = first_move
        self.absolute = True  # Marlin starts in M82
        self.e = 0.0  # where E stands, as the file has it
        self.header_e: float | None = None  # the last G92 E of the header
        self.warning: str | None = None
        self._settled = from_line <= first_move  # the whole file runs: nothing to check

    def follow(self, number: int, code: str, command: str) -> None:
        """Take the next command of the file (skipped or not)."""
        if self._settled:
            return
        if code in ("M82", "G90"):
            self.absolute = True
        elif code in ("M83", "G91"):
            self.absolute = False
        elif code not in _MOVES and code != "G92":
            return
        match = _CODE.match(command)
        parameters = _PARAMETER.findall(command[match.end() :] if match else "")
        e = next((value for letter, value in parameters if letter.upper() == "E"), None)
        if e is None:
            return
        value = float(e)
        if code == "G92":
            self.e = value
            self.header_e = value if number < self.first_move else self.header_e
            self._settled = number >= self.from_line  # the resumed part sets E itself
            return
        if number < self.from_line:
            self.e = value if self.absolute else self.e + value
            return
        self._settled = True
        if self.absolute and self.header_e is not None and value - self.header_e > 1.0:
            self.warning = (
                f"the first extruding move from line {self.from_line} on (line {number}) goes to E{value:g} with "
                f"absolute extrusion, but the header's G92 E{self.header_e:g} sets E to {self.header_e:g}: it would "
                f"push out {value - self.header_e:g} mm of filament at once. E stood at {self.e:g} before line "
                f"{self.from_line}: put 'G92 E{self.e:g}' there, or resume at a layer that sets E itself"
            )


def _first_move(path: Path) -> int | None:
    with path.open(encoding="utf-8", errors="replace") as source:
        for number, raw in enumerate(source, 1):
            if _code(marlin_aio.strip_comment(raw)) in _MOVES:
                return number
    return None


def _heat_wait(number: int, code: str, command: str) -> HeatWait:
    match = _CODE.match(command)
    rest = command[match.end() :] if match else ""
    parameters = {letter.upper(): value for letter, value in _PARAMETER.findall(rest)}
    heater = _HEAT_WAITS[code]
    if code == "M109" and "T" in parameters:
        heater = f"T{int(float(parameters['T']))}"
    target = parameters.get("S", parameters.get("R"))
    return HeatWait(number, heater, None if target is None else float(target))
