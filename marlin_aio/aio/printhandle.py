"""A print in progress, as the caller holds it: progress, pause, resume, cancel, and its outcome.

A print may be bounded by a `FeedGuard` (the service's record of its jobs, `marlin_aio.service.lifecycle`): the job
is then fed no line past the last bound the guard recorded and told (`PrintJob.feed_limit`), and the handle asks it
for the next bound, `FEED_AHEAD_LINES` further, well before the feed reaches the last one. The guard is found in
`FEED_GUARD` when the handle is made: `Printer.start_print` makes the handle, and the service reaches it only through
the farm, so a context variable carries it there rather than an argument through every layer.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Generator
from contextvars import ContextVar
from typing import Protocol

from marlin_aio.aio.link import Link
from marlin_aio.protocol.printjob import PrintJob, PrintProgress, PrintState

__all__ = ["COOL_DOWN", "FEED_AHEAD_LINES", "FEED_GUARD", "FeedGuard", "PrintHandle"]

_log = logging.getLogger("marlin_aio.print")

#: A cancel script that turns the hotend, the bed and the part fan off (`PrintHandle.cancel(COOL_DOWN)`).
COOL_DOWN = ("M104 S0", "M140 S0", "M107")

#: How many lines of the file a bounded print's feed may run ahead of the last one fed (a new bound is asked for
#: when half of that is left): a record written every ~100 lines, and never a wait for one at 1,000 lines a second.
FEED_AHEAD_LINES = 200


class FeedGuard(Protocol):
    """Whoever must know, before a line is sent, how far a print may have run (the service's job record)."""

    def bound(self, handle: PrintHandle) -> None:
        """Record and tell `handle.job.feed_limit` (just raised; no line past the old one is sent before this
        returns).

        Raises:
            Exception: it could not be recorded: the line past the old bound is not sent.
        """


#: The guard of the prints started in this context (the service sets it around `Printer.start_print`).
FEED_GUARD: ContextVar[FeedGuard | None] = ContextVar("marlin_aio_feed_guard", default=None)


class PrintHandle:
    """A print in progress: watch `progress`, `pause()`, `resume()`, `cancel()`, and await it for the outcome.

    `Printer.start_print()` makes one; it streams on the printer's link until the job ends.
    """

    def __init__(self, link: Link, job: PrintJob, timeout_s: float, saved_window: tuple[int, int]) -> None:
        self._link = link
        self.job = job
        self._timeout_s = timeout_s
        self._saved_window = saved_window
        self._done: asyncio.Future[PrintProgress] = link.loop.create_future()
        self._guard = FEED_GUARD.get()
        self._bounding = False  # a new bound is asked for (scheduled, out of the read path)
        if self._guard is not None:
            # Before the job is attached: not even its first line goes out unrecorded. A guard that cannot record
            # raises here, and the print does not start.
            job.feed_limit = FEED_AHEAD_LINES
            self._guard.bound(self)

    @property
    def progress(self) -> PrintProgress:
        """Lines and bytes sent and acknowledged, elapsed time, rate, estimate of what remains."""
        return self.job.progress(self._link.now())

    @property
    def finished(self) -> bool:
        """True once the print ended (done, cancelled or failed)."""
        return self._done.done()

    def pause(self) -> None:
        """Stop feeding lines (what is in flight completes); heaters and fans stay as they are."""
        self.job.pause()

    def resume(self) -> None:
        """Feed lines again."""
        self.job.resume(self._link.now())
        self._link.flush()
        self.check()

    async def cancel(self, script: list[str] | tuple[str, ...] = ()) -> PrintProgress:
        """Stop feeding for good, wait for what is in flight, then send `script` (e.g. heaters off).

        Raises:
            MarlinError: the print failed before it could be cancelled, or the script failed.
        """
        self.job.cancel(self._link.now())
        self.check()
        progress = await self.wait()
        for command in script:
            await self._link.send(command, timeout_s=self._timeout_s)
        return progress

    async def wait(self) -> PrintProgress:
        """Wait for the print to end; return its final progress.

        Raises:
            PrintStalledError: the printer stopped answering (the message says where and who was silent).
            PrinterHaltedError, PrinterResetError, ConnectionLostError: the printer or link failed mid-print.
            ResendLimitError: the link was too noisy.
            RemoteProtocolError: with send-ahead, the tail of a line cut in two ran on its own.
            MarlinError: a line of the file could not be sent.
        """
        return await asyncio.shield(self._done)

    def __await__(self) -> Generator[object, None, PrintProgress]:
        return self.wait().__await__()

    def check(self) -> None:
        """Resolve the outcome once the job has ended, and give the link its window back (the link calls this
        after every batch of answers)."""
        job = self.job
        if self._guard is not None and not self._bounding and job.active and job.feed_limit is not None:
            held = job.held_line is not None
            if held or job.feed_limit - job.fed_through < FEED_AHEAD_LINES // 2:
                self._bounding = True
                self._link.loop.call_soon(self._raise_bound)  # a file is written: not in the read path
        if self._done.done() or not job.finished:
            return
        self._link.set_window(*self._saved_window)
        if job.state is PrintState.FAILED and job.error is not None:
            self._done.set_exception(job.error)
            self._done.exception()  # a print nobody awaits must not log "exception never retrieved"
        else:
            self._done.set_result(job.progress(self._link.now()))

    def _raise_bound(self) -> None:
        """Raise the job's feed bound once the guard recorded and told it, and let the link feed on."""
        self._bounding = False
        job, guard = self.job, self._guard
        if guard is None or not job.active or job.feed_limit is None:
            return
        old = job.feed_limit
        job.feed_limit = max(job.fed_through, job.held_line or 0) + FEED_AHEAD_LINES
        try:
            guard.bound(self)
        except Exception as exc:  # the record cannot be kept: the print must not run where it cannot be followed
            job.feed_limit = old
            _log.exception("the record of %s could not be written: the print is cancelled", job.name)
            job.cancel(self._link.now(), f"its record could not be written ({exc})")
            self.check()
            return
        self._link.flush()
