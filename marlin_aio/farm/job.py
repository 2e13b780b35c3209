"""One print job of a printer the farm owns: the one value every door of the service reads and every client sees.

A job is started, paused, resumed and cancelled only through the farm (`Farm.start_print`, `Farm.pause_print`,
`Farm.resume_print`, `Farm.cancel_print`), which the service's table of verbs calls for every door (the socket's
JSON-RPC, MQTT commands, the OctoPrint API, the CLI through the socket): so a cancel is the same cancel whoever
asks, runs the job's one cancel script once, and every reader sees the same state.

What a job knows that the print handle does not: the file's name as its starter gave it (never the name of the
service's copy), who started it, the scripts run when it is cancelled and when it ends, whether the service's copy
of the file is removed when it ends, and, once ended, how. Its state adds the steps between the handle's states:
`starting` (the M110 that begins it is on its way), `cancelling` (stopped feeding, the script not yet done), and
`interrupted` (the service stopped or died under it).
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import time
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import marlin_aio
from marlin_aio.protocol.printjob import PrintProgress, PrintState
from marlin_aio.protocol.rpc import progress_to_json

__all__ = ["DEFAULT_CANCEL_SCRIPT", "DEFAULT_END_SCRIPT", "Job", "JobState", "cancel_script_for"]

#: What a cancel runs after the print stopped, as OctoPrint's default "after print job is cancelled" script does:
#: the hotend, the bed and the part fan off. (The farm adds `M104 T<n> S0` for each further hotend the printer
#: reports: `cancel_script_for`.)
DEFAULT_CANCEL_SCRIPT: tuple[str, ...] = marlin_aio.COOL_DOWN
#: What runs after a print that ended by itself: nothing (the G-code's own end block cools the printer).
DEFAULT_END_SCRIPT: tuple[str, ...] = ()


class JobState(Enum):
    """Where a job stands, for every door alike."""

    STARTING = "starting"
    PRINTING = "printing"
    PAUSED = "paused"
    CANCELLING = "cancelling"
    DONE = "done"
    CANCELLED = "cancelled"
    FAILED = "failed"
    INTERRUPTED = "interrupted"
    """The service stopped (SIGTERM) or was killed while it ran."""

    @property
    def active(self) -> bool:
        """True while the job holds its printer (a second print is refused)."""
        return self in _ACTIVE


_ACTIVE = frozenset({JobState.STARTING, JobState.PRINTING, JobState.PAUSED, JobState.CANCELLING})
_FROM_PRINT = {
    PrintState.RUNNING: JobState.PRINTING,
    PrintState.PAUSED: JobState.PAUSED,
    PrintState.DONE: JobState.DONE,
    PrintState.CANCELLED: JobState.CANCELLED,
    PrintState.FAILED: JobState.FAILED,
}


@dataclass(eq=False)
class Job:
    """A print of one printer, from the moment it was asked for until long after it ended (the printer's last job
    stays readable until the next starts)."""

    printer: str
    file: str
    """The file's name as the starter gave it (`part.gcode`), never the service's copy's."""
    path: Path
    """Where the service reads it."""
    started_by: str
    """Which door and client started it (`socket client 3`, `mqtt`, `octoprint`)."""
    cancel_script: tuple[str, ...] = DEFAULT_CANCEL_SCRIPT
    end_script: tuple[str, ...] = DEFAULT_END_SCRIPT
    options: dict[str, Any] = field(default_factory=dict)
    """How its lines are fed (send_ahead, timeout_s, window_bytes, stop_on_unknown): a restart feeds them alike."""
    remove_file: bool = False
    """The service's own copy (sent by a client as lines): removed when the job ends, unless kept on purpose."""
    id: str = field(default_factory=lambda: secrets.token_hex(4))
    started_s: float = field(default_factory=time.time)
    handle: marlin_aio.PrintHandle | None = None
    ended_s: float | None = None
    error: str | None = None
    """Why it failed or was interrupted, one line."""
    cancelled_by: str | None = None
    """Who cancelled it (a door and client, or `printer asked: ...`)."""
    interrupted_at: PrintProgress | None = None
    """The progress when the service stopped under it (an interrupted job's last word)."""
    recorded_lines: tuple[int, int] | None = None
    """(surely run, may have run) from the service's record, for a job known only from it (interrupted)."""
    cancel_task: asyncio.Future[None] | None = field(default=None, repr=False)
    """The one cancel under way or done (its script runs once, whoever asks)."""
    _cancelling: bool = False
    _interrupted: bool = False

    @property
    def progress(self) -> PrintProgress | None:
        """The print's progress now (None while it is starting)."""
        if self.interrupted_at is not None:
            return self.interrupted_at
        return None if self.handle is None else self.handle.progress

    @property
    def state(self) -> JobState:
        """Where it stands now (read from the print itself, so never stale)."""
        if self._interrupted:
            return JobState.INTERRUPTED
        if self.handle is None:
            return JobState.FAILED if self.error is not None else JobState.STARTING
        state = _FROM_PRINT[self.handle.progress.state]
        if self._cancelling and (state.active or state is JobState.CANCELLED) and self.ended_s is None:
            return JobState.CANCELLING
        return state

    @property
    def active(self) -> bool:
        """True while it holds its printer."""
        return self.state.active

    def cancelling(self, by: str) -> None:
        """Mark it as being cancelled by `by` (the first asker is kept)."""
        self._cancelling = True
        if self.cancelled_by is None:
            self.cancelled_by = by

    def ended(self, error: str | None = None) -> None:
        """Mark it ended (its scripts done), with why it failed if it did; its copy removed if it was ours."""
        if self.ended_s is None:
            self.ended_s = time.time()
        if error is not None and self.error is None:
            self.error = error
        if self.remove_file:
            with contextlib.suppress(OSError):
                self.path.unlink()

    def interrupted(self, why: str) -> None:
        """Mark it interrupted by the service's own end (its last progress kept)."""
        self.interrupted_at = self.progress
        self._interrupted = True
        self.error = why
        self.ended(None)

    @classmethod
    def interrupted_from_record(
        cls, printer: str, file: str, why: str, *, started_s: float, surely_run_line: int, may_have_run_line: int
    ) -> Job:
        """The job an earlier service left unfinished, as its record tells it (a restarted service reports it)."""
        job = cls(printer, file, Path(file), "an earlier service", started_s=started_s)
        job.recorded_lines = (surely_run_line, may_have_run_line)
        job.interrupted(why)
        return job

    @property
    def surely_run_line(self) -> int:
        """The file line of the last command the printer acknowledged: it ran."""
        progress = self.progress
        if progress is None:
            return 0 if self.recorded_lines is None else self.recorded_lines[0]
        return progress.last_source_line

    @property
    def may_have_run_line(self) -> int:
        """The file line of the last command written to the printer: lines after `surely_run_line` up to this one
        may have run. A resume starts after it (`resume_line`), so no line runs twice."""
        progress = self.progress
        if progress is None:
            return 0 if self.recorded_lines is None else self.recorded_lines[1]
        # The bound the feed never passes (every line written is at most it); else what was acknowledged.
        return max(progress.last_source_line, progress.may_have_run_through or 0)

    @property
    def resume_line(self) -> int:
        """The file line a resumed print (`--from-line`) starts at: past every line that may have run."""
        return self.may_have_run_line + 1

    def to_json(self) -> dict[str, Any]:
        """The job as every door tells it (the socket, MQTT's state, the OctoPrint API's `/api/job`)."""
        progress = self.progress
        total = None if progress is None else progress.source_bytes_total
        return {
            "id": self.id,
            "printer": self.printer,
            "file": self.file,
            "started_by": self.started_by,
            "state": self.state.value,
            "active": self.active,  # it holds its printer: clients read this, not a list of states of their own
            "started_s": self.started_s,
            "ended_s": self.ended_s,
            "percent": None if progress is None or not total else round(100 * progress.source_bytes_acked / total, 1),
            "surely_run_line": self.surely_run_line,
            "may_have_run_line": self.may_have_run_line,
            "resume_line": self.resume_line,
            "error": self.error,
            "cancelled_by": self.cancelled_by,
            "cancel_script": list(self.cancel_script),
            "end_script": list(self.end_script),
            "progress": None if progress is None else progress_to_json(progress),
        }

    def describe(self) -> str:
        """One line naming the job for people: `part.gcode on p (printing, 42 %, started by socket client 3)`."""
        value = self.to_json()
        percent = "" if value["percent"] is None else f", {value['percent']:g} %"
        return f"{self.file} on {self.printer} ({self.state.value}{percent}, started by {self.started_by})"


def cancel_script_for(reading: marlin_aio.TemperatureReading | None) -> tuple[str, ...]:
    """The default cancel script for a printer that last reported `reading`: `DEFAULT_CANCEL_SCRIPT`, and each
    further hotend it has (`T1:`, `T2:` in its reports) off too, since M104 alone turns off only the active one."""
    if reading is None:
        return DEFAULT_CANCEL_SCRIPT
    tools = sorted(int(key[1:]) for key in reading.temperatures.heaters if key[:1] == "T" and key[1:].isdigit())
    return DEFAULT_CANCEL_SCRIPT + tuple(f"M104 T{tool} S0" for tool in tools if tool > 0)
