"""The one G-code reading (`marlin_aio.protocol.gcode`) against Marlin's parser.cpp, and the heater limits built on it.

Three holds:
- a second, independent reading: `reference_parse` below is parser.cpp's `GCodeParser::parse` (bugfix-2.1.x, char
  pointers, FASTER_GCODE_PARSER, GCODE_CASE_INSENSITIVE) ported line by line, and Hypothesis compares the two over
  any text made of the bytes that matter (letters of both cases, digits, signs, points, spaces, `*`);
- the simulated printer's reading of the same bytes, after its queue.cpp intake (numbered and checksummed as the
  client sends them): the command it takes is the one the library read;
- the limits against what the simulated printer then holds: whatever spelling passes `check_gcode_targets`, the
  printer's targets stay within the limits.
"""

from __future__ import annotations

import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio import HeaterLimits
from marlin_aio.protocol import check_gcode_targets, command_code
from marlin_aio.protocol.commands import encode_command, validate_command
from marlin_aio.protocol.gcode import parse_gcode, value_celsius, value_float
from marlin_aio.simulator import SimulatedPrinter, SimulatorConfig

_STRING_CODES = {("M", 23), ("M", 28), ("M", 30), ("M", 117), ("M", 118), ("M", 928)}
_FLOAT = re.compile(rb"[ \t\n\v\f\r]*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")
_LONG = re.compile(rb"[ \t\n\v\f\r]*([-+]?[0-9]+)")


def _digit(c: int) -> bool:
    return 48 <= c <= 57


def _upper(c: int) -> int:
    return c - 32 if 97 <= c <= 122 else c


def _strtof_marlin(rest: bytes) -> float:
    """parser.h value_float(): cut at the first E/e/X/x before a space or the end, then strtof."""
    end = 0
    while end < len(rest) and rest[end] not in (0, 32):
        if rest[end] in b"EeXx":
            rest = rest[:end]
            break
        end += 1
    match = _FLOAT.match(rest)
    return float(match.group(1)) if match else 0.0


def _strtol_int16(rest: bytes) -> int:
    match = _LONG.match(rest)
    value = min(max(int(match.group(1)), -(2**31)), 2**31 - 1) if match else 0
    low = value & 0xFFFF
    return low - 0x10000 if low >= 0x8000 else low


def reference_parse(text: str) -> tuple[str, dict[str, tuple[float, int] | None]]:
    """parser.cpp's parse() ported literally: (code or "", {letter: (value_float, value_celsius) or None}) with
    the last word of each letter, as FASTER_GCODE_PARSER keeps it."""
    s = bytearray(text.encode("latin-1")) + b"\0"
    p = 0
    while s[p] == 32:
        p += 1
    if _upper(s[p]) == ord("N") and (_digit(s[p + 1]) or s[p + 1] in b"-+"):
        p += 2
        while _digit(s[p]):
            p += 1
        while s[p] == 32:
            p += 1
    letter = _upper(s[p])
    if letter == 0:
        return "", {}
    p += 1
    star = s.find(b"*", p, s.index(0))
    if star >= 0:
        q = star - 1
        while s[q] == 32:
            q -= 1
        s[q + 1] = 0
    if letter not in b"GMT":
        return "", {}
    while s[p] == 32:
        p += 1
    if not _digit(s[p]):
        return "", {}
    codenum = 0
    while _digit(s[p]):
        codenum = (codenum * 10 + s[p] - 48) & 0xFFFF
        p += 1
    while s[p] == 32:
        p += 1
    code = f"{chr(letter)}{codenum}"
    if (chr(letter), codenum) in _STRING_CODES:
        return code, {}
    params: dict[str, tuple[float, int] | None] = {}
    while True:
        param = _upper(s[p])
        p += 1
        if param == 0:
            break
        if 65 <= param <= 90:
            while s[p] == 32:
                p += 1
            has_val = _digit(s[p]) or (s[p] == 46 and _digit(s[p + 1]))
            has_val = has_val or (s[p] in b"-+" and (_digit(s[p + 1]) or (s[p + 1] == 46 and _digit(s[p + 2]))))
            rest = bytes(s[p : s.index(0, p)])
            params[chr(param)] = (_strtof_marlin(rest), _strtol_int16(rest)) if has_val else None
        if not (65 <= s[p] <= 90):
            while s[p] != 0 and (_digit(s[p]) or s[p] in b".-+"):
                p += 1
            while s[p] == 32:
                p += 1
    return code, params


def library_reading(text: str) -> tuple[str, dict[str, tuple[float, int] | None]]:
    line = parse_gcode(text)
    params: dict[str, tuple[float, int] | None] = {}
    for letter, value in line.words:
        params[letter] = None if value is None else (value_float(value), value_celsius(value))
    return line.code, params


# Text made of what parser.cpp tells apart: G/M/T/N and parameter letters in both cases, digits, signs, points,
# spaces, the checksum mark and a few others.
_GCODE_TEXT = st.text(alphabet="GMTNgmtnSRBEXxeHIsrb0123456789-+. *;!(", max_size=24)


@settings(max_examples=3000, deadline=None)
@given(_GCODE_TEXT)
def test_the_reading_is_parser_cpp(text: str) -> None:
    assert library_reading(text) == reference_parse(text)
    assert command_code(text) == parse_gcode(text).code


@settings(max_examples=1500, deadline=None)
@given(
    st.tuples(
        st.sampled_from(["", " ", "  "]),
        st.sampled_from(["M", "m", "G", "T", "g"]),
        st.sampled_from(["", " ", "0", "00"]),
        st.sampled_from(["104", "140", "109", "1", "0", "65640", "117", "105"]),
        st.lists(
            st.tuples(
                st.sampled_from(["", " "]),
                st.sampled_from("SRBTEXsrbtex"),
                st.sampled_from(["", " "]),
                st.sampled_from(["200", "-5", "280", "2e5", ".5", "+7", "abc", "65816", "1.5.3", ""]),
            ),
            max_size=4,
        ),
    ),
)
def test_the_simulator_runs_what_the_library_read(
    parts: tuple[str, str, str, str, list[tuple[str, str, str, str]]],
) -> None:
    """The bytes the client writes for a command (numbered, checksummed) go through the simulated board's intake
    (queue.cpp) into its parser: the command it runs is the one the library read from the text."""
    lead, letter, zeros, number, words = parts
    text = lead + letter + zeros + number + "".join("".join(word) for word in words)
    try:
        command = validate_command(text)
    except ValueError:
        return
    printer = SimulatedPrinter(
        SimulatorConfig(motion_time_scale=0.0, command_time_s=0.0, report_time_s=0.0), boot=False
    )
    printer.receive(encode_command("M110 N0", 0), 0.0)
    printer.receive(encode_command(command, 1), 0.0)
    ran = list(printer.executed)[-1]
    assert command_code(ran) == parse_gcode(command).code
    assert library_reading(ran) == library_reading(command)


# Every spelling the issue found getting past the old check, and more that Marlin reads as a target.
SPELLINGS = [
    ("M104S280", "hotend"),
    ("M109S270", "hotend"),
    ("M140S200", "bed"),
    ("M0104 S250", "hotend"),
    ("T0 M104 S1000", "hotend"),
    ("M104 B1000", "hotend"),
    ("m104 s280", "hotend"),
    ("M 104 S 280", "hotend"),
    ("M104 S100 S280", "hotend"),
    ("M65640 S280", "hotend"),
    ("M104 S65816", "hotend"),
    ("M104.1 S280", "hotend"),
    ("M190 R200", "bed"),
    ("M303 E0 S300 C8", "hotend"),
    ("M303 E-1 S150 C8", "bed"),
    ("M145 S0 H300 B60", "hotend"),
    ("M141 S90", "chamber"),
    ("M104 S-5", "hotend"),
    ("M140 S-5", "bed"),
    ("M104 Sabc", "hotend"),
    ("G1 X10 M140 S200", "bed"),
]


@pytest.mark.parametrize(("spelling", "heater"), SPELLINGS)
def test_every_spelling_of_a_target_over_the_limit_is_refused(spelling: str, heater: str) -> None:
    with pytest.raises(ValueError, match=heater) as caught:
        check_gcode_targets(spelling, HeaterLimits(240.0, 100.0, 60.0))
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize(
    "command",
    ["M104 S200", "M104S200", "m140 s60", "M109 R180", "M104 T1 S210", "G1 X300 E5", "M106 S255", "M117 S999 text"],
)
def test_targets_within_the_limit_and_other_commands_pass(command: str) -> None:
    check_gcode_targets(command, HeaterLimits(250.0, 100.0, 60.0))


def test_an_all_metal_hotend_is_a_higher_limit_not_a_way_around() -> None:
    check_gcode_targets("M104 S285", HeaterLimits(300.0, 100.0, 60.0))
    with pytest.raises(ValueError, match="above the limit of 300"):
        check_gcode_targets("M104S310", HeaterLimits(300.0, 100.0, 60.0))


_TARGET_LINE = st.tuples(
    st.sampled_from(["M104", "m104", "M0104", "M65640", "M140", "m0140", "M141", "T0 M104", "M 104"]),
    st.lists(
        st.tuples(
            st.sampled_from(["", " "]),
            st.sampled_from("SRBTsrbt"),
            st.sampled_from(["", " "]),
            st.sampled_from(["0", "45", "55", "99", "100", "101", "150", "249", "260", "65816", "-65436", "1e9"]),
        ),
        min_size=1,
        max_size=3,
    ),
)


def _targets(printer: SimulatedPrinter) -> dict[str, float]:
    printer.receive(b"M105\n", 0.0)
    report = printer.take_output().decode("latin-1").splitlines()[-1]
    return {key: float(target) for key, target in re.findall(r"([TBC]):[-0-9.]+ /([-0-9.]+)", report)}


@settings(max_examples=1500, deadline=None)
@given(_TARGET_LINE)
def test_no_line_that_passes_the_check_leaves_a_target_over_the_limit(
    parts: tuple[str, list[tuple[str, str, str, str]]],
) -> None:
    """Whatever the spelling, a line the check lets through leaves the simulated board (which reads values as
    Marlin's `value_celsius` does, 16 bits and all) with every target within the limits."""
    code, words = parts
    line = code + "".join("".join(word) for word in words)
    limits = HeaterLimits(100.0, 50.0, 40.0)  # under the simulated heaters' own caps, so these are what holds
    try:
        check_gcode_targets(line, limits)
    except ValueError:
        return
    printer = SimulatedPrinter(
        SimulatorConfig(motion_time_scale=0.0, has_chamber=True, command_time_s=0.0, report_time_s=0.0), boot=False
    )
    printer.receive(encode_command(line), 0.0)
    targets = _targets(printer)
    assert targets["T"] <= limits.hotend
    assert targets["B"] <= limits.bed
    assert targets.get("C", 0.0) <= limits.chamber
