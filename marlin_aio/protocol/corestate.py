"""The one state record of the protocol core, and the few acts that touch all of it.

`Connection` (`connection`) holds one `CoreState` and composes two parts over it: `Receiving`
(`receiving`, what each line from the printer means) and `Deadlines` (`deadlines`, what
happens when nothing comes). The state is declared here, in one place, as a record with public fields: the parts
read and write it through their one `CoreState`. The link's state and the facts its moves read (a halt, the
thermal message, numbers required) are owned by `link`, a `linkmachine.LinkMachine`: the parts call its verbs and
never write its fields. `Connection.stats()` reads its counters from here.
"""

from __future__ import annotations

from collections import deque

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.linkmachine import LinkMachine
from marlin_aio.protocol.matching import Command, InFlight
from marlin_aio.protocol.resends import Probes, Resends
from marlin_aio.protocol.states import FINAL_LINE_STATES, LineEvent
from marlin_aio.protocol.streaming import JobFeed
from marlin_aio.protocol.wire import EventParser, Trace

__all__ = ["CoreState", "check_window"]


def check_window(max_in_flight: int, rx_buffer_bytes: int) -> None:
    """Raises ValueError unless at least one command and 16 bytes may be on the wire."""
    if max_in_flight < 1:
        raise ValueError(f"max_in_flight must be at least 1, got {max_in_flight}")
    if rx_buffer_bytes < 16:
        raise ValueError(f"rx_buffer_bytes must be at least 16, got {rx_buffer_bytes}")


class CoreState:
    """The FIFO, the queue, the resend and print-job state, the link's state, the counters, the results.

    A record shared by the parts of one `Connection`, which nothing outside the core touches.
    """

    def __init__(
        self,
        *,
        numbered: bool = True,
        max_in_flight: int = 1,
        rx_buffer_bytes: int = 128,
        trace_size: int = 64,
        max_resends: int = 10,
        resend_timeout_s: float = 3.0,
        ok_after_resend: bool = True,
        advanced_ok: bool = False,
    ) -> None:
        check_window(max_in_flight, rx_buffer_bytes)
        self.numbered = numbered
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes
        self.trace = Trace(trace_size)
        self.parser = EventParser()
        self.resends = Resends(
            max_resends=max_resends, ok_after_resend=ok_after_resend, resend_timeout_s=resend_timeout_s
        )
        self.feed = JobFeed()
        self.probes = Probes()  # the link's pace, and the probes it times
        self.after_command = False  # the last command written was a user's, written for the first time
        # Write a bare line end next: it completes a line whose own end was damaged on the way (the printer then
        # answers or rejects it), and on its own it is an empty line, which Marlin ignores.
        self.send_eol = False
        self.resends.make_placeholder = self.new_placeholder
        self.queue: deque[Command] = deque()  # accepted, not yet written
        self.in_flight = InFlight()  # written, waiting for an ok, in the order they were written
        self.now = 0.0  # the latest time any call was given, for results that happen as a side effect
        self.next_id = 0
        self.exact_oks = advanced_ok  # the printer names lines in its oks (ADVANCED_OK): plain oks identify themselves
        # The link's state and the facts its moves read (halt, thermal message, numbers required): one owner.
        self.link = LinkMachine()
        # Counters (read them through `stats()`). Every submitted command ends up counted once: answered + failed
        # + cancelled + still queued or in flight.
        self.submitted = self.cancelled = 0
        self.timeouts = self.resets = self.stray_oks = self.lost_oks = self.garbage_lines = 0
        self.bytes_received = 0

    def sync_print_state(self) -> None:
        """Move PRINTING and STOPPING on as the print ends and its last lines on the wire are answered."""
        on_wire = any(c.job is not None for c in self.in_flight)
        self.link.print_moved(self.feed.active, on_wire)

    def new_id(self) -> int:
        self.next_id += 1
        return self.next_id

    def new_placeholder(self, number: int) -> Command:
        """`M110 N<number>`: takes a line number without running anything (nobody waits for its answer)."""
        text = f"M110 N{number}"
        command = Command(self.new_id(), text, "M110", True, self.resends.resend_timeout_s, self.now)
        command.placeholder = command.orphan = True
        return command

    def fail_everything(self, error: MarlinError) -> None:
        feed = self.feed
        if feed.job is not None:
            # Nothing is replayed into a board that reset or halted: the print ends here, at the line it reached.
            feed.job.fail(feed.job_error(error, self.in_flight), self.now)
        feed.detach()
        for command in (*self.in_flight, *self.queue):
            if command.state not in FINAL_LINE_STATES:
                command.move(LineEvent.FAILED)
            if not command.orphan and command.job is None and not command.probe:
                self.in_flight.finish(command, error)
        self.in_flight.clear()
        self.queue.clear()
        self.resends.clear()

    def check(self, error: MarlinError | None) -> None:
        if error is not None:
            self.fail_everything(error)

    def stop_job(self, error: MarlinError, now: float) -> None:
        """End the print with `error`; lines already written stay in the FIFO as orphans (their oks are still
        due), unwritten ones go."""
        job = self.feed.job
        if job is not None:
            job.fail(error, now)
        self.feed.job = None
        self.feed.next = None
        for command in self.in_flight:
            if command.job is not None:
                command.orphan = True
        kept = []
        for command in self.queue:
            if command.job is None:
                kept.append(command)
            elif command.state not in FINAL_LINE_STATES:
                command.move(LineEvent.WITHDRAWN)  # never written again: a placeholder takes its number if asked
        self.queue.clear()
        self.queue.extend(kept)
