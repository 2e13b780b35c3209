"""Read temperatures at 100 Hz while another task sets targets and waits for them, and account for everything.

    python examples/poll_and_heat.py                 # starts the simulated printer itself (another process, on a pty)
    python examples/poll_and_heat.py --port /dev/ttyUSB0 --hotend 200 --bed 60

At the end it prints polls per second, the poll interval (median, p99), the client's CPU time, and the count of
every M105 sent, answered and failed, so nothing goes missing unnoticed.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import os
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator

import marlin_aio


@contextlib.contextmanager
def simulator_process(time_scale: float) -> Iterator[str]:
    """Run `marlin-sim` in its own process (so its CPU is not counted as ours) and yield the pty path."""
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_aio.simulator", "--time-scale", str(time_scale)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        yield process.stdout.readline().strip()
    finally:
        process.terminate()
        process.wait(timeout=10)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


async def run(port: str, seconds: float, hotend: float, bed: float) -> int:
    async with marlin_aio.connect(port) as printer:
        print(f"connected to {printer.firmware.name if printer.firmware else 'unknown firmware'} on {port}")
        readings: list[marlin_aio.TemperatureReading] = []

        async def collect() -> None:
            async for reading in printer.temperature_readings():
                readings.append(reading)

        async def heat() -> str:
            await printer.set_temperatures(hotend=hotend, bed=bed)
            reached = await printer.wait_for_temperatures(tolerance_c=2.0)
            hot = reached.hotend.actual if reached.hotend else float("nan")
            warm = reached.bed.actual if reached.bed else float("nan")
            return f"targets reached: hotend {hot:.1f} C, bed {warm:.1f} C"

        cpu_start, wall_start = cpu_seconds(), time.monotonic()
        collector = asyncio.create_task(collect())
        async with printer.poll_temperatures(interval_s=0.01):
            heater = asyncio.create_task(heat())
            try:
                outcome = await asyncio.wait_for(asyncio.shield(heater), seconds)
            except TimeoutError:
                outcome = "targets not reached yet (still heating)"
            remaining = seconds - (time.monotonic() - wall_start)
            if remaining > 0:
                await asyncio.sleep(remaining)
        heater.cancel()
        wall = time.monotonic() - wall_start
        cpu = cpu_seconds() - cpu_start
        collector.cancel()
        await printer.set_temperatures(hotend=0, bed=0)

    polls = [r for r in readings if r.source == "poll"]
    intervals = [b.monotonic_s - a.monotonic_s for a, b in itertools.pairwise(polls)]
    stats = printer.stats
    print(outcome)
    print(f"readings: {len(readings)} ({len(polls)} from polls) in {wall:.1f} s = {len(polls) / wall:.1f} polls/s")
    if intervals:
        intervals.sort()
        p99 = intervals[int(0.99 * (len(intervals) - 1))]
        print(f"poll interval: median {statistics.median(intervals) * 1000:.2f} ms, p99 {p99 * 1000:.2f} ms")
    print(f"client CPU: {cpu:.2f} s over {wall:.1f} s ({cpu / wall * 60:.2f} CPU s per minute)")
    print(
        f"commands: {stats.submitted} sent = {stats.answered} answered + {stats.failed} failed + "
        f"{stats.cancelled} withdrawn + {stats.in_flight + stats.queued} pending; {stats.timeouts} timeouts, "
        f"{stats.resend_requests} resend requests, {stats.stray_oks} stray oks"
    )
    print("every command accounted for" if stats.accounted else "MISMATCH: some command is unaccounted for")
    return 0 if stats.accounted else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--port", help="device path or pyserial URL (default: start the simulated printer)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--hotend", type=float, default=200.0)
    parser.add_argument("--bed", type=float, default=60.0)
    parser.add_argument("--time-scale", type=float, default=20.0, help="simulator speed (default 20x)")
    args = parser.parse_args()
    if args.port:
        return asyncio.run(run(args.port, args.seconds, args.hotend, args.bed))
    with simulator_process(args.time_scale) as port:
        return asyncio.run(run(port, args.seconds, args.hotend, args.bed))


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    raise SystemExit(main())
