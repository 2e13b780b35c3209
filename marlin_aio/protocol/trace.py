"""A ring buffer of the last lines sent and received, for saying who was waiting for whom when a link stalls.

Lines are recorded redacted (`secrets.redact`): the trace ends up in error messages and logs, and an
`M511 P<password>` line must not carry the password there. The wire itself is not touched.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from marlin_aio.protocol.secrets import redact

__all__ = ["BARE_LINE_END", "Tap", "Trace", "TraceEntry"]

#: How a bare line end (written to complete a line whose own end was damaged) reads in the trace.
BARE_LINE_END = "(a bare line end)"

#: Every line on the wire, at DEBUG (`logging.getLogger("marlin_aio.wire").setLevel(logging.DEBUG)` to see them).
_wire_log = logging.getLogger("marlin_aio.wire")


@dataclass(frozen=True, slots=True)
class TraceEntry:
    """One line on the wire: `direction` is "sent" or "received"; `time_s` is on the connection's clock."""

    time_s: float
    direction: Literal["sent", "received"]
    text: str


_Line = tuple[float, Literal["sent", "received"], str]

#: What `Trace.tap` is called with: each line's time (the connection's clock), its direction and its redacted text.
Tap = Callable[[float, Literal["sent", "received"], str], None]


class Trace:
    """The last `size` lines sent and received, oldest first, plus when each direction last saw traffic.

    Lines are kept as plain tuples and turned into `TraceEntry` values only when read: two lines are recorded for
    every poll, a hundred times a second, and read only when something went wrong.

    Attributes:
        tap: called with every line as it is recorded (a wire log: `marlin_aio.aio.WireLog`), or None. It runs
            inside the link's read handler, so it must not raise.
    """

    __slots__ = ("_entries", "_last_received", "_last_sent", "tap")

    def __init__(self, size: int = 64) -> None:
        self._entries: deque[_Line] = deque(maxlen=size)
        self._last_sent: _Line | None = None
        self._last_received: _Line | None = None
        self.tap: Tap | None = None

    def sent(self, time_s: float, text: str) -> None:
        """Record a line written to the printer (redacted: see the module's docstring)."""
        text = redact(text)
        entry: _Line = (time_s, "sent", text)
        self._entries.append(entry)
        self._last_sent = entry
        if self.tap is not None:
            self.tap(time_s, "sent", text)
        if _wire_log.isEnabledFor(logging.DEBUG):
            _wire_log.debug(">> %s", text)

    def received(self, time_s: float, text: str) -> None:
        """Record a line read from the printer (redacted: firmware without PASSWORD_FEATURE echoes an M511 back in
        its `Unknown command`)."""
        text = redact(text)
        entry: _Line = (time_s, "received", text)
        self._entries.append(entry)
        self._last_received = entry
        if self.tap is not None:
            self.tap(time_s, "received", text)
        if _wire_log.isEnabledFor(logging.DEBUG):
            _wire_log.debug("<< %s", text)

    @property
    def last_sent(self) -> TraceEntry | None:
        """The last line written, or None."""
        return None if self._last_sent is None else TraceEntry(*self._last_sent)

    @property
    def last_received(self) -> TraceEntry | None:
        """The last line read, or None."""
        return None if self._last_received is None else TraceEntry(*self._last_received)

    def entries(self) -> list[TraceEntry]:
        """The recorded lines, oldest first."""
        return [TraceEntry(*entry) for entry in self._entries]

    def format(self, now: float) -> str:
        """The recorded lines as text, one per line, each with its age: `  -0.512 s >> N12 G1 X10*93`."""
        return "\n".join(
            f"{time_s - now:+9.3f} s {'>>' if direction == 'sent' else '<<'} {text}"
            for time_s, direction, text in self._entries
        )
