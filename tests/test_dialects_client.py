"""The client against firmware dialects real boards speak, each switched on in the simulator and served in memory."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import pytest
from conftest import TIME_SCALE

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_memory


@asynccontextmanager
async def served(config: SimulatorConfig, faults: Faults | None = None) -> AsyncIterator[SimulatorServer]:
    async with serve_memory(config, faults or Faults(), time_scale=TIME_SCALE) as server:
        yield server


async def test_a_firmware_that_requires_checksums_connects_and_numbers_everything() -> None:
    async with (
        served(SimulatorConfig(checksum_required=True)) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        reading = await printer.temperatures()
        assert "T" in reading.temperatures.heaters
        reply = await printer.send("M114", numbered=False)  # numbered all the same: the firmware demands it
        assert any("X:" in line for line in reply.lines)


async def test_a_locked_printer_fails_the_handshake_naming_the_unlock_command() -> None:
    async with served(SimulatorConfig(password="1234")) as server:
        with pytest.raises(marlin_aio.PrinterLockedError, match="M511"):
            async with marlin_aio.connect(server.url, timeout_s=2.0):
                pass


async def test_a_locked_printer_is_unlocked_with_the_password_and_a_wrong_one_fails_clearly() -> None:
    async with (
        served(SimulatorConfig(password="1234")) as server,
        marlin_aio.connect(server.url, timeout_s=2.0, password="1234") as printer,
    ):
        reading = await printer.temperatures()
        assert "T" in reading.temperatures.heaters
    async with served(SimulatorConfig(password="1234")) as server:
        with pytest.raises(marlin_aio.PrinterLockedError, match="password"):
            async with marlin_aio.connect(server.url, timeout_s=2.0, password="9999"):
                pass


async def test_m114_answered_on_the_ok_line_gives_the_position() -> None:
    async with (
        served(SimulatorConfig(m114_on_ok=True)) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        await printer.send("G1 X10 Y5")
        position = await printer.position()
        assert (position["X"], position["Y"]) == (10.0, 5.0)


@pytest.mark.parametrize("dialect", ["plain_wait_lines", "bare_busy"])
async def test_m109_with_plain_wait_lines_or_bare_keepalives_does_not_time_out(dialect: str) -> None:
    # A 1 s timeout and a heat-up of several simulated seconds: only the signs of life keep M109 going.
    config = SimulatorConfig(plain_wait_lines=dialect == "plain_wait_lines", bare_busy=dialect == "bare_busy")
    async with served(config) as server, marlin_aio.connect(server.url, timeout_s=1.0) as printer:
        reply = await printer.send("M109 S60", timeout_s=1.0)
        assert reply.ok is not None
        assert server.printer.heater_celsius("T0") >= 59.0


async def test_repetier_target_lines_fill_the_targets_the_reports_lack() -> None:
    async with (
        served(SimulatorConfig(repetier_targets=True)) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        await printer.set_temperatures(hotend=200, bed=60)
        reading = await printer.temperatures()
        assert reading.hotend is not None and reading.hotend.target == 200.0
        assert reading.bed is not None and reading.bed.target == 60.0


async def test_waiting_on_the_second_hotend_watches_that_hotend() -> None:
    # Defect: waits always watched the active hotend, so waiting on T1 timed out while T1 sat at its target.
    async with (
        served(SimulatorConfig(extruders=2)) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        await printer.send("M104 T1 S60")
        reading = await printer.wait_for_temperatures(hotend=60, tool=1, tolerance_c=2.0, timeout_s=60)
        t1 = reading.temperatures.heaters["T1"]
        assert abs(t1.actual - 60) <= 2.0
        assert reading.temperatures.heaters["T0"].actual < 40  # the active hotend stayed cold
        with pytest.raises(ValueError, match="tool"):
            await printer.wait_for_temperatures(hotend=60, tool=-1)


async def test_a_wait_that_times_out_names_the_heater_it_waited_for() -> None:
    async with (
        served(SimulatorConfig(extruders=2)) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        with pytest.raises(marlin_aio.TemperatureTimeoutError, match="hotend 1 did not reach"):
            await printer.wait_for_temperatures(hotend=200, tool=1, timeout_s=0.2)


async def test_lost_oks_of_the_handshake_and_of_the_m110_that_starts_a_print_cost_a_probe_not_the_print() -> None:
    # Defect 8: one lost ok on the handshake's M110 or M115, or on the M110 N0 before a print, failed the connection
    # or the print. Here the printer never sends those oks at all: each is proven processed by an answer behind it.
    faults = Faults(drop_ok_codes=frozenset({"M110", "M115"}))
    async with (
        served(SimulatorConfig(motion_time_scale=0), faults) as server,
        marlin_aio.connect(server.url, timeout_s=2.0) as printer,
    ):
        assert printer.firmware is not None and printer.firmware.name.startswith("Marlin")
        progress = await printer.print_file([f"G1 X{i}\n" for i in range(20)])
        assert progress.state is marlin_aio.PrintState.DONE
        assert [c for c in server.printer.executed if c.startswith("G1")] == [f"G1 X{i}" for i in range(20)]
        assert server.printer.executed.count("M110 N0") >= 2  # the handshake's and the print's
