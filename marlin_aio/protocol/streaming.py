"""A print job fed into the connection line by line: its next line and its stall timeout.

A print job (`printjob.PrintJob`) goes through the connection's FIFO after any submitted commands, as
far as the window allows. A line left unanswered for a few round trips gets a probe (`resends.Probes`, the line
numbers' part) so that a lost `ok` costs a moment; a line unanswered for the whole timeout, with no busy
keepalive, stalls the print with a diagnosis (`deadlines`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from marlin_aio.errors import (
    MarlinError,
    PrinterHaltedError,
    PrinterResetError,
    RemoteProtocolError,
    ResendLimitError,
    ThermalRunawayError,
)
from marlin_aio.protocol.commands import command_code
from marlin_aio.protocol.matching import Command
from marlin_aio.protocol.printjob import PrintJob, PrintState

__all__ = ["JobFeed"]

#: Errors whose only argument is the message, so the print's position can be added to it.
_PLAIN_ERRORS = (PrinterHaltedError, ThermalRunawayError, PrinterResetError, ResendLimitError, RemoteProtocolError)


class JobFeed:
    """The print job being streamed, if any, with what the connection needs to pace and probe it."""

    __slots__ = ("job", "next", "timeout_s")

    def __init__(self) -> None:
        self.job: PrintJob | None = None
        self.next: Command | None = None  # the job's next line: read from the source, not yet written
        self.timeout_s = 10.0  # how long a line may go unanswered before the print stalls

    @property
    def active(self) -> bool:
        """True while a job streams (running or paused)."""
        return self.job is not None and self.job.active

    def attach(self, job: PrintJob, timeout_s: float) -> None:
        """Stream `job` from now on.

        Raises:
            RuntimeError: another job is still running.
        """
        if self.job is not None and self.job.active:
            raise RuntimeError(f"a print is already running ({self.job.name})")
        self.job = job
        self.timeout_s = timeout_s

    def took_next(self) -> None:
        """The job's next line was written: the next call reads another."""
        self.next = None

    def detach(self) -> None:
        """The job ended (done, failed or stalled): feed nothing more."""
        self.job = None
        self.next = None

    def next_command(self, new_id: Callable[[], int], numbered: bool, now: float) -> Command | None:
        """The job's next line as a command (kept until it fits the window), or None."""
        job = self.job
        if job is None:
            return None
        if self.next is not None:
            if job.cancelling:
                self.next = None  # read from the source but never written: it is simply not sent
            elif job.state is PrintState.RUNNING:
                return self.next
            else:
                return None
        if job.finished:
            self.job = None
            return None
        item = job.next_command()
        if item is None:
            job.finish_if_idle(now)
            if job.finished:
                self.job = None
            return None
        text, source_line, source_bytes = item
        command = Command(
            new_id(),
            text,
            command_code(text),
            numbered,
            self.timeout_s,
            now,
            job=job,
            source_line=source_line,
            source_bytes=source_bytes,
        )
        self.next = command
        return command

    def job_error(self, error: MarlinError, on_the_way: Iterable[Command] = ()) -> MarlinError:
        """`error` with the print's position added, for the job it ends: the last line surely run, and the lines
        that were `on_the_way` (written, unanswered), which may have run too."""
        job = self.job
        if job is None:
            return error
        where = f"{job.name}, after line {job.last_source_line} ({job.lines_acked} commands acknowledged)"
        maybe = [c.source_line for c in on_the_way if c.job is job]
        if maybe:
            where += (
                f"; line {max(maybe)} was on its way and may have run"
                if len(maybe) == 1
                else f"; {len(maybe)} commands up to line {max(maybe)} were on their way and may have run"
            )
        return type(error)(f"{error} [print stopped: {where}]") if type(error) in _PLAIN_ERRORS else error
