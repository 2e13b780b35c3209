"""What the service remembers for clients that join later: readings at two resolutions, and console lines.

The last minutes are kept at the full rate (every reading the poller took); older ones at one a second, for
hours. Both are ring buffers: memory stays flat however long the service runs (at 10 Hz, 5 minutes is 3,000
readings and 6 hours at 1 Hz is 21,600; a reading is a few hundred bytes).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

from marlin_aio.protocol import TemperatureReading

__all__ = ["ConsoleLine", "History"]


@dataclass(frozen=True, slots=True)
class ConsoleLine:
    """One line of a printer's console: a command sent (`direction` ">"), a line of its reply ("<"), or a note of
    the service's own ("!": connected, lost, a print started or ended)."""

    direction: str
    text: str
    time_s: float = field(default_factory=time.time)


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
        self._recent: deque[TemperatureReading] = deque()
        self._long: deque[TemperatureReading] = deque(maxlen=max(1, int(long_s)))
        self._last_second: int | None = None
        self.console: deque[ConsoleLine] = deque(maxlen=console_lines)

    def add(self, reading: TemperatureReading) -> None:
        """Keep `reading`: in the recent buffer always, in the long one if it is the first of its second."""
        self._recent.append(reading)
        horizon = reading.wall_time_s - self.recent_s
        while self._recent and self._recent[0].wall_time_s < horizon:
            self._recent.popleft()
        second = int(reading.wall_time_s)
        if second != self._last_second:
            self._last_second = second
            self._long.append(reading)

    def note(self, direction: str, text: str) -> None:
        """Keep one console line."""
        self.console.append(ConsoleLine(direction, text))

    def readings(self, seconds: float, now_s: float | None = None) -> list[TemperatureReading]:
        """The readings of the last `seconds`, oldest first: one a second before the recent window, every one in it."""
        now_s = time.time() if now_s is None else now_s
        since = now_s - seconds
        recent_start = self._recent[0].wall_time_s if self._recent else now_s
        older = [r for r in self._long if since <= r.wall_time_s < recent_start]
        return older + [r for r in self._recent if r.wall_time_s >= since]

    def __len__(self) -> int:
        return len(self._recent) + len(self._long)
