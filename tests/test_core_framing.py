"""LineSplitter: bytes in any chunking give the same lines; line endings, bad bytes and overlong lines.

Every fixed case runs three ways, as h11's tests do: fed whole, fed byte by byte, and followed by a partial line
that must stay pending until its newline arrives.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.events import OverlongLine
from marlin_aio.protocol.wire import DEFAULT_MAX_LINE_BYTES, LineSplitter

Piece = str | OverlongLine


def feed_whole(splitter: LineSplitter, data: bytes) -> list[Piece]:
    return splitter.feed(data)


def feed_bytewise(splitter: LineSplitter, data: bytes) -> list[Piece]:
    out: list[Piece] = []
    for index in range(len(data)):
        out.extend(splitter.feed(data[index : index + 1]))
    return out


def feed_chunks(splitter: LineSplitter, data: bytes, cuts: list[int]) -> list[Piece]:
    out: list[Piece] = []
    start = 0
    for cut in [*sorted(set(cuts)), len(data)]:
        out.extend(splitter.feed(data[start:cut]))
        start = cut
    return out


FEEDERS: dict[str, Callable[[LineSplitter, bytes], list[Piece]]] = {
    "whole": feed_whole,
    "bytewise": feed_bytewise,
}

# (bytes on the wire, lines expected)
CASES: list[tuple[bytes, list[Piece]]] = [
    (b"ok\n", ["ok"]),
    (b"ok\nok P15 B3\n", ["ok", "ok P15 B3"]),
    (b"ok\r\nstart\r\n", ["ok", "start"]),
    (b"ok\rstart\r", ["ok", "start"]),
    (b"ok\r\n\r\nstart\n", ["ok", "start"]),
    (b"\n\n\r\n\r\rok\n\n", ["ok"]),
    (b" T:21.30 /0.00 B:20.00 /0.00 @:0 B@:0\n", [" T:21.30 /0.00 B:20.00 /0.00 @:0 B@:0"]),
    (b"a\nb\r\nc\rd\n", ["a", "b", "c", "d"]),
    (b"ab\xffcd\n", ["ab\ufffdcd"]),
    (b"a\x00b\n", ["a\ufffdb"]),
    (b"\x00\n", ["\ufffd"]),
    (b"caf\xc3\xa9 \xe2\x82\xac\n", ["caf\u00e9 \u20ac"]),
    (b"\xc3\n", ["\ufffd"]),  # a multi-byte sequence cut by the line end
]


@pytest.mark.parametrize("feeder", FEEDERS.values(), ids=FEEDERS.keys())
@pytest.mark.parametrize(("data", "expected"), CASES)
def test_lines(data: bytes, expected: list[Piece], feeder: Callable[[LineSplitter, bytes], list[Piece]]) -> None:
    splitter = LineSplitter()
    assert feeder(splitter, data) == expected
    assert splitter.pending_bytes == 0


@pytest.mark.parametrize("feeder", FEEDERS.values(), ids=FEEDERS.keys())
@pytest.mark.parametrize(("data", "expected"), CASES)
def test_trailing_partial_line_stays_pending(
    data: bytes, expected: list[Piece], feeder: Callable[[LineSplitter, bytes], list[Piece]]
) -> None:
    splitter = LineSplitter()
    assert feeder(splitter, data + b"ok T:2") == expected
    assert splitter.pending_bytes == len(b"ok T:2")
    assert splitter.feed(b"") == []
    assert splitter.feed(b"1.5") == []
    assert splitter.feed(b"\n") == ["ok T:21.5"]
    assert splitter.pending_bytes == 0


def test_cr_at_chunk_end_then_lf_in_next_chunk_ends_one_line() -> None:
    splitter = LineSplitter()
    assert splitter.feed(b"ok\r") == ["ok"]
    assert splitter.pending_bytes == 0
    assert splitter.feed(b"\nstart\r") == ["start"]
    assert splitter.feed(b"\n") == []
    assert splitter.feed(b"echo:x\r\n") == ["echo:x"]
    assert splitter.pending_bytes == 0


def test_lone_cr_in_next_chunk_is_not_swallowed() -> None:
    splitter = LineSplitter()
    assert splitter.feed(b"ok\r") == ["ok"]
    # Only a \n directly after the \r belongs to it; anything else is the next line.
    assert splitter.feed(b"start\n") == ["start"]


def test_utf8_sequence_split_across_chunks_decodes_whole() -> None:
    splitter = LineSplitter()
    assert splitter.feed(b"\xe2\x82") == []
    assert splitter.feed(b"\xac\n") == ["\u20ac"]


def test_max_line_bytes_must_be_positive() -> None:
    with pytest.raises(ValueError, match="max_line_bytes"):
        LineSplitter(0)


def test_default_cap_holds_marlins_longest_lines() -> None:
    m115 = b"FIRMWARE_NAME:Marlin bugfix-2.1.x " + b"X" * 400
    assert DEFAULT_MAX_LINE_BYTES >= 1024
    assert LineSplitter().feed(m115 + b"\n") == [m115.decode()]


# ----------------------------------------------------------------------------------------------- overlong lines

OVERLONG_CASES: list[tuple[bytes, list[Piece]]] = [
    (b"abcdefgh\n", ["abcdefgh"]),  # exactly the cap: kept whole
    (b"abcdefghi\n", [OverlongLine(head="abcdefgh", length=9)]),
    (b"x" * 1000 + b"\nok\n", [OverlongLine(head="x" * 8, length=1000), "ok"]),
    (b"ok\n" + b"y" * 20 + b"\r\nstart\n", ["ok", OverlongLine(head="y" * 8, length=20), "start"]),
    (b"\xff" * 12 + b"\n", [OverlongLine(head="\ufffd" * 8, length=12)]),
]


@pytest.mark.parametrize("feeder", FEEDERS.values(), ids=FEEDERS.keys())
@pytest.mark.parametrize(("data", "expected"), OVERLONG_CASES)
def test_overlong_lines(
    data: bytes, expected: list[Piece], feeder: Callable[[LineSplitter, bytes], list[Piece]]
) -> None:
    splitter = LineSplitter(max_line_bytes=8)
    assert feeder(splitter, data) == expected
    assert splitter.pending_bytes == 0


@pytest.mark.parametrize("feeder", FEEDERS.values(), ids=FEEDERS.keys())
@pytest.mark.parametrize(("data", "expected"), OVERLONG_CASES)
def test_overlong_lines_with_trailing_partial(
    data: bytes, expected: list[Piece], feeder: Callable[[LineSplitter, bytes], list[Piece]]
) -> None:
    splitter = LineSplitter(max_line_bytes=8)
    assert feeder(splitter, data + b"ok N") == expected
    assert splitter.pending_bytes == 4
    assert splitter.feed(b"1\n") == ["ok N1"]


def test_overlong_line_is_not_buffered() -> None:
    splitter = LineSplitter(max_line_bytes=16)
    for _ in range(1000):
        assert splitter.feed(b"noise" * 10) == []
        assert splitter.pending_bytes <= 16
    assert splitter.feed(b"\nok\n") == [OverlongLine(head="noise" * 3 + "n", length=50_000), "ok"]
    assert splitter.pending_bytes == 0


def test_one_overlong_line_per_long_line() -> None:
    splitter = LineSplitter(max_line_bytes=4)
    out = feed_bytewise(splitter, b"0123456789\n")
    assert out == [OverlongLine(head="0123", length=10)]


# ----------------------------------------------------------------------------------------------- properties

_LINE_TEXT = st.text(
    alphabet=st.characters(codec="utf-8", exclude_characters="\r\n\x00"),
    min_size=1,
    max_size=40,
)
_ENDINGS = st.sampled_from([b"\n", b"\r\n", b"\r"])


@st.composite
def streams(draw: st.DrawFn) -> tuple[list[str], bytes, list[int]]:
    lines = draw(st.lists(_LINE_TEXT, max_size=12))
    data = b"".join(line.encode() + draw(_ENDINGS) for line in lines)
    cuts = draw(st.lists(st.integers(min_value=0, max_value=len(data)), max_size=12))
    return lines, data, cuts


@settings(max_examples=200, deadline=None)
@given(streams())
def test_any_chunking_gives_the_lines(stream: tuple[list[str], bytes, list[int]]) -> None:
    lines, data, cuts = stream
    assert LineSplitter().feed(data) == lines
    assert feed_chunks(LineSplitter(), data, cuts) == lines


@settings(max_examples=200, deadline=None)
@given(
    st.binary(max_size=200),
    st.lists(st.integers(min_value=0, max_value=200), max_size=10),
    st.integers(min_value=1, max_value=12),
)
def test_any_chunking_of_any_bytes_equals_feeding_whole(data: bytes, cuts: list[int], max_line_bytes: int) -> None:
    whole = LineSplitter(max_line_bytes).feed(data)
    cut = feed_chunks(LineSplitter(max_line_bytes), data, [c for c in cuts if c <= len(data)])
    assert cut == whole


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=64), max_size=8))
def test_any_bytes_give_only_clean_lines(chunks: list[bytes]) -> None:
    splitter = LineSplitter(max_line_bytes=32)
    for chunk in chunks:
        for piece in splitter.feed(chunk):
            if isinstance(piece, OverlongLine):
                assert piece.length > 32
                assert len(piece.head) <= 32  # the head is cut at 32 bytes, and a byte decodes to at most one character
                assert not set(piece.head) & {"\r", "\n", "\x00"}
            else:
                assert isinstance(piece, str)
                assert piece
                assert not set(piece) & {"\r", "\n", "\x00"}
        assert splitter.pending_bytes <= 32


def test_clear_forgets_an_unfinished_line() -> None:
    splitter = LineSplitter()
    assert splitter.feed(b"echo: Free Mem") == []
    splitter.clear()
    assert splitter.pending_bytes == 0
    assert splitter.feed(b"ok\n") == ["ok"]
