"""`marlin-temp set`: send targets, print what the printer confirmed, and optionally wait with progress bars."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

import marlin_aio

from .connect import ConnectOptions, Exit, open_printer
from .model import heater_name

__all__ = ["SetRequest", "set_printer_targets"]


@dataclass(frozen=True)
class SetRequest:
    """Checked targets (None: leave that heater alone) and how to wait."""

    hotend: float | None = None
    bed: float | None = None
    chamber: float | None = None
    tool: int | None = None
    off: bool = False
    wait: bool = False
    tolerance_c: float = 2.0
    timeout_s: float | None = None


def _confirmed(reading: marlin_aio.TemperatureReading, keys: list[str]) -> str:
    parts = []
    for key in keys:
        heater = reading.temperatures.heaters.get(key)
        if heater is not None:
            target = "off" if not heater.target else f"{heater.target:g} C"
            parts.append(f"{heater_name(key)} target {target} (now {heater.actual:.1f} C)")
    return "; ".join(parts) or "the printer reported none of these heaters"


async def _wait_with_progress(
    printer: marlin_aio.Printer, wanted: dict[str, float], request: SetRequest, console: Console
) -> marlin_aio.TemperatureReading:
    progress = Progress(
        TextColumn("{task.description:<8}"),
        BarColumn(),
        TextColumn("{task.fields[now]:>6.1f} / {task.fields[target]:g} C"),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    )
    start = printer.latest
    tasks = {}
    for key, target in wanted.items():
        first = start.temperatures.heaters.get(key) if start else None
        origin = first.actual if first else 0.0
        total = abs(target - origin) or 1.0
        tasks[key] = (progress.add_task(heater_name(key), total=total, now=origin, target=target), origin)

    def show(reading: marlin_aio.TemperatureReading) -> None:
        for key, (task, origin) in tasks.items():
            heater = reading.temperatures.heaters.get(key)
            if heater is not None:
                progress.update(
                    task, completed=min(abs(heater.actual - origin), abs(wanted[key] - origin)), now=heater.actual
                )

    async def follow() -> None:
        async for reading in printer.temperature_readings():
            show(reading)

    with progress:
        follower = asyncio.create_task(follow())
        try:
            reached = await printer.wait_for_temperatures(
                hotend=next((v for k, v in wanted.items() if k[0] == "T"), None),
                bed=wanted.get("B"),
                chamber=wanted.get("C"),
                tool=request.tool,  # --tool 1 waits on that hotend (T1), not on the active one
                tolerance_c=request.tolerance_c,
                timeout_s=request.timeout_s,
            )
            show(reached)
            return reached
        finally:
            follower.cancel()
            await asyncio.gather(follower, return_exceptions=True)


async def set_printer_targets(options: ConnectOptions, request: SetRequest, console: Console, errors: Console) -> Exit:
    """Set the targets, print the confirmation, and wait if asked; return the exit code.

    Raises:
        MarlinError: opening, sending or waiting failed (TemperatureTimeoutError after --timeout).
    """
    async with open_printer(options, errors) as (printer, label):
        await printer.set_temperatures(
            hotend=request.hotend, bed=request.bed, chamber=request.chamber, tool=request.tool
        )
        keys = [k for k, v in (("T", request.hotend), ("B", request.bed), ("C", request.chamber)) if v is not None]
        if request.tool is not None and request.hotend is not None:
            keys[0] = f"T{request.tool}"
        reading = await printer.read_temperatures()
        console.print(f"{label}: {_confirmed(reading, keys)}")
        wanted = {
            k: v
            for k, v in zip(
                keys, [x for x in (request.hotend, request.bed, request.chamber) if x is not None], strict=True
            )
            if v > 0
        }
        if not request.wait or not wanted:
            return Exit.OK
        try:
            reached = await _wait_with_progress(printer, wanted, request, console)
        except asyncio.CancelledError:
            on = ", ".join(f"{heater_name(k)} {v:g} C" for k, v in wanted.items())
            errors.print(
                f"stopped waiting; the heaters stay on ({on}). Turn them off with: marlin-temp set --off",
                style="yellow",
            )
            raise
        console.print(f"reached: {_confirmed(reached, list(wanted))}")
    return Exit.OK
