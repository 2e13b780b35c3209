"""A print in progress, as the caller holds it: progress, pause, resume, cancel, and its outcome."""

from __future__ import annotations

import asyncio
from collections.abc import Generator

from marlin_aio.aio.link import Link
from marlin_aio.protocol.printjob import PrintJob, PrintProgress, PrintState

__all__ = ["COOL_DOWN", "PrintHandle"]

#: A cancel script that turns the hotend, the bed and the part fan off (`PrintHandle.cancel(COOL_DOWN)`).
COOL_DOWN = ("M104 S0", "M140 S0", "M107")


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
        if self._done.done() or not self.job.finished:
            return
        self._link.set_window(*self._saved_window)
        job = self.job
        if job.state is PrintState.FAILED and job.error is not None:
            self._done.set_exception(job.error)
            self._done.exception()  # a print nobody awaits must not log "exception never retrieved"
        else:
            self._done.set_result(job.progress(self._link.now()))
