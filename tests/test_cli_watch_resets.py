"""`marlin-temp watch` and board resets: a reset while the port is being opened is not an error, one later is.

Many boards reset when the port opens (DTR) and spend a moment in their bootloader before printing `start` and
the boot banner. The simulator plays such a board: silent while the client's handshake begins, then reset by
the test once the handshake's first M105 has reached it, so the banner arrives while that M105 waits.
"""

from __future__ import annotations

import asyncio
import json
import os
import termios
from typing import Any

from conftest import until
from typer.testing import CliRunner

from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.main import app

runner = CliRunner()


def reset(sim: SimulatorServer) -> None:
    sim.printer.reset(sim.now())
    sim.poke()  # the banner goes out at once


def watch_in_thread(sim: SimulatorServer, *args: str) -> asyncio.Task[Any]:
    command = ["watch", "--port", sim.url, "--refresh", "0.2", "--json", *args]
    return asyncio.create_task(asyncio.to_thread(runner.invoke, app, command))


def last_status(output: str) -> dict[str, Any]:
    records: list[dict[str, Any]] = [json.loads(line) for line in output.splitlines() if line.startswith("{")]
    assert records, output
    return records[-1]


async def test_a_reset_during_the_handshake_is_not_an_error() -> None:
    faults = Faults(silent=True)  # the bootloader: the port is open, the firmware says nothing yet
    async with serve_pty(SimulatorConfig(), faults, time_scale=20) as sim:
        watching = watch_in_thread(sim, "--duration", "1")
        await until(lambda: "M105" in sim.printer.executed, "the handshake's first M105")
        faults.silent = False
        reset(sim)  # `start` and the banner, while that M105 waits for its ok
        result = await watching
    assert result.exit_code == Exit.OK, result.output
    assert last_status(result.stdout)["errors"] == 0
    assert "0 timeouts, 0 errors" in result.stderr


async def test_a_board_that_resets_as_the_port_opens_shows_no_errors() -> None:
    # The simulator's own reset on open: quicker than a bootloader, so the banner passes during the boot wait.
    async with serve_pty(SimulatorConfig(), time_scale=20, reset_on_open=True) as sim:
        result = await watch_in_thread(sim, "--duration", "1")
        assert sim.printer.executed.count("M105") > 0
    assert result.exit_code == Exit.OK, result.output
    assert last_status(result.stdout)["errors"] == 0
    assert "0 timeouts, 0 errors" in result.stderr


async def test_a_reset_once_connected_is_an_error() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        watching = watch_in_thread(sim, "--duration", "1.5")
        await until(lambda: sim.printer.executed.count("M105") > 20, "readings to flow")
        reset(sim)
        result = await watching
    assert result.exit_code == Exit.OK, result.output
    assert last_status(result.stdout)["errors"] == 1
    assert "0 timeouts, 1 errors" in result.stderr


def test_watch_help_says_what_the_errors_count() -> None:
    result = runner.invoke(app, ["watch", "--help"])
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "from the moment the connection is established" in text and "board resets" in text


def hotend_target(status: dict[str, Any]) -> float | None:
    heaters: dict[str, dict[str, Any]] = status["heaters"]
    for key in ("T", "T0", "hotend", "hotend 0"):
        if key in heaters:
            target: float | None = heaters[key]["target"]
            return target
    raise AssertionError(f"no hotend in {heaters}")


async def test_targets_set_by_one_command_survive_into_the_next_on_a_board_that_resets_on_open() -> None:
    # The first open after plugging in resets such a board; marlin_aio then clears HUPCL, so closing the port leaves
    # DTR up and the next command's open finds the board running with the target `set` gave it.
    async with serve_pty(SimulatorConfig(), time_scale=20, reset_on_open=True) as sim:
        set_result = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--hotend", "180"])
        assert set_result.exit_code == Exit.OK, set_result.output
        assert "the board reset when the port was opened" in set_result.stderr
        result = await watch_in_thread(sim, "--duration", "1")
    assert result.exit_code == Exit.OK, result.output
    assert "board reset" not in result.stderr
    assert hotend_target(last_status(result.stdout)) == 180


async def test_a_reset_on_open_that_clears_the_targets_is_said() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20, reset_on_open=True) as sim:
        set_result = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--hotend", "180"])
        assert set_result.exit_code == Exit.OK, set_result.output
        # Another program sets HUPCL again (as most do by default): its close drops DTR, the next open resets.
        fd = os.open(sim.url, os.O_RDWR | os.O_NOCTTY)
        try:
            attributes = termios.tcgetattr(fd)
            attributes[2] |= termios.HUPCL
            termios.tcsetattr(fd, termios.TCSANOW, attributes)
        finally:
            os.close(fd)
        result = await watch_in_thread(sim, "--duration", "1")
    assert result.exit_code == Exit.OK, result.output
    assert "note: the board reset when the port was opened; targets set earlier were cleared" in result.stderr
    assert hotend_target(last_status(result.stdout)) in (0, None)


async def test_closing_the_port_leaves_hupcl_cleared_so_dtr_stays_up() -> None:
    import marlin_aio

    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        async with marlin_aio.connect(sim.url) as printer:
            assert not printer.reset_on_open  # this simulator does not reset on open
        fd = os.open(sim.url, os.O_RDWR | os.O_NOCTTY)
        try:
            assert not termios.tcgetattr(fd)[2] & termios.HUPCL
        finally:
            os.close(fd)
