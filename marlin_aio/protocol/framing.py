"""Splitting the byte stream from the printer into lines.

Marlin ends lines with `\\n`; some boards send `\\r\\n`, and noise can hold a lone `\\r`. All three end a line, and
a chunk may be cut anywhere (even between `\\r` and `\\n`): feeding the same bytes in any chunks gives the same lines.
Bytes that are not UTF-8, and NUL bytes, become U+FFFD so nothing downstream ever has to deal with a decode error.
"""

from __future__ import annotations

from marlin_aio.protocol.events import OverlongLine

__all__ = ["DEFAULT_MAX_LINE_BYTES", "LineSplitter"]

#: Marlin's longest lines (M115, M503 settings) are a few hundred bytes; 4 KiB leaves room and bounds memory.
DEFAULT_MAX_LINE_BYTES = 4096


def _decode(raw: bytes) -> str:
    text = raw.decode("utf-8", errors="replace")
    return text.replace("\x00", "\ufffd") if "\x00" in text else text


class LineSplitter:
    """Turn chunks of bytes into complete lines (without their line ending). Empty lines are skipped.

    A line longer than `max_line_bytes` is not kept whole: it yields one `OverlongLine` holding its first
    `max_line_bytes` bytes, and the rest of it is discarded as it arrives.
    """

    __slots__ = ("_buffer", "_discarding", "_max", "_overlong_head", "_skip_lf")

    def __init__(self, max_line_bytes: int = DEFAULT_MAX_LINE_BYTES) -> None:
        if max_line_bytes < 1:
            raise ValueError(f"max_line_bytes must be at least 1, got {max_line_bytes}")
        self._max = max_line_bytes
        self._buffer = b""
        self._skip_lf = False  # the last chunk ended in \r: a \n starting the next one belongs to it
        self._discarding = 0  # >0 while skipping the rest of an overlong line: bytes seen so far
        self._overlong_head = b""

    def feed(self, data: bytes) -> list[str | OverlongLine]:
        """Add bytes; return the lines they complete, in order."""
        if self._skip_lf:
            self._skip_lf = False
            if data[:1] == b"\n":
                data = data[1:]
        if not data:
            return []
        if b"\r" in data:
            self._skip_lf = data.endswith(b"\r")
            data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        buffer = self._buffer + data if self._buffer else data
        parts = buffer.split(b"\n")
        tail = parts.pop()
        out: list[str | OverlongLine] = []
        for raw in parts:
            if self._discarding:
                out.append(self._finish_overlong(len(raw)))
            elif len(raw) > self._max:
                out.append(OverlongLine(head=_decode(raw[: self._max]), length=len(raw)))
            elif raw:
                out.append(_decode(raw))
        if self._discarding:
            self._discarding += len(tail)
            tail = b""
        elif len(tail) > self._max:
            # Keep only the head; count the rest without storing it.
            self._discarding = len(tail)
            self._overlong_head = tail[: self._max]
            tail = b""
        self._buffer = tail
        return out

    def _finish_overlong(self, extra: int) -> OverlongLine:
        line = OverlongLine(head=_decode(self._overlong_head), length=self._discarding + extra)
        self._discarding = 0
        self._overlong_head = b""
        return line

    def clear(self) -> None:
        """Forget any unfinished line (after the input was flushed, its rest will never come)."""
        self._buffer = b""
        self._skip_lf = False
        self._discarding = 0
        self._overlong_head = b""

    @property
    def idle(self) -> bool:
        """True between lines: nothing of an unfinished line is held, skipped or discarded."""
        return not self._buffer and not self._skip_lf and not self._discarding

    @property
    def max_line_bytes(self) -> int:
        """The longest line kept whole."""
        return self._max

    @property
    def pending_bytes(self) -> int:
        """How many bytes of an unfinished line are held (for diagnostics)."""
        return len(self._buffer)
