"""The motion helpers: the G-code they build and what they refuse (no I/O), then `Printer.home`, `move`, `extrude`
and `disable_motors` against the simulated printer in memory, the position read back with M114."""

from __future__ import annotations

import asyncio
import math

import pytest
from conftest import TIME_SCALE

import marlin_aio
from marlin_aio.protocol import (
    LONG_COMMAND_TIMEOUT_S,
    command_timeout_s,
    disable_motors_command,
    extrude_commands,
    home_command,
    move_commands,
)
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_memory

# ------------------------------------------------------------------------------------------- the G-code (no I/O)


def test_home_names_the_axes_in_gcode_order_once_each() -> None:
    assert home_command() == "G28"
    assert home_command(["y", "X"]) == "G28 X Y"
    assert home_command(["z", "Z", " x "]) == "G28 X Z"
    assert home_command("z") == "G28 Z"  # one axis as a bare string


@pytest.mark.parametrize("axis", ["E", "A", "xy", "", "1"])
def test_home_refuses_an_unknown_axis(axis: str) -> None:
    with pytest.raises(ValueError, match="cannot home axis"):
        home_command([axis])


def test_moves_carry_their_mode_and_leave_the_printer_absolute() -> None:
    assert move_commands(x=10, y=20.5) == ["G90", "G1 X10 Y20.5"]
    assert move_commands(z=-0.25, feedrate_mm_min=600, relative=True) == ["G91", "G1 Z-0.25 F600", "G90"]
    assert move_commands(x=1 / 3, y=-0.0001, z=1e-9) == ["G90", "G1 X0.333 Y0 Z0"]  # micrometres, no `-0`


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({}, "nothing to move"),
        ({"feedrate_mm_min": 600}, "nothing to move"),
        ({"x": math.nan}, "finite"),
        ({"y": math.inf}, "finite"),
        ({"z": 10**400}, "finite"),
        ({"x": "10"}, "must be a number"),
        ({"x": True}, "must be a number"),
        ({"x": 20_000}, "beyond"),
        ({"x": 1, "feedrate_mm_min": -100}, "must be positive"),
        ({"x": 1, "feedrate_mm_min": 0}, "must be positive"),
        ({"x": 1, "feedrate_mm_min": math.nan}, "finite"),
        ({"x": 1, "feedrate_mm_min": 1e9}, "above"),
        ({"x": 1, "relative": "yes"}, "relative must be"),
    ],
)
def test_move_refuses_bad_arguments(arguments: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        move_commands(**arguments)  # type: ignore[arg-type]


def test_extrusion_is_relative_and_restores_absolute_extrusion() -> None:
    assert extrude_commands(5, feedrate_mm_min=300) == ["M83", "G1 E5 F300", "M82"]
    assert extrude_commands(-1.5, feedrate_mm_min=1800) == ["M83", "G1 E-1.5 F1800", "M82"]
    for length, message in ((0, "nothing to extrude"), (math.nan, "finite"), (1e6, "beyond")):
        with pytest.raises(ValueError, match=message):
            extrude_commands(length, feedrate_mm_min=300)
    with pytest.raises(ValueError, match="must be positive"):
        extrude_commands(5, feedrate_mm_min=-300)


def test_disable_motors_takes_x_y_z_and_e() -> None:
    assert disable_motors_command() == "M84"
    assert disable_motors_command(["e", "x"]) == "M84 X E"
    with pytest.raises(ValueError, match="cannot disable axis 'W'"):
        disable_motors_command(["W"])


def test_long_commands_get_a_long_timeout_the_rest_the_default() -> None:
    assert command_timeout_s("G28 X", 10.0) == LONG_COMMAND_TIMEOUT_S
    assert command_timeout_s("g29", 10.0) == LONG_COMMAND_TIMEOUT_S
    assert command_timeout_s("G28", 600.0) == 600.0  # a longer default stays
    assert command_timeout_s("G1 X10", 10.0) == 10.0
    assert command_timeout_s("M105", 2.0) == 2.0


# ------------------------------------------------------------------------------------------- through the simulator


def executed_since(server: SimulatorServer, start: int) -> list[str]:
    return list(server.printer.executed)[start:]


async def test_home_then_moves_land_where_m114_says(mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer) -> None:
    await mem_printer.move(x=30, y=40, z=5, feedrate_mm_min=6000)
    reply = await mem_printer.home("x", "y")
    assert reply.command == "G28 X Y"
    assert await mem_printer.position() == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 5.0, "E": 0.0})

    await mem_printer.move(x=12.5, y=20, feedrate_mm_min=3000)
    assert await mem_printer.position() == pytest.approx({"X": 12.5, "Y": 20.0, "Z": 5.0, "E": 0.0})
    await mem_printer.move(x=-2.5, z=1, relative=True)
    assert await mem_printer.position() == pytest.approx({"X": 10.0, "Y": 20.0, "Z": 6.0, "E": 0.0})
    # Left in absolute mode: a plain G1 typed afterwards goes to the coordinate, not by it.
    await mem_printer.send("G1 X1")
    assert (await mem_printer.position())["X"] == pytest.approx(1.0)


async def test_extrude_moves_e_by_the_length_and_leaves_e_absolute(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    await mem_printer.send("G92 E10")
    await mem_printer.extrude(5, feedrate_mm_min=600)
    assert (await mem_printer.position())["E"] == pytest.approx(15.0)
    await mem_printer.extrude(-2)
    assert (await mem_printer.position())["E"] == pytest.approx(13.0)
    await mem_printer.send("G1 E1")
    assert (await mem_printer.position())["E"] == pytest.approx(1.0)


async def test_disable_motors_sends_m84_with_the_axes(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    start = len(mem_sim.printer.executed)
    await mem_printer.disable_motors("E")
    await mem_printer.disable_motors()
    assert executed_since(mem_sim, start) == ["M84 E", "M84"]


async def test_bad_arguments_raise_before_anything_is_written(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    await mem_printer.send("M400")
    start = len(mem_sim.printer.executed)
    written = mem_printer.stats
    with pytest.raises(ValueError, match="finite"):
        await mem_printer.move(x=math.nan, relative=True)  # would otherwise have sent G91 first
    with pytest.raises(ValueError, match="cannot home"):
        await mem_printer.home("X", "Q")
    with pytest.raises(ValueError, match="must be positive"):
        await mem_printer.move(x=10, feedrate_mm_min=-50)
    with pytest.raises(ValueError, match="nothing to extrude"):
        await mem_printer.extrude(0)
    with pytest.raises(ValueError, match="cannot disable"):
        await mem_printer.disable_motors("XY")
    await mem_printer.send("M400")  # anything written before this would run before it
    assert executed_since(mem_sim, start) == ["M400"]
    assert mem_printer.stats.submitted == written.submitted + 1


async def test_a_relative_move_is_not_split_by_another_tasks_command(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    start = len(mem_sim.printer.executed)
    await asyncio.gather(
        mem_printer.move(x=5, relative=True), mem_printer.send("G1 Y50"), mem_printer.move(y=1, relative=True)
    )
    run = executed_since(mem_sim, start)
    assert sorted(run) == sorted(["G91", "G1 X5", "G90", "G1 Y50", "G91", "G1 Y1", "G90"])
    for index in (i for i, command in enumerate(run) if command == "G91"):
        assert run[index + 1] in ("G1 X5", "G1 Y1") and run[index + 2] == "G90"
    # Whichever order the tasks got: the absolute move went to Y50, the relative one moved by 1 from where it was.
    y = 51.0 if run.index("G1 Y50") < run.index("G1 Y1") else 50.0
    assert (await mem_printer.position())["Y"] == pytest.approx(y)


async def test_homing_on_a_board_without_keepalives_outlasts_the_client_timeout() -> None:
    # No `busy: processing` while homing takes 60 simulated seconds (3 s here): only the long wait covers it.
    config = SimulatorConfig(keepalive_interval_s=0, homing_s=60.0)
    async with (
        serve_memory(config, time_scale=TIME_SCALE) as server,
        marlin_aio.connect(server.url, timeout_s=1.0) as printer,
    ):
        await printer.move(x=50, z=10)
        reply = await printer.home()
        assert reply.latency_s > 1.0  # the client's own timeout would have given up
        assert printer.stats.timeouts == 0
        assert await printer.position() == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0})
