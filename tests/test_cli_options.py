"""The command line's rough edges (issue 25): `log --duration` counts from the first row, `sim` is a command like the
others, JSON output is asked for the same way everywhere, and the README's commands and defaults are the ones
`--help` shows.

Everything runs through typer's CliRunner against the simulated printer, as a user would type it.
"""

from __future__ import annotations

import asyncio
import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

import marlin_aio
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


# ------------------------------------------------------------------------------------ sim, a command like the others


def test_sim_help_is_typer_help_with_every_simulator_option_and_its_default() -> None:
    from marlin_aio.simulator._options import SIMULATOR_OPTIONS, build_parser

    shown = runner.invoke(app, ["sim", "--help"], env={"COLUMNS": "200"})
    assert shown.exit_code == 0, shown.output
    text = " ".join(shown.output.split())
    assert "Usage: marlin-temp sim [OPTIONS]" in text
    # One table, two command lines: every flag of marlin-sim is an option here, with the same help and default.
    listed = build_parser().format_help()
    for option in SIMULATOR_OPTIONS:
        assert f"{option.flag} " in text and option.flag in listed, option.flag
    assert "serial receive buffer (default 128)" in text and "share of oks not sent (default 0)" in text
    assert "--time-scale" not in text  # the older names work, unlisted
    assert "Exit codes: 0 stopped" in text


def test_every_command_takes_h_for_help() -> None:
    for command in ([], ["watch"], ["log"], ["sim"], ["ports"]):
        short = runner.invoke(app, [*command, "-h"], env={"COLUMNS": "200"})
        assert short.exit_code == 0, (command, short.output)
        assert short.output == runner.invoke(app, [*command, "--help"], env={"COLUMNS": "200"}).output


def test_sim_bad_values_are_one_line_and_exit_2() -> None:
    cases = {
        ("--drop-ok", "2"): "between 0 and 1",
        ("--extruders", "9"): "1-8",
        ("--rx-buffer", "0"): "--rx-buffer must be at least 1",  # the configuration's own check, named by its flag
        ("--seed", "x"): "not a int: 'x'",
        ("--password", "a b"): "password",
    }
    for args, message in cases.items():
        result = runner.invoke(app, ["sim", *args])
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2, (args, result.output)
        assert len(lines) == 1 and message in lines[0] and lines[0].startswith("error:"), (args, result.output)


async def test_sim_serves_with_the_options_given_and_its_older_names_then_stops_on_sigterm() -> None:
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "marlin_temp", "sim", "--tcp", "0", "--printers", "2", "--time-scale", "20"),
        *("--no-bed", "--chamber"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdout is not None
    try:
        async with asyncio.timeout(30):
            urls = [(await process.stdout.readline()).decode().strip() for _ in range(2)]
        assert all(url.startswith("socket://127.0.0.1:") for url in urls), urls
        async with marlin_aio.Printer(urls[1]) as printer:
            heaters = (await printer.read_temperatures()).temperatures.heaters
        assert set(heaters) == {"T", "C"}  # --no-bed and --chamber reached the printer
    finally:
        process.send_signal(signal.SIGTERM)
        async with asyncio.timeout(30):
            _, stderr = await process.communicate()
    assert process.returncode == 0, stderr
    assert b"marlin-temp sim: stopped" in stderr and b"Traceback" not in stderr


def test_marlin_sim_refuses_what_the_configuration_refuses_in_one_line() -> None:
    completed = subprocess.run(
        [sys.executable, "-m", "marlin_aio.simulator", "--rx-buffer", "0"], capture_output=True, text=True, timeout=60
    )
    assert completed.returncode == 2
    assert (
        completed.stderr.strip()
        == "marlin-sim: error: --rx-buffer must be at least 1, got 0 (--help lists the options)"
    )


# ------------------------------------------------------------------------------------------- ports --json


def test_ports_json_is_one_object_listing_every_port() -> None:
    result = runner.invoke(app, ["ports", "--json"])
    assert result.exit_code == 0, result.output
    listed = json.loads(result.output)
    assert [port["device"] for port in listed["ports"]] == [info.device for info in marlin_aio.list_ports()]


def test_a_port_in_json_has_its_usb_ids_and_whether_it_looks_like_a_printer() -> None:
    from marlin_temp.ports.options import port_record

    ch340 = port_record(marlin_aio.PortInfo("/dev/ttyUSB0", "USB Serial", "1a86:7523", "CH340"))
    assert ch340 == {
        "device": "/dev/ttyUSB0",
        "description": "USB Serial",
        "vid": "1a86",
        "pid": "7523",
        "usb_id": "1a86:7523",
        "bridge": "CH340",
        "likely_printer": True,
    }
    onboard = port_record(marlin_aio.PortInfo("/dev/ttyS0", "ttyS0", None, None))
    assert (onboard["vid"], onboard["pid"], onboard["likely_printer"]) == (None, None, False)
    json.dumps(onboard)  # plain JSON values
