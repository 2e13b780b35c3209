"""The service's CPU at 100 Hz against a direct client's: what sharing a printer costs the machine that shares it.

    python -m benchmarks.serve_cpu        # about 2 minutes; also in `python -m benchmarks.serve` (--only serve)

One simulated printer (`marlin-sim`, unpaced, its own process, not counted), polled every 10 ms, three ways, each
run alternating which goes first:

- **direct**: a client process polls it (`poll_temperatures(0.01)`, one `on_reading` callback): its CPU.
- **served**: `marlin-temp serve --interval 0.01` holds it (log rows once a second, as by default) with no client:
  the service process's CPU.
- **served + watch**: the same service with one client subscribed to its readings, as `marlin-temp watch --port
  serve:NAME` is (the client runs in this process; only the service's CPU is counted).

CPU is user and system time from /proc over the window, after 2 s for the first polls to settle.
"""

from __future__ import annotations

import asyncio
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import marlin_aio
from benchmarks._procs import UNPACED, simulator
from benchmarks.serve import _cpu_s, serving

Json = dict[str, Any]

KINDS = ("direct", "served", "served_watch")

_DIRECT = """
import asyncio, sys, time
import marlin_aio

async def main(url: str, seconds: float) -> None:
    async with marlin_aio.connect(url) as printer:
        printer.on_reading(lambda reading: None)
        async with printer.poll_temperatures(0.01):
            await asyncio.sleep(2.0)  # the first polls settle before the window (not a sync)
            cpu, wall = time.process_time(), time.monotonic()
            await asyncio.sleep(seconds)
            print(time.process_time() - cpu, time.monotonic() - wall)

asyncio.run(main(sys.argv[1], float(sys.argv[2])))
"""


async def _run(kind: str, seconds: float, folder: Path) -> Json:
    with simulator(UNPACED) as sim:
        load_before = os.getloadavg()[0]
        if kind == "direct":
            process = await asyncio.create_subprocess_exec(
                sys.executable, "-c", _DIRECT, sim.url, str(seconds), stdout=asyncio.subprocess.PIPE
            )
            output, _ = await asyncio.wait_for(process.communicate(), seconds + 60)
            cpu, wall = (float(value) for value in output.split())
        else:
            async with serving({"p1": sim.url}, folder, "--interval", "0.01") as (socket, pid):
                watcher = marlin_aio.connect(f"serve:p1@{socket}") if kind == "served_watch" else None
                if watcher is not None:
                    await watcher.open()
                    watcher.on_reading(lambda reading: None)
                try:
                    await asyncio.sleep(2.0)  # the first polls and log rows settle before the window (not a sync)
                    start_cpu, start = _cpu_s(pid), time.monotonic()
                    await asyncio.sleep(seconds)  # the measured window
                    cpu, wall = _cpu_s(pid) - start_cpu, time.monotonic() - start
                finally:
                    if watcher is not None:
                        await watcher.close()
    return {"kind": kind, "cpu_s": cpu, "wall_s": wall, "core_percent": 100 * cpu / wall,
            "load": (load_before + os.getloadavg()[0]) / 2}  # fmt: skip


async def measure(runs: int, seconds: float, folder: Path, log: Any) -> Json:
    """`runs` runs of each kind, alternating; medians, the ratios to direct and the two targets (<= 1.3x)."""
    results: dict[str, list[Json]] = {kind: [] for kind in KINDS}
    for index in range(runs):
        shift = index % len(KINDS)
        for kind in KINDS[shift:] + KINDS[:shift]:
            result = await _run(kind, seconds, folder)
            results[kind].append(result)
            log(f"  serve: CPU at 100 Hz, {kind}, run {index + 1}: {result['core_percent']:.2f} % of a core "
                f"(load {result['load']:.2f})")  # fmt: skip
    medians = {kind: statistics.median(r["core_percent"] for r in rs) for kind, rs in results.items()}
    ratios = {kind: medians[kind] / medians["direct"] for kind in ("served", "served_watch")}
    targets = [
        {
            "name": f"the service's CPU at 100 Hz, one printer, {label}, vs a direct client's",
            "goal": "<= 1.3x",
            "measured": ratios[kind],
            "unit": "x",
            "met": ratios[kind] <= 1.3,
        }
        for kind, label in (("served", "no client"), ("served_watch", "one subscribed client"))
    ]
    return {"seconds": seconds, "runs": results, "medians_core_percent": medians, "ratios": ratios, "targets": targets}


def render(entry: Json) -> list[str]:
    """The table of one measurement."""
    medians, ratios = entry["medians_core_percent"], entry["ratios"]
    labels = {"direct": "direct client", "served": "marlin-temp serve, no client", "served_watch": "serve + one watch"}
    rows = [f"| {labels[kind]} | {medians[kind]:.2f} % | {ratios.get(kind, 1.0):.2f}x |" for kind in KINDS]
    return ["| 100 Hz polling, one printer | CPU (% of a core, median) | vs direct |", "| --- | ---: | ---: |", *rows]


def main() -> None:
    """Measure and print."""
    import tempfile

    quick = "--quick" in sys.argv
    with tempfile.TemporaryDirectory() as folder:
        entry = asyncio.run(measure(1 if quick else 3, 5.0 if quick else 15.0, Path(folder), print))
    print("\n".join(render(entry)))
    for target in entry["targets"]:
        print(f"{target['name']}: {target['measured']:.2f}x ({target['goal']})")


if __name__ == "__main__":
    main()
