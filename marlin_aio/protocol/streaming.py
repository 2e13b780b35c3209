"""A print job fed into the connection line by line: its next line, the round trips it measures, and its probes.

A print job (`printjob.PrintJob`) goes through the connection's FIFO after any submitted commands, as
far as the window allows. While it streams, a line left unanswered for a few round trips gets a probe (a numbered
M105, whose `ok T:` proves every older line ran) so that a lost `ok` costs a moment; a line unanswered for the
whole timeout, with no busy keepalive, stalls the print with a diagnosis (`connection`).
"""

from __future__ import annotations

from collections import deque
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
from marlin_aio.protocol.printjob import PrintJob, PrintState
from marlin_aio.protocol.replies import Command

__all__ = ["JobFeed"]

#: Errors whose only argument is the message, so the print's position can be added to it.
_PLAIN_ERRORS = (PrinterHaltedError, ThermalRunawayError, PrinterResetError, ResendLimitError, RemoteProtocolError)


class JobFeed:
    """The print job being streamed, if any, with what the connection needs to pace and probe it."""

    __slots__ = ("_median_rtt", "job", "next", "probed_s", "probes", "rtts", "timeout_s")

    def __init__(self) -> None:
        self.job: PrintJob | None = None
        self.next: Command | None = None  # the job's next line: read from the source, not yet written
        self.timeout_s = 10.0  # how long a line may go unanswered before the print stalls
        self.rtts: deque[float] = deque(maxlen=32)  # round trips of recent commands answered by their own ok
        self.probes = 0
        self.probed_s = 0.0  # when the last probe (an M105, or a resend let out early) was written
        self._median_rtt: float | None = None  # of `rtts`, kept until the next one arrives (deadlines ask often)

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
        self.rtts.clear()
        self._median_rtt = None

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
        command = Command(new_id(), text, command_code(text), numbered, self.timeout_s, now)
        command.job, command.source_line, command.source_bytes = job, source_line, source_bytes
        self.next = command
        return command

    def new_probe(self, command_id: int, now: float) -> Command:
        """A numbered M105 asking whether the oldest line's `ok` was lost."""
        self.probes += 1
        return Command(command_id, "M105", "M105", True, self.timeout_s, now, probe=True)

    def answered(self, command: Command, now: float) -> None:
        """A command was answered by its own ok: remember the round trip since it was last written (a resent print
        line's too, so a link that starts noisy learns its pace before its first clean line). Outside a print the
        user's commands give the pace; a print starts afresh (`attach`), as lines that share the printer's buffer
        wait longer than one command alone."""
        if command.written_s is not None:
            self.rtts.append(now - command.written_s)
            self._median_rtt = None

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost.

        Eight times the median round trip of recent lines, within 50 ms to 1 s: quick on a fast link, patient
        with a slow one. A probe is a numbered M105, harmless if nothing was lost.
        """
        median = self._median()
        return 1.0 if median is None else min(max(8 * median, 0.05), 1.0)

    def quiet_s(self) -> float:
        """How long the printer must say nothing before what was on the wire at a flush is taken as all answered:
        four median round trips, within 20 ms to 0.5 s."""
        median = self._median()
        return 0.1 if median is None else min(max(4 * median, 0.02), 0.5)

    def _median(self) -> float | None:
        if self._median_rtt is None and self.rtts:
            ordered = sorted(self.rtts)
            self._median_rtt = ordered[len(ordered) // 2]
        return self._median_rtt

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
