"""Printers with two or more hotends: `set --tool` and `watch` against a two-extruder simulator; rendering pure.

Marlin reports the active hotend as `T:` and, with more than one, every hotend again as `T0:`, `T1:`, ... with its
own power (`@0:`, `@1:`): the view shows each hotend, never only the active one.
"""

from __future__ import annotations

import asyncio

from typer.testing import CliRunner

from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.connect import Exit
from marlin_temp.main import app

runner = CliRunner()


async def test_set_tool_waits_on_that_hotend() -> None:
    async with serve_pty(SimulatorConfig(extruders=2), time_scale=50) as sim:
        args = ["set", "--port", sim.url, "--tool", "1", "--hotend", "120", "--wait", "--timeout", "20"]
        result = await asyncio.to_thread(runner.invoke, app, args)
    assert result.exit_code == Exit.OK, result.output
    assert "hotend 1 target 120 C" in result.output
    assert "reached: hotend 1 target 120 C" in result.output
