"""Heater limits on every path to the wire, through the client and the simulated printer on a real pty.

The connection is the one gate (`Connection.submit` for commands, `Connection.attach` for print lines): whatever
made the command (send, set_temperatures, a print file, a list, a generator, the CLI or the farm through them), a
target over the limits, however it is spelt, never reaches the printer. What the simulated board executed and the
targets it reports are the evidence.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

import marlin_aio
from marlin_aio.simulator import SimulatorServer

SPELLINGS = [
    "M104S280",
    "M109S270",
    "M140S200",
    "M0104 S250",
    "T0 M104 S1000",
    "M104 B1000",
    "m104 s280",
    "M65640 S280",
]


async def targets(printer: marlin_aio.Printer) -> tuple[float | None, float | None]:
    reading = await printer.read_temperatures()
    heaters = reading.temperatures.heaters
    return heaters["T"].target, heaters["B"].target


@pytest.mark.parametrize("spelling", SPELLINGS)
async def test_send_refuses_every_spelling_and_writes_nothing(fast_sim: SimulatorServer, spelling: str) -> None:
    async with marlin_aio.connect(fast_sim.url, max_hotend_celsius=240.0) as printer:
        executed = fast_sim.printer.executed_count
        with pytest.raises(ValueError, match=r"(hotend|bed) target"):
            await printer.send(spelling)
        assert await targets(printer) == (0.0, 0.0)
        # Only the M105 of `targets` ran: the refused command never reached the board.
        assert fast_sim.printer.executed_count == executed + 1
        assert all(spelling not in entry.text for entry in printer.trace.entries())


async def test_a_higher_limit_lets_an_all_metal_hotend_heat(fast_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(fast_sim.url, max_hotend_celsius=300.0) as printer:
        await printer.send("M104S255")
        assert (await targets(printer))[0] == 255.0
        printer.max_hotend_celsius = 200.0  # lowered while connected: the gate follows at once
        with pytest.raises(ValueError, match="above the limit of 200"):
            await printer.send("M104 S210")


async def test_a_list_over_the_limit_is_refused_before_its_first_line(fast_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(fast_sim.url, max_hotend_celsius=200.0) as printer:
        with pytest.raises(ValueError, match=r"line 3: hotend target 250 C is above the limit of 200 C"):
            await printer.print_file(["G28", "G1 X10", "M104 S250", "G1 X20"])
        assert "G28" not in fast_sim.printer.executed
        assert (await targets(printer))[0] == 0.0


async def test_a_file_over_the_limit_is_refused_naming_its_line(tmp_path: Path, fast_sim: SimulatorServer) -> None:
    path = tmp_path / "hot.gcode"
    path.write_text("; header\nG28\nM140 S60\nM104S280 ; all-metal profile\nG1 X10\n")
    async with marlin_aio.connect(fast_sim.url) as printer:
        with pytest.raises(ValueError, match=r"hot.gcode: line 4: hotend target 280 C is above the limit of 260 C"):
            await printer.print_file(path)
    assert "G28" not in fast_sim.printer.executed


async def test_an_unchecked_file_or_a_generator_stops_before_the_line(
    tmp_path: Path, fast_sim: SimulatorServer
) -> None:
    def lines() -> Iterator[str]:
        yield "G1 X1\n"
        yield "G1 X2\n"
        yield "m0140 s200\n"
        yield "G1 X3\n"

    path = tmp_path / "hot.gcode"
    path.write_text("G1 X1\nG1 X2\nm0140 s200\nG1 X3\n")
    async with marlin_aio.connect(fast_sim.url) as printer:
        for source in (lines(), path):
            with pytest.raises(marlin_aio.MarlinError, match=r"line 3: bed target 200 C is above the limit of 140 C"):
                await printer.print_file(source, check=False)
            assert (await targets(printer))[1] == 0.0
    executed = list(fast_sim.printer.executed)
    assert [c for c in executed if c.startswith("G1")] == ["G1 X1", "G1 X2"] * 2
    assert not any(re.match(r"(?i)m0*140", c) for c in executed)


async def test_a_print_job_made_by_hand_gets_the_connections_limits(fast_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(fast_sim.url, max_bed_celsius=90.0) as printer:
        handle = await printer.start_print(iter(["G1 X1", "M190 S100", "G1 X2"]))
        with pytest.raises(marlin_aio.MarlinError, match=r"line 2: bed target 100 C is above the limit of 90 C"):
            await handle.wait()
        assert (await targets(printer))[1] == 0.0


def test_a_limit_must_be_a_positive_number() -> None:
    with pytest.raises(ValueError, match="max_hotend_celsius must be a positive number"):
        marlin_aio.Printer("/dev/null", max_hotend_celsius=float("nan"))
    printer = marlin_aio.Printer("/dev/null")
    with pytest.raises(ValueError, match="max_bed_celsius must be a positive number"):
        printer.max_bed_celsius = -1.0
    assert printer.max_bed_celsius == marlin_aio.DEFAULT_MAX_BED_CELSIUS
