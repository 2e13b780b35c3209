"""`marlin-temp plot`: appended sessions on a real time axis, one session alone, old logs still read.

Logs are written by the real `TemperatureLog` from readings stamped by hand (so the times are known exactly and
no printer is needed), or as the older marlin-temp wrote them; plots are checked through their data model
(`plot_data`) and the `--show` text, through typer's CliRunner.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import pytest
from typer.testing import CliRunner

from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_temp.common.connect import Exit
from marlin_temp.logs.files import TemperatureLog, read_log
from marlin_temp.logs.plot import describe_span, plot_data
from marlin_temp.main import app

runner = CliRunner()
START = 1_790_000_000.0  # the first session's first reading (epoch seconds)
LATER = START + 300.0  # the second session starts five minutes later


def reading(text: str, time_s: float, start_epoch_s: float) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, start_epoch_s + time_s, ReadingSource.POLL)


async def write_session(path: Path, start_epoch_s: float, seconds: int, hotend: float, fmt: str = "csv") -> str:
    """One run appending to `path`: a reading a second; return its session id."""
    async with TemperatureLog(path, fmt, interval_s=1.0) as log:
        for second in range(seconds):
            text = f"T:{hotend + second:.2f} /200.00 B:{25 + second * 0.1:.2f} /60.00 @:127 B@:127"
            log.add(reading(text, float(second), start_epoch_s))
        return str(log.session)


def one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return lines[0]


@pytest.fixture
async def two_sessions(tmp_path: Path) -> tuple[Path, str, str]:
    path = tmp_path / "appended.csv"
    first = await write_session(path, START, 60, hotend=25.0)
    second = await write_session(path, LATER, 30, hotend=150.0)
    return path, first, second


def test_two_appended_sessions_lie_on_one_clock(two_sessions: tuple[Path, str, str]) -> None:
    path, first, second = two_sessions
    data = plot_data(read_log(path), path)
    assert [session.id for session in data.sessions] == [first, second]
    assert data.heaters == ["hotend", "bed"]
    early, late = data.segments["hotend"]
    assert (early.session, late.session) == (first, second)
    assert early.times_s == [START + s for s in range(60)]
    assert late.times_s[0] == LATER > early.times_s[-1]  # no line runs back across the chart
    assert data.end_epoch_s - data.start_epoch_s == 329  # the real span, not the last elapsed_s
    assert data.describe() == f"90 readings in 2 sessions, {describe_span(START, LATER + 29)}"
    assert describe_span(START, LATER + 29).endswith("(5 min 29 s)")


def test_show_lists_the_sessions_and_labels_the_axis_with_clock_times(two_sessions: tuple[Path, str, str]) -> None:
    path, first, second = two_sessions
    result = runner.invoke(app, ["plot", str(path), "--show"], env={"COLUMNS": "100"})
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert "90 readings in 2 sessions" in lines[0] and "(5 min 29 s)" in lines[0]
    assert any(first in line and "60 readings" in line for line in lines)
    assert any(second in line and "30 readings" in line for line in lines)
    start, end = f"{datetime.fromtimestamp(START):%H:%M:%S}", f"{datetime.fromtimestamp(LATER + 29):%H:%M:%S}"
    axis = next(line for line in lines if line.strip().startswith(start))
    assert axis.rstrip().endswith(end)
    marks = lines[lines.index(axis) + 1]
    # Session 2 starts 300 s into a 329 s span: its mark stands near the right end, session 1's at the left.
    assert marks.split() == ["1", "2"]
    assert marks.index("2") > 0.8 * len(axis.rstrip())
    assert "• hotend" in lines[-1] and "• bed" in lines[-1]


def test_one_session_alone_by_number_or_id(two_sessions: tuple[Path, str, str]) -> None:
    path, first, second = two_sessions
    by_number = runner.invoke(app, ["plot", str(path), "--show", "--session", "2"])
    assert by_number.exit_code == 0, by_number.output
    assert f"30 readings in 1 session, {describe_span(LATER, LATER + 29)}" in by_number.stdout
    by_id = runner.invoke(app, ["plot", str(path), "--show", "--session", first])
    assert "60 readings in 1 session" in by_id.stdout
    unknown = runner.invoke(app, ["plot", str(path), "--show", "--session", "3"])
    assert unknown.exit_code == Exit.USAGE
    assert f"no session '3'; its sessions: 1 ({first}), 2 ({second})" in one_line(unknown.output)


async def test_sessions_written_at_the_same_time_stay_apart(tmp_path: Path) -> None:
    # `log` and `watch --log` appending to one file at once: their rows interleave, their sessions do not.
    path = tmp_path / "both.csv"
    async with TemperatureLog(path) as one, TemperatureLog(path) as other:
        for second in range(10):
            one.add(reading("T:100.00 /200.00 B:50.00 /60.00 @:127 B@:127", float(second), START))
            other.add(reading("T:101.00 /200.00 B:51.00 /60.00 @:127 B@:127", second + 0.5, START))
            one.flush()
            other.flush()
    contents = read_log(path)
    assert [len(session.rows) for session in contents.sessions] == [10, 10]
    for session in contents.sessions:
        assert len({row.heaters["hotend"].actual_c for row in session.rows}) == 1


async def test_several_hotends_are_plotted_by_number(tmp_path: Path) -> None:
    path = tmp_path / "two-hotends.csv"
    async with TemperatureLog(path) as log:
        text = "T:200.00 /200.00 T0:200.00 /200.00 T1:25.00 /0.00 B:60.00 /60.00 @:64 @0:64 @1:0 B@:30"
        log.add(reading(text, 0.0, START))
    header = path.read_text().splitlines()[0]
    assert "hotend_0_actual_c" in header and "hotend_1_power_percent" in header
    assert plot_data(read_log(path), path).heaters == ["hotend 0", "hotend 1", "bed"]  # not the active copy


async def test_json_lines_plot_too(tmp_path: Path) -> None:
    path = tmp_path / "temps.jsonl"
    await write_session(path, START, 10, hotend=25.0, fmt="jsonl")
    await write_session(path, LATER, 10, hotend=80.0, fmt="jsonl")
    result = runner.invoke(app, ["plot", str(path), "--show"])
    assert result.exit_code == 0, result.output
    assert "20 readings in 2 sessions" in result.stdout


# ------------------------------------------------------------------------------------------- older logs

OLD_CSV = (
    "time_utc,elapsed_s,T_actual,T_target,T_power,B_actual,B_target,B_power\n"
    "2026-11-20T10:00:00.000Z,0.000,25.00,200,127,25.00,60,127\n"
    "2026-11-20T10:00:01.000Z,1.000,30.00,200,127,25.50,60,64\n"
    "2026-11-20T10:05:00.000Z,0.000,150.00,0,0,50.00,0,0\n"  # appended: elapsed_s started again
    "2026-11-20T10:05:01.000Z,1.000,149.00,0,0,49.50,0,0\n"
    "2026-11-20T10:05:02.000Z,2.0"  # cut short by a crash
)


def test_an_old_csv_is_read_with_its_runs_as_sessions_and_power_in_percent(tmp_path: Path) -> None:
    path = tmp_path / "old.csv"
    path.write_text(OLD_CSV)
    contents = read_log(path)
    assert contents.old_format
    assert [len(session.rows) for session in contents.sessions] == [2, 2]
    first = contents.sessions[0].rows[1].heaters
    assert set(first) == {"hotend", "bed"}
    assert first["bed"].power_percent == pytest.approx(64 / 127 * 100)
    assert contents.sessions[1].start_epoch_s == datetime.fromisoformat("2026-11-20T10:05:00+00:00").timestamp()
    result = runner.invoke(app, ["plot", str(path), "--show"])
    assert result.exit_code == 0, result.output
    assert "4 readings in 2 sessions" in result.stdout and "(5 min 1 s)" in result.stdout


def test_an_old_json_lines_log_is_read(tmp_path: Path) -> None:
    path = tmp_path / "old.jsonl"
    path.write_text(
        '{"time_utc": "2026-11-20T10:00:00.000Z", "elapsed_s": 0.0, "source": "poll", '
        '"heaters": {"T": {"actual": 25.0, "target": 200.0, "power": 127}}}\n'
    )
    rows = read_log(path).sessions[0].rows
    assert rows[0].heaters["hotend"].power_percent == 100.0
    assert rows[0].source == "poll"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "is empty"),
        ("name,price\ntea,3\n", "is not a marlin-temp log (its first line is 'name,price')"),
        ("{not json\n", ":1 is not a temperature log line"),
        (OLD_CSV.replace("30.00", "warm"), ":3 is not a temperature log row"),
    ],
)
def test_what_is_not_a_log_is_refused_in_one_line(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "what.csv"
    path.write_text(content)
    result = runner.invoke(app, ["plot", str(path), "--show"])
    assert result.exit_code == Exit.ERROR
    assert message in one_line(result.output)


def test_a_png_has_the_sessions_on_a_time_axis(two_sessions: tuple[Path, str, str], tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="matplotlib is optional (pip install 'marlin-aio[plot]')")
    path, _, _ = two_sessions
    png = tmp_path / "plot.png"
    result = runner.invoke(app, ["plot", str(path), "--output", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "90 readings in 2 sessions" in result.stderr and "(5 min 29 s)" in result.stderr


@pytest.mark.parametrize(("name", "message"), [("nofile.csv", "No such file or directory"), (".", "Is a directory")])
def test_a_log_that_cannot_be_read_is_said_in_words_with_its_name(tmp_path: Path, name: str, message: str) -> None:
    result = runner.invoke(app, ["plot", str(tmp_path / name), "--show"])
    assert result.exit_code == Exit.USAGE
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0] and "Errno" not in lines[0]
