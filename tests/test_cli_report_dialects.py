"""Reports that leave something out: Repetier-style reports without targets, and printers with two hotends.

A Repetier-style report (`T:150.00 B:25.00 @:127 B@:0`) carries no targets; they come on lines of their own
(`TargetExtr0:150`) only when a target is set, so a client that did not set it does not know it. Such a heater is
shown with `?` for its target and as "heating?" (powered) or "unknown", never as "off" while it heats: in watch's
table, its plain line and JSON, the farm view, the print view, the log files (an empty cell, null) and the farm's
telemetry. With two hotends Marlin prints each one's power (`@0:`, `@1:`): every hotend has its power_percent.

Views and parsing are tested pure; the commands through CliRunner against the simulator on a pty.
"""

from __future__ import annotations

import asyncio
import csv
import json
import re
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from marlin_aio import TemperatureReading
from marlin_aio.farm.supervisor import FarmPrinter, PrinterSpec
from marlin_aio.farm.telemetry import telemetry_payload
from marlin_aio.protocol import HeaterReading, ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatedPrinter, SimulatorConfig, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.common.model import SetTargets, WatchControls, WatchModel, target_text
from marlin_temp.common.render import heater_table, plain_line
from marlin_temp.farm.view import farm_row, farm_table
from marlin_temp.main import app
from marlin_temp.printing.view import heaters_on_text, temperatures_text

runner = CliRunner()


def reading(text: str, time_s: float = 0.0) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_700_000_000 + time_s, ReadingSource.POLL)


def model_of(*texts: str, seconds: float = 5.0) -> WatchModel:
    """A model fed `texts` in turn over `seconds`, ten readings a second (so rates are known)."""
    model = WatchModel(window_s=60)
    count = int(seconds * 10)
    for step in range(count):
        model.add(reading(texts[min(step * len(texts) // count, len(texts) - 1)], step / 10))
    return model


def rendered(renderable: object, width: int = 100) -> str:
    console = Console(record=True, width=width, color_system=None)
    console.print(renderable)
    return console.export_text()


# A Repetier-style hotend heating with no target known, and a bed that is cold and unpowered.
HEATING = ("T:120.00 B:25.00 @:127 B@:0", "T:150.00 B:25.00 @:127 B@:0")


# ------------------------------------------------------------------------------------------- unknown targets, pure


def test_a_heater_heating_to_an_unknown_target_is_heating_not_off() -> None:
    model = model_of(*HEATING)
    hotend, bed = model.status("T"), model.status("B")
    assert hotend.target is None and hotend.state == "heating?" and hotend.eta_s is None
    assert bed.target is None and bed.state == "unknown"  # no power, steady: it may be off, or holding 25 C


def test_a_powered_heater_at_a_steady_temperature_is_heating_and_a_falling_one_cooling() -> None:
    assert model_of("T:200.00 @:20").status("T").state == "heating?"  # holding some target: it draws power
    assert model_of("T:200.00 @:0", "T:150.00 @:0").status("T").state == "cooling"


def test_a_reported_target_of_0_is_still_off() -> None:
    model = model_of("T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0")
    assert model.status("T").state == "off" and model.status("B").state == "off"
    assert [target_text(t) for t in (None, 0.0, 0, 210.0)] == ["?", "off", "off", "210"]


@pytest.mark.parametrize("width", [120, 60, 40])
def test_the_table_shows_a_question_mark_for_an_unknown_target(width: int) -> None:
    model = model_of(*HEATING)
    text = rendered(heater_table([model.status(key) for key in model.heater_keys()], width), width)
    hotend = next(line for line in text.splitlines() if line.lstrip().startswith("hotend"))
    assert re.search(r"hotend\s+150\.0( °C)?\s+\?\s", hotend), text
    assert "heating?" in hotend and "off" not in text


def test_the_plain_line_shows_a_question_mark_and_heating() -> None:
    line = plain_line(model_of(*HEATING), wall_time_s=0)
    hotend, bed = line.split(" | ")[:2]
    assert re.fullmatch(r"\S+ hotend 150\.0/\? C 100% \+\d+\.\d\d C/s heating\?", hotend), line
    assert bed == "bed 25.0/? C 0% +0.00 C/s unknown"


def test_the_farm_row_shows_a_question_mark_and_heating() -> None:
    farm_printer = FarmPrinter(PrinterSpec(name="repetier", port="socket://127.0.0.1:1"))
    farm_printer.link_up = True
    row = farm_row(1, farm_printer, model_of(*HEATING))
    assert [cell.text() for cell in row.heaters] == ["150.0/?", "25.0/?"]
    assert row.state == "heating?"  # not "idle"
    assert re.search(r"1\s+repetier\s+150/\?\s+25/\?\s+heating\?", rendered(farm_table([row], 60), 60))


def test_the_print_view_shows_a_question_mark_and_names_a_powered_heater_as_on() -> None:
    heating = reading(HEATING[1])
    assert temperatures_text(heating) == "hotend 150.0/? °C   bed 25.0/? °C"
    # Said when a command ends: the hotend draws power, so it is on; the unpowered bed is not named.
    assert heaters_on_text(heating) == "hotend 150.0/? C"


def test_plus_does_not_step_from_an_unknown_target() -> None:
    controls = WatchControls()
    model = model_of(*HEATING)
    assert controls.press("+", model) is None  # stepping from "0" would set the hotend to 5 C
    assert controls.notice is not None and "target is unknown" in controls.notice.title
    assert controls.press("1", model) == SetTargets(hotend=200.0, bed=60.0, label="PLA")  # a preset still works


def test_the_farm_telemetry_has_a_null_target_and_the_power() -> None:
    heaters = telemetry_payload(reading(HEATING[1]))["heaters"]
    assert heaters["hotend"] == {"actual": 150.0, "target": None, "power_percent": 100.0}
    assert heaters["bed"] == {"actual": 25.0, "target": None, "power_percent": 0.0}


# ------------------------------------------------------------------------------------------- unknown targets, simulator


async def test_watch_and_log_of_a_repetier_printer_heated_by_another_client(tmp_path: Path) -> None:
    async with serve_pty(SimulatorConfig(repetier_targets=True), time_scale=50) as sim:
        # Set by another client: this one's watch and log never see the `TargetExtr0:` line.
        heat = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--hotend", "150"])
        assert heat.exit_code == Exit.OK, heat.output
        args = ["watch", "--port", sim.url, "--duration", "1.2", "--refresh", "0.4"]
        plain = await asyncio.to_thread(runner.invoke, app, args)
        as_json = await asyncio.to_thread(runner.invoke, app, [*args, "--json"])
        csv_log, json_log = tmp_path / "t.csv", tmp_path / "t.jsonl"
        for path, fmt in ((csv_log, "csv"), (json_log, "jsonl")):
            logged = await asyncio.to_thread(
                runner.invoke,
                app,
                ["log", "--port", sim.url, "-o", str(path), "--format", fmt, "--interval", "0.3", "--duration", "1"],
            )
            assert logged.exit_code == Exit.OK, logged.output
    assert plain.exit_code == Exit.OK, plain.output
    line = [line for line in plain.stdout.splitlines() if "polls/s" in line][-1]
    assert re.search(r" hotend \d+\.\d/\? C \d+% .*heating\? \| bed 25\.0/\? C 0% .*unknown \|", line), line
    assert "off" not in line
    assert as_json.exit_code == Exit.OK, as_json.output
    heaters = json.loads(as_json.stdout.splitlines()[-1])["heaters"]
    assert heaters["hotend"]["target"] is None and heaters["hotend"]["state"] == "heating?"
    assert heaters["bed"]["target"] is None and heaters["bed"]["state"] == "unknown"
    rows = list(csv.DictReader(csv_log.open()))
    assert rows and all(row["hotend_target_c"] == "" and float(row["hotend_power_percent"]) > 0 for row in rows)
    records = [json.loads(line) for line in json_log.read_text().splitlines()]
    assert records and all(record["heaters"]["hotend"]["target_c"] is None for record in records)


# ------------------------------------------------------------------------------------------- two hotends' powers


def test_the_simulator_prints_each_hotends_power_as_marlin_does() -> None:
    printer = SimulatedPrinter(SimulatorConfig(extruders=2, command_time_s=0.0, report_time_s=0.0), boot=False)
    printer.receive(b"M104 T1 S200\n", 0.0)
    printer.advance(1.0)
    printer.take_output()
    printer.receive(b"M105\n", 1.0)
    line = printer.take_output().decode().strip()
    # Marlin's print_heater_states with HOTENDS 2: the active hotend (T0) as T:, bed, each hotend by number, the
    # active one's power as @:, the bed's, then each hotend's as @0: @1:.
    assert re.fullmatch(
        r"ok T:25\.00 /0\.00 B:25\.00 /0\.00 T0:25\.00 /0\.00 T1:2\d\.\d\d /200\.00 @:0 B@:0 @0:0 @1:127", line
    ), line


GOLDEN_TWO_HOTENDS = "ok T:25.00 /0.00 B:25.00 /0.00 T0:25.00 /0.00 T1:28.41 /200.00 @:0 B@:0 @0:0 @1:127"


def test_each_hotends_power_is_parsed_into_its_own_reading() -> None:
    parsed = parse_temperatures(GOLDEN_TWO_HOTENDS[3:])
    assert parsed is not None
    assert parsed.heaters == {
        "T": HeaterReading(25.0, 0.0, 0),
        "B": HeaterReading(25.0, 0.0, 0),
        "T0": HeaterReading(25.0, 0.0, 0),
        "T1": HeaterReading(28.41, 200.0, 127),
    }
    # Repetier style: no targets, the powers all the same.
    repetier = parse_temperatures(" T:25.00 B:25.00 T0:25.00 T1:28.41 @:0 B@:0 @0:0 @1:127")
    assert repetier is not None
    assert repetier.heaters["T0"] == HeaterReading(25.0, None, 0)
    assert repetier.heaters["T1"] == HeaterReading(28.41, None, 127)


def test_the_farm_telemetry_has_each_hotends_power() -> None:
    heaters = telemetry_payload(reading(GOLDEN_TWO_HOTENDS[3:]))["heaters"]
    assert set(heaters) == {"hotend 0", "hotend 1", "bed"}  # by number only: "T" repeats the active one
    assert heaters["hotend 0"]["power_percent"] == 0.0 and heaters["hotend 1"]["power_percent"] == 100.0


@pytest.mark.parametrize("repetier", [False, True], ids=["marlin", "repetier"])
async def test_log_and_watch_have_each_hotends_power(tmp_path: Path, repetier: bool) -> None:
    config = SimulatorConfig(extruders=2, repetier_targets=repetier)
    jsonl, table = tmp_path / "two.jsonl", tmp_path / "two.csv"
    async with serve_pty(config, time_scale=50) as sim:
        base = ["--port", sim.url, "--duration", "1", "--interval", "0.3"]
        heat = ["set", "--port", sim.url, "--tool", "1", "--hotend", "120"]
        assert (await asyncio.to_thread(runner.invoke, app, heat)).exit_code == Exit.OK
        for path, fmt in ((jsonl, "jsonl"), (table, "csv")):
            logged = await asyncio.to_thread(runner.invoke, app, ["log", *base, "-o", str(path), "--format", fmt])
            assert logged.exit_code == Exit.OK, logged.output
        watched = await asyncio.to_thread(
            runner.invoke, app, ["watch", "--port", sim.url, "--duration", "1.2", "--refresh", "0.4", "--json"]
        )
    records = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert records
    for record in records:
        hotends = {name: record["heaters"][name] for name in ("hotend 0", "hotend 1")}
        assert all(h["power_percent"] is not None and h["power_raw"] is not None for h in hotends.values()), record
        assert hotends["hotend 0"]["power_raw"] == 0  # off
        assert hotends["hotend 1"]["power_raw"] > 0  # heating to, or holding, 120 C
    rows = list(csv.DictReader(table.open()))
    assert rows and all(row["hotend_0_power_percent"] and row["hotend_1_power_percent"] for row in rows), rows
    assert watched.exit_code == Exit.OK, watched.output
    heaters = json.loads(watched.stdout.splitlines()[-1])["heaters"]
    assert heaters["hotend 0"]["power_percent"] == 0.0 and heaters["hotend 1"]["power_percent"] > 0


def test_watch_help_says_an_unknown_target_is_not_off() -> None:
    result = runner.invoke(app, ["watch", "--help"])
    assert result.exit_code == 0
    assert "shows as ?, and its heater as heating? while it draws power, else unknown: never off" in " ".join(
        result.output.split()
    )
