"""Temperature log files: one row per reading, in CSV or JSON lines, safe to kill at any moment.

What a row says. Every row carries its own absolute time twice (`time`, ISO 8601 with the local offset, for
people; `epoch_s`, for programs), the `session` it belongs to (one run of `log` or `watch --log`, or one
connection of `log --reconnect`), the seconds since that session's first row (`session_elapsed_s`: it restarts
with each session, which is why nothing plots against it), and the `source` of the reading (`poll`, `auto`,
`wait`: the library's `ReadingSource`). Heaters are named as on the screen (`hotend`, `bed`, `hotend 0`; in CSV
column names the space becomes `_`), temperatures are in `_c`, power in `_power_percent`; Marlin's raw 0-127
power is kept only in `_power_raw`. So appended runs plot on one true time axis, and a file says what it means.

Why rows reach the disk: rows are buffered and written as whole lines at least once a second, so a crash or
SIGKILL loses at most the last second and never leaves half a row behind (the file still parses). The flush is
driven by time, not by the next row: the first row to wait in the buffer arms a timer for one flush interval
later. A printer that falls silent (or a link that drops) brings no next row, and the rows before it must still
reach the disk. That timer is why the log is an async context manager: it belongs to the running event loop,
taken in `__aenter__`.

When the file system says no (disk full, the file size limit, an I/O error), a write may still have put part of
the rows down: the file is cut back to the end of the last whole row, logging stops (`failure` says why in one
line, `wait_for_failure()` wakes whoever runs the log), and the summary counts the rows on disk, not the rows
read. The bytes go out with `os.write` on a file descriptor of the log's own: Python's buffered file keeps what a
failed write did not take and writes it again at close, behind the cut.

Appending: a file is appended to only when it is a log in this format with the same heaters (and, for CSV, the
same header); a file from an older marlin-temp (`time_utc,elapsed_s,T_actual,...`), of the other format, or not a
log at all is refused with one line before anything is written, so two vocabularies never mix in one file.
`read_log` still reads the older format, for `plot`.

Over 400 lines because the writers and the reader of the same two formats sit together: a column changed in
one is changed in the other in the same reading, and the disk-full and kill-safety rules above apply to both.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import errno
import io
import json
import math
import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from marlin_aio import HeaterReading, TemperatureReading
from marlin_aio.protocol import heater_name

__all__ = [
    "FIXED_COLUMNS",
    "HEATER_FIELDS",
    "HeaterSample",
    "LogContents",
    "LogFormat",
    "LogRow",
    "LogSession",
    "LogSummary",
    "LogWriteError",
    "RowSampler",
    "TemperatureLog",
    "column_prefix",
    "read_log",
]

LogFormat = str  # "csv" or "jsonl"

#: The columns every CSV row starts with, in this order; the heaters' columns follow.
FIXED_COLUMNS = ("time", "epoch_s", "session", "session_elapsed_s", "source")
#: Each heater's columns (CSV: `hotend_actual_c`, ...) and fields (JSON lines: `{"hotend": {"actual_c": ...}}`).
HEATER_FIELDS = ("actual_c", "target_c", "power_percent", "power_raw")
# The header of logs written before sessions and names: still read by `read_log`, never appended to.
_OLD_FIXED_COLUMNS = ("time_utc", "elapsed_s")


def column_prefix(key: str) -> str:
    """The CSV column prefix for a report's heater key: `"T"` gives `"hotend"`, `"T0"` gives `"hotend_0"`."""
    return heater_name(key).replace(" ", "_")


def _logged(heaters: dict[str, HeaterReading]) -> dict[str, HeaterReading]:
    """The heaters a row records: with several hotends each by number only (`T`, the active one, repeats one of
    them), as the screen and `watch --json` show them."""
    if "T" in heaters and any(key[:1] == "T" and key[1:].isdigit() for key in heaters):
        return {key: heater for key, heater in heaters.items() if key != "T"}
    return heaters


def _heater_columns(keys: Iterable[str]) -> list[str]:
    return [f"{column_prefix(key)}_{part}" for key in keys for part in HEATER_FIELDS]


def _iso(wall_time_s: float) -> str:
    # Local time with its offset: what the user's clock said, and still one instant for any reader.
    return datetime.fromtimestamp(wall_time_s).astimezone().isoformat(timespec="milliseconds")


def _number(value: float | None, decimals: int = 2) -> str:
    return "" if value is None else f"{value:.{decimals}f}"


def _percent(heater: HeaterReading) -> float | None:
    fraction = heater.power_fraction
    return None if fraction is None else round(fraction * 100, 1)


def _new_session_id() -> str:
    # Sortable and readable (when it started), and unique among runs started in the same second.
    return f"{datetime.now().astimezone():%Y%m%dT%H%M%S}-{secrets.token_hex(2)}"


class RowSampler:
    """Decides which readings become rows: one per `interval_s`, whatever produced them.

    Marlin reports temperatures three ways (the M105 poll's answer, the M155 auto-report, M109/M190 wait lines),
    and the client turns auto-reporting on beside the polls, so at a 1 s interval two reports of one moment
    arrive a few ms apart. The poll is the reading taken at the requested interval: it is accepted from half an
    interval before it is due. Any other reading stands in only when no poll came by a quarter interval after
    the due time (the queue blocked by G28 or a wait, a firmware that answers M105 late), so a heat-up under
    M109 is still recorded. Rows are never closer than half an interval, and the schedule keeps to the first
    row's phase (no drift) unless a stand-in shifts it.
    """

    def __init__(self, interval_s: float) -> None:
        if not interval_s > 0:
            raise ValueError(f"interval_s must be positive, got {interval_s}")
        self.interval_s = interval_s
        self._due: float | None = None
        self._last: float = -math.inf

    def restart(self) -> None:
        """Forget the schedule: the next reading is taken (a new session)."""
        self._due = None
        self._last = -math.inf

    def take(self, reading: TemperatureReading) -> bool:
        """Whether `reading` becomes a row (and, if so, schedule the next one)."""
        now = reading.monotonic_s
        interval = self.interval_s
        if self._due is not None:
            early = interval / 2 if reading.source == "poll" else -interval / 4
            if now < self._due - early or now - self._last < interval / 2:
                return False
        self._due = now + interval if self._due is None else max(self._due + interval, now + interval / 2)
        self._last = now
        return True


@dataclass
class LogSummary:
    """What a logging run wrote, for the one-line summary at the end."""

    path: Path
    rows: int = 0
    sessions: list[str] = field(default_factory=list)
    first: dict[str, float] = field(default_factory=dict)
    last: dict[str, float] = field(default_factory=dict)
    first_epoch_s: float | None = None
    last_epoch_s: float | None = None
    stopped: str | None = None  # why logging stopped before the end, and what was lost: "disk full: the last row ..."

    @property
    def elapsed_s(self) -> float:
        """Wall-clock seconds from the first row written to the last (across sessions)."""
        if self.first_epoch_s is None or self.last_epoch_s is None:
            return 0.0
        return self.last_epoch_s - self.first_epoch_s

    def line(self) -> str:
        """`wrote 60 rows to temps.csv over 59.0 s: hotend 25.0 -> 200.1 C, bed 25.0 -> 60.0 C`."""
        changes = ", ".join(
            f"{name} {self.first[name]:.1f} -> {self.last[name]:.1f} C" for name in self.last if name in self.first
        )
        sessions = f" in {len(self.sessions)} sessions" if len(self.sessions) > 1 else ""
        stopped = f"; {self.stopped}" if self.stopped else ""
        return (
            f"wrote {self.rows} rows to {self.path} over {self.elapsed_s:.1f} s{sessions}"
            + (f": {changes}" if changes else "")
            + stopped
        )


class LogWriteError(OSError):
    """The file system refused a log's rows (disk full, the file size limit, an I/O error); logging stopped.

    The message is one line: what happened, how many rows the file holds, what was lost. `errno` is the refusal's.
    """

    def __init__(self, message: str, error_number: int | None) -> None:
        super().__init__(message)
        self.errno = error_number


def _refusal(exc: OSError) -> str:
    """A write's refusal in words."""
    if exc.errno == errno.ENOSPC:
        return "disk full"
    if exc.errno == errno.EDQUOT:
        return "disk quota exceeded"
    if exc.errno == errno.EFBIG:
        return "file size limit reached"
    return (exc.strerror or str(exc)).lower()


class _Entry:
    """A queued line: a row (with the reading and session it counts for in the summary) or a header or line end."""

    __slots__ = ("data", "reading", "session")

    def __init__(self, text: str, reading: TemperatureReading | None = None, session: str = "") -> None:
        self.data = text.encode("utf-8")
        self.reading = reading
        self.session = session


class TemperatureLog:
    """Writes readings to `path` as CSV or JSON lines; use as an async context manager (`async with`).

    No row waits in memory longer than `flush_interval_s`, whether more rows follow or not. With `interval_s`
    a `RowSampler` keeps one reading per interval (`add` says whether it wrote one); without it every reading
    is a row. Each `TemperatureLog` starts a session of its own; `new_session()` starts another (after a
    reconnect).

    A write the file system refuses stops the log instead of raising: the file keeps its whole rows only,
    `failure` holds a `LogWriteError`, `wait_for_failure()` returns it, `add` takes no more rows, and
    `summary` counts what is on disk and says that logging stopped. So a view may go on without its log, and a
    command that exists to log can end on it.

    The file is its owner's alone: made 0600, and an existing one of this user's that others could read is made
    0600 on entering (`tightened_from` says what it was).

    Raises:
        ValueError: `fmt` is unknown, `flush_interval_s` or `interval_s` is not positive; on entering, `path`
            exists and is not a log of this format (an older marlin-temp's, the other format, not a log);
            later, an existing CSV has other heaters than this printer reports.
        OSError: the file cannot be opened.
    """

    def __init__(
        self, path: Path, fmt: LogFormat = "csv", flush_interval_s: float = 1.0, interval_s: float | None = None
    ) -> None:
        if fmt not in ("csv", "jsonl"):
            raise ValueError(f"unknown log format {fmt!r}: use csv or jsonl")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be positive, got {flush_interval_s}")
        self.path = path
        self.format = fmt
        self.flush_interval_s = flush_interval_s
        self.sampler = RowSampler(interval_s) if interval_s is not None else None
        self.summary = LogSummary(path)
        self.session = _new_session_id()
        self._session_start: float | None = None
        self._fd: int | None = None  # appending; None before `async with`, after close, and once logging stopped
        self._keys: list[str] | None = None  # the heater keys the CSV columns were made from
        self._existing_columns: list[str] | None = None
        self._pending: list[_Entry] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._flush_timer: asyncio.TimerHandle | None = None
        self._error: ValueError | None = None  # met by a timed flush, raised by the next add() or flush()
        self._header: str | None = None  # the CSV header, until it is written (or found already there)
        self.failure: LogWriteError | None = None  # why logging stopped, if the file system refused a write
        self._failed: asyncio.Event | None = None
        self._created = False  # this log made the file (it was not there): one left empty is taken away again
        self.tightened_from: int | None = None
        """The mode (0o644, say) an existing file had before this log made it owner-only; None if it was already."""

    async def __aenter__(self) -> TemperatureLog:
        needs_newline = self._check_existing()
        self._created = not self.path.exists()
        # A temperature log of a print farm is nobody else's: made owner-only, and one others could read is made so.
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o600)
        mode = os.fstat(self._fd).st_mode & 0o777
        if mode & 0o077:
            # The open file, not the path: no window for a swapped file. Another user's file that we may write to
            # stays as its owner shared it.
            with contextlib.suppress(PermissionError):
                os.fchmod(self._fd, 0o600)
                self.tightened_from = mode
        if needs_newline:
            self._pending.append(_Entry("\n"))  # a last line cut short by someone else's crash stays a line of its own
        self._loop = asyncio.get_running_loop()
        self._failed = asyncio.Event()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def _check_existing(self) -> bool:
        """Refuse a file this log must not append to; return whether its last line lacks its line end."""
        if not self.path.exists() or self.path.stat().st_size == 0:
            return False
        try:
            with self.path.open(encoding="utf-8", newline="") as existing:
                first = existing.readline()
        except UnicodeDecodeError:
            raise ValueError(f"{self.path} is not a marlin-temp log (not text): choose another file") from None
        with self.path.open("rb") as raw:
            raw.seek(-1, os.SEEK_END)
            needs_newline = raw.read(1) != b"\n"
        shown = first.strip()[:60]
        other = "choose another file"
        if first.lstrip().startswith("{"):
            if self.format != "jsonl":
                raise ValueError(
                    f"{self.path} holds JSON lines and this log writes CSV: {other} "
                    "('marlin-temp log --format jsonl' appends to it)"
                )
            try:
                record = json.loads(first)
            except ValueError:
                record = None
            if isinstance(record, dict) and "session" in record and "epoch_s" in record:
                return needs_newline
            if isinstance(record, dict) and "time_utc" in record:
                raise ValueError(
                    f"{self.path} has other columns than this version of marlin-temp writes (an older log: "
                    f"time_utc, elapsed_s, T/B heaters, raw power); appending would mix them: {other} "
                    "(plot still reads it)"
                )
            raise ValueError(f"{self.path} is not a marlin-temp log (its first line is {shown!r}): {other}")
        header = next(csv.reader([first]), [])
        if self.format != "csv":
            raise ValueError(
                f"{self.path} is a CSV file and this log writes JSON lines: {other} ('--format csv' appends to it)"
            )
        if tuple(header[: len(FIXED_COLUMNS)]) == FIXED_COLUMNS:
            self._existing_columns = header
            return needs_newline
        if tuple(header[: len(_OLD_FIXED_COLUMNS)]) == _OLD_FIXED_COLUMNS:
            raise ValueError(
                f"{self.path} has other columns than this version of marlin-temp writes (an older log: "
                f"{', '.join(header[:5])}, ...); appending would mix them: {other} (plot still reads it)"
            )
        raise ValueError(f"{self.path} is not a marlin-temp log (its first line is {shown!r}): {other}")

    def check_heaters(self, keys: Iterable[str]) -> None:
        """Fix the CSV columns for these heater keys now (before the first row), or refuse them.

        Call it with a first reading's keys before changing anything on the printer: an existing file with other
        heaters is refused while nothing has happened yet. (Without it, the first row fixes the columns.)

        Raises:
            ValueError: an existing CSV, or this log's earlier rows, have other heaters.
        """
        if self.format != "csv":
            return
        keys = list(keys)
        if "T" in keys and any(key[:1] == "T" and key[1:].isdigit() for key in keys):
            keys.remove("T")  # as `_logged`: with several hotends, each by number only
        if self._keys is not None:
            if _heater_columns(self._keys) != _heater_columns(keys):
                raise ValueError(
                    f"the printer now reports other heaters ({', '.join(map(heater_name, keys))}) than when "
                    f"logging to {self.path} began ({', '.join(map(heater_name, self._keys))}); choose another "
                    "--output file"
                )
            return
        columns = [*FIXED_COLUMNS, *_heater_columns(keys)]
        if self._existing_columns is not None:
            if self._existing_columns != columns:
                theirs = ", ".join(self._existing_columns[len(FIXED_COLUMNS) :]) or "none"
                raise ValueError(
                    f"{self.path} has other columns ({theirs}) than this printer reports "
                    f"({', '.join(columns[len(FIXED_COLUMNS) :])}); choose another --output file"
                )
        else:
            self._header = ",".join(columns) + "\n"
            self._existing_columns = columns
        self._keys = keys

    def new_session(self) -> str:
        """Start a new session (a new id; `session_elapsed_s` and the sampler start again); return its id."""
        self.session = _new_session_id()
        self._session_start = None
        if self.sampler is not None:
            self.sampler.restart()
        return self.session

    def add(self, reading: TemperatureReading, extra: dict[str, Any] | None = None) -> bool:
        """Queue one row, unless the sampler skips this reading; return whether a row was queued. `extra` (JSON
        lines only) adds fields to the row: `marlin-temp serve` puts the print's file and line there.

        A row reaches the file within `flush_interval_s`, even if no other row follows. Once logging stopped
        (`failure`), nothing is queued.

        Raises:
            ValueError: an existing CSV has other heaters than this reading's (or, met by a timed flush, another
                program began the same new file with other columns).
            RuntimeError: the log is not open (`async with`).
        """
        if self._loop is None:
            raise RuntimeError("the log is not open: use `async with TemperatureLog(...)`")
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        if self.failure is not None:
            return False  # logging stopped; `failure` says why
        heaters = _logged(reading.temperatures.heaters)
        if not heaters:
            return False
        if self._keys is None and self.format == "csv":
            self.check_heaters(heaters)
        if self.sampler is not None and not self.sampler.take(reading):
            return False
        if self._session_start is None:
            self._session_start = reading.monotonic_s
        elapsed = reading.monotonic_s - self._session_start
        fixed = [_iso(reading.wall_time_s), f"{reading.wall_time_s:.3f}", self.session, f"{elapsed:.3f}"]
        if self.format == "csv":
            assert self._keys is not None
            row = [*fixed, str(reading.source)]
            for key in self._keys:
                heater = heaters.get(key)
                if heater is None:
                    row += ["", "", "", ""]
                else:
                    power = None if heater.power is None else float(heater.power)
                    row += [_number(heater.actual), _number(heater.target), _number(_percent(heater), 1)]
                    row.append(_number(power, 0))
            buffer = io.StringIO()
            csv.writer(buffer, lineterminator="\n").writerow(row)
            self._pending.append(_Entry(buffer.getvalue(), reading, self.session))
        else:
            record = {
                "time": fixed[0],
                "epoch_s": round(reading.wall_time_s, 3),
                "session": self.session,
                "session_elapsed_s": round(elapsed, 3),
                "source": str(reading.source),
                "heaters": {
                    heater_name(key): {
                        "actual_c": heater.actual,
                        "target_c": heater.target,
                        "power_percent": _percent(heater),
                        "power_raw": heater.power,
                    }
                    for key, heater in heaters.items()
                },
            }
            if extra:
                record.update(extra)
            self._pending.append(_Entry(json.dumps(record) + "\n", reading, self.session))
        if self._flush_timer is None:
            # The oldest row in the buffer sets the deadline; rows after it go out with it, sooner than theirs.
            self._flush_timer = self._loop.call_later(self.flush_interval_s, self._flush_due)
        return True

    def _count(self, reading: TemperatureReading, session: str) -> None:
        """A row is on disk: count it in the summary."""
        summary = self.summary
        summary.rows += 1
        if not summary.sessions or summary.sessions[-1] != session:
            summary.sessions.append(session)
        if summary.first_epoch_s is None:
            summary.first_epoch_s = reading.wall_time_s
        summary.last_epoch_s = reading.wall_time_s
        for key, heater in _logged(reading.temperatures.heaters).items():
            summary.first.setdefault(heater_name(key), heater.actual)
            summary.last[heater_name(key)] = heater.actual

    def _flush_due(self) -> None:
        self._flush_timer = None
        try:
            self.flush()
        except ValueError as exc:
            # Raised in a timer callback, it would only reach the loop's log: keep it for the recorder to meet.
            self._error = exc

    def flush(self) -> None:
        """Write every queued row as whole lines and push them to the disk.

        A write the file system refuses stops logging (see the class) rather than raising.

        Raises:
            ValueError: another program began the same new file with other columns meanwhile (also met by a
                timed flush since the last call).
        """
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        if not self._pending or self._fd is None:
            return
        if self._header is not None:
            self._write_header(self._fd)
        entries, self._pending = self._pending, []
        data = b"".join(entry.data for entry in entries)
        start = os.fstat(self._fd).st_size  # appends land here (another writer at the same moment aside)
        written = 0
        try:
            # One write of whole lines: a kill between writes can cut the file only at a line end. A full disk
            # takes what fits (a short write), then refuses the rest.
            while written < len(data):
                written += os.write(self._fd, data[written:])
            os.fsync(self._fd)
        except OSError as exc:
            # After a refused fsync nothing of the batch is known to be on disk: none of it counts.
            self._stop(exc, entries, start, written if written < len(data) else 0)
            return
        for entry in entries:
            if entry.reading is not None:
                self._count(entry.reading, entry.session)

    def _stop(self, exc: OSError, entries: list[_Entry], start: int, written: int) -> None:
        """The file system refused a write after `written` bytes of `entries`: keep their whole rows, cut the rest,
        and stop logging."""
        kept = lost = 0  # bytes of whole lines on disk; rows not written
        whole = True
        for entry in entries:
            whole = whole and kept + len(entry.data) <= written
            if whole:
                kept += len(entry.data)
                if entry.reading is not None:
                    self._count(entry.reading, entry.session)
            elif entry.reading is not None:
                lost += 1
        fd, self._fd = self._fd, None
        assert fd is not None
        try:
            os.ftruncate(fd, start + kept)  # a smaller file always fits, even on a full disk or at the size limit
        except OSError:
            pass  # nothing more can be done for the file
        finally:
            os.close(fd)
        why = _refusal(exc)
        unwritten = "the last row was" if lost == 1 else f"the last {lost:,} rows were"
        stopped = f"{unwritten} not written and logging stopped" if lost else "logging stopped"
        self.summary.stopped = f"{why}: {stopped}"
        self.failure = LogWriteError(f"{why}: wrote {self.summary.rows:,} rows to {self.path}; {stopped}", exc.errno)
        if self._failed is not None:
            self._failed.set()

    async def wait_for_failure(self) -> LogWriteError:
        """Wait until the file system refuses a write and logging stops; return why (at once if it already did).

        Raises:
            RuntimeError: the log is not open (`async with`).
        """
        if self._failed is None:
            raise RuntimeError("the log is not open: use `async with TemperatureLog(...)`")
        await self._failed.wait()
        assert self.failure is not None
        return self.failure

    def _write_header(self, fd: int) -> None:
        # `log` and `watch --log` started at once on a new file both found it empty: the first to write gives the
        # header, the other finds it there (the same columns, or it must not write at all).
        header, self._header = self._header, None
        assert header is not None
        if os.fstat(fd).st_size == 0:
            self._pending.insert(0, _Entry(header))
            return
        with self.path.open(encoding="utf-8", newline="") as existing:
            theirs = existing.readline()
        if theirs != header:
            self._pending.clear()
            os.close(fd)  # nothing more of ours goes into a file with their columns
            self._fd = None
            raise ValueError(
                f"another program began {self.path} with other columns ({theirs.strip()[:60]!r}) while this log was "
                "starting; choose another --output file"
            )

    def close(self) -> None:
        """Flush and close (idempotent).

        Raises:
            ValueError: as `flush` (the file is closed all the same).
        """
        if self._fd is None:
            return
        try:
            self.flush()
        finally:
            if self._fd is not None:
                empty = os.fstat(self._fd).st_size == 0
                os.close(self._fd)
                self._fd = None
                if self._created and empty:
                    # Nothing was ever written (the printer could not be reached, say): no empty file is left
                    # behind where there was none.
                    with contextlib.suppress(OSError):
                        self.path.unlink()


# ------------------------------------------------------------------------------------------- reading back


@dataclass(frozen=True, slots=True)
class HeaterSample:
    """One heater in one row read back: temperatures in C, power in percent (None where the row has none)."""

    actual_c: float | None
    target_c: float | None
    power_percent: float | None


@dataclass(frozen=True, slots=True)
class LogRow:
    """One row read back: its absolute time, what produced it, and each heater by name (`hotend`, `bed`)."""

    epoch_s: float
    source: str
    heaters: dict[str, HeaterSample]


@dataclass(frozen=True)
class LogSession:
    """The rows of one session, in time order."""

    id: str
    rows: list[LogRow]

    @property
    def start_epoch_s(self) -> float:
        """When its first row was read."""
        return self.rows[0].epoch_s

    @property
    def end_epoch_s(self) -> float:
        """When its last row was read."""
        return self.rows[-1].epoch_s


@dataclass(frozen=True)
class LogContents:
    """A log read back: its sessions in time order, and whether it is in the older format."""

    sessions: list[LogSession]
    old_format: bool = False

    @property
    def rows(self) -> int:
        """How many rows all sessions hold."""
        return sum(len(session.rows) for session in self.sessions)


def _float(text: str | float | int | None) -> float | None:
    if text is None or text == "":
        return None
    value = float(text)
    return value if math.isfinite(value) else None


def _old_percent(raw: str | float | int | None) -> float | None:
    power = _float(raw)
    return None if power is None else min(max(power / 127 * 100, 0.0), 100.0)


def _epoch_of(iso: str) -> float:
    return datetime.fromisoformat(iso).timestamp()  # `Z` and offsets alike (Python 3.11+)


class _Sessions:
    """Rows grouped by session id, in order of first appearance; an old log's runs are found by elapsed_s."""

    def __init__(self) -> None:
        self.rows: dict[str, list[LogRow]] = {}
        self._old_elapsed: float | None = None
        self._old_count = 0

    def add(self, session: str, row: LogRow) -> None:
        self.rows.setdefault(session, []).append(row)

    def add_old(self, elapsed_s: float, row: LogRow) -> None:
        # Before sessions existed, an appended run showed only as elapsed_s starting again from 0.
        if self._old_elapsed is None or elapsed_s < self._old_elapsed:
            self._old_count += 1
        self._old_elapsed = elapsed_s
        self.add(f"run {self._old_count}", row)

    def contents(self, old_format: bool) -> LogContents:
        sessions = [LogSession(key, sorted(rows, key=lambda r: r.epoch_s)) for key, rows in self.rows.items() if rows]
        sessions.sort(key=lambda s: s.start_epoch_s)
        return LogContents(sessions, old_format)


def read_log(path: Path) -> LogContents:
    """Read a CSV or JSON-lines log back (this format or the older one without sessions), sessions in time order.

    Rows cut short (by a crash in an older writer) are skipped; anything else that does not parse is an error.

    Raises:
        ValueError: the file is empty or not a temperature log (saying which line is wrong).
        OSError: it cannot be read.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not a marlin-temp log (not text)") from None
    if not text.strip():
        raise ValueError(f"{path} is empty")
    if text.lstrip().startswith("{"):
        return _read_jsonl(path, text)
    return _read_csv(path, text)


def _read_jsonl(path: Path, text: str) -> LogContents:
    sessions = _Sessions()
    old = False
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            record: dict[str, Any] = json.loads(line)
            if "session" in record:
                heaters = {
                    name: HeaterSample(
                        _float(h.get("actual_c")), _float(h.get("target_c")), _float(h.get("power_percent"))
                    )
                    for name, h in record["heaters"].items()
                }
                sessions.add(str(record["session"]), LogRow(float(record["epoch_s"]), record["source"], heaters))
            else:
                old = True
                heaters = {
                    heater_name(key): HeaterSample(
                        _float(h.get("actual")), _float(h.get("target")), _old_percent(h.get("power"))
                    )
                    for key, h in record["heaters"].items()
                }
                row = LogRow(_epoch_of(record["time_utc"]), str(record.get("source", "")), heaters)
                sessions.add_old(float(record["elapsed_s"]), row)
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"{path}:{number} is not a temperature log line ({exc})") from None
    return sessions.contents(old)


def _read_csv(path: Path, text: str) -> LogContents:
    rows = list(csv.reader(io.StringIO(text)))
    header = rows[0]
    if tuple(header[: len(FIXED_COLUMNS)]) == FIXED_COLUMNS:
        old = False
        suffix = "_" + HEATER_FIELDS[0]
    elif tuple(header[: len(_OLD_FIXED_COLUMNS)]) == _OLD_FIXED_COLUMNS:
        old = True
        suffix = "_actual"
    else:
        raise ValueError(f"{path} is not a marlin-temp log (its first line is {','.join(header)[:60]!r})")
    prefixes = [column[: -len(suffix)] for column in header if column.endswith(suffix)]
    index = {column: i for i, column in enumerate(header)}

    def cell(row: list[str], column: str) -> float | None:
        position = index.get(column)
        return None if position is None else _float(row[position])

    sessions = _Sessions()
    for number, row in enumerate(rows[1:], 2):
        if len(row) != len(header) or row == header:
            continue  # a row cut short by a crash in an older writer, or a header again; skip it rather than fail
        try:
            heaters: dict[str, HeaterSample] = {}
            if old:
                for key in prefixes:
                    actual = cell(row, f"{key}_actual")
                    if actual is not None:
                        power = _old_percent(cell(row, f"{key}_power"))
                        heaters[heater_name(key)] = HeaterSample(actual, cell(row, f"{key}_target"), power)
                sessions.add_old(float(row[1]), LogRow(_epoch_of(row[0]), "", heaters))
            else:
                for prefix in prefixes:
                    actual = cell(row, f"{prefix}_actual_c")
                    if actual is not None:
                        target, percent = cell(row, f"{prefix}_target_c"), cell(row, f"{prefix}_power_percent")
                        heaters[prefix.replace("_", " ")] = HeaterSample(actual, target, percent)
                sessions.add(row[2], LogRow(float(row[1]), row[4], heaters))
        except ValueError as exc:
            raise ValueError(f"{path}:{number} is not a temperature log row ({exc})") from None
    return sessions.contents(old)
