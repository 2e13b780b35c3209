"""The floor: the least a correct asyncio client can do on the same transport (pyserial-asyncio-fast), written by
hand for the benchmarks, so marlin_aio's cost is read against what any client must pay.

- The floor (client "floor"): a bare `asyncio.Protocol` that ends a wait at the first newline and parses
  nothing, with `asyncio.wait_for` as each command's deadline (`floor_link`); round trips, and polling from a
  task that sleeps between polls on a deadline schedule.
- The lean floor (client "lean_floor"): the cheapest correct client, one timer handle per command instead of
  `wait_for`, and a poller that is one timer callback on the 10 ms schedule reading the hotend's temperature
  from each answer (`_LeanPoller`); round trips, polling, and N links on one loop.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import serial_asyncio_fast

from benchmarks._measure import (
    ANSWER_TIMEOUT_S,
    QUIET_S,
    LagProbe,
    Meter,
    Result,
    interval_stats,
    many_summary,
    time_round_trips,
)

__all__ = [
    "floor_link",
    "floor_polling",
    "floor_round_trips",
    "lean_floor_many",
    "lean_floor_polling",
    "lean_floor_round_trips",
]


# ------------------------------------------------------------------------------------------------ the floor


class _LineProtocol(asyncio.Protocol):
    """Completes `waiter` at the first newline; parses nothing."""

    def __init__(self) -> None:
        self.buffer = b""
        self.waiter: asyncio.Future[None] | None = None

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        if b"\n" in self.buffer:
            _, _, self.buffer = self.buffer.partition(b"\n")
            if self.waiter is not None and not self.waiter.done():
                self.waiter.set_result(None)


@contextlib.asynccontextmanager
async def floor_link(url: str) -> AsyncIterator[Callable[[], Awaitable[None]]]:
    """The floor: a bare asyncio protocol on the same transport (pyserial-asyncio-fast), yielding a round trip
    that writes `M105` and waits for one line, with the same kind of deadline a client needs."""
    loop = asyncio.get_running_loop()
    transport, protocol = await serial_asyncio_fast.create_serial_connection(loop, _LineProtocol, url, baudrate=250_000)
    assert isinstance(protocol, _LineProtocol)

    async def round_trip() -> None:
        protocol.waiter = loop.create_future()
        transport.write(b"M105\n")
        await asyncio.wait_for(protocol.waiter, ANSWER_TIMEOUT_S)

    try:
        await asyncio.sleep(QUIET_S)  # the boot banner arrives and is thrown away
        protocol.buffer = b""
        yield round_trip
    finally:
        transport.close()
        await asyncio.sleep(0.05)  # the port closes in an executor


async def floor_round_trips(spec: Result) -> Result:
    async with floor_link(spec["url"]) as round_trip:
        return await time_round_trips(round_trip, spec["seconds"])


async def floor_polling(spec: Result) -> Result:
    """The floor polling at `interval_s` on a deadline schedule, as marlin_aio's poller does, with no parsing."""
    loop = asyncio.get_running_loop()
    times: list[float] = []
    async with floor_link(spec["url"]) as round_trip:
        meter = Meter()
        start = next_poll = loop.time()
        while loop.time() < start + spec["seconds"]:
            delay = next_poll - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            await round_trip()
            times.append(loop.time())
            next_poll = max(next_poll + spec["interval_s"], loop.time())
        wall, cpu = meter.stop()
    return {
        "readings": len(times),
        "other_readings": 0,
        "timeouts": 0,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        **interval_stats(times),
    }


# ------------------------------------------------------------------------------------------------ the lean floor


class _LeanProtocol(asyncio.Protocol):
    """The cheapest correct client: a line ends the wait; `on_line` sees it."""

    def __init__(self) -> None:
        self.buffer = b""
        self.waiter: asyncio.Future[None] | None = None
        self.on_line: Callable[[bytes], None] | None = None

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        while b"\n" in self.buffer:
            line, _, self.buffer = self.buffer.partition(b"\n")
            if self.on_line is not None:
                self.on_line(line)
            if self.waiter is not None and not self.waiter.done():
                self.waiter.set_result(None)


async def _lean_link(url: str) -> tuple[asyncio.BaseTransport, _LeanProtocol]:
    loop = asyncio.get_running_loop()
    transport, protocol = await serial_asyncio_fast.create_serial_connection(loop, _LeanProtocol, url, baudrate=250_000)
    assert isinstance(protocol, _LeanProtocol)
    await asyncio.sleep(QUIET_S)  # the boot banner arrives and is thrown away
    protocol.buffer = b""
    return transport, protocol


async def lean_floor_round_trips(spec: Result) -> Result:
    """Round trips with the deadline a client needs as one timer handle per command, not `asyncio.wait_for`."""
    loop = asyncio.get_running_loop()
    transport, protocol = await _lean_link(spec["url"])

    async def round_trip() -> None:
        waiter = protocol.waiter = loop.create_future()
        transport.write(b"M105\n")  # type: ignore[attr-defined]
        deadline = loop.call_later(ANSWER_TIMEOUT_S, waiter.cancel)
        try:
            await waiter
        finally:
            deadline.cancel()

    try:
        return await time_round_trips(round_trip, spec["seconds"])
    finally:
        transport.close()
        await asyncio.sleep(0.05)  # the port closes in an executor


class _LeanPoller:
    """The lean floor's poller for one link: one timer callback on the 10 ms schedule, as marlin_aio's poller is,
    reading the hotend's temperature from each answer. A slot whose answer is still out is skipped (the same
    schedule as marlin_aio's); an answer out for longer than a correct client would wait for is given up."""

    def __init__(self, transport: Any, protocol: _LeanProtocol, interval_s: float) -> None:
        self._loop = asyncio.get_running_loop()
        self._transport = transport
        self._interval = interval_s
        self._pending = False
        self._sent = 0.0
        self._next = self._loop.time()
        self.times: list[float] = []
        protocol.on_line = self._on_line
        self._timer: asyncio.TimerHandle | asyncio.Handle = self._loop.call_soon(self._tick)

    def _on_line(self, line: bytes) -> None:
        if line.startswith(b"ok T:"):
            float(line[5:].split(b" ", 1)[0])  # the hotend's temperature, read
            self.times.append(self._loop.time())
            self._pending = False

    def _tick(self) -> None:
        now = self._loop.time()
        if not self._pending or now - self._sent > ANSWER_TIMEOUT_S:
            self._transport.write(b"M105\n")
            self._pending = True
            self._sent = now
        self._next += self._interval
        if self._next <= now:
            self._next = now + self._interval
        self._timer = self._loop.call_at(self._next, self._tick)

    def stop(self) -> None:
        self._timer.cancel()


async def lean_floor_polling(spec: Result) -> Result:
    """Polling one link driven by one timer callback (`_LeanPoller`)."""
    transport, protocol = await _lean_link(spec["url"])
    try:
        meter = Meter()
        poller = _LeanPoller(transport, protocol, spec["interval_s"])
        await asyncio.sleep(spec["seconds"])
        poller.stop()
        wall, cpu = meter.stop()
    finally:
        transport.close()
        await asyncio.sleep(0.05)
    return {
        "readings": len(poller.times),
        "other_readings": 0,
        "timeouts": 0,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        **interval_stats(poller.times),
    }


async def lean_floor_many(spec: Result) -> Result:
    """N lean links on one event loop, each driven by its own `_LeanPoller`."""
    links = await asyncio.gather(*(_lean_link(url) for url in spec["urls"]))
    try:
        meter = Meter()
        probe = LagProbe()
        pollers = [_LeanPoller(transport, protocol, spec["interval_s"]) for transport, protocol in links]
        await asyncio.sleep(spec["seconds"])
        for poller in pollers:
            poller.stop()
        lag = probe.stop()
        wall, cpu = meter.stop()
    finally:
        for transport, _ in links:
            transport.close()
        await asyncio.sleep(0.05)  # the ports close in an executor
    return {
        "printers": len(links),
        "timeouts": 0,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        **lag,
        **many_summary([poller.times for poller in pollers], wall),
    }
