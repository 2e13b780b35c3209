"""What `watch` knows: a rolling window of readings per heater, and the figures derived from it.

Pure data, no I/O and no rich: the live view, the plain-line output and the tests all read the same numbers.
Readings arrive about every 10 ms, so adding one must be cheap: it appends to a deque and trims the front.
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass

from marlin_aio import HEATER_NAMES, TemperatureReading, heater_name

__all__ = ["HEATER_NAMES", "HeaterStatus", "LinkStats", "WatchModel", "heater_name"]


@dataclass(frozen=True, slots=True)
class HeaterStatus:
    """One heater's row: actual, target, power, rate and state, with an estimated time to target."""

    key: str
    name: str
    actual: float
    target: float | None
    power_percent: float | None
    rate_c_per_s: float | None
    state: str  # "heating", "cooling", "holding", "off"
    eta_s: float | None


@dataclass(frozen=True, slots=True)
class LinkStats:
    """The footer: how well the link is doing over the last window."""

    polls_per_s: float
    latency_median_ms: float | None
    latency_worst_ms: float | None
    readings: int
    timeouts: int
    errors: int


class WatchModel:
    """Readings of the last `window_s` seconds, per heater, and the figures `watch` shows.

    Args:
        window_s: how much history the chart shows.
        tolerance_c: a heater within this of its target is "holding".
        rate_window_s: the span the heating rate is measured over (short enough to follow, long enough to
            smooth the 0.01 C steps of M105).
    """

    def __init__(self, window_s: float = 60.0, tolerance_c: float = 2.0, rate_window_s: float = 3.0) -> None:
        self.window_s = window_s
        self.tolerance_c = tolerance_c
        self.rate_window_s = rate_window_s
        # time, actual, target per heater key: parallel tuples in one deque keep appends cheap
        self.series: dict[str, deque[tuple[float, float, float | None]]] = {}
        self._power: dict[str, int | None] = {}
        self._poll_times: deque[float] = deque()
        self._latencies: deque[tuple[float, float]] = deque()
        self.readings = 0
        self.timeouts = 0
        self.errors = 0
        self.latest_time: float | None = None

    def add(self, reading: TemperatureReading) -> None:
        """Record a reading (any source)."""
        now = reading.monotonic_s
        self.readings += 1
        self.latest_time = now
        horizon = now - self.window_s
        for key, heater in reading.temperatures.heaters.items():
            series = self.series.get(key)
            if series is None:
                series = self.series[key] = deque()
            series.append((now, heater.actual, heater.target))
            while series and series[0][0] < horizon:
                series.popleft()
            self._power[key] = heater.power
        if reading.source == "poll":
            self._poll_times.append(now)
            while self._poll_times and self._poll_times[0] < now - 1.0:
                self._poll_times.popleft()

    def add_latency(self, time_s: float, latency_s: float) -> None:
        """Record one command round trip (for the footer's median and worst)."""
        self._latencies.append((time_s, latency_s))
        while self._latencies and self._latencies[0][0] < time_s - self.window_s:
            self._latencies.popleft()

    def heater_keys(self) -> list[str]:
        """The heaters to show: the hotends first, then the others in the order the printer reports them.

        With several hotends Marlin reports the active one as `T` and then every one as `T0`, `T1`, ...: each of
        those is shown, in tool order where `T` stood, and `T` (a copy of one of them) is not.
        """
        keys = list(self.series)
        tools = sorted((k for k in keys if k[0] == "T" and k[1:].isdigit()), key=lambda k: int(k[1:]))
        if not tools:
            return keys
        return tools + [k for k in keys if k != "T" and k not in tools]

    def status(self, key: str) -> HeaterStatus:
        """The row for one heater."""
        series = self.series[key]
        now, actual, target = series[-1]
        rate = self._rate(series, now)
        power = self._power.get(key)
        power_percent = None if power is None else min(max(power / 127 * 100, 0.0), 100.0)
        if not target:
            state = "off" if rate is None or rate > -0.05 else "cooling"
            eta = None
        elif abs(actual - target) <= self.tolerance_c:
            state, eta = "holding", 0.0
        elif actual < target:
            state = "heating"
            eta = (target - actual) / rate if rate and rate > 0.01 else None
        else:
            state = "cooling"
            eta = (actual - target) / -rate if rate and rate < -0.01 else None
        return HeaterStatus(key, heater_name(key), actual, target, power_percent, rate, state, eta)

    def _rate(self, series: deque[tuple[float, float, float | None]], now: float) -> float | None:
        # Compare with the oldest sample inside the rate window; readings are in time order.
        start = now - self.rate_window_s
        first = None
        for sample in series:
            if sample[0] >= start:
                first = sample
                break
        if first is None or now - first[0] < 0.5:
            return None
        return (series[-1][1] - first[1]) / (now - first[0])

    def link(self) -> LinkStats:
        """Footer figures: polls in the last second, latency median and worst over the window."""
        latencies = [latency for _, latency in self._latencies]
        return LinkStats(
            polls_per_s=float(len(self._poll_times)),
            latency_median_ms=statistics.median(latencies) * 1000 if latencies else None,
            latency_worst_ms=max(latencies) * 1000 if latencies else None,
            readings=self.readings,
            timeouts=self.timeouts,
            errors=self.errors,
        )
