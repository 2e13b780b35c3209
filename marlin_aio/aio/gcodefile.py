"""G-code files for printing: checked whole before the first line is sent, then read lazily while the file is
still the one checked.

The sans-I/O `PrintJob` takes any iterable of lines; this is where a file is opened and watched, so the protocol
folder never touches the file system.

A file read lazily can change under the print: cut short by a slicer writing it again, rewritten, appended to. Its
lines would then simply stop (and the print end as done at 5 %) or turn into another file's. So `file_lines`
compares the open file with what it was when it was checked (size and modification time, by `fstat` every
`_CHECK_EVERY_LINES` lines rather than every line, and before a last line without a line end, and at the end, where
the number of lines must also match) and stops with `FileChangedError`; the job then ends FAILED with it. A file
replaced by another (saved to a new file and renamed over it, as most editors do) is not a change under the print:
the open file is still the one checked, and it prints whole.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

from marlin_aio.errors import FileChangedError
from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.protocol.printjob import PrintJob, gcode_commands

__all__ = ["file_lines", "job_from_path", "scan_gcode"]

_CHECK_EVERY_LINES = 16


def scan_gcode(path: Path, limits: HeaterLimits | None = None) -> int:
    """Check every line of a file before printing it (and its heater targets against `limits`, if given); return
    how many commands it holds.

    Reading twice costs a pass over the file, but a print that stops half way at a bad line costs a part.

    Raises:
        ValueError: a line is not a valid command, or over `limits`; the message names the file and line.
        OSError: the file cannot be read.
    """
    return _scan(path, limits)[0]


def _scan(path: Path, limits: HeaterLimits | None) -> tuple[int, int]:
    """(commands, lines) of `path`, every line checked (see `scan_gcode`)."""
    commands = lines = 0
    with path.open(encoding="utf-8", errors="replace") as source:

        def counted() -> Iterator[str]:
            nonlocal lines
            for lines, line in enumerate(source, 1):  # noqa: B007  (`lines` is read once the loop is done)
                yield line

        try:
            for _ in gcode_commands(counted(), limits):
                commands += 1
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
    return commands, lines


def job_from_path(
    path: Path, *, start_s: float = 0.0, check: bool = True, limits: HeaterLimits | None = None
) -> PrintJob:
    """A job reading `path` lazily; with `check`, every line is validated (and counted) first, its heater
    targets against `limits` too.

    If the file changes while it prints (see `file_lines`), the job feeds nothing more and ends FAILED with a
    `FileChangedError`.

    Raises:
        ValueError: with `check`, a line is not a valid command or is over `limits`.
        OSError: the file cannot be read.
    """
    stamp = path.stat()  # before the scan: a change while it is scanned is a change too
    commands, lines = _scan(path, limits) if check else (None, None)
    return PrintJob(
        file_lines(path, size_bytes=stamp.st_size, mtime_ns=stamp.st_mtime_ns, lines_total=lines),
        name=path.name,
        lines_total=commands,
        source_bytes_total=stamp.st_size,
        start_s=start_s,
        limits=limits,
    )


def file_lines(
    path: Path, *, size_bytes: int | None = None, mtime_ns: int | None = None, lines_total: int | None = None
) -> Iterator[str]:
    """The lines of `path`, read lazily, as long as the file is the one that was checked.

    The file is opened now and compared, while it is read, with `size_bytes` and `mtime_ns` (its `st_size` and
    `st_mtime_ns` when it was checked; by default, as it is now) and, at its end, with `lines_total` (its number
    of lines, comments and blank ones included), if given. A file that changed stops the lines with
    `FileChangedError` before any line read after the change was noticed; `PrintJob` ends FAILED with it.

    Raises:
        OSError: the file cannot be opened (now) or read (later).
        FileChangedError: (while iterating) the file changed since it was checked; the message names the file,
            how it changed and the line reached.
    """
    return iter(_FileLines(path, size_bytes, mtime_ns, lines_total))


class _FileLines:
    """The lines of a file being printed, read lazily, stopping with `FileChangedError` once it changed.

    Opened at once (a file that cannot be read fails the call, not the print); read one line at a time.
    """

    def __init__(self, path: Path, size_bytes: int | None, mtime_ns: int | None, lines_total: int | None) -> None:
        self._path = path
        self._source = path.open(encoding="utf-8", errors="replace")
        opened = os.fstat(self._source.fileno())
        self._size_bytes = opened.st_size if size_bytes is None else size_bytes
        self._mtime_ns = opened.st_mtime_ns if mtime_ns is None else mtime_ns
        self._lines_total = lines_total

    def __iter__(self) -> Iterator[str]:
        with self._source as source:
            self._check(0, None)  # changed since it was checked, before anything was read
            # Checked every few lines, and at once past the last line counted (the file grew).
            past_end = math.inf if self._lines_total is None else self._lines_total + 1
            due = min(_CHECK_EVERY_LINES, past_end)
            handed = 0
            for number, line in enumerate(source, 1):
                # A line without its line end is the last the file has now: perhaps one cut in two.
                if number >= due or not line.endswith("\n"):
                    self._check(handed, number)
                    due = min(number + _CHECK_EVERY_LINES, past_end)
                handed = number
                yield line
            self._check(handed, None, at_end=True)

    def _check(self, handed: int, reading: int | None, *, at_end: bool = False) -> None:
        """Raise `FileChangedError` if the file is not the one checked; `handed` lines of it went to the print,
        `reading` is the line about to go (None: none is)."""
        now = os.fstat(self._source.fileno())
        total = self._lines_total
        if now.st_size != self._size_bytes:
            how = f"was {self._size_bytes:,} bytes, now {now.st_size:,}"
        elif now.st_mtime_ns != self._mtime_ns:
            how = f"rewritten: still {now.st_size:,} bytes, but modified since"
        elif total is not None and reading is not None and reading > total:
            how = f"it had {total:,} lines and now has more"
        elif total is not None and at_end and handed != total:
            how = f"it had {total:,} lines and now ends after {handed:,}"
        else:
            return
        name = self._path.name
        if handed == 0:
            message = f"the file {name} changed since it was checked ({how}); the print stopped before its first line"
        else:
            of = "" if total is None else f" of {total:,}"
            message = f"the file {name} changed while it printed ({how}) at line {handed:,}{of}; the print was stopped"
        raise FileChangedError(message, path=str(self._path), line=handed)
