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
lines, and `lines()` reads through `marlin_aio.aio.file_lines`, which stops with `FileChangedError` once the
file is found cut short, rewritten or appended to (also between the check and the print), so a file saved again
under a running print fails it, naming the line reached, instead of ending it as done half way.

Three kinds of file are refused whole, each with one `ValueError` line, before anything is sent:

- a file that is not text (`_check_text`): a NUL byte, or a high share of undecodable or control bytes in its
  first `SNIFF_BYTES`, so a `.bgcode` or a picture is refused by name instead of dumped as mojibake (a UTF-8 or
  Latin-1 file with a few accented comments is text);
- a command the library would refuse in a print (`marlin_aio.protocol.check_command`, the check every line of a
  print passes: Marlin can take it, and it sets no heater above its limit), naming the line, and for a limit the
  option that raises it: the print would otherwise fail at that line, hot, half way through;
- with `--from-line`, a resume that would do harm (`_Resume`), unless `force`: absolute extrusion resumed from the
  header's E (the filament of every skipped layer pushed out at once), an extrusion mode set in the skipped part
  that the printer will not be in, a heater the skipped part heated and the header leaves cold. What a resume
  merely changes (a target the header sets otherwise than the skipped part did) is a note, never a refusal.

Over 400 lines because everything decided before a print is decided in one reading of the file: the check, the
selection for a resume, the heat waits and the display texts all follow the same line numbers.
"""

from __future__ import annotations

import bisect
import codecs
import unicodedata
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from marlin_aio import HeaterLimits
from marlin_aio.aio import file_lines
from marlin_aio.protocol import DEFAULT_LIMITS, GCodeLine, check_command, command_code, parse_gcode, strip_comment

__all__ = ["SNIFF_BYTES", "GcodePlan", "HeatWait", "plan_print", "transliterate"]

#: How much of a file's start is looked at to tell text from binary data.
SNIFF_BYTES = 8192

# Commands whose argument is free text for people (the display, the host's console, a pause prompt): the only
# ones where replacing a letter by its closest ASCII form changes nothing the printer does.
_TEXT_COMMANDS = frozenset({"M117", "M118", "M0", "M1"})
_MOVES = frozenset({"G0", "G1", "G2", "G3", "G5"})
_DISPLAY_COMMANDS = frozenset({"M117", "M118"})  # their text is what the printer shows or echoes
_HEAT_WAITS = {"M109": "T", "M190": "B", "M191": "C"}
# The commands that set a heater's target, with the heater's name; the option that raises each heater's limit.
_TARGETS = {"M104": "hotend", "M109": "hotend", "M140": "bed", "M190": "bed", "M141": "chamber", "M191": "chamber"}
_LIMIT_OPTIONS = {"hotend": "--max-hotend", "bed": "--max-bed", "chamber": "--max-chamber"}
# Control characters a text file may hold: tab, line ends, form feed, vertical tab.
_TEXT_CONTROLS = frozenset("\t\n\r\f\v")
# A file whose first chunk has more than this share of undecodable or control bytes is binary data.
_BINARY_SHARE = 0.3  # random bytes give over half; French comments in Latin-1 a few percent
_SHOWN_CHARACTERS = 60  # of a bad command in a message: enough to find it, not a screen of it
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


def _parameters(line: GCodeLine) -> dict[str, float]:
    """The parameters with a value, read as Marlin reads them (the last word of a letter given twice wins)."""
    return line.numbers()


def _shown(command: str) -> str:
    """`command` as a message quotes it: its repr, cut to a readable length."""
    text = repr(command)
    return text if len(text) <= _SHOWN_CHARACTERS else f"{text[:_SHOWN_CHARACTERS]}... ({len(command)} characters)"


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
    # With from_line: what makes the resume do harm (refused unless forced; with force, warnings), and what it
    # merely changes (notes).
    resume_dangers: tuple[str, ...] = ()
    resume_notes: tuple[str, ...] = ()
    # The text of each M117/M118 sent, as sent, by file line in order: what the printer shows as the print runs.
    display_texts: tuple[tuple[int, str], ...] = ()

    def lines(self) -> Iterator[str]:
        """The file's lines as they are to be sent: selected, transliterated, skipped ones empty.

        Raises:
            OSError: the file cannot be read.
            marlin_aio.FileChangedError: (while iterating) the file is no longer the one checked.
        """
        source = file_lines(self.path, size_bytes=self.size_bytes, mtime_ns=self.mtime_ns, lines_total=self.file_lines)
        for number, raw in enumerate(source, 1):
            yield (self._to_send(number, strip_comment(raw)) or "") + "\n"

    def _to_send(self, number: int, command: str) -> str | None:
        """What line `number` of the file, `command` once its comment is removed, sends: the command, transliterated
        where it is text for people; None for a blank line or a line `from_line` skips. `plan_print` checks what
        this gives, `lines` sends it.

        Raises:
            ValueError: non-ASCII characters in a command that is not text for people (no letter of it can be
                changed without changing what the printer does).
        """
        if not command or not self._selected(number):
            return None
        if command.isascii():
            return command
        code = command_code(command)
        if code not in _TEXT_COMMANDS:
            raise ValueError(f"non-ASCII characters in a {code or 'G-code'} command: {_shown(command)}")
        return transliterate(command)

    def _selected(self, number: int) -> bool:
        if self.from_line is None or self.first_move_line is None:
            return True
        return number < self.first_move_line or number >= self.from_line

    def display_text(self, last_line_answered: int) -> str | None:
        """The text of the last M117/M118 answered by `last_line_answered`, as sent (None before the first)."""
        index = bisect.bisect_right(self.display_texts, last_line_answered, key=lambda entry: entry[0])
        return self.display_texts[index - 1][1] if index else None

    def heat_wait_running(self, last_line_answered: int, in_flight: bool) -> HeatWait | None:
        """The heater wait the printer is in, if the command after the last one answered is one and it was sent."""
        return self.heat_waits.get(last_line_answered) if in_flight else None


def plan_print(
    path: Path, from_line: int | None = None, *, force: bool = False, limits: HeaterLimits = DEFAULT_LIMITS
) -> GcodePlan:
    """Read and check `path` before printing it.

    `limits` bounds the targets the file may set (by default the library's, Marlin's own clamps);
    `force` lets a `from_line` resume go on although it would do harm (the reasons are then in `resume_dangers`).

    Raises:
        ValueError: one line naming the file: it is not a text file; it holds no commands; a command is invalid or
            sets a heater above its limit (the message names its line, nothing has been sent); `from_line` lies
            past the last command or there is no move to resume at; or, without `force`, the resume would do harm
            (the message says why and to add --force).
        OSError: the file cannot be read.
    """
    stamp = path.stat()  # before the file is read: a change while it is checked is a change too
    _check_text(path)
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
    texts: list[tuple[int, str]] = []
    resume = _Resume(from_line, first_move) if from_line is not None and first_move is not None else None
    number = 0
    with path.open(encoding="utf-8", errors="replace") as source:
        for number, raw in enumerate(source, 1):
            command = strip_comment(raw)
            if not command:
                continue
            last_command_line = number
            parsed = parse_gcode(command)
            code = parsed.code
            if resume is not None:
                resume.follow(number, parsed)
            try:
                sent = plan._to_send(number, command)
                if sent is None:
                    continue  # skipped by --from-line
                check_command(sent, limits)  # the library's check of every line of a print
            except ValueError as exc:
                raise ValueError(f"{path}: line {number}: {_naming_the_option(str(exc))}") from None
            if sent != command:
                changed_count += 1
                if len(changed) < 3:
                    changed.append((number, command, sent))
            if code in _HEAT_WAITS:
                waits[previous] = _heat_wait(number, parsed)
            elif code in _DISPLAY_COMMANDS:
                texts.append((number, parse_gcode(sent).string_arg or ""))
            commands += 1
            if first_move is not None and number < first_move:
                header += 1
            previous = number
    if from_line is not None and from_line > last_command_line:
        raise ValueError(f"{path}: --from-line {from_line} is past the last command (line {last_command_line})")
    if not commands:
        raise ValueError(f"{path}: no G-code commands in it (only comments or blank lines); nothing to print")
    dangers = tuple(resume.dangers()) if resume is not None else ()
    if dangers and not force:
        raise ValueError(f"{path}: --from-line {from_line}: {'; also '.join(dangers)}; add --force to resume anyway")
    return GcodePlan(
        path,
        commands,
        from_line,
        header,
        first_move,
        tuple(changed),
        changed_count,
        waits,
        resume.extrusion_warning if resume is not None else None,
        stamp.st_size,
        stamp.st_mtime_ns,
        number,
        dangers,
        tuple(resume.notes()) if resume is not None else (),
        tuple(texts),
    )


def _check_text(path: Path) -> None:
    """Refuse a file whose start is not text: a NUL byte, or a high share of bytes no text file holds.

    Raises:
        ValueError: "<path> is not a text G-code file (binary data at byte N)", N counted from 0 (as hexdump does).
        OSError: the file cannot be read.
    """
    with path.open("rb") as source:
        head = source.read(SNIFF_BYTES)
        cut = bool(source.read(1))  # the chunk ends inside the file: its last character may be cut in two
    nul = head.find(b"\x00")
    if nul >= 0:
        raise ValueError(f"{path} is not a text G-code file (binary data at byte {nul})")
    text, _ = codecs.utf_8_decode(head, "surrogateescape", not cut)
    offset = 0
    bad: list[int] = []
    for char in text:
        size = 1 if char < "\x80" or "\udc80" <= char <= "\udcff" else len(char.encode("utf-8"))
        if ("\udc80" <= char <= "\udcff") or (char < " " and char not in _TEXT_CONTROLS) or char == "\x7f":
            bad.append(offset)
        offset += size
    if len(bad) > 2 and len(bad) > _BINARY_SHARE * len(head):
        raise ValueError(f"{path} is not a text G-code file (binary data at byte {bad[0]})")


def _naming_the_option(message: str) -> str:
    """The library's `message`, and where it is a heater's target over its limit, the option that raises it."""
    option = _LIMIT_OPTIONS.get(message.split(" ", 1)[0])  # the library's message starts with the heater's name
    return f"{message} ({option})" if option is not None and "above the limit" in message else message


def _mode_name(absolute: bool) -> str:
    return "absolute extrusion (M82)" if absolute else "relative extrusion (M83)"


class _Resume:
    """Follows the file through a `--from-line` resume: what the printer will be in after the header, against
    what the resumed part expects.

    Resuming at a layer of a file with absolute E (M82) goes wrong quietly: the header's `G92 E0` sets E to 0, and
    the layer's first extruding move then pushes out all the filament of the layers skipped. A layer that sets E
    itself (`G92 E...`) is fine. A mode switch (M82/M83, G90/G91) or a heater target in the skipped part is not
    sent either: the printer stays as the header left it.
    """

    def __init__(self, from_line: int, first_move: int) -> None:
        self.from_line = from_line
        self.first_move = first_move
        self.file_absolute = True  # Marlin starts in M82; E's mode as the file has it
        self.printer_absolute = True  # ... and as the printer will have it (skipped lines never run)
        self.mode_line: int | None = None  # the skipped line that last set the file's mode
        self.e = 0.0  # where E stands, as the file has it
        self.header_e: float | None = None  # the last G92 E of the header
        self.extrusion_warning: str | None = None
        self.mode_warning: str | None = None
        self.header_targets: dict[str, float] = {}  # heater name: the last target the header sets
        self.skipped_targets: dict[str, tuple[int, float]] = {}  # heater name: (line, target) last set when skipped
        self.resumed_targets: set[str] = set()  # heaters the resumed part sets before it first extrudes
        self._extruding = False  # the resumed part's first extruding move was seen
        self._e_settled = from_line <= first_move  # the whole file runs: nothing to check

    def follow(self, number: int, line: GCodeLine) -> None:
        """Take the next command of the file (skipped or not)."""
        if self.from_line <= self.first_move:
            return
        code = line.code
        skipped = self.first_move <= number < self.from_line
        if code in _TARGETS and not self._extruding:
            self._target(number, line, skipped)
        elif code in ("M82", "G90", "M83", "G91"):
            self.file_absolute = code in ("M82", "G90")
            if skipped:
                self.mode_line = number
            else:
                self.printer_absolute = self.file_absolute
        elif code in _MOVES or code == "G92":
            self._e(number, line)

    def _target(self, number: int, line: GCodeLine, skipped: bool) -> None:
        parameters = _parameters(line)
        value = parameters.get("S", parameters.get("R"))
        if value is None:
            return
        heater = _TARGETS[line.code]
        if heater == "hotend" and "T" in parameters:
            heater = f"hotend {int(parameters['T'])}"
        if number < self.first_move:
            self.header_targets[heater] = value
        elif skipped:
            self.skipped_targets[heater] = (number, value)
        else:
            self.resumed_targets.add(heater)

    def _e(self, number: int, line: GCodeLine) -> None:
        value = _parameters(line).get("E")
        if value is None:
            return
        if number >= self.from_line and line.code in _MOVES:
            if not self._extruding:
                self._extruding = True
                self._first_extrusion(number, value)
            self._e_settled = True
            return
        if self._e_settled:
            return
        if line.code == "G92":
            self.e = value
            self.header_e = value if number < self.first_move else self.header_e
            self._e_settled = number >= self.from_line  # the resumed part sets E itself
            return
        self.e = value if self.file_absolute else self.e + value

    def _first_extrusion(self, number: int, value: float) -> None:
        """The resumed part's first extruding move, to `value` on line `number`: is E read as the file means it?"""
        if self.file_absolute != self.printer_absolute:
            self.mode_warning = (
                f"the file switches to {_mode_name(self.file_absolute)} at line {self.mode_line}, which is skipped, "
                f"so the printer is still in {_mode_name(self.printer_absolute)} when line {number} extrudes "
                f"E{value:g}: every E from line {self.from_line} on would be read the wrong way. Put "
                f"'{'M82' if self.file_absolute else 'M83'}' before line {self.from_line}"
            )
        elif not self._e_settled and self.file_absolute and self.header_e is not None and value - self.header_e > 1:
            self.extrusion_warning = (
                f"the first extruding move from line {self.from_line} on (line {number}) goes to E{value:g} with "
                f"absolute extrusion, but the header's G92 E{self.header_e:g} sets E to {self.header_e:g}: it would "
                f"push out {value - self.header_e:g} mm of filament at once. E stood at {self.e:g} before line "
                f"{self.from_line}: put 'G92 E{self.e:g}' there, or resume at a layer that sets E itself"
            )

    def dangers(self) -> list[str]:
        """What would make the resume do harm, one sentence each."""
        found = [warning for warning in (self.extrusion_warning, self.mode_warning) if warning is not None]
        for heater, (line, target) in self.skipped_targets.items():
            if target > 0 and not self.header_targets.get(heater) and heater not in self.resumed_targets:
                found.append(
                    f"the skipped part heats the {heater} to {target:g} C (line {line}) but the header does not "
                    f"heat it, so the resumed part would print with it cold: set it in the header first"
                )
        return found

    def notes(self) -> list[str]:
        """What the resume changes without harm, one sentence each."""
        found = []
        for heater, (line, target) in self.skipped_targets.items():
            header = self.header_targets.get(heater)
            if header and target != header and heater not in self.resumed_targets:
                found.append(
                    f"the header sets the {heater} to {header:g} C; the skipped part had changed it to {target:g} C "
                    f"(line {line}), so it stays at {header:g} C until the file sets it again"
                )
        return found


def _first_move(path: Path) -> int | None:
    with path.open(encoding="utf-8", errors="replace") as source:
        for number, raw in enumerate(source, 1):
            if command_code(strip_comment(raw)) in _MOVES:
                return number
    return None


def _heat_wait(number: int, line: GCodeLine) -> HeatWait:
    parameters = _parameters(line)
    heater = _HEAT_WAITS[line.code]
    if line.code == "M109" and "T" in parameters:
        heater = f"T{int(parameters['T'])}"
    target = parameters.get("S", parameters.get("R"))
    return HeatWait(number, heater, target)
