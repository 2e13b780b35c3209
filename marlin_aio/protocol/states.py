"""The protocol core's state, as two values and two tables: the link's state, and each line's.

h11 keeps each side of an HTTP connection in one state value and lists every allowed move in one table
(`_state.py`); a move that is not in the table raises at once instead of leaving the connection somewhere no
one planned for. The core does the same, for two things:

- **The link** (`LinkState`): where the printer and the print stand. `Connection.state` *is* this value; it is
  not derived from flags. Every change goes through `LINK_TRANSITIONS` (`next_link_state`).
- **Each line** (`LineState`): where one command stands between the caller and the firmware. `Command.state`
  is this value, and every change goes through `LINE_TRANSITIONS` (`Command.move`).

The rules that keep a print exact are moves in these tables, so they can be read in one place:

- A line of a stopped print is never written again: a print that stops moves the link to STOPPING (its lines
  still on the wire are answered or resolved, never resent) and its unwritten lines to WITHDRAWN. When the
  printer asks for one of its numbers again, a placeholder that runs nothing (`M110 N<that number>`) takes it.
- An `ok` that follows `Unknown command` for a mangled copy of a numbered line means the line was not counted
  (ON_WIRE -> TO_RESEND, MANGLED): it is written again inside the print, not taken for a refusal.
- A line whose `ok` may be lost is IN_DOUBT, never dropped by time alone: only the printer resolves it (its own
  late `ok`, or the answer to a numbered probe behind it, which proves it ran: ACCEPTED, marked `ok_lost`), so a
  late `ok` always lands on its own line and never on the next caller's.
- The line counter moves only when an `M110` is answered (see `resends`).

Nothing here imports anything but the standard library: the tables are data, tested on their own.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import Enum
from types import MappingProxyType
from typing import TypeVar

__all__ = [
    "FINAL_LINE_STATES",
    "LINE_TRANSITIONS",
    "LINK_TRANSITIONS",
    "ImpossibleTransitionError",
    "LineEvent",
    "LineState",
    "LinkEvent",
    "LinkState",
    "next_line_state",
    "next_link_state",
]


_S = TypeVar("_S", bound=Enum)
_E = TypeVar("_E", bound=Enum)


class _Singletons(Enum):
    """An Enum hashed by identity: its members are singletons compared by identity anyway. `Enum.__hash__` is a
    Python function (it hashes the member's name), called by every lookup in the tables below, several times for
    each command; `object.__hash__` is a slot the interpreter calls directly."""

    __hash__ = object.__hash__


class ImpossibleTransitionError(RuntimeError):
    """A move that the state table does not allow: a bug in marlin_aio, never the printer's or the caller's fault."""


class LinkState(_Singletons):
    """Where the link to the printer stands; `Printer.state` and `Connection.state` report it.

    The protocol core moves between all of them: CONNECTING while the client's handshake runs (a connection made
    with `connecting=True`, until `handshake_done`), READY, PRINTING, STOPPING, LOCKED, STOPPED, HALTED, and LOST
    once the port closed or went away (`Connection.lose`). A board that resets (prints `start`) goes back to READY
    (during the handshake it stays CONNECTING: that is its boot banner): commands in flight fail with
    `PrinterResetError`, and nothing is replayed.
    """

    CONNECTING = "connecting"
    """The port is open and the handshake (banner, sync, M115) is under way."""
    READY = "ready"
    """Commands go out and are answered."""
    PRINTING = "printing"
    """A print streams (running or paused); commands go out between its lines."""
    STOPPING = "stopping"
    """A print stopped; lines of it that were on the wire are still being answered. None is ever written again."""
    LOCKED = "locked"
    """The printer refuses every command until unlocked (`M511 P<password>` or its screen)."""
    STOPPED = "stopped"
    """The printer stopped after an error (`Printer stopped due to errors`); `M999` resumes it."""
    HALTED = "halted"
    """The printer halted (kill(), thermal protection, M112): it answers nothing until it is reset."""
    LOST = "lost"
    """The port was closed or went away."""


class LinkEvent(_Singletons):
    """What moves the link from one state to another."""

    HANDSHAKE_DONE = "handshake done"
    PRINT_STARTED = "print started"
    PRINT_ENDED = "print ended"  # done, or stopped with nothing of it left on the wire
    PRINT_STOPPED = "print stopped"  # stopped with lines of it still on the wire
    WIRE_CLEAR = "wire clear"  # the last line of a stopped print was answered or resolved
    LOCKED = "locked"  # "Printer locked!"
    UNLOCKED = "unlocked"  # a command ran normally
    STOPPED = "stopped"  # "Printer stopped due to errors"
    RESUMED = "resumed"  # M999 answered
    HALTED = "halted"  # kill(), thermal protection, M112 sent
    RESET = "reset"  # the board printed `start`
    PORT_LOST = "port lost"


_LIVE = (LinkState.READY, LinkState.PRINTING, LinkState.STOPPING, LinkState.LOCKED)

_link_table: dict[LinkState, dict[LinkEvent, LinkState]] = {
    LinkState.CONNECTING: {LinkEvent.HANDSHAKE_DONE: LinkState.READY, LinkEvent.LOCKED: LinkState.LOCKED},
    LinkState.READY: {LinkEvent.PRINT_STARTED: LinkState.PRINTING, LinkEvent.LOCKED: LinkState.LOCKED},
    LinkState.PRINTING: {
        LinkEvent.PRINT_ENDED: LinkState.READY,
        LinkEvent.PRINT_STOPPED: LinkState.STOPPING,
        LinkEvent.LOCKED: LinkState.LOCKED,
    },
    LinkState.STOPPING: {
        LinkEvent.WIRE_CLEAR: LinkState.READY,
        LinkEvent.PRINT_STARTED: LinkState.PRINTING,  # the stopped print's last lines are still owed their oks
        LinkEvent.LOCKED: LinkState.LOCKED,
    },
    LinkState.LOCKED: {LinkEvent.UNLOCKED: LinkState.READY, LinkEvent.LOCKED: LinkState.LOCKED},
    LinkState.STOPPED: {LinkEvent.RESUMED: LinkState.READY, LinkEvent.STOPPED: LinkState.STOPPED},
    LinkState.HALTED: {LinkEvent.HALTED: LinkState.HALTED, LinkEvent.STOPPED: LinkState.HALTED},
    LinkState.LOST: {},
}
for _state in (*_LIVE, LinkState.CONNECTING):
    _link_table[_state][LinkEvent.STOPPED] = LinkState.STOPPED
for _state in (*_LIVE, LinkState.CONNECTING, LinkState.STOPPED):
    _link_table[_state][LinkEvent.HALTED] = LinkState.HALTED
for _state in (*_LIVE, LinkState.CONNECTING, LinkState.STOPPED, LinkState.HALTED):
    # A reset forgets everything, a halt and a lock included; the port being lost ends everything.
    _link_table[_state][LinkEvent.RESET] = LinkState.READY
    _link_table[_state][LinkEvent.PORT_LOST] = LinkState.LOST
# The boot banner of a board that resets as its port opens: the handshake goes on.
_link_table[LinkState.CONNECTING][LinkEvent.RESET] = LinkState.CONNECTING

#: Every allowed move of the link: `LINK_TRANSITIONS[state][event]` is the state it leads to.
LINK_TRANSITIONS: Mapping[LinkState, Mapping[LinkEvent, LinkState]] = MappingProxyType(
    {state: MappingProxyType(moves) for state, moves in _link_table.items()}
)


def _look_up(table: Mapping[_S, Mapping[_E, _S]], state: _S, event: _E, what: str) -> _S:
    # Plain dicts behind the read-only views: a line moves a few times per command, on the hot path.
    try:
        return table[state][event]
    except KeyError:
        raise ImpossibleTransitionError(f"{what} cannot go from {state.name} on {event.name}") from None


def next_link_state(state: LinkState, event: LinkEvent) -> LinkState:
    """The state `event` moves the link to from `state`.

    Raises:
        ImpossibleTransitionError: the table has no such move.
    """
    return _look_up(_link_table, state, event, "the link")


class LineState(_Singletons):
    """Where one command stands between its caller and the firmware."""

    QUEUED = "queued"
    """Accepted, never written."""
    ON_WIRE = "on the wire"
    """Written; its answer is due."""
    IN_DOUBT = "in doubt"
    """Written, and its answer is overdue (a timeout) or may have been lost: only the printer can settle it."""
    TO_RESEND = "to resend"
    """The printer did not take it (a line error, a flush, a mangled copy): it is written again, in its place."""
    ACCEPTED = "accepted"
    """The printer ran it (its own `ok`, or a later answer that proves it ran)."""
    REJECTED = "rejected"
    """The printer answered it but said it did not run it (locked, unknown command, not executed)."""
    WITHDRAWN = "withdrawn"
    """Never to be written (its caller gave up before it went out, or its print stopped)."""
    FAILED = "failed"
    """Ended without an answer: the printer halted or reset, or the link went away."""


class LineEvent(_Singletons):
    """What moves a line from one state to another."""

    WRITTEN = "written"
    OK = "ok"  # its own ok, or a later answer that proves it ran
    REFUSED = "refused"  # answered, not run
    MANGLED = "mangled"  # answered as an unknown command: the copy it got was damaged and not counted
    RESEND = "resend"  # the printer asked for it again, or threw it away with its receive buffer
    OVERDUE = "overdue"  # no answer in time, or its ok may have been lost
    WITHDRAWN = "withdrawn"
    FAILED = "failed"


_written = {
    LineEvent.OK: LineState.ACCEPTED,
    LineEvent.REFUSED: LineState.REJECTED,
    LineEvent.MANGLED: LineState.TO_RESEND,
    LineEvent.RESEND: LineState.TO_RESEND,
    LineEvent.OVERDUE: LineState.IN_DOUBT,
    LineEvent.FAILED: LineState.FAILED,
}

_line_table: dict[LineState, dict[LineEvent, LineState]] = {
    LineState.QUEUED: {
        LineEvent.WRITTEN: LineState.ON_WIRE,
        LineEvent.WITHDRAWN: LineState.WITHDRAWN,
        LineEvent.FAILED: LineState.FAILED,
    },
    LineState.ON_WIRE: dict(_written),
    LineState.IN_DOUBT: {**_written, LineEvent.OVERDUE: LineState.IN_DOUBT},
    LineState.TO_RESEND: {
        LineEvent.WRITTEN: LineState.ON_WIRE,
        LineEvent.RESEND: LineState.TO_RESEND,
        LineEvent.WITHDRAWN: LineState.WITHDRAWN,  # a line of a stopped print: a placeholder takes its number
        LineEvent.FAILED: LineState.FAILED,
    },
    LineState.ACCEPTED: {},
    LineState.REJECTED: {},
    LineState.WITHDRAWN: {},
    LineState.FAILED: {},
}

#: Every allowed move of a line: `LINE_TRANSITIONS[state][event]` is the state it leads to. ACCEPTED, REJECTED,
#: WITHDRAWN and FAILED are final: nothing moves a line out of them, so nothing that ended can run again.
LINE_TRANSITIONS: Mapping[LineState, Mapping[LineEvent, LineState]] = MappingProxyType(
    {state: MappingProxyType(moves) for state, moves in _line_table.items()}
)

#: The states a line ends in.
FINAL_LINE_STATES = frozenset(state for state, moves in _line_table.items() if not moves)


def next_line_state(state: LineState, event: LineEvent) -> LineState:
    """The state `event` moves a line to from `state`.

    Raises:
        ImpossibleTransitionError: the table has no such move.
    """
    # Inlined rather than through `_look_up`: every command moves two or three times, on the hot path.
    try:
        return _line_table[state][event]
    except KeyError:
        raise ImpossibleTransitionError(f"a line cannot go from {state.name} on {event.name}") from None
