"""How the service ends its prints, and what it does after an end it did not choose.

- Each print is recorded (`journal`), and fed no line past the last bound recorded and told to its clients
  (`printhandle.FeedGuard`): killed at any moment, the service leaves a record, and its clients a progress, whose
  "may have run through" is never below a line the printer was sent.
- Stopping (SIGTERM, systemd's stop, or Ctrl-C), the service stops feeding each print, waits for the lines in flight,
  runs the cancel script (heaters and fan off), records where the print stopped and tells its clients, then exits;
  within `STOP_TIMEOUT_S` (a long G28 in flight may hold the printer's answer), else it exits anyway and says so.
  With no print running, a stop leaves the heaters alone: targets set by hand (a preheat) are the user's, and a
  restart for an upgrade must not undo them; the firmware's thermal protection watches them either way.
- Starting, the service reads each printer's record: a print it was running when it ended is reported (an event
  line, and `status`'s `interrupted_job`) with the line surely run and the line to resume from; and once that
  printer connects, if it is heating with no print, its heaters are turned off (unless told to leave them).

Takes the `Service` as an argument and reaches it only through a few hooks (`Farm.feed_guard`,
`Service.interrupted_jobs`), so the service's own code stays as it is.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from pathlib import Path

import marlin_aio
from marlin_aio.aio.printhandle import FeedGuard, PrintHandle
from marlin_aio.farm.job import Job, cancel_script_for
from marlin_aio.farm.supervisor import FarmEvent, FarmPrinter
from marlin_aio.protocol.printjob import STOPPED_BY_SERVICE, PrintProgress, PrintState
from marlin_aio.protocol.rpc import encode_message, notification, progress_to_json
from marlin_aio.service.journal import ENDED_STATES, JobRecord, Journal
from marlin_aio.service.server import Service

__all__ = ["STOP_TIMEOUT_S", "Lifecycle", "cancel_script"]

_log = logging.getLogger("marlin_aio.service")

#: How long a stop waits for a printer to finish its lines in flight and run the cancel script.
STOP_TIMEOUT_S = 30.0
#: How long a stop waits for the last messages to reach clients that are behind.
_FLUSH_TIMEOUT_S = 2.0


def cancel_script(farm_printer: FarmPrinter) -> tuple[str, ...]:
    """The commands that end a print the service stops: its job's cancel script (the same as any door's cancel),
    else the default one for the printer (every hotend, the bed and the fan off)."""
    job = farm_printer.job
    return job.cancel_script if job is not None else cancel_script_for(farm_printer.latest)


class _Guard:
    """The feed guard of one print: records each new bound, tells it to the print's clients, then lets it be fed."""

    def __init__(self, lifecycle: Lifecycle, farm_printer: FarmPrinter, path: Path) -> None:
        self._lifecycle = lifecycle
        self._farm_printer = farm_printer
        self._file = path.name
        self._started_s = time.time()

    def bound(self, handle: PrintHandle) -> None:
        progress = handle.progress
        record = JobRecord(
            printer=self._farm_printer.name,
            file=self._file,
            state="running",
            surely_run=progress.last_source_line,
            may_have_run_through=progress.may_have_run_through or 0,
            port=self._farm_printer.spec.port,
            started_s=self._started_s,
            updated_s=time.time(),
        )
        self._lifecycle.journal.write(record)  # raises: the bound is not raised
        self._lifecycle.records[record.printer] = record
        self._lifecycle.tell(self._farm_printer.name, self._file, progress)


class Lifecycle:
    """The service's records of its prints, its stop, and its start after an end it did not choose.

    Args:
        service: the service (its farm, its clients, its socket's folder: the records go in `jobs/` there).
        leave_heaters: after a restart, leave a printer heating with no print as it is (only say so).
        stop_timeout_s: how long a stop waits for each printer (see `STOP_TIMEOUT_S`).
    """

    def __init__(
        self, service: Service, *, leave_heaters: bool = False, stop_timeout_s: float = STOP_TIMEOUT_S
    ) -> None:
        self.service = service
        self.journal = Journal(service.socket_path.parent / "jobs")
        self.leave_heaters = leave_heaters
        self.stop_timeout_s = stop_timeout_s
        self.records: dict[str, JobRecord] = {}
        """The record of each printer's print started by this service."""
        self.interrupted: dict[str, JobRecord] = {}
        """Prints an earlier service did not see to their end, by printer."""
        self._check_heaters: set[str] = set()  # printers to check once connected (their service was killed)
        self._tasks: set[asyncio.Task[None]] = set()

    def install(self) -> None:
        """Bound every print the farm starts, and report what an earlier service left (call once the socket is
        this service's: a record is only an earlier service's when no service runs)."""
        self.service.farm.feed_guard = self.guard_for
        for name, farm_printer in self.service.farm.printers.items():
            record = self.journal.read(name)
            if record is None or record.state in ENDED_STATES:
                continue
            if record.state == "running":
                # Nobody stopped it: the service was killed (or the machine went down) mid-print.
                record = record.with_state("killed", "the service ended without stopping it")
                self._write(record)
                self._check_heaters.add(name)
            self._report(farm_printer, record)

    def guard_for(self, farm_printer: FarmPrinter, path: Path) -> FeedGuard:
        """The guard of a print of `path` starting on `farm_printer` (`Farm.feed_guard`)."""
        self._forget_interrupted(farm_printer.name)  # a new print: its record replaces the old one's
        return _Guard(self, farm_printer, path)

    def on_event(self, event: FarmEvent) -> None:
        """Follow the farm's events: a print's end is recorded; a printer whose service was killed is checked for
        heaters left on once it connects."""
        if event.kind == "connected" and event.printer in self._check_heaters:
            farm_printer = self.service.farm.printers[event.printer]
            task = asyncio.get_running_loop().create_task(
                self._heaters_after_restart(farm_printer), name=f"heaters of {event.printer}"
            )
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        elif event.kind in ("print_finished", "print_cancelled", "print_failed"):
            farm_printer = self.service.farm.printers[event.printer]
            record = self.records.get(event.printer)
            handle = farm_printer.print_handle
            # A print the stop ended keeps its "stopped" (its resume line is exact), whichever is told first.
            if record is not None and record.state != "stopped" and handle is not None and handle.finished:
                self._end_record(record, handle.progress, event.message)

    def tell(self, printer: str, file: str, progress: PrintProgress) -> None:
        """Tell every client following `printer`'s prints of `progress`, never dropped: it may carry a new bound,
        which must reach them before a line past the old one is sent."""
        data = encode_message(
            notification("progress", {"printer": printer, "file": file, "progress": progress_to_json(progress)})
        )
        for session in list(self.service.sessions):
            if session.subscribed(printer, "progress"):
                session.push(data, droppable=False)

    async def stop(self, why: str, say: Callable[[str], None]) -> None:
        """End every running print as the service stops (`why`: the signal): stop feeding, wait for the lines in
        flight, run the cancel script, record where it stopped, tell its clients; each within `stop_timeout_s`.
        `say` gets one line per print for the operator."""
        farm = self.service.farm
        running = [
            (farm_printer, handle)
            for farm_printer in farm.printers.values()
            if (handle := farm_printer.print_handle) is not None and not handle.finished
        ]
        await asyncio.gather(*(self._stop_print(fp, handle, why, say) for fp, handle in running))
        if running:
            await self._flush_clients()

    async def _stop_print(
        self, farm_printer: FarmPrinter, handle: PrintHandle, why: str, say: Callable[[str], None]
    ) -> None:
        name, file = farm_printer.name, farm_printer.print_file or handle.job.name
        by = f"{STOPPED_BY_SERVICE} ({why})"
        handle.job.cancel(asyncio.get_running_loop().time(), by)  # the reason its clients read in its progress
        handle.check()  # with nothing in flight it ends at once
        script = cancel_script(farm_printer)
        try:
            async with asyncio.timeout(self.stop_timeout_s):
                # The job's one cancel, as from any door: its script runs once, and the job says who cancelled it.
                await self.service.farm.cancel_print(farm_printer, by)
        except TimeoutError:
            note = (
                f"the printer did not answer within {self.stop_timeout_s:g} s (a long move or homing?): the service "
                "exits without knowing; its heaters may still be on: turn them off (marlin-temp set --off)"
            )
        except marlin_aio.MarlinError as exc:
            note = (
                f"the cancel script failed ({exc}); its heaters may still be on: turn them off (marlin-temp set --off)"
            )
        else:
            note = f"cancel script run ({'; '.join(script)})" if script else "no cancel script"
        progress = handle.progress
        record = self.records.get(name)
        if record is not None:
            record = JobRecord(
                printer=name,
                file=record.file,
                # Not drained to its end (the printer did not answer): "running", so the next start reports it
                # and checks the heaters as after a kill.
                state="stopped" if progress.state is PrintState.CANCELLED else "running",
                surely_run=progress.last_source_line,
                may_have_run_through=progress.may_have_run_through or progress.last_source_line,
                port=record.port,
                started_s=record.started_s,
                updated_s=time.time(),
                note=note,
            )
            self._write(record)
            self.records[name] = record
            resume = record.resume_line
        else:
            resume = (progress.may_have_run_through or progress.last_source_line) + 1
        self.tell(name, file, progress)
        message = (
            f"{file}: stopped ({why}) after line {progress.last_source_line}; {note}; resume with --from-line {resume}"
        )
        self.service.farm.emit(farm_printer, "print_stopped", message)
        say(f"{name}: {message}")

    async def _flush_clients(self) -> None:
        """Give the last messages a moment to reach clients that are behind (the service closes their
        connections next, and a message still queued would be lost)."""
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(_FLUSH_TIMEOUT_S):
                behind = [session for session in self.service.sessions if session.queue]
                for session in behind:
                    session.drained.clear()  # set again once its writer wrote all it had queued
                await asyncio.gather(*(session.drained.wait() for session in behind))

    async def _heaters_after_restart(self, farm_printer: FarmPrinter) -> None:
        printer = farm_printer.printer
        handle = farm_printer.print_handle
        if printer is None:
            return
        if handle is not None and not handle.finished:
            self._check_heaters.discard(farm_printer.name)  # a print runs again: its heaters are its own
            return
        try:
            on = _targets_on(await printer.read_temperatures())
            if on and self.leave_heaters:
                self.service.farm.emit(
                    farm_printer,
                    "heaters_left_on",
                    f"heating with no print after an interrupted print ({on}); left on as asked (--leave-heaters)",
                )
            elif on:
                script = cancel_script(farm_printer)
                for command in script:
                    await printer.send(command)
                still = _targets_on(await printer.read_temperatures())
                self.service.farm.emit(
                    farm_printer,
                    "heaters_off",
                    f"heating with no print after an interrupted print ({on}): sent {'; '.join(script)}"
                    + (f"; still on: {still}" if still else ""),
                )
        except marlin_aio.MarlinError as exc:
            _log.warning(
                "%s: heaters not checked after the restart (%s); tried again at the next connect",
                farm_printer.name,
                exc,
            )
            return
        self._check_heaters.discard(farm_printer.name)

    def _report(self, farm_printer: FarmPrinter, record: JobRecord) -> None:
        self.interrupted[farm_printer.name] = record
        self.service.interrupted_jobs[farm_printer.name] = record.to_json()
        # The printer's job, as every door reads it (`job`, `/api/job`), until a new print replaces it.
        how = "stopped by the service" if record.state == "stopped" else "the service ended mid-print"
        farm_printer.job = Job.interrupted_from_record(
            farm_printer.name,
            record.file,
            how,
            started_s=record.started_s,
            surely_run_line=record.surely_run,
            may_have_run_line=record.resume_line - 1,
        )
        how = "stopped by the service" if record.state == "stopped" else "the service ended mid-print"
        maybe = (
            f", lines up to {record.may_have_run_through} may have run"
            if record.may_have_run_through > record.surely_run and record.state != "stopped"
            else ""
        )
        self.service.farm.emit(
            farm_printer,
            "interrupted_job",
            f"{record.file}: {how}; line {record.surely_run} surely ran{maybe}; "
            f"resume with --from-line {record.resume_line}",
        )

    def _forget_interrupted(self, printer: str) -> None:
        self.interrupted.pop(printer, None)
        self.service.interrupted_jobs.pop(printer, None)

    def _end_record(self, record: JobRecord, progress: PrintProgress, message: str) -> None:
        record = JobRecord(
            printer=record.printer,
            file=record.file,
            state=progress.state.value,
            surely_run=progress.last_source_line,
            may_have_run_through=progress.may_have_run_through or progress.last_source_line,
            port=record.port,
            started_s=record.started_s,
            updated_s=time.time(),
            note=message,
        )
        self.records[record.printer] = record
        self._write(record)

    def _write(self, record: JobRecord) -> None:
        try:
            self.journal.write(record)
        except OSError as exc:
            _log.error("the print record of %s cannot be written: %s", record.printer, exc)


def _targets_on(reading: marlin_aio.TemperatureReading) -> str:
    """The heaters with a target above 0, as `T0 200, B 60` (empty when none)."""
    heaters = reading.temperatures.heaters
    return ", ".join(f"{key} {h.target:g}" for key, h in heaters.items() if h.target)
