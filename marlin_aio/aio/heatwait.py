"""Waiting for heaters to reach their targets by watching readings, never by blocking the printer's queue (what
`Printer.wait_for_temperatures` does, whichever backend brings the readings)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncGenerator, Callable
from contextlib import AbstractAsyncContextManager

from marlin_aio.errors import ConnectionLostError, TemperatureTimeoutError
from marlin_aio.protocol.heaters import describe_heaters, targets_reached
from marlin_aio.protocol.temperatures import TemperatureReading, heater_name

__all__ = ["wait_for_targets"]


async def wait_for_targets(
    readings: Callable[[], AsyncGenerator[TemperatureReading, None]],
    latest: Callable[[], TemperatureReading | None],
    wanted: dict[str, float],
    *,
    tool: int | None,
    tolerance_c: float,
    timeout_s: float | None,
    poller: AbstractAsyncContextManager[None] | None,
    where: str,
) -> TemperatureReading:
    """The first reading from `readings()` with every `wanted` heater within `tolerance_c` of its target (all
    heaters with a target, if `wanted` is empty); `poller` runs meanwhile, if given.

    Raises:
        TemperatureTimeoutError: not reached within `timeout_s` (None waits as long as it takes).
        MarlinError: the readings ended (the link or the printer failed).
    """

    async def watch() -> TemperatureReading:
        stream = readings()
        try:
            # A reading from before the call may predate the targets just set: only trust it for explicit ones.
            before = latest()
            if wanted and before is not None and targets_reached(before, wanted, tool, tolerance_c):
                return before
            async for reading in stream:
                if targets_reached(reading, wanted, tool, tolerance_c):
                    return reading
        finally:
            await stream.aclose()
        raise ConnectionLostError(f"the connection to {where} ended while waiting for temperatures")

    async with contextlib.AsyncExitStack() as stack:
        if poller is not None:
            await stack.enter_async_context(poller)
        try:
            async with asyncio.timeout(timeout_s):
                return await watch()
        except TimeoutError:
            last = latest()
            state = "no reading" if last is None else describe_heaters(last)
            waited_for = ", ".join(heater_name(key) for key in wanted) or "all heaters"
            raise TemperatureTimeoutError(
                f"{waited_for} did not reach the target within {timeout_s:g} s ({state})"
            ) from None
    raise AssertionError("unreachable")  # pragma: no cover  (mypy cannot see that `async with` returns)
