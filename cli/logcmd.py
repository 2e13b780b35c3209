"""`marlin-temp log`: a headless logger for long runs.

Opening the printer and recording are apart: `record_temperatures` takes an open printer and an open log, so a
test can watch the same log object while the printer misbehaves.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

from rich.console import Console

import marlin_aio

from .connect import ConnectOptions, Exit, open_printer
from .logfile import TemperatureLog
from .terminal import on_stop_signals

__all__ = ["log_temperatures", "record_temperatures"]


async def record_temperatures(
    printer: marlin_aio.Printer,
    log: TemperatureLog,
    interval_s: float,
    duration_s: float | None,
    stop: asyncio.Event,
) -> None:
    """Poll every `interval_s` and add each reading to `log` until `stop` is set or `duration_s` has passed.

    Raises:
        MarlinError: the printer halted or went away (the log keeps what was recorded).
        ValueError: the log file holds other columns than this printer reports.
        OSError: the file cannot be written.
    """

    async def record() -> None:
        async for reading in printer.temperature_readings():
            log.add(reading)

    async with printer.poll_temperatures(interval_s):
        recorder = asyncio.create_task(record(), name="marlin-temp log")
        stopper = asyncio.create_task(stop.wait(), name="marlin-temp stop")
        try:
            done, _ = await asyncio.wait({recorder, stopper}, timeout=duration_s, return_when="FIRST_COMPLETED")
            if recorder in done:
                recorder.result()
        finally:
            for task in (recorder, stopper):
                task.cancel()
            await asyncio.gather(recorder, stopper, return_exceptions=True)
            log.flush()


async def log_temperatures(
    options: ConnectOptions, output: Path, fmt: str, interval_s: float, duration_s: float | None, errors: Console
) -> Exit:
    """Poll every `interval_s` and append each reading to `output` until Ctrl-C, SIGTERM or `duration_s`.

    Raises:
        MarlinError: the printer could not be opened, halted, or went away (the file keeps what was logged).
        ValueError: `output` holds other columns than this printer reports.
        OSError: the file cannot be written.
    """
    stop = asyncio.Event()
    with on_stop_signals(stop.set):
        async with TemperatureLog(output, fmt) as log, open_printer(options, errors) as (printer, label):
            errors.print(f"logging {label} to {output} every {interval_s:g} s; Ctrl-C stops", style="dim")
            try:
                await record_temperatures(printer, log, interval_s, duration_s, stop)
            finally:
                errors.print(log.summary.line())
    return Exit.OK
