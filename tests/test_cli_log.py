"""`marlin-temp log` and its file: rows reach the disk within a second, whatever the printer does.

The recording runs against the simulated printer on a real pty; the test holds the same `TemperatureLog` the
recorder writes to, so it knows how many rows were produced and can compare them with what is on disk.
"""

from __future__ import annotations

import asyncio
import csv
from collections.abc import Callable
from pathlib import Path

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, serve_pty
from marlin_temp.logcmd import record_temperatures
from marlin_temp.logfile import TemperatureLog


async def until(condition: Callable[[], bool], what: str, limit_s: float = 10.0) -> None:
    """Poll `condition` (bounded); the file on disk gives no other signal."""
    for _ in range(int(limit_s / 0.05)):
        if condition():
            return
        await asyncio.sleep(0.05)  # polling a condition, bounded; not a fixed wait
    raise AssertionError(f"timed out after {limit_s} s waiting for {what}")


def rows_on_disk(path: Path) -> list[list[str]]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return list(csv.reader(handle))[1:]  # without the header


async def test_rows_reach_the_disk_when_the_printer_goes_silent(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    faults = Faults()
    async with (
        serve_pty(SimulatorConfig(), faults, time_scale=20) as sim,
        marlin_aio.connect(sim.url, timeout_s=2.0) as printer,
        TemperatureLog(output) as log,
    ):
        stop = asyncio.Event()
        recording = asyncio.create_task(record_temperatures(printer, log, 0.01, None, stop))
        try:
            await until(lambda: log.summary.rows >= 50, "readings to be recorded")
            faults.silent = True  # the board keeps running but says nothing more
            sim.poke()
            produced = log.summary.rows
            # Readings already on their way still arrive; then none does, and every row must reach the disk
            # without a next reading to push it there.
            await until(
                lambda: len(rows_on_disk(output)) == log.summary.rows >= produced,
                "every row recorded before the silence to be on disk",
            )
            on_disk = rows_on_disk(output)
            assert all(len(row) == len(on_disk[0]) for row in on_disk)
            assert float(on_disk[-1][1]) == round(log.summary.elapsed_s, 3)  # the last row recorded is there
        finally:
            stop.set()
            await recording
