"""What the service remembers for clients that join later: readings at two resolutions, and console lines.

The last minutes are kept at the full rate (every reading the poller took); older ones at one a second, for
hours. Both are ring buffers: memory stays flat however long the service runs (at 10 Hz, 5 minutes is 3,000
readings and 6 hours at 1 Hz is 21,600; a reading is a few hundred bytes).

A `history` answer is hundreds of kilobytes of JSON, and encoding it whole took a quarter of a second of the
service's one event loop (3,000 readings): a client asking again and again held every other client and the print.
So each reading and console line is encoded once, the first time an answer carries it, and kept with it; an answer
is then a join of bytes already made (a few milliseconds), however often and by however many clients it is asked.
What has not been encoded yet is, in slices of `ENCODE_SLICE` with the loop let go between them: the first answer
after a quiet hour takes longer, but holds nobody else for more than a slice.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from marlin_aio.protocol import TemperatureReading
from marlin_aio.protocol.rpc import reading_to_json

__all__ = ["ConsoleLine", "History"]

T = TypeVar("T")

#: Values encoded between two turns of the loop (a few milliseconds' work).
ENCODE_SLICE = 100


@dataclass(frozen=True, slots=True)
class ConsoleLine:
    """One line of a printer's console: a command sent (`direction` ">"), a line of its reply ("<"), or a note of
    the service's own ("!": connected, lost, a print started or ended)."""

    direction: str
    text: str
    time_s: float = field(default_factory=time.time)


class _Kept(Generic[T]):
    """A value kept, with its JSON once an answer needed it (never before: most are never asked for)."""

    __slots__ = ("encoded", "value")

    def __init__(self, value: T) -> None:
        self.value = value
        self.encoded: bytes | None = None


async def _json_array(kept: list[_Kept[T]], to_json: Callable[[T], Any]) -> bytes:
    parts = []
    made = 0
    for entry in kept:
        encoded = entry.encoded
        if encoded is None:
            # As `rpc.encode_message` writes it: compact, ASCII, no NaN.
            encoded = json.dumps(to_json(entry.value), separators=(",", ":"), allow_nan=False).encode("ascii")
            entry.encoded = encoded
            made += 1
            if made % ENCODE_SLICE == 0:
                await asyncio.sleep(0)  # let the loop serve others between slices
        parts.append(encoded)
    return b"[" + b",".join(parts) + b"]"


def _line_to_json(line: ConsoleLine) -> dict[str, Any]:
    return {"direction": line.direction, "text": line.text, "time_s": line.time_s}


class History:
    """A printer's recent readings and console lines.

    Args:
        recent_s: how far back every reading is kept.
        long_s: how far back one reading a second is kept.
        console_lines: how many console lines are kept.
    """

    def __init__(self, *, recent_s: float = 300.0, long_s: float = 6 * 3600.0, console_lines: int = 500) -> None:
        self.recent_s = recent_s
        self.long_s = long_s
        # The first reading of each second is in both buffers as one `_Kept`: encoded once for both.
        self._recent: deque[_Kept[TemperatureReading]] = deque()
        self._long: deque[_Kept[TemperatureReading]] = deque(maxlen=max(1, int(long_s)))
        self._last_second: int | None = None
        self._console: deque[_Kept[ConsoleLine]] = deque(maxlen=console_lines)

    def add(self, reading: TemperatureReading) -> None:
        """Keep `reading`: in the recent buffer always, in the long one if it is the first of its second."""
        kept = _Kept(reading)
        self._recent.append(kept)
        horizon = reading.wall_time_s - self.recent_s
        while self._recent and self._recent[0].value.wall_time_s < horizon:
            self._recent.popleft()
        second = int(reading.wall_time_s)
        if second != self._last_second:
            self._last_second = second
            self._long.append(kept)

    def note(self, direction: str, text: str) -> None:
        """Keep one console line."""
        self._console.append(_Kept(ConsoleLine(direction, text)))

    @property
    def console(self) -> list[ConsoleLine]:
        """The console lines kept, oldest first."""
        return [kept.value for kept in self._console]

    def readings(self, seconds: float, now_s: float | None = None) -> list[TemperatureReading]:
        """The readings of the last `seconds`, oldest first: one a second before the recent window, every one in it."""
        return [kept.value for kept in self._kept_readings(seconds, now_s)]

    async def readings_json(self, seconds: float, limit: int, now_s: float | None = None) -> bytes:
        """`readings(seconds)` as a JSON array of `rpc.reading_to_json`, evenly thinned to at most `limit`."""
        kept = self._kept_readings(seconds, now_s)
        if len(kept) > limit:
            step = len(kept) / limit
            kept = [kept[int(index * step)] for index in range(limit)]
        return await _json_array(kept, reading_to_json)

    async def console_json(self) -> bytes:
        """The console lines as a JSON array of `{"direction", "text", "time_s"}`."""
        return await _json_array(list(self._console), _line_to_json)

    def _kept_readings(self, seconds: float, now_s: float | None) -> list[_Kept[TemperatureReading]]:
        now_s = time.time() if now_s is None else now_s
        since = now_s - seconds
        recent_start = self._recent[0].value.wall_time_s if self._recent else now_s
        older = [kept for kept in self._long if since <= kept.value.wall_time_s < recent_start]
        return older + [kept for kept in self._recent if kept.value.wall_time_s >= since]

    def __len__(self) -> int:
        return len(self._recent) + len(self._long)
