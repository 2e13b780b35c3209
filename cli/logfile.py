"""Temperature log files: one row per reading, in CSV or JSON lines, safe to kill at any moment.

Rows are buffered and written as whole lines at least once a second, so a crash or SIGKILL loses at most the
last second and never leaves half a row behind (the file still parses). Appending to an existing CSV keeps its
columns, and refuses (with a clear message) a file whose columns differ.

The flush is driven by time, not by the next row: the first row to wait in the buffer arms a timer for one
flush interval later. A printer that falls silent (or a link that drops) brings no next row, and the rows
before it must still reach the disk. That timer is why the log is an async context manager: it belongs to the
running event loop, taken in `__aenter__`.
"""

from __future__ import annotations

import asyncio
import csv
import io
import json
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

from marlin_aio import TemperatureReading, heater_name

__all__ = ["LogFormat", "LogSummary", "TemperatureLog", "read_log"]

LogFormat = str  # "csv" or "jsonl"


def _columns_for(keys: list[str]) -> list[str]:
    columns = ["time_utc", "elapsed_s"]
    for key in keys:
        columns += [f"{key}_actual", f"{key}_target", f"{key}_power"]
    return columns


def _iso(wall_time_s: float) -> str:
    return datetime.fromtimestamp(wall_time_s, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _number(value: float | int | None) -> str:
    return "" if value is None else f"{value:g}" if isinstance(value, int) else f"{value:.2f}"


@dataclass
class LogSummary:
    """What a logging run wrote, for the one-line summary at the end."""

    path: Path
    rows: int = 0
    first: dict[str, float] = field(default_factory=dict)
    last: dict[str, float] = field(default_factory=dict)
    elapsed_s: float = 0.0

    def line(self) -> str:
        """`wrote 6000 rows to temps.csv over 60.0 s: hotend 25.0 -> 200.1 C, bed 25.0 -> 60.0 C`."""
        changes = ", ".join(
            f"{heater_name(key)} {self.first[key]:.1f} -> {self.last[key]:.1f} C"
            for key in self.last
            if key in self.first
        )
        return f"wrote {self.rows} rows to {self.path} over {self.elapsed_s:.1f} s" + (
            f": {changes}" if changes else ""
        )


class TemperatureLog:
    """Writes readings to `path` as CSV or JSON lines; use as an async context manager (`async with`).

    No row waits in memory longer than `flush_interval_s`, whether more rows follow or not.

    Raises:
        ValueError: `fmt` is unknown, `flush_interval_s` is not positive, or an existing CSV has other columns
            than this printer reports.
        OSError: the file cannot be opened or written.
    """

    def __init__(self, path: Path, fmt: LogFormat = "csv", flush_interval_s: float = 1.0) -> None:
        if fmt not in ("csv", "jsonl"):
            raise ValueError(f"unknown log format {fmt!r}: use csv or jsonl")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be positive, got {flush_interval_s}")
        self.path = path
        self.format = fmt
        self.flush_interval_s = flush_interval_s
        self.summary = LogSummary(path)
        self._file: IO[str] | None = None
        self._columns: list[str] | None = None
        self._existing_columns: list[str] | None = None
        self._pending: list[str] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._flush_timer: asyncio.TimerHandle | None = None
        self._error: OSError | None = None  # met by a timed flush, raised by the next add() or flush()
        self._start: float | None = None

    async def __aenter__(self) -> TemperatureLog:
        if self.format == "csv" and self.path.exists() and self.path.stat().st_size > 0:
            with self.path.open(newline="") as existing:
                self._existing_columns = next(csv.reader(existing), None)
        self._file = self.path.open("a", newline="", encoding="utf-8")
        self._loop = asyncio.get_running_loop()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def add(self, reading: TemperatureReading) -> None:
        """Queue one row; it reaches the file within `flush_interval_s`, even if no other row follows.

        Raises:
            ValueError: an existing CSV has other columns than this reading's heaters.
            RuntimeError: the log is not open (`async with`).
            OSError: a timed flush since the last row could not write the file.
        """
        if self._loop is None:
            raise RuntimeError("the log is not open: use `async with TemperatureLog(...)`")
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        if self._start is None:
            self._start = reading.monotonic_s
        elapsed = reading.monotonic_s - self._start
        heaters = reading.temperatures.heaters
        if self.format == "csv":
            if self._columns is None:
                self._start_csv(list(heaters))
            assert self._columns is not None
            row = [_iso(reading.wall_time_s), f"{elapsed:.3f}"]
            for column in self._columns[2:]:
                key, _, part = column.rpartition("_")
                heater = heaters.get(key)
                value = None if heater is None else getattr(heater, part)
                row.append(_number(value))
            buffer = io.StringIO()
            csv.writer(buffer, lineterminator="\n").writerow(row)
            self._pending.append(buffer.getvalue())
        else:
            record = {
                "time_utc": _iso(reading.wall_time_s),
                "elapsed_s": round(elapsed, 3),
                "source": reading.source,
                "heaters": {
                    key: {"actual": h.actual, "target": h.target, "power": h.power} for key, h in heaters.items()
                },
            }
            self._pending.append(json.dumps(record) + "\n")
        self.summary.rows += 1
        self.summary.elapsed_s = elapsed
        for key, heater in heaters.items():
            self.summary.first.setdefault(key, heater.actual)
            self.summary.last[key] = heater.actual
        if self._flush_timer is None:
            # The oldest row in the buffer sets the deadline; rows after it go out with it, sooner than theirs.
            self._flush_timer = self._loop.call_later(self.flush_interval_s, self._flush_due)

    def _start_csv(self, keys: list[str]) -> None:
        columns = _columns_for(keys)
        if self._existing_columns is not None:
            if self._existing_columns != columns:
                raise ValueError(
                    f"{self.path} has other columns ({', '.join(self._existing_columns[2:]) or 'none'}) than this "
                    f"printer reports ({', '.join(columns[2:])}); choose another --output file"
                )
        else:
            self._pending.append(",".join(columns) + "\n")
        self._columns = columns

    def _flush_due(self) -> None:
        self._flush_timer = None
        try:
            self.flush()
        except OSError as exc:
            # Raised in a timer callback, it would only reach the loop's log: keep it for the recorder to meet.
            self._error = exc

    def flush(self) -> None:
        """Write every queued row as whole lines and push them to the operating system.

        Raises:
            OSError: the file cannot be written (also one that a timed flush met since the last call).
        """
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        if not self._pending or self._file is None:
            return
        # One write of whole lines: a kill between writes can cut the file only at a line end.
        self._file.write("".join(self._pending))
        self._pending.clear()
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        """Flush and close (idempotent).

        Raises:
            OSError: the last rows could not be written (the file is closed all the same).
        """
        if self._file is None:
            return
        try:
            self.flush()
        finally:
            self._file.close()
            self._file = None


def read_log(path: Path) -> tuple[list[float], dict[str, list[tuple[float | None, float | None]]]]:
    """Read a CSV or JSONL log back: elapsed seconds, and per heater key a list of (actual, target).

    Raises:
        ValueError: the file is empty or not a temperature log.
        OSError: it cannot be read.
    """
    text = path.read_text(encoding="utf-8")
    if not text.strip():
        raise ValueError(f"{path} is empty")
    elapsed: list[float] = []
    series: dict[str, list[tuple[float | None, float | None]]] = {}
    if text.lstrip().startswith("{"):
        for number, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                elapsed.append(float(record["elapsed_s"]))
                for key, heater in record["heaters"].items():
                    series.setdefault(key, []).append((heater.get("actual"), heater.get("target")))
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"{path}:{number} is not a temperature log line: {exc}") from None
        return elapsed, series
    rows = list(csv.reader(io.StringIO(text)))
    header = rows[0]
    if header[:2] != ["time_utc", "elapsed_s"]:
        raise ValueError(f"{path} is not a marlin-temp log (its first line is {','.join(header)[:60]!r})")
    keys = [column[: -len("_actual")] for column in header[2:] if column.endswith("_actual")]
    index = {column: i for i, column in enumerate(header)}
    for row in rows[1:]:
        if len(row) != len(header):
            continue  # a row cut short by a crash in an older writer; skip it rather than fail
        elapsed.append(float(row[1]))
        for key in keys:
            actual = row[index[f"{key}_actual"]]
            target = row[index[f"{key}_target"]]
            series.setdefault(key, []).append((float(actual) if actual else None, float(target) if target else None))
    return elapsed, series
