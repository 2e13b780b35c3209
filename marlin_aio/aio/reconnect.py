"""Keeping a printer connected: open it, run a session on it, and when the printer cannot be opened or its link
fails (unplugged, halted, silent), wait and do it again.

Every front end used to write this loop itself (the farm's supervisor, `watch --reconnect`, `log --reconnect`),
each with its own waits. Here it is once, as aiomqtt leaves it to its users but with the waits decided:
`keep_connected(connect, session)` retries on the printer's failures (`MarlinError`) only, so a bug in the session
still ends it, and says each retry to `on_retry` (what failed, whether a connection had been made, how long it
waits), which is where a front end reports an outage once rather than at every attempt.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TypeVar

from marlin_aio.aio.printer import Printer
from marlin_aio.errors import MarlinError

__all__ = ["Backoff", "Retry", "keep_connected"]

T = TypeVar("T")


@dataclass
class Backoff:
    """The waits between attempts: `start_s`, doubling after each failed attempt up to `max_s`, and `start_s`
    again once a connection is made (`reset`).

    Raises:
        ValueError: (when made) a wait that is not positive, or `max_s` below `start_s`.
    """

    start_s: float = 1.0
    max_s: float = 30.0
    _next_s: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (self.start_s > 0 and self.max_s >= self.start_s):
            raise ValueError(f"backoff needs 0 < start_s <= max_s, got {self.start_s:g} and {self.max_s:g}")
        self._next_s = self.start_s

    def next_delay(self) -> float:
        """The wait before the next attempt; the one after it is twice as long (up to `max_s`)."""
        delay = self._next_s
        self._next_s = min(delay * 2, self.max_s)
        return delay

    def reset(self) -> None:
        """A connection was made: the next wait is `start_s` again."""
        self._next_s = self.start_s


@dataclass(frozen=True)
class Retry:
    """One failed attempt or lost connection, as `keep_connected` tells `on_retry` before it waits."""

    error: MarlinError
    """Why: the printer could not be opened (`ConnectError`, `HandshakeError`), or the link failed."""
    connected: bool
    """True if the failure ended a connection that had been made; False if none could be made."""
    attempt: int
    """Failures in a row since the last connection was made: 1 for the first (report an outage when it is 1)."""
    delay_s: float
    """How long it waits before the next attempt."""


async def keep_connected(
    connect: Callable[[], contextlib.AbstractAsyncContextManager[Printer]],
    session: Callable[[Printer], Awaitable[T]],
    *,
    backoff: Backoff | None = None,
    on_retry: Callable[[Retry], None] | None = None,
    stop: asyncio.Event | None = None,
    deadline: float | None = None,
) -> T | None:
    """Open a printer with `connect()` (a `Printer`, or any async context manager giving one) and return what
    `session(printer)` returns; when opening it fails or the session fails with a `MarlinError`, tell `on_retry`,
    wait (`backoff`, 1 s doubling to 30 s by default) and try again. Runs until the session returns, or until
    cancelled; or returns None when `stop` is set or the `deadline` (the event loop's time) comes between two
    attempts, at once even in the middle of a wait. A running session is never cut: it watches `stop` and the
    deadline itself, if it should.

        await marlin_aio.aio.keep_connected(lambda: marlin_aio.Printer(port), watch_it, stop=ctrl_c)

    The printer is closed after each session, whatever ended it. `on_retry` is called on the event loop before
    each wait; if it raises, so does this.

    Raises:
        Exception: anything the session raises that is not a `MarlinError` (a bug is not retried).
    """
    backoff = backoff or Backoff()
    loop = asyncio.get_running_loop()
    attempt = 0
    while True:
        if (stop is not None and stop.is_set()) or (deadline is not None and loop.time() >= deadline):
            return None
        connected = False
        try:
            async with connect() as printer:
                connected = True
                attempt = 0
                backoff.reset()
                return await session(printer)
        except MarlinError as exc:
            attempt += 1
            delay = backoff.next_delay()
            if on_retry is not None:
                on_retry(Retry(exc, connected, attempt, delay))
        if deadline is not None:
            delay = min(delay, max(deadline - loop.time(), 0.0))
        if stop is None:
            await asyncio.sleep(delay)
        else:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), delay)  # a stop ends the wait at once
