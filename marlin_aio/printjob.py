"""A G-code print job: the lines of a file, fed to the connection as its window opens, with progress.

No I/O beyond reading the source lazily (one line at a time, so a 1 GB file streams in constant memory), and no
asyncio: the connection pulls the next command with `next_command()` and reports back with `sent()`, `acked()` and
`fail()`. The job knows nothing of line numbers; the connection numbers every line it writes.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from marlin_aio.commands import encode_command, strip_comment
from marlin_aio.errors import MarlinError

__all__ = ["PrintJob", "PrintProgress", "PrintState", "gcode_commands", "scan_gcode"]


class PrintState(Enum):
    """Where a job stands."""

    RUNNING = "running"
    PAUSED = "paused"  # no new lines are fed; what is in flight completes; heaters stay as they are
    CANCELLED = "cancelled"
    DONE = "done"
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class PrintProgress:
    """A snapshot of a job: counts, rates and the estimate of what remains.

    Lines and bytes are G-code commands as sent (comments and blank lines removed); `source_*` count the file.
    `fraction` is based on the source bytes acknowledged when the total is known.
    """

    state: PrintState
    lines_sent: int
    lines_acked: int
    lines_total: int | None
    bytes_acked: int
    source_bytes_acked: int
    source_bytes_total: int | None
    elapsed_s: float
    resends: int
    last_source_line: int  # the file line of the last command acknowledged

    @property
    def fraction(self) -> float | None:
        """Share done, 0.0-1.0, or None when the size is unknown."""
        if self.lines_total:
            return min(self.lines_acked / self.lines_total, 1.0)
        if self.source_bytes_total:
            return min(self.source_bytes_acked / self.source_bytes_total, 1.0)
        return None

    @property
    def lines_per_s(self) -> float:
        """Average rate of acknowledged lines since the start."""
        return self.lines_acked / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def eta_s(self) -> float | None:
        """Seconds left at the average rate so far, or None when unknown."""
        fraction = self.fraction
        if fraction is None or fraction <= 0 or self.elapsed_s <= 0:
            return None
        return self.elapsed_s * (1 - fraction) / fraction


def gcode_commands(lines: Iterable[str]) -> Iterator[tuple[str, int, int]]:
    """Yield (command, source line number, source bytes) for each line that holds a command.

    Comments and blank lines are dropped (Marlin would lose a checksum placed after a `;`). Source bytes include
    the skipped lines before a command, so their sum is the size of the source.

    Raises:
        ValueError: a line is not a valid command (too long, non-ASCII, ...); the message names its line number.
    """
    pending_bytes = 0
    for number, raw in enumerate(lines, 1):
        pending_bytes += len(raw.encode("utf-8", errors="replace")) + (0 if raw.endswith("\n") else 1)
        command = strip_comment(raw)
        if not command:
            continue
        try:
            encode_command(command)
        except ValueError as exc:
            raise ValueError(f"line {number}: {exc}") from None
        yield command, number, pending_bytes
        pending_bytes = 0


def scan_gcode(path: Path) -> int:
    """Check every line of a file before printing it; return how many commands it holds.

    Reading twice costs a pass over the file, but a print that stops half way at a bad line costs a part.

    Raises:
        ValueError: a line is not a valid command; the message names the file and line.
        OSError: the file cannot be read.
    """
    count = 0
    with path.open(encoding="utf-8", errors="replace") as source:
        try:
            for _ in gcode_commands(source):
                count += 1
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
    return count


class PrintJob:
    """The state of one print: where the source stands, what was sent and acknowledged, and how it ended.

    Args:
        lines: the G-code, read lazily (a file object, a generator, a list).
        name: shown in messages (the file name).
        lines_total: number of commands, if known (for progress).
        source_bytes_total: size of the source, if known (for progress).
        start_s: the connection clock's time when the job starts.
    """

    def __init__(
        self,
        lines: Iterable[str],
        *,
        name: str = "G-code",
        lines_total: int | None = None,
        source_bytes_total: int | None = None,
        start_s: float = 0.0,
    ) -> None:
        self.name = name
        self._commands = gcode_commands(lines)
        self.lines_total = lines_total
        self.source_bytes_total = source_bytes_total
        self.state = PrintState.RUNNING
        self.error: MarlinError | None = None
        self.exhausted = False
        self.cancelling = False  # cancel() was called; the state turns CANCELLED once nothing is in flight
        self.start_s = start_s
        self.end_s: float | None = None
        self.lines_sent = 0
        self.lines_acked = 0
        self.bytes_acked = 0
        self.source_bytes_acked = 0
        self.resends = 0
        self.in_flight = 0
        self.last_source_line = 0

    @classmethod
    def from_path(cls, path: Path, *, start_s: float = 0.0, check: bool = True) -> PrintJob:
        """A job reading `path` lazily; with `check`, every line is validated (and counted) first.

        Raises:
            ValueError: with `check`, a line is not a valid command.
            OSError: the file cannot be read.
        """
        total = scan_gcode(path) if check else None
        source = path.open(encoding="utf-8", errors="replace")
        return cls(
            _closing_lines(source),
            name=path.name,
            lines_total=total,
            source_bytes_total=os.path.getsize(path),
            start_s=start_s,
        )

    @property
    def active(self) -> bool:
        """True while the job may still feed lines or wait for answers."""
        return self.state in (PrintState.RUNNING, PrintState.PAUSED)

    @property
    def finished(self) -> bool:
        """True once the job ended, one way or another."""
        return not self.active

    def next_command(self) -> tuple[str, int, int] | None:
        """The next command to send, with its source line and source bytes; None if none should go now."""
        if self.state is not PrintState.RUNNING or self.exhausted:
            return None
        try:
            return next(self._commands)
        except StopIteration:
            self.exhausted = True
            return None
        except ValueError as exc:
            # Only reachable without the up-front check: stop feeding, let what is in flight complete.
            self.exhausted = True
            self.error = MarlinError(f"{self.name}: {exc}; the print stopped before that line")
            return None

    def sent(self) -> None:
        """A command of this job went out for the first time."""
        self.lines_sent += 1
        self.in_flight += 1

    def acked(self, wire_bytes: int, source_bytes: int, source_line: int, now: float) -> None:
        """The printer acknowledged a command of this job."""
        self.in_flight -= 1
        self.lines_acked += 1
        self.bytes_acked += wire_bytes
        self.source_bytes_acked += source_bytes
        self.last_source_line = source_line
        self.finish_if_idle(now)

    def finish_if_idle(self, now: float) -> None:
        """End the job once nothing more will be fed and everything sent was answered."""
        if self.in_flight == 0 and self.active and self.exhausted:
            if self.error is not None:
                self.state = PrintState.FAILED
            elif self.cancelling:
                self.state = PrintState.CANCELLED
            elif self.state is PrintState.RUNNING:
                self.state = PrintState.DONE
            else:
                return  # paused with the source used up: done only once resumed
            self.end_s = now

    def fail(self, error: MarlinError, now: float) -> None:
        """The print cannot go on (stall, halt, reset, link lost)."""
        if self.active:
            self.error = error
            self.state = PrintState.FAILED
            self.end_s = now

    def pause(self) -> None:
        """Stop feeding new lines; what is in flight still completes."""
        if self.state is PrintState.RUNNING:
            self.state = PrintState.PAUSED

    def resume(self, now: float = 0.0) -> None:
        """Feed lines again after `pause()`."""
        if self.state is PrintState.PAUSED:
            self.state = PrintState.RUNNING
            self.finish_if_idle(now)

    def cancel(self, now: float) -> None:
        """Stop feeding for good; the job ends (CANCELLED) once what is in flight has been answered."""
        if self.active:
            self.cancelling = True
            self.exhausted = True
            self.finish_if_idle(now)

    def progress(self, now: float) -> PrintProgress:
        """A snapshot for display."""
        end = self.end_s if self.end_s is not None else now
        return PrintProgress(
            state=self.state,
            lines_sent=self.lines_sent,
            lines_acked=self.lines_acked,
            lines_total=self.lines_total,
            bytes_acked=self.bytes_acked,
            source_bytes_acked=self.source_bytes_acked,
            source_bytes_total=self.source_bytes_total,
            elapsed_s=max(end - self.start_s, 0.0),
            resends=self.resends,
            last_source_line=self.last_source_line,
        )


def _closing_lines(source: Iterable[str]) -> Iterator[str]:
    """Yield the lines of an open file and close it when done (or when the generator is dropped)."""
    try:
        yield from source
    finally:
        close = getattr(source, "close", None)
        if close is not None:
            close()
