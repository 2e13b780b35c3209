"""`marlin-temp set`: send targets, print what the printer confirmed, and optionally wait with progress bars.

The printer is asked which heaters it has (one M105) before anything is set, so a target for a heater it lacks
(`--tool 3` on a one-hotend printer, `--chamber` with no chamber) exits 2 naming the heaters it has, with nothing
sent. What is reported afterwards is the target the printer confirmed in its next report, not the one asked for:
Marlin keeps whole degrees (200.5 becomes 200) and caps a target at its own maximum (300 becomes 260), and a wait
watches the confirmed target, which is the one the printer heats to. `--off --wait` waits until every heater is
below `--cool-to`, so "done" means safe to touch.

Every way out that leaves a heater on (a wait timed out, Ctrl-C, a lost link, an error) says which heaters are on,
with actual/target, and how to turn them off: `heaters_left_on` is that one sentence, and `log` and `watch` say it
with the same words. A halt or a board reset is the exception: the firmware itself turned the heaters off.

Printed lines carry the port's name and the printer's numbers: they go out with markup and emoji codes off.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Callable
from dataclasses import dataclass

from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

import marlin_aio

from ..common.connect import OPENED_PORT, ConnectOptions, Exit, UsageProblem, open_printer
from ..common.hooks import Done, outcome_of_error, with_on_done
from ..common.model import heater_name
from ..printing.view import heaters_on

__all__ = [
    "PrinterHeaters",
    "SetRequest",
    "confirmation",
    "heaters_left_on",
    "say_heaters_left_on",
    "set_printer_targets",
]

#: Below this a heater is safe to touch (and a hotend no longer oozes): what `--off --wait` waits for by default.
SAFE_CELSIUS = 50.0


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
    cool_to_c: float = SAFE_CELSIUS
    preset: str | None = None
    """The preset the targets came from (said in the confirmation line)."""
    on_done: str | None = None
    """With `wait`: the shell command run when the wait ends (`--on-done`)."""


@dataclass(frozen=True, slots=True)
class PrinterHeaters:
    """The heaters a printer reports: how many hotends, and whether it has a heated bed and a chamber."""

    hotends: int
    bed: bool
    chamber: bool

    @classmethod
    def of(cls, reading: marlin_aio.TemperatureReading) -> PrinterHeaters:
        """The heaters in a report (with two or more hotends Marlin numbers them `T0:`, `T1:`, ...)."""
        keys = reading.temperatures.heaters
        numbered = [key for key in keys if re.fullmatch(r"T\d+", key)]
        hotends = len(numbered) if numbered else int("T" in keys)
        return cls(hotends, "B" in keys, "C" in keys)

    def describe(self) -> str:
        """ "hotends 0-1, bed" for messages."""
        parts = []
        if self.hotends == 1:
            parts.append("one hotend")
        elif self.hotends > 1:
            parts.append(f"hotends 0-{self.hotends - 1}")
        parts += [name for name, present in (("bed", self.bed), ("chamber", self.chamber)) if present]
        return ", ".join(parts) or "no heaters"

    def hotend_key(self, tool: int | None) -> str:
        """The report key of the hotend `--tool` names (`T` for the active one and for a single hotend)."""
        return "T" if tool is None or self.hotends == 1 else f"T{tool}"

    def off_keys(self) -> list[str]:
        """Every heater, as report keys: what `--off` turns off."""
        hotends = ["T"] if self.hotends == 1 else [f"T{n}" for n in range(self.hotends)]
        return hotends + ["B"] * self.bed + ["C"] * self.chamber


def _targets(request: SetRequest, heaters: PrinterHeaters) -> dict[str, float]:
    """The targets to set, keyed by report key.

    Raises:
        UsageProblem: a target names a heater the printer does not have (exit 2).
    """
    if request.off:
        return dict.fromkeys(heaters.off_keys(), 0.0)
    has = f"this printer has {heaters.describe()}"
    targets: dict[str, float] = {}
    if request.hotend is not None:
        if heaters.hotends == 0:
            raise UsageProblem(f"{has}: no hotend to set")
        if request.tool is not None and request.tool >= heaters.hotends:
            raise UsageProblem(f"{has}: there is no --tool {request.tool}; nothing was set")
        targets[heaters.hotend_key(request.tool)] = request.hotend
    if request.bed is not None:
        if not heaters.bed:
            raise UsageProblem(f"{has}: no heated bed; nothing was set")
        targets["B"] = request.bed
    if request.chamber is not None:
        if not heaters.chamber:
            raise UsageProblem(f"{has}: no chamber; nothing was set")
        targets["C"] = request.chamber
    return targets


async def _send_targets(printer: marlin_aio.Printer, targets: dict[str, float]) -> None:
    for key, celsius in targets.items():
        if key.startswith("T"):
            await printer.set_temperatures(hotend=celsius, tool=int(key[1:]) if key[1:] else None)
        elif key == "B":
            await printer.set_temperatures(bed=celsius)
        else:
            await printer.set_temperatures(chamber=celsius)


def confirmation(reading: marlin_aio.TemperatureReading, asked: dict[str, float]) -> str:
    """What the printer confirmed for each heater asked for, saying where it differs from what was asked.

    "hotend target 260 C (now 25.0 C; asked for 300 C: the printer capped it)".
    """
    parts = []
    for key, wanted in asked.items():
        heater = reading.temperatures.heaters.get(key)
        if heater is None:
            parts.append(f"{heater_name(key)}: not in the printer's report")
            continue
        now = f"now {heater.actual:.1f} C"
        if heater.target is None:
            parts.append(f"{heater_name(key)} target not reported ({now})")
            continue
        target = "off" if not heater.target else f"{heater.target:g} C"
        note = ""
        if abs(heater.target - wanted) >= 0.01:
            if heater.target < wanted and wanted - heater.target >= 1:
                why = "the printer capped it at its maximum"
            elif abs(heater.target - wanted) < 1:
                why = "the printer keeps whole degrees"
            else:
                why = "the printer set another value"
            note = f"; asked for {wanted:g} C: {why}"
        parts.append(f"{heater_name(key)} target {target} ({now}{note})")
    return "; ".join(parts)


def _confirmed_targets(reading: marlin_aio.TemperatureReading, asked: dict[str, float]) -> dict[str, float]:
    """The targets the printer confirmed (the asked one where a report shows none, as Repetier-style ones do)."""
    heaters = reading.temperatures.heaters
    confirmed = {}
    for key, wanted in asked.items():
        heater = heaters.get(key)
        confirmed[key] = heater.target if heater is not None and heater.target is not None else wanted
    return confirmed


def heaters_left_on(reading: marlin_aio.TemperatureReading | None, ended_by: BaseException | None = None) -> str | None:
    """What to tell the user whose command ends while heaters are on: "the heaters stay on (hotend 151.2/200 C,
    bed 60.0/60 C). Turn them off with: marlin-temp set --off".

    None when `reading` (the latest, or None: there was none) shows no heater with a target, or when `ended_by` is
    a halt or a board reset: the firmware turned every heater off then.
    """
    if reading is None or isinstance(ended_by, marlin_aio.PrinterHaltedError | marlin_aio.PrinterResetError):
        return None
    on = heaters_on(reading)
    if not on:
        return None
    which = "the heaters stay" if len(on) > 1 else "the heater stays"
    return f"{which} on ({', '.join(on)}). Turn {'them' if len(on) > 1 else 'it'} off with: marlin-temp set --off"


def say_heaters_left_on(
    errors: Console, reading: marlin_aio.TemperatureReading | None, ended_by: BaseException | None = None
) -> None:
    """Print `heaters_left_on` (if it has anything to say) on `errors`, as one line."""
    note = heaters_left_on(reading, ended_by)
    if note is not None:
        errors.print(note, style="yellow", markup=False, emoji=False, soft_wrap=True)


def _bars(console: Console) -> Progress:
    return Progress(
        TextColumn("{task.description:<9}", markup=False),
        BarColumn(),
        TextColumn("{task.fields[now]:>6.1f} / {task.fields[goal]} C", markup=False),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    )


def _follower(
    progress: Progress, tasks: dict[str, tuple[TaskID, float, float]]
) -> Callable[[marlin_aio.TemperatureReading], None]:
    """A callback moving each heater's bar from where it started towards its goal."""

    def show(reading: marlin_aio.TemperatureReading) -> None:
        for key, (task, origin, goal) in tasks.items():
            heater = reading.temperatures.heaters.get(key)
            if heater is not None:
                moved = min(abs(heater.actual - origin), abs(goal - origin))
                progress.update(task, completed=moved, now=heater.actual)

    return show


async def _wait_with_progress(
    printer: marlin_aio.Printer, wanted: dict[str, float], request: SetRequest, console: Console
) -> marlin_aio.TemperatureReading:
    progress = _bars(console)
    start = printer.latest
    tasks = {}
    for key, target in wanted.items():
        first = start.temperatures.heaters.get(key) if start else None
        origin = first.actual if first else 0.0
        task = progress.add_task(heater_name(key), total=abs(target - origin) or 1.0, now=origin, goal=f"{target:g}")
        tasks[key] = (task, origin, target)
    show = _follower(progress, tasks)
    with progress:
        unsubscribe = printer.on_reading(show)
        try:
            reached = await printer.wait_for_temperatures(
                hotend=next((v for k, v in wanted.items() if k[0] == "T"), None),
                bed=wanted.get("B"),
                chamber=wanted.get("C"),
                tool=request.tool,  # --tool 1 waits on that hotend (T1), not on the active one
                tolerance_c=request.tolerance_c,
                timeout_s=request.timeout_s,
            )
        finally:
            unsubscribe()
        show(reached)
        return reached


async def _wait_until_cool(
    printer: marlin_aio.Printer, keys: list[str], request: SetRequest, console: Console
) -> marlin_aio.TemperatureReading:
    """Wait until every heater of `keys` reads at most `cool_to_c`, with a bar each.

    Raises:
        TemperatureTimeoutError: not cool within the request's timeout.
    """
    limit = request.cool_to_c

    def cool(reading: marlin_aio.TemperatureReading) -> bool:
        heaters = reading.temperatures.heaters
        return all(key not in heaters or heaters[key].actual <= limit for key in keys)

    progress = _bars(console)
    start = printer.latest
    tasks = {}
    for key in keys:
        first = start.temperatures.heaters.get(key) if start else None
        origin = first.actual if first else limit
        task = progress.add_task(heater_name(key), total=max(origin - limit, 1.0), now=origin, goal=f"<{limit:g}")
        tasks[key] = (task, origin, min(limit, origin))
    show = _follower(progress, tasks)
    with progress:
        unsubscribe = printer.on_reading(show)
        try:
            async with printer.poll_temperatures(0.5, auto_report=False):
                latest = printer.latest
                if latest is not None and cool(latest):
                    return latest
                try:
                    async with asyncio.timeout(request.timeout_s):
                        async for reading in printer.temperature_readings():
                            if cool(reading):
                                return reading
                except TimeoutError:
                    now = printer.latest
                    state = ", ".join(
                        f"{heater_name(k)} {now.temperatures.heaters[k].actual:.1f} C"
                        for k in keys
                        if now is not None and k in now.temperatures.heaters
                    )
                    raise marlin_aio.TemperatureTimeoutError(
                        f"the heaters did not cool below {limit:g} C within {request.timeout_s:g} s ({state})"
                    ) from None
        finally:
            unsubscribe()
    raise marlin_aio.ConnectionLostError("the connection ended while waiting for the heaters to cool")


async def set_printer_targets(options: ConnectOptions, request: SetRequest, console: Console, errors: Console) -> Exit:
    """Set the targets, print what the printer confirmed, and wait if asked; return the exit code. With
    `request.on_done`, run that command when it ends (`common.hooks`), whatever the end but a bad target.

    Raises:
        UsageProblem: a target names a heater the printer does not have (nothing is sent).
        MarlinError: opening, sending or waiting failed (TemperatureTimeoutError after --wait-timeout).
    """

    def describe(code: Exit | None, error: BaseException | None, elapsed_s: float) -> Done:
        port = OPENED_PORT.get()
        if error is None:
            outcome, exit_code = ("cool" if _only_cooling(request) else "reached"), int(code or 0)
            message = f"{_wanted(request)} on {port or 'the printer'}"
        else:
            outcome, exit_code = outcome_of_error(error)
            message = f"set --wait on {port or 'the printer'}: {outcome}" + (f": {error}" if str(error) else "")
        return Done("set", outcome, exit_code, message, port=port, elapsed_s=elapsed_s)

    body = _set_printer_targets(options, request, console, errors)
    return await with_on_done(body, request.on_done, errors, describe)


def _only_cooling(request: SetRequest) -> bool:
    return request.off or not any((request.hotend, request.bed, request.chamber))


def _wanted(request: SetRequest) -> str:
    """What the wait waited for, for --on-done's message: "hotend 200 C, bed 60 C reached"."""
    if _only_cooling(request):
        return f"heaters below {request.cool_to_c:g} C"
    asked = (("hotend", request.hotend), ("bed", request.bed), ("chamber", request.chamber))
    parts = [f"{name} {celsius:g} C" if celsius else f"{name} off" for name, celsius in asked if celsius is not None]
    return ", ".join(parts) + " reached"


async def _set_printer_targets(options: ConnectOptions, request: SetRequest, console: Console, errors: Console) -> Exit:
    async with open_printer(options, errors) as (printer, label):
        heaters = PrinterHeaters.of(await printer.read_temperatures())
        targets = _targets(request, heaters)
        try:
            return await _set_and_wait(printer, label, targets, request, console)
        except BaseException as exc:
            # Ctrl-C, --wait-timeout, a lost link, an error: whatever set so far stays set.
            say_heaters_left_on(errors, printer.latest, exc)
            raise


async def _set_and_wait(
    printer: marlin_aio.Printer, label: str, targets: dict[str, float], request: SetRequest, console: Console
) -> Exit:
    await _send_targets(printer, targets)
    reading = await printer.read_temperatures()
    preset = f"preset {request.preset}: " if request.preset else ""
    console.print(f"{label}: {preset}{confirmation(reading, targets)}", soft_wrap=True, markup=False, emoji=False)
    if not request.wait:
        return Exit.OK
    confirmed = _confirmed_targets(reading, targets)
    heating = {key: celsius for key, celsius in confirmed.items() if celsius > 0}
    cooling = [key for key, celsius in confirmed.items() if celsius <= 0]
    if heating:
        reached = await _wait_with_progress(printer, heating, request, console)
        said = confirmation(reached, {k: targets[k] for k in heating})
        console.print(f"reached: {said}", soft_wrap=True, markup=False, emoji=False)
    if cooling:
        await _wait_until_cool(printer, cooling, request, console)
        names = ", ".join(heater_name(key) for key in cooling)
        console.print(f"cool: {names} below {request.cool_to_c:g} C", markup=False, emoji=False)
    return Exit.OK
