"""The parts of one protocol core held together, and the few acts that touch all of them.

`Connection` (`connection`) holds one `CoreState` and composes two behaviours over it: `Receiving` (`receiving`,
what each line from the printer means) and `Deadlines` (`deadlines`, what happens when nothing comes). Each part
owns its fields and is changed only through its verbs: the wire (`parser`, `trace`), the FIFO (`in_flight`, with
the outcomes), the line numbers (`resends`, `probes`), the link's state machine (`link`), the print job being fed
(`feed`). What is left here is the queue of commands not yet written (a deque that `Connection`, `Receiving` and
`Deadlines` reorder as they decide what goes next), the window, and the counters of what happened (changed
through the verbs below). `Connection.stats()` reads the counters of every part.
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
        connecting: bool = False,
    ) -> None:
        check_window(max_in_flight, rx_buffer_bytes)
        self.numbered = numbered
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes
        self.trace = Trace(trace_size)
        self.parser = EventParser()
        self.resends = Resends(
            max_resends=max_resends,
            ok_after_resend=ok_after_resend,
            resend_timeout_s=resend_timeout_s,
            make_placeholder=self.new_placeholder,
        )
        self.feed = JobFeed()
        self.probes = Probes()  # the link's pace, and the probes it times
        # Write a bare line end next: it completes a line whose own end was damaged on the way (the printer then
        # answers or rejects it), and on its own it is an empty line, which Marlin ignores.
        self.send_eol = False
        self.queue: deque[Command] = deque()  # accepted, not yet written
        self.in_flight = InFlight()  # written, waiting for an ok, in the order they were written
        self.next_id = 0
        self.exact_oks = advanced_ok  # the printer names lines in its oks (ADVANCED_OK): plain oks identify themselves
        # The link's state and the facts its moves read (halt, thermal message, numbers required): one owner.
        self.link = LinkMachine(connecting=connecting)
        # Counters (read them through `stats()`). Every submitted command ends up counted once: answered + failed
        # + cancelled + still queued or in flight.
        self.submitted = self.cancelled = 0
        self.timeouts = self.resets = self.stray_oks = self.lost_oks = 0

    # Its own fields are written only by these verbs (the parts of `Connection` call them).

    def set_window(self, max_in_flight: int, rx_buffer_bytes: int) -> None:
        """How many commands and unanswered bytes may be on the wire.

        Raises:
            ValueError: `max_in_flight` below 1 or `rx_buffer_bytes` below 16.
        """
        check_window(max_in_flight, rx_buffer_bytes)
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes

    def want_line_end(self, wanted: bool = True) -> None:
        """Write a bare line end next (or not: it was just written)."""
        self.send_eol = wanted

    def oks_name_lines(self) -> None:
        """The printer named a line in an ok (ADVANCED_OK): numbered commands may share the wire."""
        self.exact_oks = True

    def accept(self, text: str, code: str, numbered: bool, timeout_s: float, now: float) -> Command:
        """A new command, counted as submitted."""
        self.submitted += 1
        return Command(self.new_id(), text, code, numbered, timeout_s, now)

    def withdrawn(self) -> None:
        """A command never written was withdrawn by its caller."""
        self.cancelled += 1

    def stray_ok(self) -> None:
        """An ok that answers no command waiting."""
        self.stray_oks += 1

    def lost_ok(self) -> None:
        """A command's own ok was lost; a later answer proved it ran."""
        self.lost_oks += 1

    def timed_out(self) -> None:
        """A command got no answer within its timeout."""
        self.timeouts += 1

    def was_reset(self) -> None:
        """The printer reset (it printed `start`)."""
        self.resets += 1

    def sync_print_state(self) -> None:
        """Move PRINTING and STOPPING on as the print ends and its last lines on the wire are answered."""
        on_wire = any(c.job is not None for c in self.in_flight)
        self.link.print_moved(self.feed.active, on_wire)

    def new_id(self) -> int:
        self.next_id += 1
        return self.next_id

    def new_probe(self, now: float) -> Command:
        """A numbered M105 asking whether the oldest line's `ok` was lost (`Probes`), as patient as a print line."""
        return self.probes.new_probe(self.new_id(), now, self.feed.timeout_s)

    def new_placeholder(self, number: int, now: float) -> Command:
        """`M110 N<number>`: takes a line number without running anything (nobody waits for its answer)."""
        text = f"M110 N{number}"
        return Command(
            self.new_id(), text, "M110", True, self.resends.resend_timeout_s, now, placeholder=True, orphan=True
        )

    def fail_everything(self, error: MarlinError, now: float) -> None:
        feed = self.feed
        if feed.job is not None:
            # Nothing is replayed into a board that reset or halted: the print ends here, at the line it reached.
            feed.job.fail(feed.job_error(error, self.in_flight), now)
        feed.detach()
        for command in (*self.in_flight, *self.queue):
            if command.state not in FINAL_LINE_STATES:
                command.move(LineEvent.FAILED)
            if not command.orphan and command.job is None and not command.probe:
                self.in_flight.finish(command, error)
        self.in_flight.clear()
        self.queue.clear()
        self.resends.clear()

    def check(self, error: MarlinError | None, now: float) -> None:
        if error is not None:
            self.fail_everything(error, now)

    def stop_job(self, error: MarlinError, now: float) -> None:
        """End the print with `error`; lines already written stay in the FIFO as orphans (their oks are still
        due), unwritten ones go."""
        job = self.feed.job
        if job is not None:
            job.fail(error, now)
        self.feed.detach()
        for command in self.in_flight:
            if command.job is not None:
                command.give_up()
        kept = []
        for command in self.queue:
            if command.job is None:
                kept.append(command)
            elif command.state not in FINAL_LINE_STATES:
                command.move(LineEvent.WITHDRAWN)  # never written again: a placeholder takes its number if asked
        self.queue.clear()
        self.queue.extend(kept)
