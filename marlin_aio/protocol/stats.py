"""A read-only snapshot of a link's counters: what `Printer.stats` and `Connection.stats()` return.

The counters live in the protocol core (`connection`), which alone changes them; everyone else (the
client, the CLI, the benchmarks, tests) reads a frozen copy, so nothing outside the core can set them by mistake.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LinkStats"]


@dataclass(frozen=True, slots=True)
class LinkStats:
    """The link's counters at one moment, since the connection was made.

    Every command submitted is accounted for: `submitted == answered + failed + cancelled + in_flight + queued`.
    """

    submitted: int
    """Commands accepted for sending (the client's own polls included)."""
    answered: int
    """Commands that got their reply."""
    failed: int
    """Commands that ended with an error (timeouts included)."""
    cancelled: int
    """Commands withdrawn before they were written."""
    in_flight: int
    """Commands written and waiting for their `ok` now."""
    queued: int
    """Commands accepted and waiting to be written now."""
    timeouts: int
    """Commands (or print lines) that got no answer within their timeout."""
    resend_requests: int
    """`Resend:` requests received (a line the printer rejected, or stale rejections of lines behind it)."""
    resets: int
    """Times the printer reset (printed `start`) while connected."""
    lost_oks: int
    """`ok`s proven lost on the line: a later answer showed their command had run."""
    stray_oks: int
    """`ok`s that answered no command waiting."""
    garbage_lines: int
    """Lines of noise received (not ASCII text a firmware prints), given to no command."""
    probes: int
    """M105 probes written during prints to find out whether an `ok` was lost."""
    fragments: int
    """Tails of lines a flush cut in two that the printer refused (`Unknown command`), recognised as such."""
    fragments_run: int
    """Tails of cut lines the printer ran as commands of their own (send-ahead only; the print stopped)."""
    bytes_received: int
    """Bytes read from the printer."""

    @property
    def accounted(self) -> bool:
        """True when every submitted command is answered, failed, withdrawn, in flight or queued."""
        return self.submitted == self.answered + self.failed + self.cancelled + self.in_flight + self.queued
