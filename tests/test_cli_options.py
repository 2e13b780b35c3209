"""The command line's rough edges (issue 25): `log --duration` counts from the first row, `sim` is a command like the
others, JSON output is asked for the same way everywhere, and the README's commands and defaults are the ones
`--help` shows.

Everything runs through typer's CliRunner against the simulated printer, as a user would type it.
"""

from __future__ import annotations

import asyncio
import csv
from pathlib import Path

from typer.testing import CliRunner

from marlin_aio.simulator import SimulatorConfig, serve_tcp
from marlin_temp.main import app

runner = CliRunner()


def rows_on_disk(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


# ------------------------------------------------------------------------------------------- log --duration


async def test_log_duration_counts_from_the_first_row_not_from_before_the_handshake(tmp_path: Path) -> None:
    # A board that resets when the port is opened (a TCP client always finds it reset) spends its bootloader's 2 s
    # deaf: the handshake takes that long. Counted from before it, 2.5 s of --duration left half a second of rows.
    duration_s, interval_s = 2.5, 0.25
    output = tmp_path / "t.csv"
    async with serve_tcp(SimulatorConfig(boot_delay_s=2.0), time_scale=1.0) as sim:
        args = ["log", "--port", sim.url, "-o", str(output), "--duration", str(duration_s)]
        result = await asyncio.to_thread(runner.invoke, app, [*args, "--interval", str(interval_s)])
    assert result.exit_code == 0, result.output
    rows = rows_on_disk(output)
    epochs = [float(row["epoch_s"]) for row in rows]
    # The last row is at most one interval short of the duration; one more interval of slack for a loaded machine.
    assert epochs[-1] - epochs[0] >= duration_s - 2 * interval_s, epochs
    assert len(rows) >= duration_s / interval_s - 2, epochs
