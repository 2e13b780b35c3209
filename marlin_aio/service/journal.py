"""The service's record of each printer's print, on disk: so a service that was killed can say, when it starts
again, which print it was running and where that print stopped.

One small JSON file per printer in `jobs/` beside the socket (the socket's folder is the owner's alone; each file is
made owner-only by `mkstemp`), replaced whole (a temporary file, then `os.replace`), so a reader finds the old
record or the new one, never half of one, whenever the writer is killed. Not fsync'ed: a killed process's writes
are in the kernel already; a power cut also resets the printer, whose print is then over either way.

The print's feed is bounded by this record (`marlin_aio.aio.printhandle`): no line past `may_have_run_through` is
sent before the record says so. `surely_run` is the last line the printer acknowledged.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from urllib.parse import quote

__all__ = ["ENDED_STATES", "JobRecord", "Journal"]

_log = logging.getLogger("marlin_aio.service")

#: States of a record whose print ended while the service watched: nothing to report after a restart.
ENDED_STATES = frozenset({"done", "cancelled", "failed"})


@dataclass(frozen=True)
class JobRecord:
    """Where one printer's print stands, as the service last recorded it.

    `state` is `running` (the service was running it: after a restart, it was killed meanwhile), `killed` (a
    restarted service found it running and reported it), `stopped` (the service cancelled it as it stopped), or
    how it ended: `done`, `cancelled`, `failed`.
    """

    printer: str
    file: str
    state: str
    surely_run: int
    """The last file line the printer acknowledged."""
    may_have_run_through: int
    """No file line after this one was sent."""
    port: str | None = None
    started_s: float = 0.0
    """When the print started (`time.time()`)."""
    updated_s: float = 0.0
    note: str = ""
    """How it ended, for people (the cancel script's outcome, the error)."""

    @property
    def resume_line(self) -> int:
        """The first line to print again: after the line surely run where the print was drained to its end (it
        stopped or was cancelled with nothing in flight), else after every line that may have run."""
        if self.state in ("stopped", "cancelled"):
            return self.surely_run + 1
        return max(self.surely_run, self.may_have_run_through) + 1

    def to_json(self) -> dict[str, object]:
        """The record as JSON, with its resume line (what a client reads from `status`)."""
        return {**asdict(self), "resume_line": self.resume_line}

    def with_state(self, state: str, note: str = "") -> JobRecord:
        """The same record in `state`, stamped now."""
        return replace(self, state=state, note=note or self.note, updated_s=time.time())


class Journal:
    """The records of the printers' prints in `folder` (made owner-only when first written)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def path_of(self, printer: str) -> Path:
        """The file of `printer`'s record (its name quoted: a printer's name is any text)."""
        return self.folder / f"{quote(printer, safe='')}.json"

    def write(self, record: JobRecord) -> None:
        """Replace `record.printer`'s record with `record`, whole.

        Raises:
            OSError: the folder or the file cannot be written.
        """
        self.folder.mkdir(mode=0o700, exist_ok=True)
        data = json.dumps(asdict(record))
        fd, temporary = tempfile.mkstemp(dir=self.folder, prefix=".job.", suffix=".json")  # mode 0600
        try:
            with os.fdopen(fd, "w") as handle:
                handle.write(data)
            os.replace(temporary, self.path_of(record.printer))
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(temporary)
            raise

    def read(self, printer: str) -> JobRecord | None:
        """`printer`'s record, or None when there is none (or it cannot be read: said in the log)."""
        path = self.path_of(printer)
        try:
            value = json.loads(path.read_text())
            return JobRecord(**value)
        except FileNotFoundError:
            return None
        except (OSError, ValueError, TypeError) as exc:
            _log.warning("the print record %s cannot be read (%s): ignored", path, exc)
            return None
