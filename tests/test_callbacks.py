"""No user code in the read path: `on_reading` callbacks and slow readers against the simulated printer, in memory
(and on a pty where the read handler beneath is pyserial's).

A callback that raises, stops itself, or a reader that stops reading must never stop the link: commands still
return, polls go on, the other callbacks and readers still get every reading, and the error is logged once. Every
wait here is on an event with a bound, never a sleep.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import pytest

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource

#: A bound on every wait below, not a synchronisation: the events do that.
BOUND_S = 30.0


class Counter:
    """An `on_reading` callback that keeps every reading and sets an event once it has `target` of them."""

    def __init__(self) -> None:
        self.seen: list[TemperatureReading] = []
        self.target = 0
        self.reached = asyncio.Event()

    def __call__(self, reading: TemperatureReading) -> None:
        self.seen.append(reading)
        if len(self.seen) >= self.target:
            self.reached.set()

    async def wait_for_more(self, count: int) -> None:
        """Return once `count` more readings than now have arrived."""
        self.target = len(self.seen) + count
        self.reached.clear()
        async with asyncio.timeout(BOUND_S):
            await self.reached.wait()


def callback_warnings(caplog: pytest.LogCaptureFixture, name: str) -> list[logging.LogRecord]:
    return [
        record
        for record in caplog.records
        if record.name == "marlin_aio" and record.levelno == logging.WARNING and name in record.getMessage()
    ]


async def test_a_callback_that_always_raises_is_logged_once_and_stops_nothing(
    mem_printer: marlin_aio.Printer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="marlin_aio")
    calls = 0

    def always_raises(reading: TemperatureReading) -> None:
        nonlocal calls
        calls += 1
        raise RuntimeError(f"a bug in the user's callback, call {calls}")

    mem_printer.on_reading(always_raises)  # first in line: the one after it must not suffer
    counter = Counter()
    mem_printer.on_reading(counter)
    reader = mem_printer.temperature_readings()
    async with mem_printer.poll_temperatures(0.01), asyncio.timeout(BOUND_S):
        read_first = await anext(reader)  # subscribed from here on
        async with asyncio.timeout(10):
            reply = await mem_printer.send("M105")
            echo = await mem_printer.send("M118 E1 x")
        assert reply.temperatures is not None
        assert echo.lines == ("echo:x",)
        await counter.wait_for_more(100)  # polling goes on, long after the first error
        assert sum(reading.source is ReadingSource.POLL for reading in counter.seen[-100:]) >= 50
        last = counter.seen[-1]
        read = [read_first]
        while read[-1] is not last:  # the reader catches up with the callback
            read.append(await anext(reader))
    await reader.aclose()
    # The raising callback was called with every reading, and the one after it got them all too.
    assert calls == len(counter.seen) == mem_printer.callback_errors >= 100
    start = next(i for i, reading in enumerate(counter.seen) if reading is read_first)
    # Up to `last` (the callback may have been given a few more since: polls went on until the block ended).
    assert all(a is b for a, b in zip(counter.seen[start : start + len(read)], read, strict=True))
    assert mem_printer.stats.timeouts == 0
    (warning,) = callback_warnings(caplog, "always_raises")
    assert "call 1" in warning.getMessage()
    assert warning.exc_info is not None


async def test_a_callback_that_raises_once_is_logged_and_called_again(
    mem_printer: marlin_aio.Printer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="marlin_aio")
    seen: list[TemperatureReading] = []
    first_call = True

    def raises_once(reading: TemperatureReading) -> None:
        nonlocal first_call
        if first_call:
            first_call = False
            raise ValueError("only the first time")
        seen.append(reading)

    mem_printer.on_reading(raises_once)
    counter = Counter()
    mem_printer.on_reading(counter)
    async with mem_printer.poll_temperatures(0.01):
        await counter.wait_for_more(20)
    await mem_printer.send("M118 E1 still here")
    assert len(seen) == len(counter.seen) - 1
    assert all(a is b for a, b in zip(seen, counter.seen[1:], strict=True))
    assert mem_printer.callback_errors == 1
    assert len(callback_warnings(caplog, "raises_once")) == 1


async def test_a_callback_that_stops_itself_while_called_gets_nothing_more(mem_printer: marlin_aio.Printer) -> None:
    calls = 0
    stop: list[Callable[[], None]] = []  # on_reading's own, once it returned

    def stops_on_third(reading: TemperatureReading) -> None:
        nonlocal calls
        calls += 1
        if calls == 3:
            stop[0]()
            stop[0]()  # twice is harmless

    stop.append(mem_printer.on_reading(stops_on_third))
    counter = Counter()
    mem_printer.on_reading(counter)
    async with mem_printer.poll_temperatures(0.005):
        await counter.wait_for_more(30)
    await mem_printer.read_temperatures()
    assert calls == 3
    assert mem_printer.callback_errors == 0


async def test_a_callback_stopped_by_another_gets_nothing_more(mem_printer: marlin_aio.Printer) -> None:
    stopped = Counter()
    stop_other = mem_printer.on_reading(stopped)
    counter = Counter()
    mem_printer.on_reading(counter)

    def stops_the_other(reading: TemperatureReading) -> None:
        stop_other()

    mem_printer.on_reading(stops_the_other)
    async with mem_printer.poll_temperatures(0.005):
        await counter.wait_for_more(30)
    # Stopped after the first reading it got; its position before the stopper is why it got that one.
    assert len(stopped.seen) == 1
    assert stopped.seen[0] is counter.seen[0]


async def test_callbacks_run_once_the_reads_step_is_done_and_before_the_awaiting_caller_resumes(
    printer: marlin_aio.Printer,
) -> None:
    # On the pty. A callback runs after the link carried out the read that brought its reading (the reply was
    # handed to its caller, the round trip recorded), never in the middle of it, and before that caller resumes.
    recorded_when_called: list[int] = []

    def record(reading: TemperatureReading) -> None:
        recorded_when_called.append(len(printer.round_trips))

    printer.on_reading(record)
    for count in range(1, 6):
        before = len(printer.round_trips)
        reading = await printer.read_temperatures()
        # The callback was called with this reply's reading before `read_temperatures` returned...
        assert len(recorded_when_called) == count
        assert reading.source is ReadingSource.POLL
        # ... and after the reply was delivered: the read's step was complete when user code ran.
        assert recorded_when_called[-1] == before + 1


async def test_a_reader_that_stops_reading_stops_nothing(mem_printer: marlin_aio.Printer) -> None:
    stuck = mem_printer.temperature_readings()
    counter = Counter()
    mem_printer.on_reading(counter)
    async with mem_printer.poll_temperatures(0.001):
        await anext(stuck)  # subscribed; it never reads again
        await counter.wait_for_more(1_100)  # past the bound of its queue
        async with asyncio.timeout(10):
            await mem_printer.send("M105")
            await mem_printer.send("M118 E1 x")
    assert mem_printer.readings_dropped > 0
    assert mem_printer.stats.timeouts == 0
    await stuck.aclose()
