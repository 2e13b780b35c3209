"""`python -m benchmarks.serve`: what sharing a printer through `marlin-temp serve` costs.

    python -m benchmarks.serve                  # 3 runs each, 5 s of round trips, 30 s of CPU per size (~3 min)
    python -m benchmarks.serve --quick          # 1 run, 2 s, 10 s

Two figures, each measured against the same simulated printer (a fresh `marlin-sim` process per run, served on a
pty, unpaced) in the same invocation:

- **Round trips, served against direct.** M105 back to back for the same time, once by a `Printer` on the pty and
  once by a `ServedPrinter` through a `marlin-temp serve` that holds the pty (its own poller slowed to once an hour,
  so both put the same commands on the wire). The ratio is served rate / direct rate; the runs alternate which
  goes first. The client's loop is the suite's own (`_measure.time_round_trips`).
- **The service's CPU at its default rates**: `marlin-temp serve` holding 1 and then 10 printers (one `marlin-sim
  --printers N` process, so the simulators' CPU is not counted), polling each every 0.1 s and logging each once a
  second, with no client attached: CPU seconds per minute of the service process (from /proc), and microseconds
  per reading.

The load average is recorded with each run; results go to `benchmarks/serve-results.json`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import Any

import marlin_aio
from benchmarks._measure import time_round_trips
from benchmarks._procs import UNPACED, simulator

_HERE = Path(__file__).resolve().parent
OUTPUT = _HERE / "serve-results.json"
#: Clock ticks per second of /proc's CPU times.
_TICKS = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    """User and system CPU seconds of process `pid` so far (all its threads)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS


@contextlib.asynccontextmanager
async def serving(ports: dict[str, str], folder: Path, *options: str) -> AsyncIterator[tuple[str, int]]:
    """A `marlin-temp serve` process holding `ports`, once every printer is connected: (socket, pid)."""
    socket = folder / f"serve-{time.monotonic_ns()}.sock"
    args = [arg for name, port in ports.items() for arg in ("--port", f"{name}={port}")]
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "marlin_temp", "serve", "--socket", str(socket), *args, *options,
        stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    assert process.stderr is not None
    connected = 0
    try:
        async with asyncio.timeout(60):
            while connected < len(ports):
                line = (await process.stderr.readline()).decode()
                if not line:
                    raise RuntimeError("marlin-temp serve exited before its printers connected")
                connected += ": connected:" in line
        drain = asyncio.create_task(process.stderr.read())  # keep reading, so the pipe never fills
        yield str(socket), process.pid
    finally:
        if process.returncode is None:
            process.terminate()
        await process.wait()
        with contextlib.suppress(NameError):
            await drain


async def _round_trips(url: str, seconds: float) -> dict[str, Any]:
    async with marlin_aio.connect(url) as printer:
        result = await time_round_trips(lambda: printer.send("M105"), seconds)
    result["rate_per_s"] = result["round_trips"] / result["wall_s"]
    return result


async def _one_round_trip_run(kind: str, seconds: float, folder: Path) -> dict[str, Any]:
    with simulator(UNPACED) as sim:
        if kind == "direct":
            result = await _round_trips(sim.url, seconds)
        else:
            async with serving({"bench": sim.url}, folder, "--interval", "3600", "--no-log") as (socket, _):
                result = await _round_trips(f"serve:bench@{socket}", seconds)
    result["load"] = os.getloadavg()[0]
    return result


async def _cpu_run(printers: int, seconds: float, folder: Path) -> dict[str, Any]:
    with simulator(UNPACED, printers=printers) as sim:
        ports = {f"p{n + 1}": url for n, url in enumerate(sim.urls)}
        logs = folder / f"logs-{printers}"
        async with serving(ports, folder, "--log-dir", str(logs)) as (_, pid):
            await asyncio.sleep(2.0)  # the first polls and log files settle before the window (not a sync)
            start_cpu, start = _cpu_s(pid), time.monotonic()
            load_before = os.getloadavg()[0]
            await asyncio.sleep(seconds)  # the measured window: the service runs on its own
            cpu, wall = _cpu_s(pid) - start_cpu, time.monotonic() - start
    readings = printers * wall / 0.1
    return {
        "printers": printers,
        "wall_s": wall,
        "cpu_s": cpu,
        "cpu_s_per_min": 60 * cpu / wall,
        "core_percent": 100 * cpu / wall,
        "us_per_reading": 1e6 * cpu / readings,
        "load": (load_before + os.getloadavg()[0]) / 2,
    }


async def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the table, write the results file."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.serve", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 run, 2 s of round trips, 10 s of CPU")
    parser.add_argument("--runs", type=int, help="runs of each contender (default 3; 1 with --quick)")
    args = parser.parse_args(argv)
    runs = args.runs or (1 if args.quick else 3)
    seconds = 2.0 if args.quick else 5.0
    cpu_seconds = 10.0 if args.quick else 30.0
    results: dict[str, Any] = {"when": time.strftime("%Y-%m-%d %H:%M:%S"), "cores": os.cpu_count(), "runs": runs}
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        trips: dict[str, list[dict[str, Any]]] = {"direct": [], "served": []}
        for run in range(runs):
            order = ("direct", "served") if run % 2 == 0 else ("served", "direct")
            for kind in order:
                result = await _one_round_trip_run(kind, seconds, folder)
                trips[kind].append(result)
                print(f"round trips, {kind}, run {run + 1}: {result['rate_per_s']:.0f}/s (load {result['load']:.2f})",
                      file=sys.stderr, flush=True)  # fmt: skip
        cpu = []
        for printers in (1, 10):
            result = await _cpu_run(printers, cpu_seconds, folder)
            cpu.append(result)
            print(f"service CPU, {printers} printer(s): {result['core_percent']:.1f} % of a core", file=sys.stderr)
    direct = statistics.median(r["rate_per_s"] for r in trips["direct"])
    served = statistics.median(r["rate_per_s"] for r in trips["served"])
    results |= {"round_trips": trips, "cpu": cpu, "served_over_direct": served / direct}
    OUTPUT.write_text(json.dumps(results, indent=2) + "\n")
    print()
    print("| round trips (M105, back to back) | per second (median) | ratio |")
    print("| --- | --- | --- |")
    print(f"| direct (Printer on the pty) | {direct:.0f} | 1.00 |")
    print(f"| served (ServedPrinter through marlin-temp serve) | {served:.0f} | {served / direct:.2f} |")
    print()
    print("| marlin-temp serve, default rates (0.1 s polls, 1 s log rows) | CPU s/min | % of a core | us per reading |")
    print("| --- | --- | --- | --- |")
    for result in cpu:
        print(f"| {result['printers']} printer(s) | {result['cpu_s_per_min']:.2f} | {result['core_percent']:.1f} | "
              f"{result['us_per_reading']:.0f} |")  # fmt: skip
    loads = [r["load"] for rs in trips.values() for r in rs] + [r["load"] for r in cpu]
    print(f"\nload average during the runs: {min(loads):.2f} to {max(loads):.2f} on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(asyncio.run(main()))
