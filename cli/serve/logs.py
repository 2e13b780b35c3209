"""The temperature log `marlin-temp serve` writes of every printer while it runs.

One JSON-lines file per printer and day (`NAME-YYYY-MM-DD.jsonl`, the format of `marlin-temp log --format
jsonl`, so `marlin-temp plot` reads it), one row a `--log-interval`, and while a print runs each row names its file
and the file line last acknowledged (`"print": {"file": ..., "line": ...}`). A new file starts at local midnight.

The supervisors hand each reading over without waiting (a bounded queue; a reading that finds it full is dropped
and counted): a slow disk never slows a printer. The writing is `TemperatureLog`'s, with its rules: rows reach the
disk within a second, a kill leaves whole rows, a full disk stops the log with one line and the service goes on.
The logs are their owner's alone: files 0600 (`TemperatureLog`), and the folders made for them 0700.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

import marlin_aio
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.service import Service

from ..logs.files import RowSampler, TemperatureLog

__all__ = ["QUEUE_READINGS", "ServeLogs"]

#: Readings waiting to be logged before new ones are dropped (a minute of ten printers at 10 Hz).
QUEUE_READINGS = 6_000


class ServeLogs:
    """The daily logs of every printer of `service` in `folder`, one row each `interval_s`."""

    def __init__(self, service: Service, folder: Path, interval_s: float, errors: Console) -> None:
        self.service = service
        self.folder = folder
        self.interval_s = interval_s
        self.errors = errors
        self.queue: asyncio.Queue[tuple[FarmPrinter, marlin_aio.TemperatureReading]] = asyncio.Queue(QUEUE_READINGS)
        self.dropped = 0
        self._logs: dict[str, tuple[str, TemperatureLog]] = {}
        for farm_printer in service.farm.printers.values():
            farm_printer.reading_listeners.append(self._listener(farm_printer))

    def _listener(self, farm_printer: FarmPrinter) -> Callable[[marlin_aio.TemperatureReading], None]:
        # The printer's row schedule lives here, not in its log: only the readings that become rows are queued, so
        # the writer task wakes once a row (once a second by default), not once a reading (a hundred times a second
        # at 100 Hz). The log writes every row it is given, and the schedule goes on across a day's new file.
        sampler = RowSampler(self.interval_s)

        def on_reading(reading: marlin_aio.TemperatureReading) -> None:
            if not reading.temperatures.heaters or not sampler.take(reading):
                return  # no row of it (a reading without heaters is none either)
            try:
                self.queue.put_nowait((farm_printer, reading))
            except asyncio.QueueFull:
                self.dropped += 1

        return on_reading

    async def run(self) -> None:
        """Write until cancelled; every log is flushed and closed on the way out.

        Raises:
            OSError: the folder cannot be made.
        """
        _make_private_folder(self.folder)
        try:
            while True:
                farm_printer, reading = await self.queue.get()
                log = await self._log_for(farm_printer.name, reading.wall_time_s)
                if log is not None:
                    log.add(reading, _print_of(farm_printer))
        finally:
            for _, log in self._logs.values():
                with contextlib.suppress(OSError, ValueError):
                    log.close()

    async def _log_for(self, name: str, wall_time_s: float) -> TemperatureLog | None:
        day = time.strftime("%Y-%m-%d", time.localtime(wall_time_s))
        current = self._logs.get(name)
        if current is not None and current[0] == day:
            log = current[1]
            return None if log.failure is not None else log
        if current is not None:
            current[1].close()  # midnight: the next day's file
        log = TemperatureLog(self.folder / f"{name}-{day}.jsonl", "jsonl")  # rows chosen by `_listener`'s schedule
        try:
            await log.__aenter__()
        except (OSError, ValueError) as exc:
            self.errors.print(f"[red]error:[/] not logging {escape(name)}: {escape(str(exc))}")
            self._logs[name] = (day, log)
            log.failure = log.failure or _stopped(exc)
            return None
        self._logs[name] = (day, log)
        if log.tightened_from is not None:
            self.errors.print(
                f"{escape(str(log.path))} was readable by others ({log.tightened_from:o}): made it owner-only (600)",
                style="dim",
            )
        return log


def _make_private_folder(folder: Path) -> None:
    """Make `folder` and each missing folder above it owner-only (0700): `Path.mkdir` gives the parents it makes the
    default mode. A folder that exists is left as its owner made it."""
    missing = [level for level in (folder, *folder.parents) if not level.exists()]
    for level in reversed(missing):
        level.mkdir(mode=0o700, exist_ok=True)


def _stopped(exc: Exception) -> Any:
    from ..logs.files import LogWriteError

    return LogWriteError(str(exc), getattr(exc, "errno", None))


def _print_of(farm_printer: FarmPrinter) -> dict[str, Any] | None:
    handle = farm_printer.print_handle
    if handle is None or handle.finished:
        return None
    return {"print": {"file": farm_printer.print_file, "line": handle.progress.last_source_line}}
