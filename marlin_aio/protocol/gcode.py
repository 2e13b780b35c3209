"""Reading a G-code line the way Marlin reads it: `GCodeParser::parse` of `gcode/parser.cpp` and the value accessors
of `gcode/parser.h` (Marlin 2.1, with its default `FASTER_GCODE_PARSER` and `GCODE_CASE_INSENSITIVE`).

One reading for everything that must agree with the firmware: the heater limits (`heaters.check_gcode_targets`),
the command code the core and the CLI act on (`command_code`), the print planner, the farm, and the simulated
printer, which runs what this module reads. A check that reads a line differently from the firmware can be walked
around by spelling: Marlin needs no space before a parameter (`M104S280`), skips leading zeros (`M0104`), reads
lowercase (`m104 s280`), takes spaces between the letter and the number (`M 104`), keeps only the low 16 bits of a
command number (`M65640` is M104), and with several words of one letter keeps the last (`M104 S100 S280` sets 280).

What parser.cpp does, in order:
- skip spaces, then an `N` word (`N` and a digit or sign, more digits, spaces);
- the command letter, which must be G, M or T (else the command is unknown), spaces, then its digits (none:
  unknown); the text is cut at the first `*` and the spaces before it;
- M23, M28, M30, M117, M118 and M928 take the rest as a string (no parameters);
- otherwise each character is a parameter letter (a-z as A-Z); spaces after it are skipped; it has a value when
  what follows is `[-+]?.?[0-9]`; unless the next character is A-Z, the run of `[0-9.+-]` and the spaces after
  it are skipped. So `Sabc` is four letters without values, and `S2e5` is S2 and E5.

Values are read as parser.h reads them: `value_float` cuts the text at the first E or X (so `X10E5` is not 10e5)
and reads a C float; `value_long` is C's `strtol` for a 32-bit long; `value_int` (and `value_celsius`, without
TEMPERATURE_UNITS_SUPPORT) keeps its low 16 bits as a signed number, so `S65816` is 280.

Pure functions, no I/O; `parse_gcode` and `command_code` are cached, as the same few commands come back many times
a second.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

__all__ = [
    "STRING_ARGUMENT_CODES",
    "GCodeLine",
    "command_code",
    "parse_gcode",
    "parse_parameters",
    "value_celsius",
    "value_float",
    "value_long",
]

# parser.cpp: `N` and a digit or sign (NUMERIC_SIGNED), more digits, spaces. Case-insensitive by default.
_LINE_NUMBER_WORD = re.compile(r"[Nn][-+0-9][0-9]* *")
_LINE_NUMBER_WORD_UPPER = re.compile(r"N[-+0-9][0-9]* *")
# The command code alone: what `command_code` needs, without walking the parameters (the core asks for it for
# every line it sends, print lines included).
_CODE = re.compile(r" *(?:[Nn][-+0-9][0-9]* *)?([GMTgmt]) *([0-9]+)")
_DIGITS = re.compile(r" *([0-9]+) *")
_VALID_FLOAT = re.compile(r"[-+]?\.?[0-9]")  # parser.h valid_float(): [-+]?.?[0-9]
_DECIMAL_RUN = re.compile(r"[-+.0-9]* *")  # the value section skipped after a parameter (DECIMAL_SIGNED), spaces
_SPACES = re.compile(r" *")
_FLOAT_PREFIX = re.compile(r"[ \t\n\v\f\r]*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")
_LONG_PREFIX = re.compile(r"[ \t\n\v\f\r]*([-+]?[0-9]+)")
_FLOAT_CUT = re.compile(r"[EeXx]")
_LONG_MIN, _LONG_MAX = -(2**31), 2**31 - 1  # a long on AVR and 32-bit ARM
#: The M codes that take the rest of the line as one string argument (parser.cpp, default configuration).
STRING_ARGUMENT_CODES = frozenset({"M23", "M28", "M30", "M117", "M118", "M928"})


@dataclass(frozen=True, slots=True)
class GCodeLine:
    """One line as Marlin's parser reads it."""

    text: str
    """The command as parser.cpp sees it: no leading spaces or `N` word, cut at the first `*` (and the spaces
    before it); what `echo:Unknown command: "..."` shows."""
    code: str
    """`"M104"`, `"G1"`, `"T0"` (letter in upper case, number as Marlin keeps it), or `""` for an unknown command."""
    args: str
    """The text after the command's number and the spaces after it (`""` for an unknown command)."""
    words: tuple[tuple[str, str | None], ...]
    """Every parameter in order, its letter in upper case with the text its value starts with (`("S", "280")`),
    or None when it has no value (`M104 S` gives `("S", None)`). Empty for string-argument commands."""
    string_arg: str | None
    """The string argument: the whole text after the code for M23/M28/M30/M117/M118/M928, else the first word
    without a value (as `M0 S5 You win` gives `You win`), or None."""

    def value(self, letter: str) -> str | None:
        """The value text of parameter `letter` as Marlin keeps it (the last word of that letter), or None when it
        is absent or has no value."""
        found = None
        for word, value in self.words:
            if word == letter:
                found = value
        return found

    def numbers(self) -> dict[str, float]:
        """The parameters that have a value, by letter, as Marlin's `floatval` reads them (the last word of a
        letter wins): `G1 X10 E` gives `{"X": 10.0}`."""
        return {letter: value_float(value) for letter, value in self.words if value is not None}

    def seen(self, letter: str) -> bool:
        """Whether the line has parameter `letter`, with or without a value."""
        return any(word == letter for word, _ in self.words)


@functools.lru_cache(maxsize=512)
def parse_gcode(text: str, *, case_insensitive: bool = True) -> GCodeLine:
    """Read `text` (one line, without its line end, comment already cut off) as Marlin's `GCodeParser::parse`.

    Never raises: whatever the bytes, the result is a command or an unknown one (`code == ""`), as on the board.
    `case_insensitive=False` reads as a firmware built without GCODE_CASE_INSENSITIVE.
    """
    at = _SPACES.match(text).end()  # type: ignore[union-attr]  # " *" always matches
    word = (_LINE_NUMBER_WORD if case_insensitive else _LINE_NUMBER_WORD_UPPER).match(text, at)
    if word is not None:
        at = word.end()
    star = text.find("*", at + 1)
    if star >= 0:
        text = text[:star].rstrip(" ")  # (never below the letter: the cut starts after it)
    command = text[at:]
    letter = command[:1]
    if case_insensitive and "a" <= letter <= "z":
        letter = letter.upper()
    if letter not in ("G", "M", "T"):
        return GCodeLine(command, "", "", (), None)
    digits = _DIGITS.match(command, 1)
    if digits is None:
        return GCodeLine(command, "", "", (), None)
    code = f"{letter}{int(digits.group(1)) % 65536}"  # codenum is a uint16_t: M65640 is M104
    args = command[digits.end() :]
    if code in STRING_ARGUMENT_CODES:
        return GCodeLine(command, code, args, (), args)
    words, string_arg = _parameters(args, case_insensitive)
    return GCodeLine(command, code, args, words, string_arg)


def _parameters(args: str, case_insensitive: bool) -> tuple[tuple[tuple[str, str | None], ...], str | None]:
    """parser.cpp's parameter loop over the text after the command code."""
    words: list[tuple[str, str | None]] = []
    string_arg: str | None = None
    end = len(args)
    at = 0
    while at < end:
        letter = args[at]
        at += 1
        if case_insensitive and "a" <= letter <= "z":
            letter = letter.upper()
        if "A" <= letter <= "Z":
            at = _SPACES.match(args, at).end()  # type: ignore[union-attr]
            if _VALID_FLOAT.match(args, at):
                run = _DECIMAL_RUN.match(args, at).end()  # type: ignore[union-attr]
                words.append((letter, args[at:run].rstrip(" ")))
            else:
                words.append((letter, None))
                if string_arg is None:
                    string_arg = args[at - 1 :]  # from the character before, as parser.cpp's `p - 1`
        elif string_arg is None:
            string_arg = args[at - 1 :]
        if at < end and not ("A" <= args[at] <= "Z"):
            at = _DECIMAL_RUN.match(args, at).end()  # type: ignore[union-attr]
    return tuple(words), string_arg


@functools.lru_cache(maxsize=512)
def command_code(text: str) -> str:
    """The command word of a G-code line as Marlin reads it (`"m0104s280"` gives `"M104"`), or `""` when Marlin
    would not know it as a G, M or T command. A leading `N<number>` word is skipped.

    The same answer as `parse_gcode(text).code`, without reading the parameters.
    """
    match = _CODE.match(text)
    if match is None:
        return ""
    return f"{match.group(1).upper()}{int(match.group(2)) % 65536}"


def parse_parameters(args: str, *, case_insensitive: bool = True) -> dict[str, float | None]:
    """The parameters of a command's argument text by letter, as Marlin's `floatval` reads them (the last word
    of a letter wins): `X10 E` gives `{"X": 10.0, "E": None}`."""
    words, _ = _parameters(args, case_insensitive)
    return {letter: None if value is None else value_float(value) for letter, value in words}


def value_float(value: str) -> float:
    """parser.h `value_float()`: the text up to the first E or X, read as C's `strtof` reads a decimal (0.0 if
    no number starts it)."""
    cut = _FLOAT_CUT.search(value)
    if cut is not None:
        value = value[: cut.start()]
    match = _FLOAT_PREFIX.match(value)
    return float(match.group(1)) if match is not None else 0.0


def value_long(value: str) -> int:
    """parser.h `value_long()`: C's `strtol(value, nullptr, 10)` for a 32-bit long (saturating; 0 if no digits)."""
    match = _LONG_PREFIX.match(value)
    if match is None:
        return 0
    return min(max(int(match.group(1)), _LONG_MIN), _LONG_MAX)


def value_celsius(value: str) -> int:
    """parser.h `value_celsius()` without TEMPERATURE_UNITS_SUPPORT: `value_int()`, the long's low 16 bits as a
    signed number (`65816` is 280, `-65256` is 280)."""
    low = value_long(value) & 0xFFFF
    return low - 0x10000 if low >= 0x8000 else low
