"""Polling temperatures: one M105 at a time, on a deadline-based schedule, from a single timer callback."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from marlin_aio.aio.link import Link
from marlin_aio.errors import MarlinError
from marlin_aio.protocol.replies import Reply

__all__ = ["Poller"]


class Poller:
    """Sends M105 every interval while at least one `poll_temperatures()` block asks for it; the shortest interval
    asked for wins. The replies reach readers through the temperature feed, like every other report.

    Args:
        link: the link to send on.
        timeout_s: how long a poll may go unanswered.
        slow_down: returns the interval to poll at no faster than (a print streaming), or None.
    """

    def __init__(self, link: Link, timeout_s: float, slow_down: Callable[[], float | None]) -> None:
        self._link = link
        self._timeout_s = timeout_s
        self._slow_down = slow_down
        self._intervals: list[float] = []  # one per active poll block
        self._timer: asyncio.Handle | None = None
        self._pending = False  # the last M105 is still on its way; never more than one
        self._next = 0.0

    @property
    def active(self) -> bool:
        """True while some block asks for polls."""
        return bool(self._intervals)

    def start(self, interval_s: float) -> None:
        """Poll at least every `interval_s` until `stop(interval_s)`."""
        self._intervals.append(interval_s)
        if self._timer is None:
            self._next = self._link.now()
            self._timer = self._link.loop.call_soon(self._tick)

    def stop(self, interval_s: float) -> None:
        """One block that asked for `interval_s` ended."""
        self._intervals.remove(interval_s)
        if not self._intervals:
            self.cancel()

    def cancel(self) -> None:
        """Stop polling at once (the link closes)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _answered(self, outcome: Reply | MarlinError) -> None:
        # Answered, timed out or failed: the next slot may poll again. The reading itself arrives as an event.
        self._pending = False

    def _tick(self) -> None:
        """One slot of the poll schedule: send an M105 unless the last one is still unanswered.

        Driven by one timer callback rather than a task awaiting each reply: no future, no task switch and no
        sleep per poll, which halves the event-loop work at 100 Hz (it matters on a Raspberry Pi).
        """
        self._timer = None
        link = self._link
        intervals = self._intervals
        if not intervals or link.lost is not None:
            return
        loop = link.loop
        now = loop.time()
        if not self._pending:
            self._pending = link.submit_quietly("M105", timeout_s=self._timeout_s, done=self._answered)
        interval = intervals[0] if len(intervals) == 1 else min(intervals)
        slowest = self._slow_down()
        if slowest is not None and slowest > interval:
            interval = slowest
        # Deadline-based, so the rate does not drift; slots missed behind a long command are skipped, not repeated.
        self._next += interval
        if self._next <= now:
            self._next = now + interval
        self._timer = loop.call_at(self._next, self._tick)
