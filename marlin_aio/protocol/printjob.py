"""A G-code print job: lines from any iterable, fed to the connection as its window opens, with progress.

No I/O and no asyncio: the job pulls its lines from the iterable it was given (one at a time, so a 1 GB file streams
in constant memory; `marlin_aio.aio.gcodefile` makes that iterable from a file, and is where files are opened), the
connection pulls the next command with `next_command()` and reports back with `sent()`, `acked()` and `fail()`.
The job knows nothing of line numbers; the connection numbers every line it writes.

When its lines stop with `FileChangedError` (the file changed under the print), the job feeds nothing more and ends
FAILED with that error once what is in flight is answered, as it does at a bad line. (Not through `fail()`: that
would end the print while lines of the file as checked are still on their way, and `next_command` has no clock
for the end time.)

A job may be fed under a bound (`feed_limit`, a line of the file): it feeds no line past it, holding the next one
until the bound is raised. A service raises it in steps, each after recording and telling it
(`marlin_aio.service.lifecycle`), so "may have run through" (`PrintProgress.may_have_run_through`) is never below a
line the printer was sent, even if the service is killed the next moment.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from enum import Enum

from marlin_aio.errors import FileChangedError, MarlinError
from marlin_aio.protocol.commands import check_numbered_length, encode_command, strip_comment
from marlin_aio.protocol.heaters import HeaterLimits, check_gcode_targets

__all__ = ["STOPPED_BY_SERVICE", "PrintJob", "PrintProgress", "PrintState", "check_command", "gcode_commands"]

#: How `PrintProgress.cancelled_by` begins when the service that ran the print cancelled it as it stopped.
STOPPED_BY_SERVICE = "the service stopped"


# Checked every 16 lines, reading costs about 0.2 us a line more than a bare file (1M lines: 0.28 s against 0.07 s),
# a fifth of what `gcode_commands` alone spends on a line; and a file rewritten in place slips at most 15 lines in.
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
    paused_by: str | None = None
    """Why the printer itself paused the print (`printer asked: filament_runout 0`); None when it runs, or when
    the caller paused it."""
    cancelled_by: str | None = None
    """Why the printer itself cancelled the print (`printer asked: cancel`), or the service running it as it
    stopped (begins with `STOPPED_BY_SERVICE`); None when the caller did, or it was not cancelled."""
    may_have_run_through: int | None = None
    """The last file line that may have run: no line after it was sent. While a bounded job runs, its bound (lines
    up to it may be sent before the next report); else the last line written. None: not known (an older service)."""
    unknown_codes: tuple[str, ...] = ()
    """Commands the firmware does not know (`Unknown command` with the text as sent), in the order first met:
    Marlin skipped those lines and the print went on (unless the job stops on them, `stop_on_unknown`)."""

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


def check_command(command: str, limits: HeaterLimits | None = None) -> None:
    """Check one command (its comment removed) as a print sends it: Marlin can take it (`encode_command`: one line,
    ASCII, no `*`; and short enough once numbered and checksummed, as every print line is: `check_numbered_length`)
    and, with `limits`, it sets no heater above them however it is spelt (`check_gcode_targets`). Every line of a
    print passes this, whoever reads the file: `gcode_commands` here, or a front end that reads it its own way
    (the CLI's print plan, which also transliterates display text).

    Raises:
        ValueError: the command is not valid, or sets a target that is not a number, negative or over `limits`.
    """
    encode_command(command)
    check_numbered_length(command)
    if limits is not None:
        check_gcode_targets(command, limits)


def gcode_commands(lines: Iterable[str], limits: HeaterLimits | None = None) -> Iterator[tuple[str, int, int]]:
    """Yield (command, source line number, source bytes) for each line that holds a command.

    Comments and blank lines are dropped (Marlin would lose a checksum placed after a `;`). Source bytes include
    the skipped lines before a command, so their sum is the size of the source. With `limits`, a line that sets a
    heater target above them (however it is spelt) is refused like a malformed one.

    Raises:
        ValueError: a line is not a valid command (too long, non-ASCII, ...) or is over `limits`; the message names
            its line number.
    """
    pending_bytes = 0
    for number, raw in enumerate(lines, 1):
        pending_bytes += len(raw.encode("utf-8", errors="replace")) + (0 if raw.endswith("\n") else 1)
        command = strip_comment(raw)
        if not command:
            continue
        try:
            check_command(command, limits)
        except ValueError as exc:
            raise ValueError(f"line {number}: {exc}") from None
        yield command, number, pending_bytes
        pending_bytes = 0


class PrintJob:
    """The state of one print: where the source stands, what was sent and acknowledged, and how it ended.

    Args:
        lines: the G-code, read lazily (a file object, a generator, a list).
        name: shown in messages (the file name).
        lines_total: number of commands, if known (for progress).
        source_bytes_total: size of the source, if known (for progress).
        start_s: the connection clock's time when the job starts.
        limits: the heater limits each line is checked against as it is fed (a line over them stops the print
            before it). None: those of the connection it is attached to.
        stop_on_unknown: stop the print at a command the firmware does not know (its `Unknown command` echoes the
            line as sent), instead of warning once per command and going on as Marlin does (it skips the line;
            OctoPrint and Pronterface go on too). A build without `M73`, which slicers write near the top, would
            otherwise stop every print there.
    """

    def __init__(
        self,
        lines: Iterable[str],
        *,
        name: str = "G-code",
        lines_total: int | None = None,
        source_bytes_total: int | None = None,
        start_s: float = 0.0,
        limits: HeaterLimits | None = None,
        stop_on_unknown: bool = False,
    ) -> None:
        self.name = name
        self.stop_on_unknown = stop_on_unknown
        self.unknown_codes: dict[str, int] = {}  # code -> the file line it was first met at (see `lacked`)
        self.limits = limits
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
        self.paused_by: str | None = None  # the firmware's request that paused it (see PrintProgress.paused_by)
        self.cancelled_by: str | None = None
        self.feed_limit: int | None = None
        """No line of the file past this one is fed (None: no bound). Raised by whoever bounds the job."""
        self.fed_through = 0  # the file line of the last command handed to the connection
        self.written_through = 0  # the file line of the last command written to the printer
        self._held: tuple[str, int, int] | None = None  # read, but past `feed_limit`: fed once the bound is raised

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
        command = self._held if self._held is not None else self._read()
        if command is None:
            return None
        if self.feed_limit is not None and command[1] > self.feed_limit:
            self._held = command  # fed once the bound is raised past it
            return None
        self._held = None
        self.fed_through = command[1]
        return command

    @property
    def held_line(self) -> int | None:
        """The file line of the command waiting for `feed_limit` to be raised past it, or None."""
        return None if self._held is None else self._held[1]

    def _read(self) -> tuple[str, int, int] | None:
        """The next command of the source, checked; None (and the job exhausted) when there is none."""
        try:
            command = next(self._commands)
            if self.limits is not None:
                try:
                    check_gcode_targets(command[0], self.limits)
                except ValueError as exc:
                    raise ValueError(f"line {command[1]}: {exc}") from None
            return command
        except StopIteration:
            self.exhausted = True
            return None
        except ValueError as exc:
            # Only reachable without the up-front check (a bad line, a target over the limits): stop feeding, let
            # what is in flight complete.
            self.exhausted = True
            self.error = MarlinError(f"{self.name}: {exc}; the print stopped before that line")
            return None
        except FileChangedError as exc:
            # As at a bad line: what is on its way is the file as checked; nothing read after the change goes.
            self.exhausted = True
            self.error = exc
            return None
        except OSError as exc:
            self.exhausted = True
            self.error = MarlinError(f"{self.name} could not be read further ({exc}); the print was stopped")
            return None
        except Exception as exc:
            # The lines may come from the caller's own iterable: user code, run from the read path. Whatever it
            # raises ends the print with that error, never the link, and never as "done".
            self.exhausted = True
            self.error = MarlinError(f"{self.name}: its lines raised {exc!r}; the print was stopped before the next")
            return None

    def sent(self, source_line: int = 0) -> None:
        """A command of this job (at `source_line` of the file) went out for the first time."""
        self.lines_sent += 1
        self.in_flight += 1
        self.written_through = max(self.written_through, source_line)

    def limit_by(self, limits: HeaterLimits) -> None:
        """Check every line against `limits`, unless the job was made with limits of its own."""
        if self.limits is None:
            self.limits = limits

    def asked_again(self) -> None:
        """The printer asked for a line of this job again."""
        self.resends += 1

    def withdrew_line(self) -> None:
        """A line of this job that went out will never be answered (withdrawn, or refused: its print stops)."""
        self.in_flight -= 1

    def not_run(self) -> None:
        """A command of this job went out but did not run (the printer counted its number, but what arrived was
        damaged), and goes again as a new line: it counts as sent once, and as resent."""
        self.lines_sent -= 1
        self.in_flight -= 1
        self.resends += 1

    def lacked(self, code: str, source_line: int) -> bool:
        """The firmware does not know `code` (at `source_line`); True the first time this job meets it."""
        if code in self.unknown_codes:
            return False
        self.unknown_codes[code] = source_line
        return True

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

    def pause(self, reason: str | None = None) -> None:
        """Stop feeding new lines; what is in flight still completes. `reason`: the firmware's request that
        paused it (None: the caller did)."""
        if self.state is PrintState.RUNNING:
            self.state = PrintState.PAUSED
            self.paused_by = reason

    def resume(self, now: float = 0.0) -> None:
        """Feed lines again after `pause()`."""
        if self.state is PrintState.PAUSED:
            self.state = PrintState.RUNNING
            self.paused_by = None
            self.finish_if_idle(now)

    def cancel(self, now: float, reason: str | None = None) -> None:
        """Stop feeding for good; the job ends (CANCELLED) once what is in flight has been answered. `reason`: the
        firmware's request that cancelled it (None: the caller did)."""
        if self.active:
            if reason is not None and not self.cancelling:
                self.cancelled_by = reason
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
            paused_by=self.paused_by,
            cancelled_by=self.cancelled_by,
            # While bounded and feeding, lines up to the bound may go out before the next report; once nothing
            # more will be fed, the last line written is the tighter truth (a line read and never written, as a
            # print stops, did not run).
            may_have_run_through=(
                self.feed_limit
                if self.feed_limit is not None and self.active and not self.exhausted
                else self.written_through
            ),
            unknown_codes=tuple(self.unknown_codes),
        )
