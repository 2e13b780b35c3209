"""One direction of a UART, as a schedule: bytes put in at some moment come out no faster than the baud rate.

A byte takes `byte_s` seconds on the wire (10 bits with start and stop bit: 40 us at 250000 baud) and the wire
carries one byte at a time, so the k-th byte of a chunk put in at `now` has arrived at
`max(when the wire was free, now) + k * byte_s`. `Wire` keeps that schedule for the bytes still under way and
hands out, at any later moment, everything that has arrived by then. It never reads a clock itself: the caller
passes the time, which keeps it testable without waiting and lets the server use real time while the printer
runs on simulated time.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["BITS_PER_BYTE", "Wire"]

#: 8N1 framing: a start bit, eight data bits, a stop bit.
BITS_PER_BYTE = 10


class _Segment:
    """Bytes put in together: byte k (from 1) has arrived at `start + k * byte_s`; `taken` are handed out."""

    __slots__ = ("data", "start", "taken")

    def __init__(self, start: float, data: bytes) -> None:
        self.start = start
        self.data = data
        self.taken = 0


class Wire:
    """Bytes in flight on one direction of a serial line."""

    __slots__ = ("_free_at", "_pending", "_segments", "byte_s")

    def __init__(self, baud_rate: int) -> None:
        """A wire at `baud_rate` bits per second.

        Raises:
            ValueError: if `baud_rate` is not positive.
        """
        if baud_rate <= 0:
            raise ValueError(f"baud_rate must be positive, got {baud_rate}")
        self.byte_s = BITS_PER_BYTE / baud_rate
        """Seconds one byte takes on the wire."""
        self._segments: deque[_Segment] = deque()
        self._free_at = -math.inf
        self._pending = 0

    @property
    def pending(self) -> int:
        """Bytes put in that have not been taken out yet."""
        return self._pending

    def put(self, data: bytes, now: float) -> None:
        """Start sending `data` at `now`, behind whatever is still on the wire."""
        if not data:
            return
        start = max(self._free_at, now)
        self._segments.append(_Segment(start, data))
        self._free_at = start + len(data) * self.byte_s
        self._pending += len(data)

    def take(self, now: float) -> bytes:
        """Return every byte that has fully arrived by `now` (possibly none), in order."""
        segments = self._segments
        taken: list[bytes] = []
        while segments:
            segment = segments[0]
            # A millionth of a byte time of slack, so that float rounding does not hold the last byte of a
            # burst back for another call when the caller comes exactly when it said it would.
            arrived = min(math.floor((now - segment.start) / self.byte_s + 1e-6), len(segment.data))
            if arrived > segment.taken:
                # Sliced from an offset, so a large read handed out a little at a time is not copied each time.
                taken.append(segment.data[segment.taken : arrived])
                segment.taken = arrived
            if arrived < len(segment.data):
                break
            segments.popleft()
        out = b"".join(taken)
        self._pending -= len(out)
        return out

    def next_arrival(self) -> float | None:
        """When the next byte will have arrived, or None when nothing is under way."""
        if not self._segments:
            return None
        segment = self._segments[0]
        return segment.start + (segment.taken + 1) * self.byte_s

    def last_arrival(self) -> float | None:
        """When the last byte under way will have arrived, or None when nothing is under way."""
        return self._free_at if self._segments else None

    def due(self, now: float, interval_s: float) -> float | None:
        """When to call `take()` next, batching a busy wire into one call per `interval_s`.

        The end of a burst is taken the moment it arrives (a short reply is not held back), and a long one
        piece by piece, at most every `interval_s`.
        """
        first = self.next_arrival()
        if first is None:
            return None
        return min(self._free_at, max(first, now + interval_s))

    def delay(self, seconds: float) -> None:
        """Hold everything still under way back by `seconds`, as if the line had stopped for that long."""
        if not self._segments or seconds <= 0:
            return
        for segment in self._segments:
            segment.start += seconds
        self._free_at += seconds

    def clear(self) -> None:
        """Forget everything under way (the cable was pulled)."""
        self._segments.clear()
        self._free_at = -math.inf
        self._pending = 0
