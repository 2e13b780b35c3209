"""How a benchmark worker measures, the same for every contender: the conditions of a run, the clocks, the memory
readings and the statistics a contender's run reports.

- The conditions: `WARMUP_S` before every measured window, `QUIET_S` for the simulator's boot banner, and
  `ANSWER_TIMEOUT_S`, past which a run is broken, not slow (`RunFailedError`).
- `Meter`: wall time and the process's CPU time (every thread, user and kernel) over the measured window.
- `peak_rss_bytes`, `ru_maxrss_bytes`, `current_rss_bytes`: the process's memory (see BENCHMARKS.md for why the
  peak is `VmHWM`).
- `time_round_trips`: the one loop that times every asyncio contender's round trips.
- `interval_stats`, `LagProbe`, `many_summary`: poll intervals, the event loop's lag, many printers' readings.
- `profiled`: cProfile around the measured window (`--profile` without py-spy).

The contenders (`_contender_*.py`) import from here; this module imports only the standard library.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import os
import resource
import statistics
import time
from collections.abc import Awaitable, Callable, Iterator
from typing import Any

__all__ = [
    "ANSWER_TIMEOUT_S",
    "QUIET_S",
    "WARMUP_S",
    "LagProbe",
    "Meter",
    "Result",
    "RunFailedError",
    "current_rss_bytes",
    "interval_stats",
    "many_summary",
    "peak_rss_bytes",
    "profiled",
    "ru_maxrss_bytes",
    "time_round_trips",
]

# Before each measured window: the same short warm-up for every contender (imports, caches, the first replies).
WARMUP_S = 0.5
# How long the boot banner of the simulated printer takes to arrive and be thrown away.
QUIET_S = 0.3
# A single answer that takes longer than this means the run is broken, not slow.
ANSWER_TIMEOUT_S = 5.0

Result = dict[str, Any]


class RunFailedError(RuntimeError):
    """The contender could not complete the run (no answer, not online, print failed)."""


class Meter:
    """Wall time and this process's CPU time (all threads) from construction to `stop()`."""

    def __init__(self) -> None:
        self._times = os.times()
        self._cpu = time.process_time()
        self.start = time.perf_counter()
        self._split = {"cpu_user_s": math.nan, "cpu_system_s": math.nan}

    def stop(self) -> tuple[float, float]:
        """Return (wall seconds, CPU seconds: user and system, every thread)."""
        wall, cpu, times = time.perf_counter() - self.start, time.process_time() - self._cpu, os.times()
        self._split = {"cpu_user_s": times.user - self._times.user, "cpu_system_s": times.system - self._times.system}
        return wall, cpu

    def split(self) -> dict[str, float]:
        """The CPU time of the measured window as user and system (kernel) seconds."""
        return dict(self._split)


def ru_maxrss_bytes() -> int:
    """`ru_maxrss` of this process (kilobytes on Linux).

    On Linux it is not this program's alone: across fork and exec the kernel keeps the larger of the old and the
    new address space's high-water mark, so a worker started by a 30 MB orchestrator reports at least 30 MB.
    """
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def peak_rss_bytes() -> int:
    """Peak RSS of this process image: `VmHWM` (the high-water mark of the address space exec made), falling back
    to `ru_maxrss` where there is no /proc."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return ru_maxrss_bytes()


def current_rss_bytes() -> int:
    """Resident set size now, from /proc (0 where there is no /proc)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def interval_stats(times_s: list[float]) -> dict[str, float]:
    """Median, 99th percentile (nearest rank) and worst of the gaps between consecutive times, in milliseconds."""
    gaps = sorted(b - a for a, b in itertools.pairwise(times_s))
    if not gaps:
        return {"interval_median_ms": math.nan, "interval_p99_ms": math.nan, "interval_max_ms": math.nan}
    p99 = gaps[max(0, math.ceil(0.99 * len(gaps)) - 1)]
    return {
        "interval_median_ms": statistics.median(gaps) * 1000,
        "interval_p99_ms": p99 * 1000,
        "interval_max_ms": gaps[-1] * 1000,
    }


@contextlib.contextmanager
def profiled(path: str | None) -> Iterator[None]:
    """cProfile the block into `path` (pstats format) when a path is given; otherwise do nothing."""
    if not path:
        yield
        return
    import cProfile

    profile = cProfile.Profile()
    profile.enable()
    try:
        yield
    finally:
        profile.disable()
        profile.dump_stats(path)


async def time_round_trips(round_trip: Callable[[], Awaitable[object]], seconds: float) -> Result:
    """Warm up, then count `round_trip()`s back to back for `seconds`, with the CPU they took: every asyncio
    contender of the round-trip scenario is measured by this one loop."""
    deadline = time.perf_counter() + WARMUP_S
    while time.perf_counter() < deadline:
        await round_trip()
    count = 0
    meter = Meter()
    end = meter.start + seconds
    while time.perf_counter() < end:
        await round_trip()
        count += 1
    wall, cpu = meter.stop()
    return {"round_trips": count, "wall_s": wall, "cpu_s": cpu, **meter.split()}


class LagProbe:
    """How late the event loop runs a timer: one callback every `interval_s`, each recording how long after its
    due time it ran. A loop that keeps up with its printers runs it within about a millisecond (epoll's grain)."""

    def __init__(self, interval_s: float = 0.01) -> None:
        self._loop = asyncio.get_running_loop()
        self._interval = interval_s
        self.lags_s: list[float] = []
        self._due = self._loop.time() + interval_s
        self._timer = self._loop.call_at(self._due, self._tick)

    def _tick(self) -> None:
        now = self._loop.time()
        self.lags_s.append(now - self._due)
        self._due = max(self._due + self._interval, now)
        self._timer = self._loop.call_at(self._due, self._tick)

    def stop(self) -> dict[str, float]:
        """Stop probing; the lag's median, p99 and worst in milliseconds."""
        self._timer.cancel()
        lags = sorted(self.lags_s)
        if not lags:
            return {"lag_median_ms": math.nan, "lag_p99_ms": math.nan, "lag_max_ms": math.nan}
        return {
            "lag_median_ms": statistics.median(lags) * 1000,
            "lag_p99_ms": lags[max(0, math.ceil(0.99 * len(lags)) - 1)] * 1000,
            "lag_max_ms": lags[-1] * 1000,
        }


def many_summary(per_printer: list[list[float]], wall: float) -> Result:
    """Readings per second of each printer (the slowest and the median) and the poll intervals of all printers
    pooled: a printer that falls behind shows in the p99 whichever it is."""
    rates = sorted(len(times) / wall for times in per_printer)
    gaps = sorted(b - a for times in per_printer for a, b in itertools.pairwise(times))
    p99 = gaps[max(0, math.ceil(0.99 * len(gaps)) - 1)] * 1000 if gaps else math.nan
    return {
        "readings": sum(len(times) for times in per_printer),
        "readings_per_s_min": rates[0] if rates else math.nan,
        "readings_per_s_median": statistics.median(rates) if rates else math.nan,
        "interval_median_ms": statistics.median(gaps) * 1000 if gaps else math.nan,
        "interval_p99_ms": p99,
        "interval_max_ms": gaps[-1] * 1000 if gaps else math.nan,
    }
