"""`--wire-log FILE`: every line sent to and read from the printer, with times, appended to a file (issue 25). Through
CliRunner against the simulated printer (`--sim`, or one served on a real pty where the test sets it up), and the
library's `WireLog` against one directly."""

from __future__ import annotations

import asyncio
import re
from datetime import datetime
from pathlib import Path

import pytest
from conftest import until
from test_serve import serving
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.aio import WireLog
from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.main import app

runner = CliRunner()

#: `2026-11-28T04:10:00.123 > N3 M105*41`: a time to the millisecond, the direction (or # for a note), the line.
LINE = re.compile(r"^(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}) ([<>#]) (.*)$")


def wire_lines(path: Path) -> list[tuple[datetime, str, str]]:
    """The log's lines as (time, direction, text); every line must have the format."""
    lines = []
    for raw in path.read_text(encoding="utf-8").splitlines():
        match = LINE.match(raw)
        assert match is not None, f"not a wire log line: {raw!r}"
        lines.append((datetime.fromisoformat(match[1]), match[2], match[3]))
    return lines


def test_the_wire_log_has_the_handshake_and_each_command_with_its_reply_in_time_order(tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    result = runner.invoke(app, ["send", "--sim", "--wire-log", str(log), "M105"])
    assert result.exit_code == 0, result.output
    lines = wire_lines(log)
    times = [time for time, _, _ in lines]
    assert times == sorted(times)
    direction, header = lines[0][1:]
    assert direction == "#" and "at 250000 baud: opening" in header
    assert lines[-1][1] == "#" and lines[-1][2].endswith("closed")
    sent = [text for _, direction, text in lines if direction == ">"]
    received = [text for _, direction, text in lines if direction == "<"]
    assert any(re.fullmatch(r"N\d+ M110 N\d+\*\d+", text) for text in sent), sent
    assert any(re.fullmatch(r"N\d+ M115\*\d+", text) for text in sent), sent
    assert "ok" in received and any(text.startswith("FIRMWARE_NAME:") for text in received)
    # The user's M105 is the last command: its reply follows it.
    last_m105 = max(index for index, (_, direction, text) in enumerate(lines) if direction == ">" and "M105" in text)
    assert lines[last_m105 + 1][1] == "<" and lines[last_m105 + 1][2].startswith("ok T:")


def test_the_wire_log_appends_one_header_per_connection(tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    for _ in range(2):
        result = runner.invoke(app, ["send", "--sim", "--wire-log", str(log), "M105"])
        assert result.exit_code == 0, result.output
    headers = [text for _, direction, text in wire_lines(log) if direction == "#" and "opening" in text]
    assert len(headers) == 2


async def test_a_password_never_reaches_the_wire_log(tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    async with serve_pty(SimulatorConfig(password="7391"), time_scale=20) as sim:
        result = await asyncio.to_thread(
            runner.invoke,
            app,
            ["send", "--port", sim.url, "--wire-log", str(log), "M104 S201"],
            env={"MARLIN_PASSWORD": "7391"},
        )
        executed = list(sim.printer.executed)
    assert result.exit_code == 0, result.output
    assert "M104 S201" in executed  # it was unlocked: the password went over the wire
    text = log.read_text(encoding="utf-8")
    assert "7391" not in text
    assert re.search(r"> N\d+ M511 \*\*\*\*$", text, re.MULTILINE), text


@pytest.mark.parametrize(
    ("where", "message"),
    [("missing/wire.log", "its folder does not exist"), (".", "is a folder")],
)
def test_a_wire_log_that_cannot_be_made_exits_2_before_connecting(tmp_path: Path, where: str, message: str) -> None:
    before = sorted(tmp_path.iterdir())
    # A port that does not exist: had it connected first, the exit code would be 3 (port not found).
    result = runner.invoke(app, ["send", "--port", "/dev/no-such-port", "--wire-log", str(tmp_path / where), "M105"])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "--wire-log" in lines[0]
    assert sorted(tmp_path.iterdir()) == before


def test_a_port_that_cannot_be_opened_is_logged_with_why(tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    result = runner.invoke(app, ["send", "--port", "/dev/no-such-port", "--wire-log", str(log), "M105"])
    assert result.exit_code == 3, result.output
    notes = [text for _, direction, text in wire_lines(log)]
    assert notes[0].startswith("/dev/no-such-port at 250000 baud: opening")
    assert notes[-1].startswith("/dev/no-such-port: not opened (") and len(notes) == 2


@pytest.mark.parametrize("command", ["watch", "set", "log", "print", "send", "terminal", "bench"])
def test_every_command_that_talks_to_a_printer_has_the_option(command: str) -> None:
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert "--wire-log" in result.output and "Default: no wire log" in result.output


def test_a_print_logs_every_line_of_the_file(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("".join(f"G1 X{i}.5 Y7\n" for i in range(40)))
    log = tmp_path / "wire.log"
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50", "--wire-log", str(log)])
    assert result.exit_code == 0, result.output
    sent = [text for _, direction, text in wire_lines(log) if direction == ">"]
    for i in range(40):
        assert any(re.fullmatch(rf"N\d+ G1 X{i}\.5 Y7\*\d+", text) for text in sent), i


async def test_a_wire_log_that_cannot_be_written_stops_itself_not_the_link() -> None:
    # /dev/full opens, and every write to it fails with "No space left on device": a full disk.
    wire_log = WireLog("/dev/full")
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim, marlin_aio.Printer(sim.url, wire_log=wire_log) as p:
        await p.read_temperatures()
        wire_log.flush()
        assert wire_log.error is not None
        reading = await p.read_temperatures()  # the link goes on
    assert reading.temperatures.heaters
    assert wire_log.take_error() is not None and wire_log.take_error() is None  # told once


def test_the_command_says_once_that_the_wire_log_stopped() -> None:
    result = runner.invoke(app, ["send", "--sim", "--wire-log", "/dev/full", "M105"])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if "--wire-log /dev/full stopped" in line]
    assert len(warnings) == 1, result.output


async def test_two_printers_share_one_file_each_line_named(tmp_path: Path) -> None:
    path = tmp_path / "farm.log"
    wire_log = WireLog(path)
    async with (
        serve_pty(SimulatorConfig(), time_scale=20) as one,
        serve_pty(SimulatorConfig(), time_scale=20) as two,
        marlin_aio.Printer(one.url, wire_log=wire_log.named("left")) as left,
        marlin_aio.Printer(two.url, wire_log=wire_log.named("right")) as right,
    ):
        await asyncio.gather(left.send("M114"), right.send("M119"))
    text = path.read_text(encoding="utf-8")
    assert re.search(r"\.\d{3} left > N\d+ M114\*\d+$", text, re.MULTILINE), text
    assert re.search(r"\.\d{3} right > N\d+ M119\*\d+$", text, re.MULTILINE), text
    assert not re.search(r"\.\d{3} left > N\d+ M119", text) and not re.search(r"\.\d{3} right > N\d+ M114", text)


async def test_a_served_printers_wire_is_the_services_to_log(tmp_path: Path) -> None:
    service_log = tmp_path / "service-wire.log"
    client_log = tmp_path / "client-wire.log"
    args = ("--sim", "--sim-speed", "50", "--interval", "0.05", "--wire-log", str(service_log))
    async with serving(tmp_path, *args) as served:
        result = await asyncio.to_thread(
            runner.invoke, app, ["send", "--port", served.url(), "--wire-log", str(client_log), "M118 hello"]
        )
    assert result.exit_code == 0, result.output
    assert "wire belongs to marlin-temp serve" in result.output
    assert not client_log.exists()
    # The service's log has the command the client sent through it, named after its printer.
    text = service_log.read_text(encoding="utf-8")
    assert re.search(r"\.\d{3} sim > N\d+ M118 hello\*\d+$", text, re.MULTILINE), text[-2000:]


def test_the_farm_view_logs_every_printer_in_one_file_each_line_named(tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    result = runner.invoke(app, ["watch", "--sims", "2", "--json", "--duration", "1", "--wire-log", str(log)])
    assert result.exit_code == 0, result.output
    names = {raw.split(" ")[1] for raw in log.read_text(encoding="utf-8").splitlines()}
    assert names == {"sim1", "sim2"}
    for name in names:
        assert re.search(rf"\.\d{{3}} {name} < ok T:", log.read_text(encoding="utf-8")), name


async def test_lines_reach_the_file_while_the_printer_stays_open(tmp_path: Path) -> None:
    # Buffered, yet on disk within about a second: a crash loses little. Read while still connected, so no close
    # has flushed it.
    path = tmp_path / "wire.log"
    wire_log = WireLog(path)
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim, marlin_aio.Printer(sim.url, wire_log=wire_log) as p:
        await p.send("M118 E1 flushed")
        await until(lambda: "M118 E1 flushed" in path.read_text(encoding="utf-8"), "the line on disk")
        assert p.is_connected
