"""marlin-temp through typer's CliRunner, against the simulated printer; rendering with a recording Console."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_temp.common.model import WatchModel
from marlin_temp.common.render import chart, heater_table, plain_line, watch_view
from marlin_temp.main import app

runner = CliRunner()
FAST = ["--sim", "--sim-speed", "50"]


def reading(text: str, time_s: float, source: ReadingSource = ReadingSource.POLL) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_700_000_000 + time_s, source)


def heating_model(seconds: float = 30.0) -> WatchModel:
    model = WatchModel(window_s=60)
    for step in range(int(seconds * 20)):
        t = step / 20
        hotend = 25 + 3.3 * t
        bed = 25 + 0.4 * t
        model.add(reading(f"T:{hotend:.2f} /200.00 B:{bed:.2f} /60.00 @:127 B@:127", t))
    return model


# ------------------------------------------------------------------------------------------- rendering


def test_the_table_shows_actual_target_power_rate_state_and_eta() -> None:
    model = heating_model()
    console = Console(record=True, width=100)
    console.print(heater_table([model.status(k) for k in model.heater_keys()]))
    text = console.export_text()
    assert "hotend" in text and "bed" in text
    assert "123.8 °C" in text  # 25 + 3.3 * 29.95, the last sample
    assert "200 °C" in text and "60 °C" in text
    assert "100 %" in text
    assert "+3.30 °C/s" in text
    assert "heating" in text


def test_states_holding_and_off() -> None:
    model = WatchModel()
    for step in range(100):
        model.add(reading("T:199.50 /200.00 B:30.00 /0.00 @:40 B@:0", step / 10))
    assert model.status("T").state == "holding"
    assert model.status("T").eta_s == 0.0
    assert model.status("B").state == "off"


def test_the_chart_draws_curves_and_targets() -> None:
    model = heating_model()
    console = Console(record=True, width=80)
    console.print(chart(model, width=80, height=10))
    text = console.export_text()
    assert text.count("•") > 20
    assert "─" in text  # target lines
    assert "-60 s" in text and "now" in text
    assert "hotend" in text and "bed" in text


def test_the_whole_view_and_the_plain_line() -> None:
    model = heating_model()
    model.add_latency(29.0, 0.0008)
    console = Console(record=True, width=100)
    console.print(watch_view(model, "/dev/pts/9", "Marlin 2.1.2.4", width=100))
    text = console.export_text()
    assert "/dev/pts/9" in text and "Marlin 2.1.2.4" in text and "polls/s" in text and "0.8 ms median" in text
    line = plain_line(model)
    assert "hotend 123.8/200 C" in line and "bed" in line and "heating" in line


# ------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--hotend", "abc"], "must be a number"),
        (["--hotend", "900"], "above the limit"),
        (["--bed", "141"], "above the limit"),
        (["--hotend", "nan"], "finite"),
        (["--bed", "-5"], "negative"),
        ([], "nothing to set"),
        (["--off", "--hotend", "200"], "do not combine"),
    ],
)
def test_bad_targets_exit_2_with_one_line_and_send_nothing(args: list[str], message: str) -> None:
    result = runner.invoke(app, ["set", *FAST, *args])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1, result.output
    assert message in lines[0]
    assert "Traceback" not in result.output


def test_a_missing_port_exits_3_with_one_line() -> None:
    result = runner.invoke(app, ["set", "--port", "/dev/no-such-printer", "--hotend", "200"])
    assert result.exit_code == 3
    assert result.output.strip().startswith("error: no such port: /dev/no-such-printer")
    assert len(result.output.strip().splitlines()) == 1


def test_nothing_listening_exits_3() -> None:
    result = runner.invoke(app, ["watch", "--port", "socket://127.0.0.1:9", "--duration", "1"])
    assert result.exit_code == 3
    assert "refused" in result.output


def test_version_and_help() -> None:
    assert runner.invoke(app, ["--version"]).output.startswith("marlin-temp ")
    result = runner.invoke(app, ["set", "--help"])
    assert result.exit_code == 0
    assert "Exit codes" in result.output and "--wait" in result.output


# ------------------------------------------------------------------------------------------- against the simulator


def test_set_prints_what_the_printer_confirmed() -> None:
    result = runner.invoke(app, ["set", *FAST, "--hotend", "200", "--bed", "60"])
    assert result.exit_code == 0, result.output
    assert "hotend target 200 C" in result.output
    assert "bed target 60 C" in result.output


def test_set_wait_heats_up_and_returns() -> None:
    result = runner.invoke(app, ["set", *FAST, "--hotend", "120", "--bed", "40", "--wait", "--tolerance", "1.5"])
    assert result.exit_code == 0, result.output
    assert "reached:" in result.output


def test_set_wait_timeout_exits_9() -> None:
    result = runner.invoke(app, ["set", *FAST, "--hotend", "250", "--wait", "--wait-timeout", "0.5"])
    assert result.exit_code == 9, result.output
    assert "did not reach" in result.output


def test_watch_without_a_terminal_prints_plain_lines() -> None:
    result = runner.invoke(app, ["watch", *FAST, "--duration", "2.5", "--refresh", "0.5"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if "polls/s" in line]
    assert len(lines) >= 3
    assert all("hotend" in line and "bed" in line for line in lines)


def test_watch_piped_shows_the_first_reading_at_once_not_a_refresh_later() -> None:
    # A refresh period longer than the run: before, the only line came when the run ended.
    result = runner.invoke(app, ["watch", *FAST, "--duration", "2", "--refresh", "30"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if "polls/s" in line]
    assert len(lines) == 2  # the first reading, then the end of the run


def test_watch_json_lines_parse() -> None:
    result = runner.invoke(app, ["watch", *FAST, "--duration", "1.5", "--refresh", "0.5", "--json"])
    assert result.exit_code == 0, result.output
    records = [json.loads(line) for line in result.output.splitlines() if line.startswith("{")]
    assert records
    assert set(records[-1]["heaters"]) >= {"hotend", "bed"}  # by name, as on the screen and in the log files
    assert records[-1]["polls_per_s"] > 0


def test_log_writes_rows_and_appends_with_the_same_columns(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    for _ in range(2):
        result = runner.invoke(app, ["log", *FAST, "--output", str(output), "--interval", "0.05", "--duration", "1"])
        assert result.exit_code == 0, result.output
        assert "wrote" in result.output
    with output.open() as handle:
        rows = list(csv.reader(handle))
    header = rows[0]
    assert header[:5] == ["time", "epoch_s", "session", "session_elapsed_s", "source"]
    assert "hotend_actual_c" in header and "bed_target_c" in header and "hotend_power_percent" in header
    assert rows.count(header) == 1  # the second run appended without a second header
    assert len(rows) > 20
    assert datetime.fromisoformat(rows[1][0]).utcoffset() is not None  # ISO 8601 with its offset


def test_log_refuses_a_file_with_other_columns(tmp_path: Path) -> None:
    output = tmp_path / "other.csv"
    output.write_text("time_utc,elapsed_s,X_actual,X_target,X_power\n")
    result = runner.invoke(app, ["log", *FAST, "--output", str(output), "--duration", "1"])
    assert result.exit_code != 0
    assert "other columns" in result.output


def test_log_killed_mid_run_leaves_a_file_that_parses(tmp_path: Path) -> None:
    output = tmp_path / "killed.csv"
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_temp", "log", *FAST, "--output", str(output), "--interval", "0.01"],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    # Wait (on its own output, not a timer) until it has started logging, then for rows to reach the file.
    assert "logging" in process.stderr.readline()
    for _ in range(200):
        if output.exists() and output.stat().st_size > 2000:
            break
        time.sleep(0.05)  # polling a condition (rows on disk), bounded; not a fixed wait
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    with output.open() as handle:
        rows = list(csv.reader(handle))
    assert len(rows) > 10
    assert all(len(row) == len(rows[0]) for row in rows)
    assert all(float(row[1]) >= 0 for row in rows[1:])


def test_plot_show_in_the_terminal(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    assert (
        runner.invoke(app, ["log", *FAST, "--output", str(output), "--interval", "0.05", "--duration", "1"]).exit_code
        == 0
    )
    result = runner.invoke(app, ["plot", str(output), "--show"])
    assert result.exit_code == 0, result.output
    assert "•" in result.output


def test_plot_png_or_a_clear_message_without_matplotlib(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    assert (
        runner.invoke(app, ["log", *FAST, "--output", str(output), "--interval", "0.05", "--duration", "1"]).exit_code
        == 0
    )
    png = tmp_path / "temps.png"
    result = runner.invoke(app, ["plot", str(output), "--output", str(png)])
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert result.exit_code == 2
        assert "pip install 'marlin-aio[plot]'" in result.output
    else:
        assert result.exit_code == 0, result.output
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ports_lists_every_port_the_system_knows() -> None:
    result = runner.invoke(app, ["ports"])
    assert result.exit_code == 0
    known = marlin_aio.list_ports()
    if not known:
        assert "no serial ports found" in result.output
    for port in known:
        assert port.device in result.output
        assert (port.bridge or "-") in result.output
