"""`marlin-temp serve` at work: the service runs until --duration, SIGTERM (systemd's stop) or Ctrl-C; every
printer's events are printed as they happen, one line each."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from marlin_aio.farm.supervisor import FarmEvent, PrinterSpec
from marlin_aio.service import Service, ServiceRunningError

from ..common.connect import Exit, UsageProblem

__all__ = ["run_serve"]


async def run_serve(specs: list[PrinterSpec], socket: Path | None, duration_s: float | None, errors: Console) -> None:
    """Serve `specs` at `socket` until `duration_s` passed, SIGTERM, or the task is cancelled.

    Raises:
        UsageProblem: another service already listens at the socket (exit 2: it is the user's to stop).
        OSError: the socket cannot be made.
    """

    def show(event: FarmEvent) -> None:
        stamp = time.strftime("%H:%M:%S", time.localtime(event.time_s))
        errors.print(f"{stamp} {escape(event.printer)}: {escape(event.kind)}: {escape(event.message)}")

    service = Service(specs, socket, on_event=show)
    stopped = asyncio.Event()
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):  # not the main thread, or no signals
        loop.add_signal_handler(signal.SIGTERM, stopped.set)
    started = time.monotonic()

    async def announce() -> None:
        await service.ready.wait()
        names = ", ".join(specs_names(specs))
        errors.print(
            f"serving {escape(names)} at {escape(str(service.socket_path))}; reach it as --port serve:NAME; "
            "Ctrl-C stops",
            style="dim",
        )

    running = asyncio.create_task(service.run(), name="service")
    waiters = [asyncio.create_task(stopped.wait(), name="SIGTERM"), asyncio.create_task(announce(), name="announce")]
    try:
        async with asyncio.timeout(duration_s):
            await asyncio.wait([running, waiters[0]], return_when=asyncio.FIRST_COMPLETED)
    except TimeoutError:
        pass  # --duration is up
    finally:
        # Ctrl-C (this task cancelled), SIGTERM, --duration or the service's own end: every printer is closed on
        # the way out and the socket removed before this returns.
        for task in (running, *waiters):
            task.cancel()
        outcome = (await asyncio.gather(running, *waiters, return_exceptions=True))[0]
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.remove_signal_handler(signal.SIGTERM)
    if isinstance(outcome, ServiceRunningError):
        raise UsageProblem(str(outcome), Exit.USAGE)
    if isinstance(outcome, Exception):
        raise outcome
    errors.print(f"serve: stopped after {time.monotonic() - started:.0f} s", style="dim")


def specs_names(specs: list[PrinterSpec]) -> list[str]:
    """The printers' names, in order."""
    return [spec.name for spec in specs]
