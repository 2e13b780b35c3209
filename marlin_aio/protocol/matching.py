"""The FIFO of commands in flight: each command's record (`Command`), which command an `ok` answers, and whose
reply lines are whose.

A `Command` is the connection's record of one command: queued, written (with its line number and the bytes on the
wire), answered or failed. Its reply lines collect on it while it is the oldest command waiting, bounded so a
chatty or noisy printer cannot grow one reply without limit.

Marlin answers every command it processes with exactly one `ok`, in the order it received them, so the commands
written but not yet answered wait in a FIFO (`InFlight`) and an `ok` completes the oldest one it can answer.

Why a reply handed to a caller is its own. An `ok` can name its command only by its shape: `ok N<line>`
(ADVANCED_OK) names a numbered line, `ok T:...` names "an M105", a plain `ok` names nothing. So an ok answers the
oldest command in flight whose answer it can be (`match_ok`), and every command ahead of that one was processed
(Marlin answers in order) but lost its ok: such a command is never handed the later answer; it fails with
`LostReplyError`, or, for a print line, counts as run. That is sound only if no two commands in flight could take
each other's ok, so `answer_stays_distinct` lets a command out only when a lost ok cannot make its answer ambiguous:
at most one M105 at a time, and, unless the printer names lines in its oks, a command someone waits for is never in
flight beside another plainly answered one (print lines may share the wire with each other, as a later answer
proves that they ran). Reply lines go to the oldest command waiting when they arrive; after a lost ok they may
belong to a later command, so `attribute` hands them on only when the skipped commands print nothing (a bare M105),
and otherwise to nobody.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.events import Ok
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.states import LINE_TRANSITIONS, LineEvent, LineState, next_line_state

if TYPE_CHECKING:
    from marlin_aio.protocol.printjob import PrintJob

__all__ = ["MAX_REPLY_LINES", "Command", "InFlight", "answer_stays_distinct", "attribute", "match_ok"]

#: How many reply lines one command keeps (M115 prints about 40, M503 about 25); older ones are counted only.
MAX_REPLY_LINES = 256


@dataclass(slots=True, eq=False)
class Command:
    """A command the connection has accepted: queued, in flight, or finished.

    `id` is unique per connection, for matching results to waiters.
    """

    id: int
    text: str
    code: str
    numbered: bool
    timeout_s: float
    submitted_s: float
    line_number: int | None = None
    wire: bytes = b""
    sent_s: float | None = None  # when it was first written
    written_s: float | None = None  # when it was last written (a resend writes it again)
    head_since_s: float | None = None  # when it became the oldest command waiting for an ok
    alive_s: float | None = None  # last busy keepalive / wait line while it was the oldest
    lines: list[str] = field(default_factory=list)
    lines_dropped: int = 0  # reply lines beyond MAX_REPLY_LINES, counted, not kept
    sends: int = 0
    orphan: bool = False  # its caller already gave up (timed out); an answer completes nothing
    job: PrintJob | None = None  # set for the lines of a print job: their answers go to the job, not to a waiter
    source_line: int = 0
    source_bytes: int = 0
    probe: bool = False  # an M105 written to find out whether a stalled stream lost an ok
    refusal: str | None = None  # the printer's line saying it did not run this command (locked, not executed)
    placeholder: bool = False  # an `M110 N<n>` that takes the number of a line that must not run (again)
    emergency: bool = False  # M108/M410/M876 written at once (`Connection.emergency`): never written again
    state: LineState = LineState.QUEUED  # moved only by `move`, through `states.LINE_TRANSITIONS`

    def move(self, event: LineEvent) -> None:
        """Move this line's state by the table.

        Raises:
            ImpossibleTransitionError: the table has no such move (a bug in the core).
        """
        # The table read directly (a dict look-up), as every command moves two or three times; the function only
        # for a move the table lacks, which it reports.
        moved = LINE_TRANSITIONS[self.state].get(event)
        self.state = next_line_state(self.state, event) if moved is None else moved

    # Its fields are written only here: the FIFO's record, moved by the verbs below (the core's parts call them).

    def written(self, now: float) -> None:
        """Written to the printer at `now` (again, for a resend: `sent_s` stays the first time)."""
        self.move(LineEvent.WRITTEN)
        self.sends += 1
        if self.sent_s is None:
            self.sent_s = now
        self.written_s = now

    def numbered_as(self, line_number: int | None, wire: bytes) -> None:
        """Its line number (None: unnumbered) and the bytes that go on the wire."""
        self.line_number = line_number
        self.wire = wire

    def waits_from(self, now: float) -> None:
        """It is answered next from `now` on (it became the oldest, or its wait starts over)."""
        self.head_since_s = now

    def alive(self, now: float) -> None:
        """The printer showed it is working on it (a busy keepalive, a wait line) at `now`."""
        self.alive_s = now

    def overdue(self, now: float) -> None:
        """Unanswered past its deadline: in doubt from `now`, until the printer settles it."""
        self.move(LineEvent.OVERDUE)
        self.head_since_s = now
        self.alive_s = None

    def give_up(self) -> None:
        """Nobody waits for its answer any more (its caller was told, or gave up): the answer completes nothing."""
        self.orphan = True

    def refuse(self, said: str) -> None:
        """The printer said (`said`) that it did not run it; its ok, when it comes, answers a refusal."""
        self.refusal = said

    def replaced(self, said: str) -> None:
        """Counted by the printer but not run (`said`): a new copy takes its place in the print; this entry stays
        only for the ok its number is still owed, with nobody waiting."""
        self.job = None
        self.orphan = True
        self.refusal = said

    def add_line(self, text: str) -> None:
        """Collect one reply line, keeping only the last `MAX_REPLY_LINES` (a chatty or noisy printer must not
        grow one command's reply without bound)."""
        self.lines.append(text)
        if len(self.lines) > MAX_REPLY_LINES:
            del self.lines[0]
            self.lines_dropped += 1


class InFlight:
    """The commands written and waiting for their `ok`, oldest first, and the bytes they hold in the printer's
    receive buffer; and the outcomes of the commands that ended, for the driver to take (`finish`, `take_results`).
    The oldest command's `head_since_s` says since when it has been the one answered next.

    Every submitted command ends here once: answered (a `Reply`) or failed (an error), counted in `answered` and
    `failed`."""

    __slots__ = ("_commands", "answered", "barriers", "bytes", "emergencies", "failed", "results")

    def __init__(self) -> None:
        self._commands: deque[Command] = deque()
        self.results: list[tuple[Command, Reply | MarlinError]] = []
        self.answered = 0
        self.failed = 0
        self.bytes = 0
        self.barriers = 0  # M110s in flight: nothing may be written behind one (see `resends`)
        # Emergency commands in flight (`Connection.emergency`): they hold no place in the window of commands, as
        # the host did not choose to write them, and one whose ok never comes must not hold a print line back.
        self.emergencies = 0

    def __len__(self) -> int:
        return len(self._commands)

    def __bool__(self) -> bool:
        return bool(self._commands)

    def __iter__(self) -> Iterator[Command]:
        return iter(self._commands)

    def __getitem__(self, index: int) -> Command:
        return self._commands[index]

    @property
    def head(self) -> Command | None:
        """The command the printer should answer next."""
        return self._commands[0] if self._commands else None

    def after(self, command: Command) -> list[Command]:
        """The commands written after `command` (which is in flight)."""
        commands = list(self._commands)
        return commands[commands.index(command) + 1 :]

    def append(self, command: Command, now: float) -> None:
        """`command` was just written."""
        if not self._commands:
            command.waits_from(now)
        self._commands.append(command)
        self.bytes += len(command.wire)
        if command.code == "M110":
            self.barriers += 1
        elif command.emergency:
            self.emergencies += 1

    def popleft(self, now: float) -> Command:
        """Take the oldest command off; the next one is answered next from `now` on."""
        command = self._commands.popleft()
        self.bytes -= len(command.wire)
        if command.code == "M110":
            self.barriers -= 1
        elif command.emergency:
            self.emergencies -= 1
        if self._commands:
            self._commands[0].waits_from(now)
        return command

    def remove(self, command: Command, now: float) -> None:
        """Take `command` out wherever it is (the printer will never answer it)."""
        was_head = self._commands[0] is command
        self._commands.remove(command)
        self.bytes -= len(command.wire)
        if command.code == "M110":
            self.barriers -= 1
        elif command.emergency:
            self.emergencies -= 1
        if was_head and self._commands:
            self._commands[0].waits_from(now)

    def keep_only(self, keep: Iterable[Command], now: float, *, restart_head: bool) -> None:
        """Keep only `keep` (in order): the others will not be answered, or go out again. The new oldest command
        waits from `now` if `restart_head`, else only if it had not been the oldest before."""
        self._commands = deque(keep)
        self.bytes = sum(len(c.wire) for c in self._commands)
        self.barriers = sum(c.code == "M110" for c in self._commands)
        self.emergencies = sum(c.emergency for c in self._commands)
        if self._commands and (restart_head or self._commands[0].head_since_s is None):
            self._commands[0].waits_from(now)

    def finish(self, command: Command, outcome: Reply | MarlinError) -> None:
        """`command` ended with `outcome`, for its caller (taken with `take_results`)."""
        if isinstance(outcome, Reply):
            self.answered += 1
        else:
            self.failed += 1
        self.results.append((command, outcome))

    def take_results(self) -> list[tuple[Command, Reply | MarlinError]]:
        """Return and forget the commands finished since the last call, with their reply or error."""
        results, self.results = self.results, []
        return results

    def clear(self) -> None:
        """Forget every command in flight (the printer reset, halted, or the link is gone); outcomes stay."""
        self._commands.clear()
        self.bytes = 0
        self.barriers = 0
        self.emergencies = 0


def match_ok(flight: InFlight, ok: Ok, *, exact_oks: bool) -> int | None:
    """The index in the FIFO of the command `ok` answers, or None when it answers none of them.

    `exact_oks`: the printer names the line in the ok of every numbered command (ADVANCED_OK).
    """
    if ok.line_number is not None:
        for index, command in enumerate(flight):
            if command.line_number == ok.line_number:
                return index
        # It names a line no longer in flight: completing another command with it would hand that command
        # someone else's answer. (An unnumbered command's ok carries no N, so only numbered heads rule it out.)
        head = flight.head
        return 0 if head is not None and head.line_number is None else None
    if ok.temperatures is not None:
        # Only M105 answers `ok T:...`.
        return next((i for i, c in enumerate(flight) if c.code == "M105"), None)
    if exact_oks:
        # This printer names the line in the ok of every numbered command: a plain ok is an unnumbered one's.
        # (Or that of a numbered line whose `N` was damaged on the way, which the printer took as unnumbered, or
        # of the tail of a line cut by a flush: the connection tells those apart, `Receiving._on_ok`.)
        return next(
            (i for i, c in enumerate(flight) if c.line_number is None and (c.code != "M105" or c.refusal)), None
        )
    # A plain ok: the oldest command that answers with a plain ok (not M105, whose answer carries temperatures;
    # a refused one is answered plainly whatever it was).
    return next((i for i, c in enumerate(flight) if c.code != "M105" or c.refusal is not None), None)


def attribute(skipped: list[Command], command: Command) -> tuple[str, ...] | None:
    """The reply lines of `command`, or None when they cannot be told apart from a skipped command's.

    Lines go to the oldest command waiting when they arrive; when its ok was lost, the lines of the commands
    behind it landed in its slot too. They are `command`'s for certain only if every skipped command prints
    nothing but its ok line (a bare M105, or an emergency command: its queued copy is a no-op, or prints nothing).
    """
    if not skipped:
        return tuple(command.lines)
    if all(lost.text == "M105" or lost.probe or lost.emergency for lost in skipped):
        return tuple(line for lost in skipped for line in lost.lines) + tuple(command.lines)
    if not any(lost.lines for lost in skipped):
        return tuple(command.lines)
    return None


def answer_stays_distinct(command: Command, flight: InFlight, *, exact_oks: bool) -> bool:
    """May `command` go out now without its answer becoming confusable with another's if an ok is lost?

    An ok names its command only by line number (ADVANCED_OK) or by its shape (M105's `ok T:`). So, unless
    the printer numbers its oks, a command whose reply someone waits for is never in flight together with
    another whose ok looks the same: at most one M105 at a time, and a user's command that is answered by
    a plain ok only while no other plainly answered command is in flight. Print lines may share the line
    with each other (a print line needs only to be known to have run, and a later answer proves that).
    """
    if command.code == "M105":
        # Probes may follow each other (nobody waits for their answers, and each proves the same thing).
        return not any(c.code == "M105" and not (command.probe and c.probe) for c in flight)
    if exact_oks and command.numbered:
        return True
    waits_for_reply = command.job is None and not command.probe
    for other in flight:
        if other.code == "M105" or (other.emergency and command.numbered):
            # An emergency command's ok comes before a numbered command's written behind it; if it never comes (its
            # line thrown away with a flush), the numbered command's ok settles the emergency command's entry and
            # a probe then proves the numbered one ran (`ok_lost`): never another caller's answer. Waiting for such
            # an entry instead waits forever while emergency commands keep being written (core seed 509).
            continue
        if waits_for_reply or (other.job is None and not other.probe and not other.orphan):
            return False
    return True
