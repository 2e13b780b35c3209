"""A command's life on the link (`Command`) and the answer its caller gets (`Reply`).

A `Command` is the connection's record of one command: queued, written (with its line number and the bytes on the
wire), answered or failed. Its reply lines collect on it while it is the oldest command waiting, bounded so a
chatty or noisy printer cannot grow one reply without limit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from marlin_aio.protocol.events import Ok
from marlin_aio.protocol.states import LineEvent, LineState, next_line_state
from marlin_aio.protocol.temperatures import Temperatures

if TYPE_CHECKING:
    from marlin_aio.protocol.printjob import PrintJob

__all__ = ["MAX_REPLY_LINES", "Command", "Reply", "is_noise"]

#: How many reply lines one command keeps (M115 prints about 40, M503 about 25); older ones are counted only.
MAX_REPLY_LINES = 256


@dataclass(frozen=True, slots=True)
class Reply:
    """What the printer answered to one command: the lines that came with it, and its `ok`.

    `sent_s` and `answered_s` are on the connection's clock, so `latency_s` is the round trip.
    """

    command: str
    lines: tuple[str, ...]
    ok: Ok
    sent_s: float
    answered_s: float
    lines_dropped: int = 0
    """Lines that came before `lines` and were not kept (over `MAX_REPLY_LINES`)."""
    ok_lost: bool = False
    """The command's own `ok` was lost on the line, and a later answer proved that it ran: `ok` is that later
    answer, and `lines` are its reply lines as far as they can be told apart (else none)."""

    @property
    def latency_s(self) -> float:
        """Seconds from writing the command to its `ok`."""
        return self.answered_s - self.sent_s

    @property
    def temperatures(self) -> Temperatures | None:
        """The temperatures an M105 `ok` carried, if any."""
        return self.ok.temperatures


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
        self.state = next_line_state(self.state, event)

    def add_line(self, text: str) -> None:
        """Collect one reply line, keeping only the last `MAX_REPLY_LINES` (a chatty or noisy printer must not
        grow one command's reply without bound)."""
        self.lines.append(text)
        if len(self.lines) > MAX_REPLY_LINES:
            del self.lines[0]
            self.lines_dropped += 1


def is_noise(text: str) -> bool:
    """True for a line no firmware prints: Marlin writes ASCII only, so anything else is noise from the link."""
    return not text.isascii() or any(ch < " " or ch == "\x7f" for ch in text)
