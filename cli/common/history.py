"""One heater's readings for the watch chart: the last minute as read, and hours of them downsampled.

Readings come at up to 100 Hz for as long as `watch` runs, and the chart shows from one minute to hours of them,
redrawn once a second. So a heater's history has two parts:

- `raw`: the readings of the last `RAW_S` seconds as they came (and at most `RAW_LIMIT` of them, whatever the
  poll rate), for the one-minute chart, the heating rate and the latest values;
- three levels of buckets, 1 s, 10 s and 60 s wide, `BUCKETS` of each kept (12 min, 2 h, 12 h): each bucket holds
  the lowest and highest actual temperature in it, its last target and the time of its last reading. Only the
  1 s level sees each reading; a bucket that closes is folded into the next level up (once a second at most), so
  adding a reading costs a comparison or two and no allocation, except the raw tuple and one tuple a second.

Memory is bounded whatever the rate and however long it runs: at most `RAW_LIMIT` raw tuples (6,000 at 100 Hz)
and 3 x `BUCKETS` bucket tuples per heater: about 1 MB a heater at 100 Hz, 1.8 MB at worst (measured with
tracemalloc; `tests/test_cli_watch_history.py` checks the counts and that a full history no longer grows).

The chart asks `points(start_s, column_s)`: the coarsest source whose buckets are no wider than one column of the
chart (so nothing is lost to the eye) that still reaches back to `start_s`, plus the open buckets up to now.
A bucket comes out as two points at its last reading's time, its lowest and its highest, so a column of the chart
spans them.
"""

from __future__ import annotations

from collections import deque

__all__ = ["BUCKETS", "LEVELS_S", "RAW_LIMIT", "RAW_S", "HeaterHistory", "Point"]

#: (time in s, actual C, target C or None): a reading, or one end of a bucket's range, as `Curve` takes them.
Point = tuple[float, float, float | None]

RAW_S = 60.0
#: 200 Hz for the whole raw minute; above that the oldest raw readings go early (the buckets still hold them).
RAW_LIMIT = 12_000
LEVELS_S = (1.0, 10.0, 60.0)
BUCKETS = 720  # of each level: 12 min of 1 s, 2 h of 10 s, 12 h of 60 s


class _Level:
    """Buckets `bucket_s` wide: the closed ones (the last `BUCKETS`) and the one being filled."""

    __slots__ = ("bucket_s", "closed", "dropped", "end_s", "high", "low", "target", "time_s")

    def __init__(self, bucket_s: float) -> None:
        self.bucket_s = bucket_s
        # (time of the last reading, lowest, highest, last target) per bucket
        self.closed: deque[tuple[float, float, float, float | None]] = deque(maxlen=BUCKETS)
        self.dropped = False  # a bucket has fallen off the front: the level no longer holds everything
        self.end_s = float("-inf")  # where the open bucket ends; -inf: none open yet
        self.time_s = 0.0
        self.low = 0.0
        self.high = 0.0
        self.target: float | None = None

    def fold(
        self, time_s: float, low: float, high: float, target: float | None
    ) -> tuple[float, float, float, float | None] | None:
        """Add a reading (low == high) or a closed bucket of the level below; return the bucket this closed."""
        closed = None
        if time_s >= self.end_s:
            if self.end_s != float("-inf"):
                closed = (self.time_s, self.low, self.high, self.target)
                if len(self.closed) == BUCKETS:
                    self.dropped = True
                self.closed.append(closed)
            # Aligned on the clock, so each bucket of a level lies within one bucket of the level above.
            self.end_s = (time_s // self.bucket_s + 1) * self.bucket_s
            self.low, self.high = low, high
        else:
            if low < self.low:
                self.low = low
            if high > self.high:
                self.high = high
        self.time_s = time_s
        self.target = target
        return closed

    def reaches(self, start_s: float) -> bool:
        """Whether this level holds everything from `start_s` on."""
        return not self.dropped or (bool(self.closed) and self.closed[0][0] <= start_s)

    def open_points(self) -> list[Point]:
        """The open bucket as points (none before the first reading)."""
        if self.end_s == float("-inf"):
            return []
        return [(self.time_s, self.low, self.target), (self.time_s, self.high, self.target)]


class HeaterHistory:
    """One heater's readings: the last minute as read, and up to 12 hours in min/max buckets (module docstring)."""

    __slots__ = ("_levels", "raw")

    def __init__(self) -> None:
        #: (time, actual, target) of the last `RAW_S` seconds, oldest first
        self.raw: deque[Point] = deque(maxlen=RAW_LIMIT)
        self._levels = tuple(_Level(bucket_s) for bucket_s in LEVELS_S)

    def add(self, time_s: float, actual: float, target: float | None) -> None:
        """Record a reading (in time order)."""
        raw = self.raw
        raw.append((time_s, actual, target))
        horizon = time_s - RAW_S
        while raw[0][0] < horizon:
            raw.popleft()
        closed = self._levels[0].fold(time_s, actual, actual, target)
        if closed is not None:  # once a second at most
            for level in self._levels[1:]:
                closed = level.fold(*closed)
                if closed is None:
                    break

    def points(self, start_s: float, column_s: float) -> list[Point]:
        """The readings from `start_s` on for a chart whose columns are `column_s` seconds wide: as read, or in
        the widest buckets no wider than a column (wider ones where the narrower no longer reach `start_s`)."""
        raw = self.raw
        if column_s < LEVELS_S[0] and raw and (len(raw) < RAW_LIMIT or raw[0][0] <= start_s):
            return [point for point in raw if point[0] >= start_s]
        chosen = 0
        for index, level in enumerate(self._levels):
            if level.bucket_s <= column_s or not self._levels[chosen].reaches(start_s):
                chosen = index
        points: list[Point] = []
        for time_s, low, high, target in self._levels[chosen].closed:
            if time_s >= start_s:
                points.append((time_s, low, target))
                points.append((time_s, high, target))
        # The open buckets, coarsest first: each covers the time after the closed buckets of the level above it.
        for level in reversed(self._levels[: chosen + 1]):
            points += level.open_points()
        return points

    def bucket_counts(self) -> tuple[int, ...]:
        """How many closed buckets each level holds (1 s, 10 s, 60 s): for tests of the memory bound."""
        return tuple(len(level.closed) for level in self._levels)
