"""`marlin-temp log` and its file: one row per interval, sessions on a real clock, names and units as on screen.

The recording runs against the simulated printer on a real pty (or TCP, where it is stopped and started again);
the CLI runs through typer's CliRunner, in a worker thread when the test must look at the simulator meanwhile.
Which readings become rows is decided by `RowSampler`, a pure class: its schedule is tested with readings
stamped by hand, the command against the simulator.
"""

from __future__ import annotations

import asyncio
import csv
import io
import itertools
import json
import re
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
from conftest import until
from rich.console import Console
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import Faults, SimulatorConfig, serve_pty, serve_tcp
from marlin_temp.common.connect import ConnectOptions, Exit
from marlin_temp.logs.command import LogSettings, log_temperatures, record_temperatures
from marlin_temp.logs.files import FIXED_COLUMNS, RowSampler, TemperatureLog, read_log
from marlin_temp.main import app

runner = CliRunner()
FAST = ["--sim", "--sim-speed", "50"]


def rows_on_disk(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return lines[0]


def log_in_thread(*args: str) -> asyncio.Task[Any]:
    return asyncio.create_task(asyncio.to_thread(runner.invoke, app, ["log", *args]))


def reading(time_s: float, source: ReadingSource = ReadingSource.POLL, hotend: float = 25.0) -> TemperatureReading:
    temperatures = parse_temperatures(f"T:{hotend:.2f} /200.00 B:25.00 /60.00 @:64 B@:127")
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_790_000_000 + time_s, source)


# ------------------------------------------------------------------------------------------- which readings are rows


def taken(sampler: RowSampler, readings: list[TemperatureReading]) -> list[TemperatureReading]:
    return [r for r in sorted(readings, key=lambda r: r.monotonic_s) if sampler.take(r)]


def test_a_poll_and_an_auto_report_of_one_moment_make_one_row() -> None:
    # Issue 11, defect 2: at 1 s the M105 answer and the M155 report arrived 1-6 ms apart, and both were rows.
    polls = [reading(float(second)) for second in range(10)]
    after = [reading(second + 0.003, ReadingSource.AUTO) for second in range(10)]
    before = [reading(second + 0.994, ReadingSource.AUTO) for second in range(10)]
    rows = taken(RowSampler(1.0), polls + after + before)
    assert rows == polls  # the poll is the reading taken at the interval


def test_when_polls_are_held_up_the_auto_reports_and_wait_lines_stand_in() -> None:
    # G28 or a wait for heat holds the command queue: no M105 answers, but Marlin's own reports go on.
    polls = [reading(float(second)) for second in range(3)] + [reading(float(second)) for second in range(9, 12)]
    autos = [reading(second + 0.6, ReadingSource.AUTO) for second in range(3, 6)]
    waits = [reading(second + 0.6, ReadingSource.WAIT) for second in range(6, 9)]
    rows = taken(RowSampler(1.0), polls + autos + waits)
    times = [row.monotonic_s for row in rows]
    assert [row.source for row in rows][3:9] == ["auto"] * 3 + ["wait"] * 3
    assert all(0.5 <= later - earlier <= 1.7 for earlier, later in itertools.pairwise(times))


def test_every_on_time_poll_is_a_row_even_with_jitter() -> None:
    polls = [reading(index * 0.01) for index in range(1000)]
    assert len(taken(RowSampler(0.01), polls)) == 1000
    jittery = [reading(second + (0.2 if second % 2 else -0.2)) for second in range(1, 50)]
    assert len(taken(RowSampler(1.0), jittery)) == len(jittery)


def test_the_command_writes_one_row_per_interval_with_its_source(tmp_path: Path) -> None:
    # The defect's own setting: the default 1 s interval, the simulated printer auto-reporting every second.
    output = tmp_path / "temps.csv"
    result = runner.invoke(app, ["log", "--sim", "--output", str(output), "--duration", "6"])
    assert result.exit_code == 0, result.output
    rows = rows_on_disk(output)
    assert 2 <= len(rows) <= 7  # at most one a second (the handshake takes some of the six)
    times = [float(row["epoch_s"]) for row in rows]
    assert all(later - earlier >= 0.5 for earlier, later in itertools.pairwise(times)), times
    sources = {row["source"] for row in rows}
    assert sources <= {"poll", "auto", "wait"} and "poll" in sources


# ------------------------------------------------------------------------------------------- times and sessions


def test_appended_runs_are_sessions_with_absolute_times(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    for _ in range(2):
        result = runner.invoke(app, ["log", *FAST, "-o", str(output), "--interval", "0.1", "--duration", "1"])
        assert result.exit_code == 0, result.output
    rows = rows_on_disk(output)
    sessions = list(dict.fromkeys(row["session"] for row in rows))
    assert len(sessions) == 2
    epochs = [float(row["epoch_s"]) for row in rows]
    assert epochs == sorted(epochs)  # one clock across both runs: nothing to draw back across a chart
    for row in rows:
        stamped = datetime.fromisoformat(row["time"])
        assert stamped.utcoffset() is not None  # ISO 8601 with its offset
        assert abs(stamped.timestamp() - float(row["epoch_s"])) < 0.002
    second = [row for row in rows if row["session"] == sessions[1]]
    assert float(second[0]["session_elapsed_s"]) == 0  # elapsed is per session, and says so in its name
    contents = read_log(output)
    assert [session.id for session in contents.sessions] == sessions
    assert contents.sessions[1].start_epoch_s > contents.sessions[0].end_epoch_s


async def test_reconnect_across_a_simulator_stopped_and_started_again(tmp_path: Path) -> None:
    output = tmp_path / "long.csv"
    errors = Console(file=io.StringIO(), record=True, force_terminal=False, width=300)

    def sessions() -> dict[str, int]:
        counts: dict[str, int] = {}
        for row in rows_on_disk(output):
            counts[row["session"]] = counts.get(row["session"], 0) + 1
        return counts

    async with serve_tcp(SimulatorConfig(), time_scale=20) as sim:
        url = sim.url
        settings = LogSettings(output, interval_s=0.05, reconnect=True)
        logging = asyncio.create_task(log_temperatures(ConnectOptions(port=url, timeout_s=2.0), settings, errors))
        await until(lambda: sum(sessions().values()) >= 5, "rows of the first session")
    # The simulator is gone (the log's reconnect attempts are refused meanwhile); then it is back on its port.
    await until(lambda: "reconnecting in" in errors.export_text(clear=False), "the log to notice")
    port = int(url.rsplit(":", 1)[1])
    async with serve_tcp(SimulatorConfig(), port=port, time_scale=20):
        await until(lambda: len(sessions()) == 2 and min(sessions().values()) >= 5, "rows of a second session")
        logging.cancel()
        with pytest.raises(asyncio.CancelledError):
            await logging
    rows = rows_on_disk(output)
    counts = sessions()
    first, second = counts
    assert [row["session"] for row in rows] == [first] * counts[first] + [second] * counts[second]
    epochs = [float(row["epoch_s"]) for row in rows]
    assert epochs == sorted(epochs)
    assert float(next(row for row in rows if row["session"] == second)["session_elapsed_s"]) == 0
    text = errors.export_text()
    assert "reconnecting in 1 s" in text
    assert f"session {second}" in text  # the new session is named when it starts
    assert "in 2 sessions" in text  # and the summary counts them


async def test_without_reconnect_a_lost_link_ends_the_log_saying_how_to_keep_going(tmp_path: Path) -> None:
    output = tmp_path / "lost.csv"
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        logging = log_in_thread("--port", sim.url, "-o", str(output), "--interval", "0.05", "--duration", "60")
        await until(lambda: len(rows_on_disk(output)) >= 5, "rows on disk")
        await sim.disconnect()
        result = await logging
    assert result.exit_code == Exit.LOST
    problems = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(problems) == 1 and "use --reconnect" in problems[0], result.stderr
    assert "wrote" in result.stderr  # the summary still says what the file holds


# ------------------------------------------------------------------------------------------- names and units


def test_columns_name_heaters_as_the_screen_does_and_power_in_percent(tmp_path: Path) -> None:
    output = tmp_path / "named.csv"
    result = runner.invoke(app, ["log", *FAST, "-o", str(output), "--interval", "0.1", "--duration", "1"])
    assert result.exit_code == 0, result.output
    header = output.read_text().splitlines()[0].split(",")
    parts = ("actual_c", "target_c", "power_percent", "power_raw")
    assert header == [*FIXED_COLUMNS, *(f"{heater}_{part}" for heater in ("hotend", "bed") for part in parts)]
    assert not any(column.startswith(("T_", "B_")) for column in header)
    for row in rows_on_disk(output):
        for heater in ("hotend", "bed"):
            raw, percent = row[f"{heater}_power_raw"], row[f"{heater}_power_percent"]
            assert float(percent) == round(min(int(raw), 127) / 127 * 100, 1)


def test_json_lines_use_the_same_names_and_units(tmp_path: Path) -> None:
    output = tmp_path / "temps.jsonl"
    args = ["log", *FAST, "-o", str(output), "--format", "jsonl", "--interval", "0.1", "--duration", "1"]
    assert runner.invoke(app, args).exit_code == 0
    records = [json.loads(line) for line in output.read_text().splitlines()]
    assert records
    for record in records:
        assert {"time", "epoch_s", "session", "session_elapsed_s", "source"} <= set(record)
        assert set(record["heaters"]) == {"hotend", "bed"}
        assert set(record["heaters"]["hotend"]) == {"actual_c", "target_c", "power_percent", "power_raw"}
    assert read_log(output).rows == len(records)


# ------------------------------------------------------------------------------------------- targets first


def test_hotend_target_is_set_before_the_first_row(tmp_path: Path) -> None:
    output = tmp_path / "heatup.csv"
    args = ["log", "--sim", "--sim-speed", "20", "-o", str(output), "--hotend", "50", "--interval", "0.1"]
    result = runner.invoke(app, [*args, "--duration", "1.5"])
    assert result.exit_code == 0, result.output
    assert "set hotend target 50 C" in result.stderr
    rows = rows_on_disk(output)
    assert float(rows[0]["hotend_target_c"]) == 50  # the heat-up is recorded from its first reading
    assert float(rows[0]["hotend_actual_c"]) < 30  # ...which is still at room temperature
    assert float(rows[-1]["hotend_actual_c"]) > float(rows[0]["hotend_actual_c"])
    # The log ends with the hotend still heating: it says so, after the summary, as set would.
    last = result.stderr.splitlines()[-1]
    assert re.fullmatch(r"the heater stays on \(hotend \d+\.\d/50 C\)\. Turn it off with: marlin-temp set --off", last)


def test_a_log_that_set_no_target_says_nothing_of_the_heaters(tmp_path: Path) -> None:
    result = runner.invoke(app, ["log", *FAST, "-o", str(tmp_path / "t.csv"), "--interval", "0.1", "--duration", "0.3"])
    assert result.exit_code == 0, result.output
    assert "stays on" not in result.stderr and "set --off" not in result.stderr


async def test_a_lost_link_after_setting_targets_says_the_heaters_stay_on(tmp_path: Path) -> None:
    output = tmp_path / "lost.csv"
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        args = ["--port", sim.url, "-o", str(output), "--hotend", "150", "--bed", "60", "--interval", "0.05"]
        logging = log_in_thread(*args, "--duration", "60")
        await until(lambda: len(rows_on_disk(output)) >= 3, "rows on disk")  # read after the targets were set
        await sim.disconnect()
        result = await logging
    assert result.exit_code == Exit.LOST, result.output
    assert re.search(
        r"^the heaters stay on \(hotend \d+\.\d/150 C, bed \d+\.\d/60 C\)\. Turn them off with: marlin-temp set --off$",
        result.stderr,
        re.MULTILINE,
    ), result.stderr
    assert "Traceback" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--hotend", "900"], "hotend target 900 C is above the limit of 260 C (raise the limit with --max-hotend)"),
        (["--bed", "61", "--max-bed", "60"], "bed target 61 C is above the limit of 60 C"),
        (["--bed", "hot"], "bed target must be a number"),
        (["--hotend", "-5"], "hotend target"),
        (["--duration", "0"], "--duration must be more than 0 seconds, got 0"),
        (["--duration", "-10"], "--duration must be more than 0 seconds, got -10"),
        (["--interval", "0"], "--interval must be at least 0.005 seconds"),
    ],
)
async def test_bad_targets_and_durations_are_refused_before_the_port_is_opened(
    tmp_path: Path, args: list[str], message: str
) -> None:
    output = tmp_path / "never.csv"
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        result = await log_in_thread("--port", sim.url, "-o", str(output), *args)
        assert sim.printer.executed_count == 0  # nothing reached the printer
    assert result.exit_code == Exit.USAGE
    assert message in one_line(result.output)
    assert not output.exists()


# ------------------------------------------------------------------------------------------- files not to append to


@pytest.mark.parametrize(
    ("content", "fmt", "message"),
    [
        ("time_utc,elapsed_s,T_actual,T_target,T_power\n2026-11-20T10:00:00.000Z,0.000,25.00,0,0\n", "csv", "older"),
        ('{"time_utc": "2026-11-20T10:00:00.000Z", "elapsed_s": 0, "heaters": {}}\n', "jsonl", "older"),
        ("time,epoch_s,session,session_elapsed_s,source,hotend_actual_c\n", "jsonl", "is a CSV file"),
        ("name,price\ntea,3\n", "csv", "is not a marlin-temp log"),
    ],
)
async def test_files_of_another_format_are_refused_before_anything_is_sent(
    tmp_path: Path, content: str, fmt: str, message: str
) -> None:
    output = tmp_path / "existing.log"
    output.write_text(content)
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        result = await log_in_thread("--port", sim.url, "-o", str(output), "--format", fmt, "--hotend", "50")
        assert sim.printer.executed_count == 0
    assert result.exit_code == Exit.USAGE
    assert message in one_line(result.output)
    assert "choose another file" in result.output
    assert output.read_text() == content  # untouched


async def test_a_log_of_other_heaters_is_refused_before_the_targets_are_set(tmp_path: Path) -> None:
    output = tmp_path / "two-hotends.csv"
    header = [*FIXED_COLUMNS, *(f"hotend_{n}_{part}" for n in (0, 1) for part in ("actual_c", "target_c"))]
    output.write_text(",".join(header) + "\n")
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        result = await log_in_thread("--port", sim.url, "-o", str(output), "--hotend", "50", "--duration", "5")
        executed = list(sim.printer.executed)
    assert result.exit_code == Exit.USAGE
    assert "other columns" in one_line(result.output)
    assert not any(command.startswith("M104") for command in executed), executed
    assert output.read_text() == ",".join(header) + "\n"


# ------------------------------------------------------------------------------------------- on disk within a second


async def test_rows_reach_the_disk_when_the_printer_goes_silent(tmp_path: Path) -> None:
    output = tmp_path / "temps.csv"
    faults = Faults()
    async with (
        serve_pty(SimulatorConfig(), faults, time_scale=20) as sim,
        marlin_aio.connect(sim.url, timeout_s=2.0) as printer,
        TemperatureLog(output) as log,
    ):
        stop = asyncio.Event()
        recording = asyncio.create_task(record_temperatures(printer, log, 0.01, None, stop))
        try:
            await until(lambda: log.summary.rows >= 50, "readings to be recorded")
            faults.silent = True  # the board keeps running but says nothing more
            sim.poke()
            produced = log.summary.rows
            # Readings already on their way still arrive; then none does, and every row must reach the disk
            # without a next reading to push it there.
            await until(
                lambda: len(rows_on_disk(output)) == log.summary.rows >= produced,
                "every row recorded before the silence to be on disk",
            )
            on_disk = rows_on_disk(output)
            assert all(len(row) == len(on_disk[0]) for row in on_disk)
            assert float(on_disk[-1]["epoch_s"]) == round(log.summary.last_epoch_s or 0, 3)  # the last row is there
        finally:
            stop.set()
            await recording


def test_help_says_what_happens_to_an_older_file_and_what_the_columns_mean() -> None:
    result = runner.invoke(app, ["log", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "is refused with one line before anything is sent to the printer" in text
    assert "power_percent" in text and "session_elapsed_s" in text
    assert "not again after a reconnect" in text


async def test_several_hotends_are_logged_by_number_only(tmp_path: Path) -> None:
    # `T` (the active hotend) repeats one of T0, T1: a column of its own would log it twice.
    output = tmp_path / "two.csv"
    async with serve_pty(SimulatorConfig(extruders=2), time_scale=20) as sim:
        args = ["log", "--port", sim.url, "--output", str(output), "--interval", "0.1", "--duration", "1"]
        result = await asyncio.to_thread(runner.invoke, app, args)
    assert result.exit_code == 0, result.output
    header = output.read_text().splitlines()[0].split(",")
    assert "hotend_0_actual_c" in header and "hotend_1_actual_c" in header
    assert "hotend_actual_c" not in header


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["log", "--output", "{missing}/t.csv"],
            "--output {missing}/t.csv: its folder does not exist: {missing} (create it first)",
        ),
        (
            ["watch", "--log", "{missing}/t.csv"],
            "--log {missing}/t.csv: its folder does not exist: {missing} (create it first)",
        ),
        (["log", "--output", "{folder}"], "--output {folder} is a folder: give a file name in it"),
    ],
    ids=["log-output-without-its-folder", "watch-log-without-its-folder", "log-output-a-folder"],
)
def test_a_log_file_that_cannot_be_made_exits_2_naming_the_folder_before_connecting(
    tmp_path: Path, args: list[str], message: str
) -> None:
    # Checked before anything connects (the simulated printer is never started): exit code 2, one line that names
    # the folder, and no file or folder made. (Before: exit code 1 after the connect, naming only the file.)
    names = {"missing": str(tmp_path / "nodir"), "folder": str(tmp_path)}
    result = runner.invoke(app, [*(a.format(**names) for a in args), "--sim", "--duration", "1"])
    assert result.exit_code == Exit.USAGE, result.output
    assert result.output.strip().splitlines() == [f"error: {message.format(**names)}"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["log", "--output"], ["watch", "--log"]], ids=["log", "watch"])
def test_a_failed_connect_leaves_no_empty_log_file_but_keeps_one_that_was_there(
    tmp_path: Path, command: list[str]
) -> None:
    new, there = tmp_path / "new.csv", tmp_path / "there.csv"
    there.write_text("")  # the user's own (empty) file: not ours to take away
    for path in (new, there):
        result = runner.invoke(app, [*command, str(path), "--port", str(tmp_path / "no-such-port")])
        assert result.exit_code == Exit.NO_PORT, result.output
    assert not new.exists()
    assert there.exists()
