"""The answer a caller gets for one command (`Reply`).

(The connection's record of a command on its way, `Command`, is the FIFO's: `matching`.)
"""

from __future__ import annotations

from dataclasses import dataclass

from marlin_aio.protocol.events import Ok
from marlin_aio.protocol.temperatures import Temperatures

__all__ = ["Reply"]


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
