"""`marlin-temp set` against printers of other shapes (no chamber, no bed, two hotends): through CliRunner, with
the simulated printer served on a real pty so the test can see what it ran."""

from __future__ import annotations

import asyncio
import re

import pytest
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.heaters.command import PrinterHeaters, confirmation
from marlin_temp.main import app

runner = CliRunner()
TARGETS = ("M104", "M109", "M140", "M190", "M141", "M191")


def targets_run(sim: SimulatorServer) -> list[str]:
    return [command for command in sim.printer.executed if command.startswith(TARGETS)]


async def set_on(config: SimulatorConfig, *args: str, time_scale: float = 50) -> tuple[int, str, list[str]]:
    """Run `set` against a fresh simulator of this shape: exit code, output, and the target commands it ran."""
    async with serve_pty(config, time_scale=time_scale) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, *args])
        return result.exit_code, result.output, targets_run(sim)


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


# ------------------------------------------------------------------------------------------- heaters it lacks


@pytest.mark.parametrize(
    ("config", "args", "message"),
    [
        (
            SimulatorConfig(),
            ["--tool", "3", "--hotend", "200"],
            "this printer has one hotend, bed: there is no --tool 3",
        ),
        (SimulatorConfig(extruders=2), ["--tool", "2", "--hotend", "200"], "hotends 0-1, bed: there is no --tool 2"),
        (SimulatorConfig(), ["--chamber", "40"], "this printer has one hotend, bed: no chamber"),
        (SimulatorConfig(has_bed=False), ["--hotend", "200", "--bed", "60"], "one hotend: no heated bed"),
    ],
)
async def test_a_heater_the_printer_lacks_exits_2_naming_its_heaters_and_sets_nothing(
    config: SimulatorConfig, args: list[str], message: str
) -> None:
    code, output, ran = await set_on(config, *args)
    assert code == Exit.USAGE, output
    assert message in one_line(output)
    assert ran == []  # not even the hotend of `--hotend 200 --bed 60`


def test_tool_without_a_hotend_target_exits_2() -> None:
    result = runner.invoke(app, ["set", "--sim", "--tool", "1", "--bed", "60"])
    assert result.exit_code == Exit.USAGE
    assert "give --hotend too" in one_line(result.output)


# ------------------------------------------------------------------------------------------- what the printer confirmed


async def test_a_target_the_firmware_capped_is_reported_as_the_printer_set_it() -> None:
    code, output, ran = await set_on(SimulatorConfig(), "--hotend", "300", "--max-hotend", "300")
    assert code == Exit.OK, output
    assert ran == ["M104 S300"]
    assert "hotend target 260 C" in output
    assert "asked for 300 C: the printer capped it at its maximum" in output


async def test_a_fraction_of_a_degree_dropped_by_the_firmware_is_reported() -> None:
    code, output, _ = await set_on(SimulatorConfig(), "--hotend", "200.5")
    assert code == Exit.OK, output
    assert "hotend target 200 C" in output
    assert "asked for 200.5 C: the printer keeps whole degrees" in output


def test_the_confirmation_is_plain_when_the_printer_set_what_was_asked() -> None:
    temperatures = parse_temperatures("T:25.0 /200.0 B:24.0 /60.0 @:0 B@:0")
    assert temperatures is not None
    reading = TemperatureReading(temperatures, 0.0, 1_700_000_000.0, ReadingSource.POLL)
    assert (
        confirmation(reading, {"T": 200.0, "B": 60.0})
        == "hotend target 200 C (now 25.0 C); bed target 60 C (now 24.0 C)"
    )
    assert PrinterHeaters.of(reading) == PrinterHeaters(hotends=1, bed=True, chamber=False)


async def test_wait_waits_for_the_confirmed_target_not_the_asked_one() -> None:
    # 300 asked, 260 set: waiting for 300 would never end.
    code, output, _ = await set_on(
        SimulatorConfig(), "--hotend", "300", "--max-hotend", "300", "--wait", "--wait-timeout", "60", time_scale=100
    )
    assert code == Exit.OK, output
    assert "reached: hotend target 260 C" in output


# ------------------------------------------------------------------------------------------- --off


async def test_off_turns_off_every_hotend_the_bed_and_the_chamber() -> None:
    code, output, ran = await set_on(SimulatorConfig(extruders=2, has_chamber=True), "--off")
    assert code == Exit.OK, output
    assert ran == ["M104 T0 S0", "M104 T1 S0", "M140 S0", "M141 S0"]
    assert "hotend 0 target off" in output and "hotend 1 target off" in output and "chamber target off" in output


async def test_off_on_a_printer_without_a_bed_sends_no_bed_command() -> None:
    code, output, ran = await set_on(SimulatorConfig(has_bed=False), "--off")
    assert code == Exit.OK, output
    assert ran == ["M104 S0"]


async def test_off_wait_on_a_cold_printer_returns_at_once() -> None:
    code, output, _ = await set_on(SimulatorConfig(), "--off", "--wait", "--wait-timeout", "30")
    assert code == Exit.OK, output
    assert "cool: hotend, bed below 50 C" in output


async def test_off_wait_waits_until_the_heaters_are_cool() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=100) as sim:
        heat = ["set", "--port", sim.url, "--hotend", "80", "--wait", "--wait-timeout", "60"]
        assert (await asyncio.to_thread(runner.invoke, app, heat)).exit_code == Exit.OK
        cool = ["set", "--port", sim.url, "--off", "--wait", "--cool-to", "60", "--wait-timeout", "60"]
        result = await asyncio.to_thread(runner.invoke, app, cool)
        check = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--off"])
    assert result.exit_code == Exit.OK, result.output
    assert "cool: hotend, bed below 60 C" in result.output
    now = float(check.output.split("hotend target off (now ")[1].split(" C")[0])
    assert now <= 60.5  # the command returned once the hotend was below 60 C (it cools on meanwhile)


async def test_off_wait_times_out_with_exit_9_while_still_hot() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=100) as sim:
        heat = ["set", "--port", sim.url, "--hotend", "150", "--wait", "--wait-timeout", "60"]
        assert (await asyncio.to_thread(runner.invoke, app, heat)).exit_code == Exit.OK
        cool = ["set", "--port", sim.url, "--off", "--wait", "--wait-timeout", "0.5"]
        result = await asyncio.to_thread(runner.invoke, app, cool)
    assert result.exit_code == Exit.TIMEOUT, result.output
    assert "did not cool below 50 C within 0.5 s" in result.output


# ------------------------------------------------------------------------------------------- heaters left on


HEATER_LEFT_ON = re.compile(
    r"^the heater stays on \(hotend \d+\.\d/250 C\)\. Turn it off with: marlin-temp set --off$", re.MULTILINE
)


async def hotend_target(url: str) -> float | None:
    """The hotend target the printer reports now, read by a connection of its own."""
    async with marlin_aio.connect(url) as printer:
        return (await printer.read_temperatures()).temperatures.heaters["T"].target


async def test_a_wait_that_times_out_says_the_heater_stays_on_and_how_to_turn_it_off() -> None:
    # At the simulator's own pace a hotend takes well over a minute to 250 C: 0.5 s cannot be enough, however
    # loaded the machine (a stall slows the simulated time with it).
    async with serve_pty(SimulatorConfig(), time_scale=1) as sim:
        args = ["set", "--port", sim.url, "--hotend", "250", "--wait", "--wait-timeout", "0.5"]
        result = await asyncio.to_thread(runner.invoke, app, args)
        target = await hotend_target(sim.url)
    assert result.exit_code == Exit.TIMEOUT, result.output
    assert HEATER_LEFT_ON.search(result.output), result.output
    assert "did not reach the target within 0.5 s" in result.output
    assert "Traceback" not in result.output
    assert target == 250  # what the line says: it is still on


async def test_a_link_lost_while_waiting_says_the_heater_stays_on() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=1) as sim:
        args = ["set", "--port", sim.url, "--hotend", "250", "--wait", "--wait-timeout", "120"]
        setting = asyncio.create_task(asyncio.to_thread(runner.invoke, app, args))
        for _ in range(600):  # polling a condition, bounded: the wait's polls have begun
            ran = list(sim.printer.executed)
            # A second M105 after the target goes out only once the first one's answer (target 250) was read.
            if "M104 S250" in ran and ran[ran.index("M104 S250") :].count("M105") >= 2:
                break
            await asyncio.sleep(0.05)
        await sim.disconnect()
        result = await setting
    assert result.exit_code == Exit.LOST, result.output
    assert HEATER_LEFT_ON.search(result.output), result.output


async def test_a_wait_for_cooling_that_times_out_names_no_heater_as_on() -> None:
    code, output, _ = await set_on(
        SimulatorConfig(), "--hotend", "0", "--wait", "--cool-to", "1", "--wait-timeout", "0.3"
    )
    assert code == Exit.TIMEOUT, output
    assert "stay" not in output and "set --off" not in output  # every target is 0: nothing is on
