"""What happens when nothing comes: deadlines, probes, timeouts, stalls, and who waits for whom.

The oldest command in flight has three deadlines (`_deadlines`): its timeout, counted from when it became the oldest
or from the last sign of life (a busy keepalive, a wait line); while lines are being resent, a shorter one after
which a resent line is written again; and while a print streams, a probe after a few round trips of silence. A
command that times out keeps its place for one more timeout (its late ok must land on it, not on the next
caller's), and everything queued behind it fails at once; a print line that times out stalls the print.
"""

from __future__ import annotations

import logging
import math

from marlin_aio.corestate import CoreState
from marlin_aio.errors import CommandTimeoutError, PrintStalledError
from marlin_aio.replies import Command

__all__ = ["Deadlines"]

#: Recoveries at INFO, oddities and failures at WARNING (lines on the wire: "marlin_aio.wire" at DEBUG).
_log = logging.getLogger("marlin_aio")


class Deadlines(CoreState):
    """The time side of `Connection`."""

    def next_deadline(self) -> float | None:
        """When the oldest command in flight times out (or a stalled stream is probed) unless the printer shows a
        sign of life first."""
        drain_until = self._resends.drain_until
        head = self._in_flight.head
        if head is None:
            return drain_until
        due = min(self._deadlines(head))
        return due if drain_until is None else min(due, drain_until)

    def _deadlines(self, head: Command) -> tuple[float, float, float]:
        """(time out, write again, probe) for the oldest command; inf where that step does not apply."""
        start = max(head.head_since_s or 0.0, head.alive_s or 0.0)
        resends = self._resends
        resend_at = start + min(head.timeout_s, resends.resend_timeout_s) if resends.resending(head) else math.inf
        feed = self._feed
        # Only while a job streams: outside prints a probe M105 could answer a user's own M105 (say M105 T9).
        may_probe = feed.active and feed.probe is None and self._numbered and not resends.draining
        probe_at = max(start, feed.probed_s) + feed.probe_delay_s() if may_probe else math.inf
        return start + head.timeout_s, resend_at, probe_at

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost (see `JobFeed`)."""
        return self._feed.probe_delay_s()

    def check_timeouts(self, now: float) -> None:
        """Time out the oldest command if its deadline has passed; the commands behind it go on.

        While a job streams, a line that waits too long first gets a probe (a numbered M105: its `ok T:` proves
        every older line was processed, so a lost `ok` costs a moment, not the print). A line that still gets no
        answer within the timeout, with no busy keepalive, stalls the print: the job fails with a diagnosis.
        """
        self._now = now
        resends = self._resends
        resends.drain_over(now)
        while (head := self._in_flight.head) is not None:
            deadline = self.next_deadline()
            if deadline is None or now < deadline:
                return
            timeout_at, resend_at, probe_at = self._deadlines(head)
            last_in = self.trace.last_received
            talking = last_in is not None and last_in.time_s > (head.head_since_s or 0.0)
            if now >= resend_at and head.line_number is not None and talking:
                # A resent line went unanswered while the printer talked: its rejection was probably taken for a
                # stale one. (A silent printer is not helped by resends: it times out below.)
                self._check(resends.resend_overdue(head, self._in_flight, self._queue, now, self._feed.quiet_s()))
                continue
            if now < timeout_at:
                if now >= probe_at:
                    self._probe(now)
                return
            # No stale rejection can still be on its way after this much silence.
            resends.forget_stale()
            self._timeouts += 1
            _log.warning("no answer to %r within %g s", head.text, head.timeout_s)
            if head.job is not None or head.probe:
                self._stall_job(head, now)
                continue
            if head.orphan:
                # Its caller was told already (it timed out behind another command, or gave up): drop it quietly.
                self._in_flight.popleft(now)
                continue
            summary = self.describe_stall(head, now)
            # Its caller is told now, but the command keeps its place for one more timeout (quarantine): Marlin may
            # still answer it (a long G28), and that late ok must land on it, not on the next caller's command,
            # which waits (see `answer_stays_distinct`). Only then is its place given up.
            head.orphan = True
            head.head_since_s = now
            head.alive_s = None
            self._finish(head, CommandTimeoutError(summary, command=head.text))
            self._give_up_behind(head, summary)
            return

    def _probe(self, now: float) -> None:
        self._feed.probed_s = now
        if self._queue and self._queue[0].wire:
            # Lines wait to be written again, one at a time, behind this one, whose ok may be lost. With plain oks
            # only an M105's `ok T:` can prove that, so the probe goes behind those lines (its number comes after
            # theirs) and they all go out now. One at a time (ping-pong) the next of them is the probe.
            if self._max_in_flight > 1:
                at = 0
                while at < len(self._queue) and self._queue[at].wire:
                    at += 1
                self._resends.forget_stale()
                self._queue.insert(at, self._feed.new_probe(self._new_id(), now))
            self._resends.nudge_pending = True
            return
        # A probe follows several round trips of silence: no rejection of a line written before the last resend
        # can still be on its way, so whatever the printer asks for next is a fresh request, acted on at once.
        self._resends.forget_stale()
        self._queue.appendleft(self._feed.new_probe(self._new_id(), now))

    def _give_up_behind(self, dead: Command, summary: str) -> None:
        """The oldest command got no answer for its whole timeout: fail everything behind it at once.

        Commands never written are dropped, so a printer that wakes up later does not run a backlog nobody waits
        for. If the printer has been silent all that time, commands already written fail too: they stay in the
        FIFO (their late `ok`s must land on them, not on a newer command), but their callers are told now instead
        of one timeout after another.
        """
        last_in = self.trace.last_received
        silent = last_in is None or self._now - last_in.time_s >= dead.timeout_s
        for command in self._in_flight if silent else ():
            if not command.orphan and command.job is None and not command.probe:
                command.orphan = True
                self._finish(
                    command, CommandTimeoutError(f"gave up behind {dead.text!r}: {summary}", command=command.text)
                )
        kept: list[Command] = []
        for command in self._queue:
            if command.job is None and not command.probe:
                error = CommandTimeoutError(
                    f"not sent: the printer stopped answering ({summary})", command=command.text
                )
                self._finish(command, error)
            else:
                kept.append(command)
        self._queue.clear()
        self._queue.extend(kept)

    def _stall_job(self, head: Command, now: float) -> None:
        """The stream got no answer within the timeout: end the print with a diagnosis, drop its lines."""
        feed = self._feed
        job = feed.job or head.job
        summary = self.describe_stall(head, now)
        where = f"line {head.source_line} of {job.name}" if head.job is not None and job else "a probe"
        error = PrintStalledError(
            f"print stalled at {where}: {summary}", command=head.text, trace=self.trace.format(now)
        )
        if job is not None:
            job.fail(error, now)
        feed.detach()
        # The stream's lines will not be answered (the printer is silent): take them out so the FIFO stays true
        # for whatever the user sends next.
        self._in_flight.keep_only((c for c in self._in_flight if c.job is None and not c.probe), now, restart_head=True)
        kept = [c for c in self._queue if c.job is None and not c.probe]
        self._queue.clear()
        self._queue.extend(kept)

    def describe_stall(self, command: Command, now: float) -> str:
        """One line saying who waits for whom: the command, for how long, and what each side last said."""
        waited = now - (command.submitted_s if command.head_since_s is None else command.head_since_s)
        parts = [f"no 'ok' for {command.text!r} after {waited:.1f} s"]
        if command.line_number is not None:
            parts[0] += f" (line {command.line_number})"
        behind = len(self._in_flight) - 1 + len(self._queue)
        if behind:
            parts.append(f"{behind} more command{'s' if behind != 1 else ''} waiting behind it")
        last_in = self.trace.last_received
        last_out = self.trace.last_sent
        if last_out is not None:
            parts.append(f"last sent {last_out.text!r} {now - last_out.time_s:.1f} s ago")
        if last_in is None:
            parts.append("nothing ever received: the printer is silent (wrong port or baud rate?)")
        else:
            silent = now - last_in.time_s
            parts.append(f"last received {last_in.text!r} {silent:.1f} s ago")
            if silent >= command.timeout_s:
                parts.append("the printer has been silent since")
            else:
                parts.append("the printer is talking but did not answer this command")
        return "; ".join(parts)
