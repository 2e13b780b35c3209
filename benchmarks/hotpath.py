"""`python -m benchmarks.hotpath`: the two hot-path figures BENCHMARKS.md quotes for issue 24.

    python -m benchmarks.hotpath        # about 15 s

- **The core's poll, in-process:** `Connection.submit_and_write` of an M105 and `Connection.receive` of its
  `ok T:`, 50,000 times with no I/O (a hot loop: the cheapest the core's own work gets), microseconds a poll,
  best of three.
- **Calls per polled reading, in place:** 100 Hz polling of a `marlin-sim` on a pty for 2 s, by marlin_aio
  (`poll_temperatures`, `on_reading`) and by the lean floor of the suite, with `sys.setprofile` counting every
  Python and C function call in the client's process over the window, divided by the readings. Deterministic
  where CPU times are not, so it shows what a change to the hot path adds or removes.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from types import FrameType
from typing import Any

import marlin_aio
from benchmarks import _contender_floor as floor
from benchmarks._procs import UNPACED
from marlin_aio.protocol import Connection

_ANSWER = b"ok T:200.00 /200.00 B:60.00 /60.00 @:0 B@:0\n"
_POLLS = 50_000
_WINDOW_S = 2.0


def core_poll_us() -> float:
    """Microseconds the core takes over one poll of an idle link (write the M105, read its answer), hot."""
    best = float("inf")
    for _ in range(3):
        connection = Connection()
        now = 0.0
        started = time.perf_counter()
        for _ in range(_POLLS):
            now += 0.01
            command = connection.submit_and_write("M105", timeout_s=5.0, now=now, checked=False)
            assert command is not None  # the link is idle between polls
            assert connection.receive(_ANSWER, now + 0.001).finished
        best = min(best, (time.perf_counter() - started) / _POLLS * 1e6)
    return best


class _Counter:
    """Counts function calls (Python and C) while installed with `sys.setprofile`."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, frame: FrameType, event: str, arg: Any) -> None:
        if event in ("call", "c_call"):
            self.calls += 1


async def _marlin_calls(url: str) -> tuple[int, int]:
    async with marlin_aio.connect(url) as printer:
        readings = 0

        def read(reading: marlin_aio.TemperatureReading) -> None:
            nonlocal readings
            if reading.source == "poll":
                hotend = reading.hotend
                assert hotend is not None
                readings += 1

        printer.on_reading(read)
        counter = _Counter()
        async with printer.poll_temperatures(0.01):
            await asyncio.sleep(0.3)  # the first polls, before the counted window (a warm-up, not a sync)
            readings = 0
            sys.setprofile(counter)
            await asyncio.sleep(_WINDOW_S)
            sys.setprofile(None)
        return counter.calls, readings


async def _floor_calls(url: str) -> tuple[int, int]:
    transport, protocol = await floor._lean_link(url)
    poller = floor._LeanPoller(transport, protocol, 0.01)
    counter = _Counter()
    try:
        await asyncio.sleep(0.3)
        before = len(poller.times)
        sys.setprofile(counter)
        await asyncio.sleep(_WINDOW_S)
        sys.setprofile(None)
        return counter.calls, len(poller.times) - before
    finally:
        poller.stop()
        transport.close()
        await asyncio.sleep(0.05)  # the port closes in an executor


def calls_per_reading(client: str) -> float:
    """Function calls in the client's process per polled reading at 100 Hz ("marlin_aio" or "lean floor")."""
    simulator = subprocess.Popen(
        [sys.executable, "-m", "marlin_aio.simulator", *UNPACED],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert simulator.stdout is not None
        url = simulator.stdout.readline().strip()
        run = _marlin_calls if client == "marlin_aio" else _floor_calls
        calls, readings = asyncio.run(run(url))
        return calls / max(readings, 1)
    finally:
        simulator.terminate()
        simulator.wait(timeout=10)


def main() -> int:
    """Print the figures."""
    print(f"core poll, in-process: {core_poll_us():.1f} us")
    for client in ("marlin_aio", "lean floor"):
        print(f"calls per polled reading at 100 Hz, {client}: {calls_per_reading(client):.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
