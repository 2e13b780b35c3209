"""Printers with two or more hotends: `set --tool` and `watch` against a two-extruder simulator; rendering pure.

Marlin reports the active hotend as `T:` and, with more than one, every hotend again as `T0:`, `T1:`, ... with its
own power (`@0:`, `@1:`): the view shows each hotend, never only the active one.
"""

from __future__ import annotations

import asyncio
import json
import re

from rich.console import Console
from typer.testing import CliRunner

from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.common.model import WatchModel
from marlin_temp.common.render import chart, heater_table, plain_line
from marlin_temp.main import app

runner = CliRunner()
TWO_HOTENDS = "T:200.0 /200.0 B:60.0 /60.0 T0:200.0 /200.0 T1:25.0 /0.0 @:64 B@:0 @0:64 @1:0"


def model_of(report: str, seconds: float = 10.0) -> WatchModel:
    model = WatchModel(window_s=60)
    temperatures = parse_temperatures(report)
    assert temperatures is not None
    for step in range(int(seconds * 10)):
        model.add(TemperatureReading(temperatures, step / 10, 1_700_000_000 + step / 10, ReadingSource.POLL))
    return model


def rendered(renderable: object, width: int = 100) -> str:
    console = Console(record=True, width=width)
    console.print(renderable)
    return console.export_text()


# ------------------------------------------------------------------------------------------- rendering


def test_the_table_has_a_row_per_hotend_with_its_own_figures_and_no_row_for_the_active_one() -> None:
    model = model_of(TWO_HOTENDS)
    text = rendered(heater_table([model.status(key) for key in model.heater_keys()]))
    rows = [line.split() for line in text.splitlines()[1:] if line.strip()]
    # Hotends first, in tool order, where Marlin reports them; `T:` (the active one again) has no row of its own.
    assert [row[:2] for row in rows] == [["hotend", "0"], ["hotend", "1"], ["bed", "60.0"]]
    assert rows[0][2:8] == ["200.0", "°C", "200", "°C", "50", "%"]  # @0:64 of 127
    assert rows[1][2:7] == ["25.0", "°C", "off", "0", "%"]


def test_the_chart_draws_every_hotend() -> None:
    model = model_of(TWO_HOTENDS)
    text = rendered(chart(model, width=80, height=13))
    legend = text.splitlines()[-1]
    assert re.search(r"• hotend 0\s+• hotend 1\s+• bed", legend), legend
    plot = text.splitlines()[:13]
    dotted = [line.split("┤")[0].split("│")[0].strip() for line in plot if "•" in line]
    assert len(dotted) == 3  # one row of dots each for 200 C, 60 C and 25 C


def test_the_plain_line_names_each_hotend() -> None:
    line = plain_line(model_of(TWO_HOTENDS), wall_time_s=0)
    parts = line.split(" | ")
    assert parts[0].endswith("hotend 0 200.0/200 C 50% +0.00 C/s holding")
    assert parts[1] == "hotend 1 25.0/off C 0% +0.00 C/s off"
    assert parts[2].startswith("bed 60.0/60 C")


def test_one_hotend_keeps_its_plain_name() -> None:
    model = model_of("T:25.0 /0.0 B:25.0 /0.0 @:0 B@:0")
    assert model.heater_keys() == ["T", "B"]
    assert "• hotend  • bed" in rendered(chart(model, width=80, height=8))


# ------------------------------------------------------------------------------------------- against the simulator


async def test_set_tool_waits_on_that_hotend() -> None:
    async with serve_pty(SimulatorConfig(extruders=2), time_scale=50) as sim:
        args = ["set", "--port", sim.url, "--tool", "1", "--hotend", "120", "--wait", "--wait-timeout", "20"]
        result = await asyncio.to_thread(runner.invoke, app, args)
    assert result.exit_code == Exit.OK, result.output
    assert "hotend 1 target 120 C" in result.output
    assert "reached: hotend 1 target 120 C" in result.output


async def test_watch_shows_each_hotend_of_a_two_extruder_printer() -> None:
    async with serve_pty(SimulatorConfig(extruders=2), time_scale=50) as sim:
        heat = [
            "set",
            "--port",
            sim.url,
            "--tool",
            "1",
            "--hotend",
            "120",
            "--bed",
            "50",
            "--wait",
            "--wait-timeout",
            "20",
        ]
        assert (await asyncio.to_thread(runner.invoke, app, heat)).exit_code == Exit.OK
        plain = await asyncio.to_thread(
            runner.invoke, app, ["watch", "--port", sim.url, "--duration", "1.2", "--refresh", "0.4"]
        )
        lines = await asyncio.to_thread(
            runner.invoke, app, ["watch", "--port", sim.url, "--duration", "1.2", "--refresh", "0.4", "--json"]
        )
    assert plain.exit_code == Exit.OK, plain.output
    line = [line for line in plain.stdout.splitlines() if "polls/s" in line][-1]
    parts = line.split(" | ")
    assert " hotend 0 25.0/off C 0% " in parts[0], line
    assert re.fullmatch(r"hotend 1 1[12]\d\.\d/120 C \d+% .*", parts[1]), line
    assert re.match(r"bed [45]\d\.\d/50 C", parts[2]), line
    assert lines.exit_code == Exit.OK, lines.output
    heaters = json.loads(lines.stdout.splitlines()[-1])["heaters"]
    assert list(heaters) == ["hotend 0", "hotend 1", "bed"]  # by name, as on the screen and in the log files
    assert heaters["hotend 0"]["target"] == 0 and heaters["hotend 1"]["target"] == 120
    assert heaters["bed"]["target"] == 50
    assert heaters["hotend 1"]["power_percent"] is not None


def test_watch_help_says_each_hotend_is_shown() -> None:
    result = runner.invoke(app, ["watch", "--help"])
    assert result.exit_code == 0
    assert "each one (hotend 0, hotend 1, ...) has its own row" in " ".join(result.output.split())
