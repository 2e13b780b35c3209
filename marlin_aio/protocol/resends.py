"""Numbered lines and getting them through: line numbers, the history of lines sent, and recovery when the printer
asks for a line again.

After a line-number or checksum error Marlin prints `Resend: N` then an `ok` that answers nothing, and throws away
what sat in its receive buffer; so every line from N on is written again from the history, and the rejections of
lines that were already on the wire ("stale") do not start more resends.

Why a print line runs exactly once, in order. Every line is numbered, and Marlin runs a numbered line only if it
follows the last one it ran, so a line written twice is never run twice. The exception is a firmware fact: when
Marlin rejects a line it throws away its receive buffer, and a line that was half received is cut in two; its tail
arrives later as an unnumbered line of its own. Marlin refuses most tails (an `Unknown command` whose text is none
of ours, `Receiving._damaged_input`: its ok answers nothing), but a tail that begins at the command word runs, out
of place. Only
a line written behind an unanswered one can be cut, so ping-pong (one line in flight) is exact on any link. With
send-ahead, after a line error nothing is written until the printer has been quiet (`draining`: every stale line and
tail has arrived), then one line at a time for `CALM_LINES` lines while a line on the wire may still be rejected; a
tail that ran shows as an ok that no command earned while draining, and the connection stops the print saying so.

Over 400 lines because the history of lines sent, the `Resend:` request, draining and the cut lines' tails are
one recovery: the argument above holds only for all of them together, and it is checked here in one place; split
over modules, a change to one part could break the argument without a reader seeing it.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable

from marlin_aio.errors import MarlinError, RemoteProtocolError, ResendLimitError
from marlin_aio.protocol.commands import number_command
from marlin_aio.protocol.matching import Command, InFlight
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.states import LineEvent, LineState

__all__ = ["CALM_LINES", "Probes", "Resends"]

#: Recoveries at INFO, oddities and failures at WARNING (lines on the wire: "marlin_aio.wire" at DEBUG).
_log = logging.getLogger("marlin_aio")

#: After a line error, how many print lines must be answered without another before send-ahead writes more than
#: one line at a time again. One line at a time never leaves a line on the wire behind one the firmware may reject.
CALM_LINES = 100


def wanted(line: Command) -> bool:
    """Should `line` run if the printer asks for it again?

    Not if it already ran (ACCEPTED: its `N` was damaged and the printer ran it unnumbered), nor if its caller
    gave up, nor if it belongs to a print that stopped or is being cancelled: nothing of a stopped print runs
    after the stop. Probes and placeholders run nothing that matters, so they may go again.
    """
    if line.placeholder and line.state is LineState.QUEUED:
        return True  # the placeholder of an earlier request, not written yet
    if line.emergency or line.state not in (LineState.TO_RESEND, LineState.ON_WIRE, LineState.IN_DOUBT):
        return False  # an emergency command acted as its bytes arrived: it is never written again
    if line.placeholder or line.probe:
        return True
    if line.orphan:
        return False
    job = line.job
    return job is None or (job.active and not job.cancelling)


def answers_plainly(command: Command) -> bool:
    """Is `command`'s ok a plain one (not an M105's `ok T:...`; a refused M105 is answered plainly too)?"""
    return command.code != "M105" or command.refusal is not None


class Resends:
    """Line numbering and resend recovery for one connection.

    Args:
        max_resends: how often one line may be requested again before the link is declared too noisy.
        ok_after_resend: the firmware follows every `Resend:` with an `ok` that answers nothing (Marlin 2.1).
        resend_timeout_s: while lines are being resent, how long a resent line may go unanswered (with the printer
            talking) before it is written again (its rejection may have been taken for a stale one).
        make_placeholder: builds the `M110 N<n>` (at a time) that takes the number n of lines that must not run.
    """

    def __init__(
        self,
        *,
        max_resends: int,
        ok_after_resend: bool,
        resend_timeout_s: float,
        make_placeholder: Callable[[int, float], Command],
    ) -> None:
        self.max_resends = max_resends
        self.ok_after_resend = ok_after_resend
        self.resend_timeout_s = resend_timeout_s
        self.next_line = 1  # after reset (or M110 N0) Marlin expects line 1
        self.accepted_through = 0  # the printer has taken every numbered line up to this one (it cannot reject it)
        self._history: dict[int, Command] = {}  # numbered lines by number, for resends
        self._history_order: deque[int] = deque()
        self.resend_from: int | None = None  # the resend being carried out
        self._stale = 0  # answers still due for lines written before the last resend request
        self._swallow_ok = False  # the ok right after a resend request answers nothing
        self._after_line_error = False  # the last line was `Error:...Last Line` (a rejection, not an M999 request)
        # After a line error with more lines on the wire behind the rejected one: write nothing until the printer has
        # been quiet this long (every stale line and fragment has arrived and been answered), then resend.
        self.drain_until: float | None = None
        self._calm_left = 0  # print lines still to be answered one at a time after the last line error
        self.fragment_texts: list[str] = []  # the commands of lines a flush may have cut in two (for the diagnosis)
        self._fragment_oks = 0  # oks still due for fragments the firmware reported as unknown commands
        self.spare_oks = 0  # oks that may still come for copies of an M110 written more than once
        self.sequence_error = False  # the last line error was `Line Number is not Last Line Number+1`
        self.unanswered_m110: int | None = None  # the value of an M110 written twice and still unanswered
        self.held: Command | None = None  # a line asked for again that may have run unnumbered (see `resend`)
        self.nudge_pending = False  # let the next resend out past the window, as a probe
        self.make_placeholder = make_placeholder
        self.requests = 0
        self.fragments = 0  # pieces of lines the printer received on their own after a flush (and refused)
        self.fragments_run = 0  # pieces of lines the printer ran on their own: a line ran out of place

    # Its fields are written only here; the other parts call these verbs.

    def nudge(self, pending: bool = True) -> None:
        """Let the next resend out past the window, as a probe (or no longer)."""
        self.nudge_pending = pending

    def release_held(self) -> Command | None:
        """Forget the line held (asked for again, maybe run unnumbered) and return it, if any."""
        held, self.held = self.held, None
        return held

    def line_error(self, *, sequence: bool) -> None:
        """The printer reported a line error; `sequence`: `Line Number is not Last Line Number+1`."""
        self.sequence_error = sequence

    def fragment_ran(self) -> None:
        """A piece of a line cut by a flush ran on its own: a line ran out of place."""
        self.fragments_run += 1

    def probe_m110(self, value: int | None) -> None:
        """An M110 setting `value` was written twice and is still unanswered: a probe numbered as if it took effect
        asks (None: it was answered)."""
        self.unanswered_m110 = value

    # ------------------------------------------------------------------------------------------- numbering

    def line_number_for(self, command: Command) -> int:
        """The number `command` gets when it is written."""
        if command.code == "M110":
            # M110 sets the counter: number the line with the value it sets, as Marlin's own hosts do.
            words = command.text.split()
            return next((int(w[1:]) for w in words[1:] if w[:1] in "Nn" and w[1:].isdigit()), 0)
        if command.probe and self.unanswered_m110 is not None:
            # A probe behind an M110 whose ok has not come: numbered as if it took effect, so its answer proves it.
            return self.unanswered_m110 + 1
        return self.next_line

    def wire_size(self, command: Command) -> int:
        """The bytes `command` takes on the wire (an upper bound before it has its number)."""
        if command.wire:
            return len(command.wire)
        if not command.numbered:
            return len(command.text) + 1
        # "N<n> <text>*<checksum>\n": the checksum has at most 3 digits, so this is never too small.
        return len(command.text) + len(str(self.line_number_for(command))) + 7

    def assign_wire(self, command: Command, history_size: int) -> None:
        """Give `command` its line number (if numbered) and its bytes, and keep it for resends.

        An `M110` is numbered with the value it sets, but the counter moves only when it is answered
        (`m110_answered`): a damaged `M110` is an ordinary numbered line to Marlin, which changes nothing.
        """
        if not command.numbered:
            command.numbered_as(None, command.text.encode("ascii") + b"\n")
            return
        number = self.line_number_for(command)
        if command.code != "M110":
            self.next_line = number + 1
        command.numbered_as(number, number_command(command.text, number).encode("ascii") + b"\n")
        self._history[number] = command
        self._history_order.append(number)
        while len(self._history_order) > history_size:
            self._history.pop(self._history_order.popleft(), None)

    def m110_answered(self, command: Command) -> None:
        """An `M110` was answered: the printer's counter is now its number.

        A placeholder only takes the number of lines that must not run; a user's `M110 N<n>` (the handshake's
        `M110 N0`) starts the numbering again from n + 1.
        """
        # A probe written behind it was numbered as if it took effect (and moved our counter past itself).
        probed = self.unanswered_m110 is not None and self.next_line == self.unanswered_m110 + 2
        self.unanswered_m110 = None
        number = command.line_number
        if number is None:
            number = self.line_number_for(command)
        if command.placeholder:
            self.accepted_through = max(self.accepted_through, number)
            return
        self.forget_history()
        self.accepted_through = number
        self.next_line = number + 2 if probed else number + 1

    def write_m110_again(
        self, m110: Command, flight: InFlight, queue: deque[Command], now: float
    ) -> MarlinError | None:
        """Take the M110 in flight (and a probe written behind it) off the wire and queue it to be written again,
        alone; return the error that ends everything, if it must.

        It was rejected (damaged into an ordinary numbered line), or dropped without a word (numbered like the
        printer's last line), or its ok is only late or lost: it sets what it sets however often it runs, and the
        oks of copies beyond the first answer nothing (`m110_repeated`).
        """
        behind = flight.after(m110)
        flight.keep_only([c for c in flight if c is not m110 and c not in behind], now, restart_head=False)
        for probe in behind:  # only a probe goes behind an M110, numbered as if it took effect: withdrawn with it
            if probe.state in (LineState.ON_WIRE, LineState.IN_DOUBT):
                probe.move(LineEvent.RESEND)
            if probe.state is LineState.TO_RESEND:
                probe.move(LineEvent.WITHDRAWN)
        m110.move(LineEvent.RESEND)
        queue.appendleft(m110)
        self.unanswered_m110 = None
        return self._limit_error(m110, m110.line_number or 0)

    def m110_repeated(self, command: Command, now: float, quiet_s: float) -> None:
        """A repeated M110 was answered: the oks of its other copies may still come. Write nothing until the
        printer has been quiet, and let those oks answer nothing."""
        self.spare_oks = command.sends - 1
        self.drain_until = now + quiet_s

    def forget_history(self) -> None:
        """Forget every line sent (the numbering restarts, or the printer forgot them)."""
        self._history.clear()
        self._history_order.clear()

    def restart_numbering(self) -> None:
        """The board reset: it expects line 1 and has taken nothing."""
        self.next_line = 1
        self.accepted_through = 0

    # ------------------------------------------------------------------------------------------- requests

    def note_line(self, is_line_error: bool | None, now: float, quiet_s: Callable[[], float]) -> bool:
        """Every line received passes here first (`is_line_error` None for an `ok`, which does not count as the
        line before a `Resend:`); return whether the line before it was a line error.

        A noise line between `Resend:` and its `ok` does not end the wait for that ok: both are printed by one
        call in Marlin's queue.cpp, so any line between them came from the link, not from the firmware.
        """
        if self.drain_until is not None:
            # The printer is still answering what was on the wire when it threw its buffer away.
            self.drain_until = max(self.drain_until, now + quiet_s())
        after_line_error = self._after_line_error
        if is_line_error is not None:
            self._after_line_error = is_line_error
        return after_line_error

    def take_ok(self, plain: bool = True) -> bool:
        """True if the `ok` just received answers nothing (it follows a `Resend:`, or a refused fragment, or is a
        spare of a repeated M110; `plain`: it carries no temperatures, as only an M105's ok does)."""
        if self._swallow_ok:
            self._swallow_ok = False
            return True
        if self._fragment_oks:
            if plain:
                self._fragment_oks -= 1
                return True
            # An M105's `ok T:`: a refused fragment's ok is plain and follows its `Unknown command` at once, so it
            # was lost. Taking this one for it put every later ok one command behind: probes answered one by one
            # and taken for the one before, the print never going on (core and client seed 2114).
            self._fragment_oks = 0
        if self.spare_oks and self.drain_until is not None and plain:
            self.spare_oks -= 1
            return True
        return False

    def on_request(
        self, line_number: int, flight: InFlight, queue: deque[Command], now: float, *, rejected: bool, quiet_s: float
    ) -> MarlinError | None:
        """The printer asked for `line_number` again; return the error that ends everything, if it must.

        `rejected`: the request follows a line error (not M999's own request for the next line).
        """
        self.requests += 1
        _log.info("the printer asked for line %d again", line_number)
        # The printer took every line before the one it asks for.
        self.accepted_through = max(self.accepted_through, line_number - 1)
        # The ok right after a resend request answers nothing. (M999 prints `Resend:` and `ok` too, then its own ok.)
        self._swallow_ok = self.ok_after_resend
        if line_number != self.resend_from:
            # A request for another line means the firmware has got past every stale line.
            self._stale = 0
        elif self._stale > 0:
            # The rejection of a line that was already on the wire when this resend began: expected, no action.
            # (If it was in fact the resent line failing again, the resend deadline recovers.)
            self._stale -= 1
            return None
        if flight.barriers and rejected:
            # An M110 goes alone, so this rejection is its own: it was damaged into an ordinary numbered line,
            # and the firmware's counter did not move (nor did ours). Write it again; it sets the counter whatever
            # its own number and whatever the printer's counter is.
            m110 = next(c for c in reversed(flight) if c.code == "M110")
            return self.write_m110_again(m110, flight, queue, now)
        if line_number == self.next_line:
            # The printer has every line we sent (M999 asks this way): nothing to write again.
            return None
        return self.resend(line_number, flight, queue, now, quiet_s)

    def resend(
        self, line_number: int, flight: InFlight, queue: deque[Command], now: float, quiet_s: float
    ) -> MarlinError | None:
        """Write every line from `line_number` on again; return the error that ends everything, if it must."""
        first = self._history.get(line_number)
        if first is None:
            return RemoteProtocolError(
                f"the printer asked for line {line_number}, which was never sent or is too old to resend "
                f"(next line is {self.next_line})"
            )
        if first.job is not None:
            first.job.asked_again()
        error = self._limit_error(first, line_number)
        if error is not None:
            return error
        # Marlin rejected one line and threw away its receive buffer: every numbered line from N on that is on
        # the wire will be rejected or lost. Take them out of the in-flight FIFO (all but the one this rejection
        # answers will each send a stale rejection, or nothing) and write every line from N on again, in order,
        # ahead of new commands.
        # A line-number error means a *later* line was rejected: the line asked for was not counted. If it is in
        # flight with lines behind it, the printer may have taken it unnumbered (its `N` damaged): then its ok
        # comes before anything the flush let through, and it ran. Hold it in flight until the printer is quiet.
        # (Its own digits damaged give the same error, and a cut line's tail may then earn that first ok instead:
        # unless `held_answer_proven`, such an ok stops the print, `Receiving._held_in_doubt`.)
        held = first if self.sequence_error and first.state is LineState.ON_WIRE and first in flight else None
        if held is not None and not any(c.line_number is not None for c in flight.after(held)):
            held = None
        keep: list[Command] = []
        removed = 0
        # Written after the rejected line: on the wire when the firmware flushed. With a line held, the rejected
        # line may be the held one (its own digits damaged), so the flush may have cut the line right behind it.
        behind: list[Command] = flight.after(held) if held is not None else []
        for command in flight:
            if removed and held is None:
                behind.append(command)
            if command is not held and command.line_number is not None and command.line_number >= line_number:
                removed += 1
            else:
                keep.append(command)
        self.held = held
        self._stale = max(removed - 1, 0)
        self._calm_left = CALM_LINES
        if behind or held is not None:
            # One of those lines may have been cut in two by the flush; its tail arrives as a line of its own. Hold
            # every write until the printer has answered all of them, so nothing new is cut, and recognise the
            # pieces.
            self.drain_until = now + quiet_s
            self.fragment_texts = [c.text for c in behind]
        again: list[Command] = []
        unwanted: list[Command] = []  # a run of lines that must not run: one placeholder takes their numbers
        for number in range(line_number, self.next_line):
            resend = self._history.get(number)
            if resend is None or resend is held:
                continue
            if resend.state in (LineState.ON_WIRE, LineState.IN_DOUBT):
                resend.move(LineEvent.RESEND)
            if wanted(resend):
                if unwanted:
                    again.append(self.placeholder_for(unwanted, now))
                    unwanted = []
                again.append(resend)
            else:
                unwanted.append(resend)
        if unwanted:
            again.append(self.placeholder_for(unwanted, now))
        flight.keep_only(keep, now, restart_head=False)
        self.resend_from = line_number
        # Every line from N on goes out again in order, ahead of everything else, including the lines an earlier
        # request had already queued for resending.
        again_ids = {id(c) for c in again}
        rest = [c for c in queue if id(c) not in again_ids and c.state is not LineState.WITHDRAWN]
        queue.clear()
        queue.extend(again)
        queue.extend(rest)
        return None

    def placeholder_for(self, lines: list[Command], now: float) -> Command:
        """A numbered `M110 N<n>` that takes the numbers of `lines` (n the last of them) without running any.

        Every line of a stopped print, of a caller who gave up, or one that already ran (taken unnumbered after
        its `N` was damaged) is withdrawn: writing it again would run what nobody means to run (again).
        """
        for line in lines:
            if line.state is LineState.TO_RESEND:
                line.move(LineEvent.WITHDRAWN)
                if line.job is not None and not line.placeholder:
                    line.job.withdrew_line()  # it will never be answered
                    if not self.draining:
                        # While draining, the tail of a line cut by the flush may still run; its ok must find the
                        # print still running (`Receiving._fragment_ran`), so the print ends once the drain is
                        # over (`Connection.data_to_send`).
                        line.job.finish_if_idle(now)
        number = lines[-1].line_number
        assert number is not None
        placeholder = self.make_placeholder(number, now)
        self._history[number] = placeholder
        return placeholder

    def resend_overdue(
        self, head: Command, flight: InFlight, queue: deque[Command], now: float, quiet_s: float
    ) -> MarlinError | None:
        """A resent line went unanswered while the printer talked: its rejection was probably taken for a stale
        one. Write it (and what follows) again."""
        self._stale = 0
        assert head.line_number is not None
        return self.resend(head.line_number, flight, queue, now, quiet_s)

    def _limit_error(self, command: Command, line_number: int) -> MarlinError | None:
        if command.sends <= self.max_resends:
            return None
        return ResendLimitError(
            f"the printer asked for line {line_number} ({redact(command.text)!r}) {command.sends} times; "
            "the link is too noisy (check the cable, baud rate and grounding)"
        )

    # ------------------------------------------------------------------------------------------- after a flush

    @property
    def draining(self) -> bool:
        """True while nothing may be written: the printer is still answering what was on the wire at a flush."""
        return self.drain_until is not None

    def drain_over(self, now: float) -> bool:
        """End the drain if the printer has been quiet long enough; return True while it still lasts."""
        if self.drain_until is None:
            return False
        if now < self.drain_until:
            return True
        # The printer has been quiet: every line that was on the wire at the flush was rejected or answered, so a
        # rejection from now on is a fresh one.
        self.drain_until = None
        self._stale = 0
        self.spare_oks = 0
        return False

    @property
    def calm(self) -> bool:
        """True while lines go out one at a time after a line error (no line behind one that may be rejected)."""
        return self._calm_left > 0

    def rejectable(self, flight: InFlight) -> bool:
        """Is a numbered line on the wire that the printer may still reject (and so flush what follows it)?"""
        through = self.accepted_through
        return any(c.line_number is not None and c.line_number > through for c in flight)

    def held_answer_proven(self, held: Command, *, plain: bool) -> bool:
        """Is an ok that no command earned (`plain`: without temperatures), which the printer sent while `held`
        waits, surely `held`'s own: did it run unnumbered?

        The same line-number error comes when the held line's own digits were damaged (it did not run), and the
        flush may then cut a line behind it whose tail runs: that tail's ok is the first one no command earned, as
        the held line's would be. So it is the held line's only if it has the shape of the held line's answer and
        no line behind it answers that way (only an M105 answers with temperatures).
        """
        tails_plain = [text.split()[:1] != ["M105"] for text in self.fragment_texts]
        return plain == answers_plainly(held) and plain not in tails_plain

    def fragment_refused(self) -> None:
        """The firmware refused a fragment (`Unknown command`); the ok after it answers nothing."""
        _log.info("the printer refused the tail of a line cut in two by its flush")
        self.fragments += 1
        self._fragment_oks += 1

    @property
    def idle(self) -> bool:
        """Nothing under way: no ok to swallow, no flush to drain, no line held; an ok is an ordinary answer."""
        return not self._swallow_ok and not self._fragment_oks and self.drain_until is None and self.held is None

    def settled(self, command: Command, *, answered_line: bool) -> None:
        """`command` came off the FIFO (`answered_line`: a print line answered by its own ok)."""
        if command.line_number is not None and command.line_number > self.accepted_through:
            self.accepted_through = command.line_number
        if self._stale == 0 or (self.resend_from is not None and (command.line_number or 0) >= self.resend_from):
            # The firmware has reached the lines written again: nothing older can still answer.
            self._stale = 0
            self.resend_from = None
        if answered_line and self._calm_left and self.resend_from is None and self.drain_until is None:
            self._calm_left -= 1

    def resending(self, head: Command) -> bool:
        """True if `head` is a line being written again (so it gets the shorter resend deadline)."""
        return (
            self.resend_from is not None
            and head.line_number is not None
            and head.line_number >= self.resend_from
            and head.sends <= self.max_resends
        )

    def forget_stale(self) -> None:
        """Enough silence has passed that no stale rejection can still be on its way."""
        self._stale = 0

    def clear(self) -> None:
        """Everything in flight is gone (a reset, a halt, the link lost): no resend is under way."""
        self.forget_history()
        self._stale = 0
        self.resend_from = None
        self._swallow_ok = False
        self.drain_until = None
        self._fragment_oks = 0
        self.spare_oks = 0
        self.held = None
        self.unanswered_m110 = None
        self.fragment_texts = []


class Probes:
    """The link's pace and the probes it times: round trips learnt from answers, and the numbered M105s that ask
    whether an ok was lost.

    A command answered by its own ok gives a round trip (`answered`); a probe goes behind a line left unanswered
    for `delay_s` (eight median round trips), in a print or not, and its `ok T:` proves every older line ran.
    After a flush, the printer must be quiet for `quiet_s` before what was on the wire is taken as all answered.
    """

    __slots__ = ("_median_rtt", "emergency_probed_s", "probed_s", "rtts", "sent")

    def __init__(self) -> None:
        self.rtts: deque[float] = deque(maxlen=32)  # round trips of recent commands answered by their own ok
        self._median_rtt: float | None = None  # of `rtts`, kept until the next one arrives (deadlines ask often)
        self.sent = 0  # probes made
        self.probed_s = 0.0  # when the last probe (an M105, or a resend let out early) was asked for
        self.emergency_probed_s = -math.inf  # when a probe last went behind emergency commands

    def restart(self) -> None:
        """A print starts: its lines share the printer's buffer and wait longer than one command alone, so the
        pace is learnt afresh."""
        self.rtts.clear()
        self._median_rtt = None

    def new_probe(self, command_id: int, now: float, timeout_s: float) -> Command:
        """A numbered M105 asking whether the oldest line's `ok` was lost."""
        self.sent += 1
        return Command(command_id, "M105", "M105", True, timeout_s, now, probe=True)

    def asked(self, now: float, *, emergency: bool = False) -> None:
        """A probe (or a bare line end) was asked for at `now`: the next waits a whole delay from here."""
        if emergency:
            self.emergency_probed_s = now
        else:
            self.probed_s = now

    def answered(self, command: Command, now: float) -> None:
        """A command was answered by its own ok: remember the round trip since it was last written (a resent print
        line's too, so a link that starts noisy learns its pace before its first clean line)."""
        if command.written_s is not None:
            self.rtts.append(now - command.written_s)
            self._median_rtt = None

    def delay_s(self) -> float:
        """How long a line may wait before a probe asks whether its `ok` was lost.

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
