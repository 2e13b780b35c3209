"""`marlin_aio.aio.keep_connected`: a session again after an unplug, waits that double while nothing answers and
start over once a connection is made, and a bug that is not retried; through the simulator on the in-memory link
(which can be unplugged and plugged back) and a name where nothing listens."""

from __future__ import annotations

import asyncio

import pytest

import marlin_aio
from marlin_aio.aio import Backoff, Retry, keep_connected
from marlin_aio.simulator import SimulatorConfig, serve_memory

#: Where nothing listens: each attempt fails at once with PortNotFoundError.
NOBODY = "memory://nobody-listens-here"


async def test_a_session_lost_to_an_unplug_runs_again_on_a_new_connection() -> None:
    retries: list[Retry] = []
    sessions = 0
    async with serve_memory(SimulatorConfig(), time_scale=20) as sim:

        async def session(printer: marlin_aio.Printer) -> str:
            nonlocal sessions
            sessions += 1
            reply = await printer.send("M115")
            if sessions == 1:
                await sim.disconnect()  # unplugged under the first session
                raise await printer.wait_for_failure()
            return reply.lines[0]

        result = await keep_connected(
            lambda: marlin_aio.Printer(sim.url, timeout_s=5),
            session,
            backoff=Backoff(0.01, 0.05),
            on_retry=retries.append,
        )
    assert result is not None and result.startswith("FIRMWARE_NAME:Marlin")
    assert sessions == 2
    assert len(retries) == 1
    assert retries[0].connected and retries[0].attempt == 1 and retries[0].delay_s == 0.01
    assert isinstance(retries[0].error, marlin_aio.ConnectionLostError)


async def test_attempts_wait_longer_each_time_up_to_the_most() -> None:
    class Enough(Exception):
        pass

    retries: list[Retry] = []

    def on_retry(retry: Retry) -> None:
        retries.append(retry)
        if len(retries) == 5:
            raise Enough

    async def never(printer: marlin_aio.Printer) -> None:
        raise AssertionError("nothing listens: no session can start")

    with pytest.raises(Enough):
        await keep_connected(
            lambda: marlin_aio.Printer(NOBODY, timeout_s=1), never, backoff=Backoff(0.01, 0.04), on_retry=on_retry
        )
    assert [retry.delay_s for retry in retries] == [0.01, 0.02, 0.04, 0.04, 0.04]
    assert [retry.attempt for retry in retries] == [1, 2, 3, 4, 5]
    assert not any(retry.connected for retry in retries)
    assert all(isinstance(retry.error, marlin_aio.ConnectError) for retry in retries)


async def test_a_bug_in_the_session_is_not_retried() -> None:
    retries: list[Retry] = []
    async with serve_memory(SimulatorConfig(), time_scale=20) as sim:

        async def buggy(printer: marlin_aio.Printer) -> None:
            raise KeyError("a bug")

        with pytest.raises(KeyError):
            await keep_connected(lambda: marlin_aio.Printer(sim.url), buggy, on_retry=retries.append)
    assert retries == []


async def test_a_stop_or_the_deadline_ends_a_wait_at_once() -> None:
    """A 30 s wait between attempts ends as soon as `stop` is set (Ctrl-C) or the deadline (--duration) comes:
    keep_connected returns None. Bounded at 10 s here, so a wait that ran its course fails the test."""
    stop = asyncio.Event()
    retries: list[Retry] = []

    def on_retry(retry: Retry) -> None:
        retries.append(retry)
        stop.set()  # as Ctrl-C would, while the 30 s wait starts

    async def never(printer: marlin_aio.Printer) -> int:
        raise AssertionError("nothing listens: no session can start")

    async with asyncio.timeout(10):
        stopped = await keep_connected(
            lambda: marlin_aio.Printer(NOBODY, timeout_s=1),
            never,
            backoff=Backoff(30, 30),
            on_retry=on_retry,
            stop=stop,
        )
        assert stopped is None and len(retries) == 1 and retries[0].delay_s == 30
        deadline = asyncio.get_running_loop().time() + 0.2
        ended = await keep_connected(
            lambda: marlin_aio.Printer(NOBODY, timeout_s=1), never, backoff=Backoff(30, 30), deadline=deadline
        )
        assert ended is None and asyncio.get_running_loop().time() >= deadline


def test_a_backoff_starts_over_once_connected() -> None:
    backoff = Backoff(1.0, 5.0)
    assert [backoff.next_delay() for _ in range(5)] == [1.0, 2.0, 4.0, 5.0, 5.0]
    backoff.reset()
    assert backoff.next_delay() == 1.0
    for start, most in ((0.0, 1.0), (2.0, 1.0), (-1.0, 5.0)):
        with pytest.raises(ValueError, match="0 < start_s <= max_s"):
            Backoff(start, most)
