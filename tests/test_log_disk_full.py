"""A temperature log on a file system that refuses more: whole rows only, one line saying so, and true counts.

The refusal is real, without root or a mount: each case runs in a child process whose file size limit
(`RLIMIT_FSIZE`) is set low, with SIGXFSZ ignored so that a write past the limit fails with EFBIG instead of killing
the process; Linux then writes what fits (a short write) and refuses the rest, as a full disk does. The log itself
runs on readings stamped by hand (so the limit falls at a chosen place), and `marlin-temp log` and
`watch --log` run whole against the simulated printer.
"""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from marlin_temp.logs.files import FIXED_COLUMNS, read_log

# Limits the child's files, then runs the rest of its script: imports come first, so nothing of Python's own
# start-up meets the limit.
PRELUDE = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
if sys.argv[1] != "none":
    resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
"""

# The log itself, on readings stamped by hand: `batches` lists how many rows each flush writes.
LOG_SCRIPT = """
import asyncio, json
from pathlib import Path
from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_temp.logs.files import TemperatureLog

def reading(i):
    temperatures = parse_temperatures(f"T:{{20 + i:.2f}} /200.00 B:25.00 /60.00 @:64 B@:127")
    return TemperatureReading(temperatures, float(i), 1_790_000_000.0 + i, ReadingSource.POLL)

async def main():
    added = 0
    async with TemperatureLog(Path({path!r}), {fmt!r}, flush_interval_s=3600) as log:
        for batch in {batches!r}:
            for _ in range(batch):
                assert log.add(reading(added)) or log.failure is not None
                added += 1
            log.flush()
        taken_after = log.add(reading(added))
    print(json.dumps({{
        "rows": log.summary.rows,
        "failure": None if log.failure is None else str(log.failure),
        "errno": None if log.failure is None else log.failure.errno,
        "summary": log.summary.line(),
        "taken_after": taken_after,
    }}))

asyncio.run(main())
"""


def run_child(script: str, limit: int | None, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
    """Run `script` in a Python whose files may not grow past `limit` bytes (None: no limit)."""
    imports = "import marlin_temp.main, marlin_temp.logs.files, marlin_aio.simulator\n"
    return subprocess.run(
        [sys.executable, "-c", imports + PRELUDE + script, str(limit).lower()],
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


def whole_rows(path: Path, fmt: str) -> list[dict[str, Any]]:
    """The file's rows, asserting every line is a whole one (and the file ends at a line end)."""
    text = path.read_text(encoding="utf-8")
    if not text:
        return []
    assert text.endswith("\n"), f"the file ends in a torn line: {text[-80:]!r}"
    lines = text.splitlines()
    if fmt == "jsonl":
        rows = [json.loads(line) for line in lines]
        for row in rows:
            assert set(row) == {"time", "epoch_s", "session", "session_elapsed_s", "source", "heaters"}, row
            assert all(
                set(h) == {"actual_c", "target_c", "power_percent", "power_raw"} for h in row["heaters"].values()
            )
        return rows
    table = list(csv.reader(lines))
    header = table[0]
    assert tuple(header[: len(FIXED_COLUMNS)]) == FIXED_COLUMNS
    assert all(len(row) == len(header) for row in table[1:]), "a row with too few cells"
    assert all(row[-1] != "" for row in table[1:]), "a row cut at a cell boundary"
    return [dict(zip(header, row, strict=True)) for row in table[1:]]


def written(message: str) -> int:
    match = re.search(r"wrote ([\d,]+) rows to ", message)
    assert match is not None, message
    return int(match[1].replace(",", ""))


# ------------------------------------------------------------------------------------------- the log itself


def row_bytes(tmp_path: Path, fmt: str, rows: int) -> list[int]:
    """Where each line of a log of `rows` rows ends, as the same log writes it with no limit."""
    path = tmp_path / f"unlimited.{fmt}"
    result = run_child(LOG_SCRIPT.format(path=str(path), fmt=fmt, batches=[rows]), limit=None)
    assert result.returncode == 0, result.stderr
    ends, total = [], 0
    for line in path.read_bytes().splitlines(keepends=True):
        total += len(line)
        ends.append(total)
    return ends


@pytest.mark.parametrize("fmt", ["csv", "jsonl"])
def test_a_row_that_does_not_fit_is_cut_away_and_the_rest_of_its_batch_is_not_counted(tmp_path: Path, fmt: str) -> None:
    ends = row_bytes(tmp_path, fmt, 8)
    header = 1 if fmt == "csv" else 0
    # Three rows go down in a first flush; the second flush's five meet the limit half way through the 5th row.
    limit = (ends[header + 4 - 1] + ends[header + 5 - 1]) // 2
    path = tmp_path / f"t.{fmt}"
    result = run_child(LOG_SCRIPT.format(path=str(path), fmt=fmt, batches=[3, 5]), limit)
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    rows = whole_rows(path, fmt)
    assert len(rows) == 4  # the three of the first flush and the one of the second that fitted whole
    assert path.stat().st_size == ends[header + 4 - 1]
    assert outcome["rows"] == 4 == read_log(path).rows
    assert (
        outcome["failure"]
        == f"file size limit reached: wrote 4 rows to {path}; the last 4 rows were not written and logging stopped"
    )
    assert outcome["errno"] == 27  # EFBIG
    assert outcome["taken_after"] is False  # logging stopped: nothing more is queued
    assert outcome["summary"].startswith("wrote 4 rows to ")
    assert outcome["summary"].endswith(
        "; file size limit reached: the last 4 rows were not written and logging stopped"
    )


def test_when_not_even_the_header_fits_the_file_stays_empty_and_a_later_run_starts_it_cleanly(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    result = run_child(LOG_SCRIPT.format(path=str(path), fmt="csv", batches=[2]), limit=40)
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    assert path.read_bytes() == b""
    assert outcome["rows"] == 0
    assert (
        outcome["failure"]
        == f"file size limit reached: wrote 0 rows to {path}; the last 2 rows were not written and logging stopped"
    )
    again = run_child(LOG_SCRIPT.format(path=str(path), fmt="csv", batches=[2]), limit=None)
    assert again.returncode == 0, again.stderr
    assert len(whole_rows(path, "csv")) == 3  # its two batches' rows and the one added after them


def test_a_row_that_fits_exactly_is_kept_and_the_next_is_the_one_refused(tmp_path: Path) -> None:
    ends = row_bytes(tmp_path, "csv", 4)
    path = tmp_path / "t.csv"
    result = run_child(LOG_SCRIPT.format(path=str(path), fmt="csv", batches=[4]), limit=ends[2])  # header + 2 rows
    outcome = json.loads(result.stdout)
    assert len(whole_rows(path, "csv")) == 2 == outcome["rows"]
    assert outcome["failure"].endswith(
        "wrote 2 rows to " + str(path) + "; the last 2 rows were not written and logging stopped"
    )


# ------------------------------------------------------------------------------------------- the commands


def cli_script(args: list[str]) -> str:
    return textwrap.dedent(
        f"""
        from marlin_temp.main import app
        app({args!r}, prog_name="marlin-temp")
        """
    )


@pytest.mark.parametrize("fmt", ["csv", "jsonl"])
def test_log_ends_at_a_full_file_with_one_line_exit_1_and_the_rows_on_disk_counted(tmp_path: Path, fmt: str) -> None:
    path = tmp_path / f"t.{fmt}"
    limit = 20_011  # some hundred rows, and the limit falls inside one
    args = ["log", "--sim", "--sim-speed", "50", "-o", str(path), "--interval", "0.01", "--format", fmt]
    result = run_child(cli_script([*args, "--duration", "60"]), limit)
    assert result.returncode == 1, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("logging ")]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: file size limit reached: wrote ")
    assert re.search(r"; the last (row was|[\d,]+ rows were) not written and logging stopped$", lines[0]), lines[0]
    assert "Traceback" not in result.stderr
    rows = whole_rows(path, fmt)
    assert len(rows) > 20
    assert path.stat().st_size <= limit
    assert written(lines[0]) == len(rows) == read_log(path).rows


def test_watch_goes_on_when_its_log_stops_and_its_summary_says_so(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    args = ["watch", "--sim", "--sim-speed", "50", "--log", str(path), "--interval", "0.01", "--refresh", "0.1"]
    result = run_child(cli_script([*args, "--duration", "4"]), limit=15_013)
    assert result.returncode == 0, result.stderr
    rows = whole_rows(path, "csv")
    assert path.stat().st_size <= 15_013
    summary = result.stderr.strip().splitlines()[-1]
    assert "watched 4." in summary  # the whole duration, the log having stopped well before
    assert re.search(
        r"; file size limit reached: the last (row was|[\d,]+ rows were) not written and logging stopped$", summary
    ), summary
    assert written(summary) == len(rows) == read_log(path).rows
    assert len(result.stdout.splitlines()) >= 20  # the readings went on being shown
