"""`python -m benchmarks.serve`: what sharing a printer through `marlin-temp serve` costs.

    python -m benchmarks.serve                  # 3 runs each, 5 s of round trips, 30 s of CPU per size (~4 min)
    python -m benchmarks.serve --quick          # 1 run, 2 s, 10 s
    python -m benchmarks --only serve           # the same, as one scenario of the suite (its targets in the table)

Three figures, each measured against the same simulated printer (a fresh `marlin-sim` process per run, served on
a pty) in the same invocation:

- **Round trips, served against direct.** M105 back to back for the same time, once by a `Printer` on the pty and
  once by a `ServedPrinter` through a `marlin-temp serve` that holds the pty (its own poller slowed to once an hour,
  so both put the same commands on the wire). The ratio is served rate / direct rate; the runs alternate which
  goes first. The client's loop is the suite's own (`_measure.time_round_trips`). Measured twice: on the unpaced
  simulator (answers at once: what the service's hops cost, the target's case), and on one paced like Marlin
  (250000 baud, its command loop's time: a 6.3 ms M105 round trip), what a user of a real printer sees.
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


#: The simulators the round trips are measured on: unpaced (the target's case), and paced like Marlin.
PACINGS = {"unpaced": UNPACED, "like Marlin": ["--baud", "250000"]}


async def _one_round_trip_run(kind: str, seconds: float, folder: Path, pacing: str = "unpaced") -> dict[str, Any]:
    with simulator(PACINGS[pacing]) as sim:
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


async def measure(runs: int, quick: bool, log: Any = None) -> dict[str, Any]:
    """Every run of the three figures, their medians, the ratios and the target (served round trips within 1.5x
    of direct ones, on the unpaced simulator)."""
    say = log or (lambda text: print(text, file=sys.stderr, flush=True))
    seconds = 2.0 if quick else 5.0
    cpu_seconds = 10.0 if quick else 30.0
    results: dict[str, Any] = {"when": time.strftime("%Y-%m-%d %H:%M:%S"), "cores": os.cpu_count(), "runs_each": runs}
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        trips: dict[str, dict[str, list[dict[str, Any]]]] = {p: {"direct": [], "served": []} for p in PACINGS}
        for pacing in PACINGS:
            for run in range(runs):
                order = ("direct", "served") if run % 2 == 0 else ("served", "direct")
                for kind in order:
                    result = await _one_round_trip_run(kind, seconds, folder, pacing)
                    trips[pacing][kind].append(result)
                    say(f"  serve: round trips {pacing}, {kind}, run {run + 1}: {result['rate_per_s']:.0f}/s "
                        f"(load {result['load']:.2f})")  # fmt: skip
        cpu = []
        for printers in (1, 10):
            result = await _cpu_run(printers, cpu_seconds, folder)
            cpu.append(result)
            say(f"  serve: service CPU, {printers} printer(s): {result['core_percent']:.1f} % of a core")
        from benchmarks import serve_cpu  # here: it reuses this module's helpers

        at_100hz = await serve_cpu.measure(runs, 5.0 if quick else 15.0, folder, say)
    medians = {
        pacing: {kind: statistics.median(r["rate_per_s"] for r in runs_) for kind, runs_ in kinds.items()}
        for pacing, kinds in trips.items()
    }
    # As times: a served round trip takes this many times as long as a direct one.
    slower = {pacing: m["direct"] / m["served"] for pacing, m in medians.items()}
    results |= {
        "round_trips": trips,
        "medians": medians,
        "served_time_over_direct": slower,
        "served_over_direct": medians["unpaced"]["served"] / medians["unpaced"]["direct"],
        "cpu": cpu,
        "cpu_at_100hz": at_100hz,
        "targets": [
            {
                "name": "served round trips vs direct ones (time per round trip, unpaced simulator)",
                "goal": "<= 1.5x",
                "measured": slower["unpaced"],
                "unit": "x",
                "met": slower["unpaced"] <= 1.5,
            },
            *at_100hz["targets"],
        ],
    }
    loads = [r["load"] for kinds in trips.values() for rs in kinds.values() for r in rs] + [r["load"] for r in cpu]
    loads += [r["load"] for rs in at_100hz["runs"].values() for r in rs]
    results["load_range"] = [min(loads), max(loads)]
    return results


def render(results: dict[str, Any]) -> list[str]:
    """The tables of `measure`'s results."""
    lines = [
        "| round trips (M105, back to back) | simulator | per second (median) | time per round trip vs direct |",
        "| --- | --- | --- | --- |",
    ]
    for pacing, medians in results["medians"].items():
        direct, served = medians["direct"], medians["served"]
        lines.append(f"| direct (Printer on the pty) | {pacing} | {direct:,.0f} | 1.00x |")
        lines.append(
            f"| served (ServedPrinter through marlin-temp serve) | {pacing} | {served:,.0f} | {direct / served:.2f}x |"
        )
    lines += [
        "",
        "| marlin-temp serve, default rates (0.1 s polls, 1 s log rows) | CPU s/min | % of a core | us per reading |",
        "| --- | --- | --- | --- |",
    ]
    for result in results["cpu"]:
        lines.append(
            f"| {result['printers']} printer(s) | {result['cpu_s_per_min']:.2f} | {result['core_percent']:.1f} | "
            f"{result['us_per_reading']:.0f} |"
        )
    if "cpu_at_100hz" in results:
        from benchmarks import serve_cpu

        lines += ["", *serve_cpu.render(results["cpu_at_100hz"])]
    low, high = results["load_range"]
    lines.append(f"\nload average during the runs: {low:.2f} to {high:.2f} on {results['cores']} cores")
    return lines


async def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the table, write the results file."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.serve", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 run, 2 s of round trips, 10 s of CPU")
    parser.add_argument("--runs", type=int, help="runs of each contender (default 3; 1 with --quick)")
    args = parser.parse_args(argv)
    results = await measure(args.runs or (1 if args.quick else 3), args.quick)
    OUTPUT.write_text(json.dumps(results, indent=2) + "\n")
    print()
    print("\n".join(render(results)))
    for target in results["targets"]:
        print(f"\ntarget: {target['name']} {target['goal']}: {target['measured']:.2f}x, "
              f"{'met' if target['met'] else 'missed'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(asyncio.run(main()))
