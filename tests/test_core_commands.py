"""Command encoding: checksums as real Marlin accepted them, validation before anything is written, targets."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.commands import (
    DEFAULT_MAX_BED_CELSIUS,
    DEFAULT_MAX_HOTEND_CELSIUS,
    MAX_COMMAND_BYTES,
    check_target,
    checksum,
    command_code,
    encode_command,
    format_celsius,
    number_command,
    strip_comment,
)

# Every numbered line the captured Marlin 2.1 accepted (session-basic.log), and the doc's example.
ACCEPTED_LINES = [
    "N1 M105*38",
    "N0 M110 N0*125",
    "N1 G1 X10 Y10 F3000*77",
    "N2 G1 X20 Y20 Z5*100",
    "N3 G1 X50 Y30*44",
    "N4 M400*35",
    "N5 M114*34",
    "N6 G1 X60 Y40*45",
    "N7 G1 X65*84",
    "N8 G1 X70*95",
]


@pytest.mark.parametrize("line", ACCEPTED_LINES)
def test_checksum_matches_captures(line: str) -> None:
    body, _, value = line.partition("*")
    assert checksum(body.encode("ascii")) == int(value)


@pytest.mark.parametrize("line", ACCEPTED_LINES)
def test_number_command_matches_captures(line: str) -> None:
    number, _, rest = line.partition(" ")
    command = rest.partition("*")[0]
    assert number_command(command, int(number[1:])) == line
    assert encode_command(command, int(number[1:])) == line.encode("ascii") + b"\n"


def test_checksum_rejected_by_marlin_differs() -> None:
    # The capture's deliberately wrong line: `N6 G1 X60 Y40*46` got `Error:checksum mismatch`.
    assert checksum(b"N6 G1 X60 Y40") != 46


def test_checksum_of_nothing() -> None:
    assert checksum(b"") == 0


def test_number_command_rejects_negative_line_numbers() -> None:
    with pytest.raises(ValueError, match="negative"):
        number_command("M105", -1)


def test_encode_unnumbered() -> None:
    assert encode_command("M105") == b"M105\n"
    assert encode_command("  G28  ") == b"G28\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("G28 ; home all", "G28"),
        ("M104 S200;comment", "M104 S200"),
        ("M117 hello ; *99", "M117 hello"),
        (";only a comment then G1", ""),
        ("G1 X1", "G1 X1"),
    ],
)
def test_strip_comment(text: str, expected: str) -> None:
    assert strip_comment(text) == expected


def test_comment_stripped_before_numbering() -> None:
    # A `*checksum` after a `;` would be lost to Marlin's comment stripping: the comment must go first.
    assert encode_command("M105 ; poll", 1) == b"N1 M105*38\n"
    assert encode_command("M105;*0", 1) == b"N1 M105*38\n"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("M105\nM105", "line break"),
        ("M105\n", "line break"),
        ("M105\rG28", "line break"),
        ("M117 a\x00b", "NUL"),
        ("M117 caf\u00e9", "non-ASCII"),
        ("M117 \u20ac", "non-ASCII"),
        ("", "empty"),
        ("   ", "empty"),
        ("; just a comment", "empty"),
        ("  ;", "empty"),
    ],
)
@pytest.mark.parametrize("line_number", [None, 7])
def test_encode_rejects(text: str, problem: str, line_number: int | None) -> None:
    with pytest.raises(ValueError, match=problem):
        encode_command(text, line_number)


def test_encode_rejects_over_95_bytes_once_numbered() -> None:
    fits = "M117 " + "A" * 83 + "Z"  # numbered: "N1 " + 89 bytes + "*30" = 95 bytes
    numbered = number_command(fits, 1)
    assert len(numbered) == MAX_COMMAND_BYTES
    assert encode_command(fits, 1) == numbered.encode("ascii") + b"\n"
    too_long = fits + "Z"
    assert len(too_long) <= MAX_COMMAND_BYTES  # fits without a number...
    assert encode_command(too_long) == too_long.encode("ascii") + b"\n"
    with pytest.raises(ValueError, match=r"is 96 bytes, longer than Marlin's 95-byte limit"):
        encode_command(too_long, 1)  # ...but not once numbered
    with pytest.raises(ValueError, match="95-byte limit"):
        encode_command(fits, 10)  # a longer line number is enough to push it over


def test_encode_rejects_over_95_bytes_unnumbered() -> None:
    assert encode_command("M117 " + "A" * 90) == b"M117 " + b"A" * 90 + b"\n"
    with pytest.raises(ValueError, match="95-byte limit"):
        encode_command("M117 " + "A" * 91)


def test_comment_does_not_count_towards_the_limit() -> None:
    assert encode_command("G28 ; " + "x" * 200, 3) == b"N3 G28*" + str(checksum(b"N3 G28")).encode() + b"\n"


@settings(max_examples=200, deadline=None)
@given(
    st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters=";*"), max_size=60),
    st.integers(min_value=0, max_value=10**6),
)
def test_encoded_line_carries_its_own_checksum(text: str, line_number: int) -> None:
    if not text.strip():
        with pytest.raises(ValueError, match="empty"):
            encode_command(text, line_number)
        return
    wire = encode_command(text, line_number)
    assert wire.endswith(b"\n")
    assert wire.count(b"\n") == 1
    body, _, value = wire[:-1].rpartition(b"*")
    assert body == f"N{line_number} {text.strip()}".encode()
    assert checksum(body) == int(value)
    assert len(wire) - 1 <= MAX_COMMAND_BYTES


@pytest.mark.parametrize(
    ("text", "code"),
    [("m105 t0", "M105"), ("N12 G1 X1", "G1"), ("n3 m110 n0", "M110"), ("", ""), ("   ", ""), ("N5", "")],
)
def test_command_code(text: str, code: str) -> None:
    assert command_code(text) == code


# ----------------------------------------------------------------------------------------------- targets


@pytest.mark.parametrize(
    ("value", "expected"),
    [(200, 200.0), (0, 0.0), (60.5, 60.5), ("215", 215.0), (" 42.5 ", 42.5), (DEFAULT_MAX_HOTEND_CELSIUS, 260.0)],
)
def test_check_target_accepts(value: object, expected: float) -> None:
    assert check_target("hotend", value, DEFAULT_MAX_HOTEND_CELSIUS) == expected


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        ("abc", "must be a number"),
        ("", "must be a number"),
        (None, "must be a number"),
        ([200], "must be a number"),
        (True, "must be a number"),
        (False, "must be a number"),
        (math.nan, "finite"),
        ("nan", "finite"),
        (math.inf, "finite"),
        (-math.inf, "finite"),
        ("inf", "finite"),
        (-1, "negative"),
        (-0.01, "negative"),
        (260.01, "above the limit of 260"),
        (1000, "above the limit of 260"),
    ],
)
def test_check_target_rejects(value: object, problem: str) -> None:
    with pytest.raises(ValueError, match=problem) as raised:
        check_target("hotend", value, DEFAULT_MAX_HOTEND_CELSIUS)
    assert "hotend" in str(raised.value)


def test_check_target_limit_is_per_heater() -> None:
    assert check_target("bed", 140, DEFAULT_MAX_BED_CELSIUS) == 140.0
    with pytest.raises(ValueError, match=r"bed target 141 C is above the limit of 140 C"):
        check_target("bed", 141, DEFAULT_MAX_BED_CELSIUS)


def test_check_target_rejects_huge_int_with_value_error() -> None:
    with pytest.raises(ValueError, match="hotend"):
        check_target("hotend", 10**400, DEFAULT_MAX_HOTEND_CELSIUS)


@pytest.mark.parametrize(
    ("value", "text"),
    [(200.0, "200"), (200, "200"), (60.5, "60.5"), (0.0, "0"), (10.0, "10"), (100.0, "100"), (42.25, "42.25"),
     (42.256, "42.26"), (0.004, "0"), (1e6, "1000000")],
)  # fmt: skip
def test_format_celsius(value: float, text: str) -> None:
    assert format_celsius(value) == text


@settings(max_examples=200, deadline=None)
@given(st.integers(min_value=0, max_value=30_000))
def test_format_celsius_round_trips_hundredths(centi: int) -> None:
    text = format_celsius(centi / 100)
    assert "e" not in text
    assert float(text) == centi / 100
    assert not text.endswith(("0", ".")) or "." not in text


def test_a_star_inside_a_command_is_rejected() -> None:
    # Marlin takes the first `*` as the checksum marker, so such a line could never be accepted.
    with pytest.raises(ValueError, match="reserves for the checksum"):
        encode_command("M117 a*b", 5)
