"""What happens when nothing comes: deadlines, probes, timeouts, stalls, and who waits for whom.

The oldest command in flight has three deadlines (`_deadlines`): its timeout, counted from when it became the oldest
or from the last sign of life (a busy keepalive, a wait line); while lines are being resent, a shorter one after
which a resent line is written again; and a probe after a few round trips of silence, in a print or not. A
command that times out keeps its place, in doubt (its late ok must land on it, not on the next caller's); each
command behind it ends at its own bound, its timeout from when it began waiting there or from the printer's last
word if that came first (`_caller_bound`), unless the printer answers first; a print line that times out stalls
the print.
"""

from __future__ import annotations

import logging
import math

from marlin_aio.errors import CommandTimeoutError, PrintStalledError
from marlin_aio.protocol.corestate import CoreState
from marlin_aio.protocol.matching import Command
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.states import FINAL_LINE_STATES, LineEvent, LineState
from marlin_aio.protocol.wire import BARE_LINE_END

__all__ = ["Deadlines"]

#: Recoveries at INFO, oddities and failures at WARNING (lines on the wire: "marlin_aio.wire" at DEBUG).
_log = logging.getLogger("marlin_aio")


class Deadlines:
    """The time side of `Connection`: a part composed over the core's one state record (`CoreState`)."""

    __slots__ = ("_core",)

    def __init__(self, core: CoreState) -> None:
        self._core = core

    def next_deadline(self) -> float | None:
        """When the oldest command in flight times out (or a stalled stream is probed) unless the printer shows a
        sign of life first."""
        drain_until = self._core.resends.drain_until
        head = self._core.in_flight.head
        if head is None:
            return drain_until
        due = min(self._deadlines(head))
        if head.state is LineState.IN_DOUBT:
            due = min(due, self._waiting_bound(), self._silence_bound())
        return due if drain_until is None else min(due, drain_until)

    def _silence_bound(self) -> float:
        """While a print streams behind a line in doubt: when the printer's silence stalls it."""
        core = self._core
        if not core.feed.active:
            return math.inf
        last_in = core.trace.last_received_s
        head = core.in_flight.head
        since = last_in if last_in is not None else 0.0
        if head is not None and not head.emergency:
            # (Emergency commands let go one after another restart no clock: a silent printer stays silent.)
            since = max(since, head.head_since_s or 0.0)
        return since + core.feed.timeout_s

    def _deadlines(self, head: Command) -> tuple[float, float, float]:
        """(time out, write again, probe) for the oldest command; inf where that step does not apply."""
        core = self._core
        start = max(head.head_since_s or 0.0, head.alive_s or 0.0)
        resends = core.resends
        feed = core.feed
        if (
            head.code == "M110"
            and head.numbered
            and head.state is LineState.ON_WIRE
            and core.resends.unanswered_m110 is None  # not while a probe behind it asks
        ):
            # An M110 goes alone and sets what it sets however often it runs: unanswered, it is written again
            # soon (a damaged one may be dropped without a word), not after a whole timeout.
            resend_at = start + core.probes.delay_s()
        elif resends.resending(head):
            resend_at = start + min(head.timeout_s, resends.resend_timeout_s)
        else:
            resend_at = math.inf
        if head.state is LineState.IN_DOUBT:
            # Only the printer settles it: a late ok, or the answer to an M105 behind it (not a resend: the probe
            # finds out whether it is needed). An M105 in doubt is let go after one more timeout, as only another
            # M105 could take its late `ok T:`, and that answer would be as true for it.
            probe_at = start if self._may_probe_doubt() else math.inf
            # An emergency command in doubt is let go the same way: its queued copy ran nothing, and nobody waits.
            timeout_at = start + head.timeout_s if head.code == "M105" or head.emergency else math.inf
            return timeout_at, math.inf, probe_at
        # A probe whose own line end was damaged waits in the printer for a line end: another probe behind it
        # brings it out (as a line error), so an unanswered probe is followed by another, two at most.
        may_probe = (
            core.numbered
            and not resends.draining
            and ((feed.job is not None and feed.active) or self._may_probe_outside_print(head))
            and self._probes_out() < 2  # last: it walks the FIFO
        )
        probe_at = max(start, core.probes.probed_s) + core.probes.delay_s() if may_probe else math.inf
        return start + head.timeout_s, resend_at, probe_at

    def _may_probe_outside_print(self, head: Command) -> bool:
        """May a probe go behind `head`, with no print streaming? A lost ok costs a moment there too, and the
        queue behind it goes on: the probe's `ok T:` proves `head` ran (`Receiving._on_ok`, `ok_lost=True`).

        Not behind an M110 (it goes alone) or an emergency command (its own path, `_settle_doubt`). While an M105
        is in flight only a bare line end goes (`_probe`).
        """
        return not (head.code == "M110" or head.emergency or self._core.in_flight.barriers)

    def _probes_out(self) -> int:
        """Probes written and unanswered (a queued one may wait behind lines held back, and tells nothing)."""
        return sum(c.probe for c in self._core.in_flight)

    def _may_probe_doubt(self) -> bool:
        """May an M105 go behind a line in doubt? Not while one is on its way (it will tell), nor while draining."""
        core = self._core
        if core.resends.draining or core.in_flight.barriers:
            return False
        # A user's M105 still queued does not count: one at a time, nothing but a probe goes behind a line in doubt.
        return not any(c.code == "M105" for c in core.in_flight) and not any(c.probe for c in core.queue)

    def _waiting_bound(self) -> float:
        """The earliest bound of a caller waiting behind a line in doubt (its own timeout from when it began
        waiting there)."""
        core = self._core
        head = core.in_flight.head
        since = 0.0 if head is None or head.head_since_s is None else head.head_since_s
        bounds = [
            self._caller_bound(c, since)
            for c in (*core.in_flight, *core.queue)
            if not c.orphan and c.job is None and not c.probe
        ]
        return min(bounds, default=math.inf)

    def _caller_bound(self, command: Command, since: float) -> float:
        """When a caller waiting behind a line in doubt (in doubt from `since`) fails: its own timeout from when it
        began waiting there, or from the printer's last word if that came before. So a printer that has gone
        silent fails each caller once it has said nothing for the caller's own timeout, however many emergency
        commands in doubt are let go one after another ahead of it, each restarting the clock of the oldest
        (core seeds 1058, 1096)."""
        last_in = self._core.trace.last_received_s
        start = 0.0 if last_in is None else min(since, last_in)  # no word ever: from when it was submitted
        return max(command.submitted_s, start) + command.timeout_s

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost (see `JobFeed`)."""
        return self._core.probes.delay_s()

    def check_timeouts(self, now: float) -> None:
        """Time out the oldest command if its deadline has passed; the commands behind it go on.

        While a job streams, a line that waits too long first gets a probe (a numbered M105: its `ok T:` proves
        every older line was processed, so a lost `ok` costs a moment, not the print). A line that still gets no
        answer within the timeout, with no busy keepalive, stalls the print: the job fails with a diagnosis.
        """
        core = self._core
        resends = core.resends
        resends.drain_over(now)
        while (head := core.in_flight.head) is not None:
            deadline = self.next_deadline()
            if deadline is None or now < deadline:
                return
            timeout_at, resend_at, probe_at = self._deadlines(head)
            last_in = core.trace.last_received_s
            talking = last_in is not None and last_in > (head.head_since_s or 0.0)
            if now >= resend_at and head.code == "M110" and head.state is LineState.ON_WIRE:
                if head.sends >= 2 and not head.placeholder and len(core.in_flight) == 1:
                    # Written twice and still no ok: its oks may be the ones being lost. An M105 numbered as if
                    # it took effect asks (it has long run by now, so the counter it set is the one checked).
                    core.resends.probe_m110(head.line_number)
                    head.waits_from(now)
                    core.want_line_end()
                    core.queue.appendleft(core.new_probe(now))
                    return
                core.check(resends.write_m110_again(head, core.in_flight, core.queue, now), now)
                return
            if head.state is LineState.IN_DOUBT:
                if self._settle_doubt(head, now, timeout_at, probe_at):
                    continue
                return
            if now >= resend_at and head.line_number is not None and talking:
                # A resent line went unanswered while the printer talked: its rejection was probably taken for a
                # stale one. (A silent printer is not helped by resends: it times out below.)
                core.check(resends.resend_overdue(head, core.in_flight, core.queue, now, core.probes.quiet_s()), now)
                continue
            if now < timeout_at:
                if now >= probe_at:
                    self._probe(now)
                return
            if head.emergency:
                # Everything ahead of it was answered and its own ok has not come: the printer threw the line away
                # with its receive buffer (after a line error), or the ok was lost. Nobody waits for it, so it is
                # no caller's timeout: in doubt, a probe behind it settles it (`_settle_doubt`).
                head.overdue(now)
                continue
            # No stale rejection can still be on its way after this much silence.
            resends.forget_stale()
            core.timed_out()
            _log.warning("no answer to %r within %g s", redact(head.text), head.timeout_s)
            if (head.job is not None or head.probe) and not head.orphan:
                self._stall_job(head, now)
                continue
            if head.code == "M110" and head.numbered and not head.placeholder:
                # Written again until the resend limit says the link is too noisy; its caller is told now.
                if not head.orphan:
                    head.give_up()
                    core.in_flight.finish(
                        head, CommandTimeoutError(self.describe_stall(head, now), command=redact(head.text))
                    )
                core.check(resends.write_m110_again(head, core.in_flight, core.queue, now), now)
                return
            summary = self.describe_stall(head, now)
            # Its caller is told now, but the command keeps its place, in doubt, until the printer settles it:
            # Marlin may still answer it (a long G28), and that late ok must land on it, never on the next
            # caller's command, which waits (see `answer_stays_distinct`) or goes out behind it.
            was_orphan = head.orphan
            core.want_line_end()  # in case its line end was damaged and the printer still waits for it
            head.give_up()
            head.overdue(now)
            if not was_orphan:
                core.in_flight.finish(head, CommandTimeoutError(summary, command=redact(head.text)))
            # What waits behind it is not failed with it, silent printer or not: each caller ends at its own bound
            # (`_caller_bound`, checked in `_settle_doubt`), unless the printer answers first (a probe goes behind
            # it).
            return

    def _settle_doubt(self, head: Command, now: float, timeout_at: float, probe_at: float) -> bool:
        """The oldest command is in doubt: probe behind it, let an M105 go, fail callers past their bound, stall a
        print the printer has been silent for. True if it was let go (the next one is looked at now)."""
        core = self._core
        if now >= timeout_at:
            # An M105 in doubt (see `_deadlines`). A line in doubt behind it has been in doubt at least as long (a
            # line behind the oldest goes in doubt only when a print stalls, which restarts the oldest's time): it
            # keeps that time, so the callers behind both end at their own bound from when they began waiting
            # behind lines in doubt, not one more timeout for each; an M105 there is let go now too.
            core.in_flight.popleft(now)
            if head.emergency:
                head.move(LineEvent.FAILED)  # never answered: its place is given up (nobody is told; nobody waits)
            after = core.in_flight.head
            if after is not None and after.state is LineState.IN_DOUBT:
                after.waits_from(now if head.head_since_s is None else head.head_since_s)
            return True
        if now >= self._silence_bound():
            self._stall_job(head, now)
        if now >= probe_at:
            core.probes.asked(now)
            core.want_line_end()
            core.queue.appendleft(core.new_probe(now))
        if now >= self._waiting_bound():
            since = head.head_since_s or now
            for command in (*core.in_flight, *core.queue):
                if command.orphan or command.job is not None or command.probe:
                    continue
                if now >= self._caller_bound(command, since):
                    error = CommandTimeoutError(
                        f"no answer within {command.timeout_s:g} s: it waited behind {redact(head.text)!r}, which the "
                        f"printer has not answered ({self.describe_stall(head, now)})",
                        command=redact(command.text),
                    )
                    if command.sends == 0:
                        core.queue.remove(command)
                        command.move(LineEvent.WITHDRAWN)
                    else:
                        command.give_up()  # it keeps its place: its late ok must land on it
                    core.timed_out()
                    core.in_flight.finish(command, error)
        return False

    def _probe(self, now: float) -> None:
        core = self._core
        core.probes.asked(now)
        if not core.feed.active and any(c.code == "M105" for c in core.in_flight):
            # Outside a print only one `ok T:` is awaited at a time, and an M105 in flight (a poll's, behind the
            # oldest command) tells what a probe would. A bare line end still goes, once: it completes a line
            # whose own end was damaged, which the printer then answers at once.
            last_out = core.trace.last_sent
            core.want_line_end(last_out is None or last_out.text != BARE_LINE_END)
            return
        core.want_line_end()
        if core.queue and core.queue[0].wire:
            # Lines wait to be written again, one at a time, behind this one, whose ok may be lost. With plain oks
            # only an M105's `ok T:` can prove that, so the probe goes behind those lines (its number comes after
            # theirs) and they all go out now. One at a time (ping-pong) the next of them is the probe.
            if core.max_in_flight > 1:
                at = 0
                while at < len(core.queue) and core.queue[at].wire:
                    at += 1
                core.resends.forget_stale()
                core.queue.insert(at, core.new_probe(now))
            core.resends.nudge()
            return
        # A probe follows several round trips of silence: no rejection of a line written before the last resend
        # can still be on its way, so whatever the printer asks for next is a fresh request, acted on at once.
        core.resends.forget_stale()
        if core.queue and core.queue[0].probe:
            # One already waits to go out (behind a poll's M105, say, which no M105 may follow): another would go
            # out no sooner, and one a probe delay would pile up and then go out together. The line end goes.
            return
        core.queue.appendleft(core.new_probe(now))

    def _stall_job(self, head: Command, now: float) -> None:
        """The stream got no answer within the timeout: end the print with a diagnosis, drop its lines."""
        core = self._core
        feed = core.feed
        job = feed.job or head.job
        summary = self.describe_stall(head, now)
        if head.job is not None and job:
            where = f"line {head.source_line} of {job.name}"
        elif job is not None and not head.probe:
            where = f"{job.name} behind {redact(head.text)!r}, which the printer has not answered,"
        else:
            where = "a probe"
        if job is not None:
            maybe = [c.source_line for c in core.in_flight if c.job is job]
            where += f" (line {job.last_source_line} surely ran"
            where += f"; lines up to {max(maybe)} may have run)" if maybe else ")"
        error = PrintStalledError(
            f"print stalled at {where}: {summary}", command=redact(head.text), trace=core.trace.format(now)
        )
        if job is not None:
            job.fail(error, now)
        feed.detach()
        # The stream's lines on the wire keep their places, in doubt: a printer that answers late must not hand
        # their oks to whatever the user sends next. Unwritten ones are withdrawn.
        head.waits_from(now)
        for command in core.in_flight:
            if command.job is not None or command.probe:
                command.give_up()
                if command.state is LineState.ON_WIRE:
                    command.move(LineEvent.OVERDUE)
        kept = []
        for command in core.queue:
            if command.job is None and not command.probe:
                kept.append(command)
            elif command.state not in FINAL_LINE_STATES:
                command.move(LineEvent.WITHDRAWN)
        core.queue.clear()
        core.queue.extend(kept)

    def describe_stall(self, command: Command, now: float) -> str:
        """One line saying who waits for whom: the command, for how long, and what each side last said."""
        core = self._core
        waited = now - (command.submitted_s if command.head_since_s is None else command.head_since_s)
        parts = [f"no 'ok' for {redact(command.text)!r} after {waited:.1f} s"]
        if command.line_number is not None:
            parts[0] += f" (line {command.line_number})"
        behind = len(core.in_flight) - 1 + len(core.queue)
        if behind:
            parts.append(f"{behind} more command{'s' if behind != 1 else ''} waiting behind it")
        last_in = core.trace.last_received
        last_out = core.trace.last_sent
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
