"""`SimulatedTimeLoop` and `run_in_simulated_time`: the clock starts at 0 and jumps to the next timer, timers and
timeouts keep their order and their simulated deadlines, a client on the memory link spends the simulator's
seconds, and work handed to a thread is waited for in real time.

Each test runs its own loop with `run_in_simulated_time` (plain functions, not pytest-asyncio's loop), and asserts
on `loop.time()`. Real durations are only compared with the simulated ones: a clock that jumps covers its
simulated span in well under half of it for real, however loaded the machine (a real one could not).
"""

from __future__ import annotations

import asyncio
import time

import pytest

import marlin_aio
from marlin_aio.simulator import Faults, SimulatedTimeLoop, SimulatorConfig, run_in_simulated_time, serve_memory


def test_time_starts_at_zero_and_an_hour_of_sleep_takes_none() -> None:
    async def main() -> tuple[float, float, bool]:
        loop = asyncio.get_running_loop()
        start = loop.time()
        await asyncio.sleep(3600)
        return start, loop.time(), isinstance(loop, SimulatedTimeLoop)

    began = time.monotonic()
    start, end, simulated = run_in_simulated_time(main())
    assert simulated
    assert start == 0.0
    assert end == pytest.approx(3600.0)
    assert time.monotonic() - began < (end - start) / 2


def test_timers_fire_in_order_each_at_its_simulated_time() -> None:
    async def main() -> list[tuple[str, float]]:
        loop = asyncio.get_running_loop()
        fired: list[tuple[str, float]] = []
        done: asyncio.Future[None] = loop.create_future()

        def fire(name: str) -> None:
            fired.append((name, loop.time()))

        for name, delay_s in (("c", 30.0), ("a", 0.5), ("d", 86_400.0 * 3), ("b", 2.0)):
            loop.call_later(delay_s, fire, name)
        loop.call_later(86_400.0 * 3 + 1, done.set_result, None)
        await done
        return fired

    fired = run_in_simulated_time(main())
    assert [name for name, _ in fired] == ["a", "b", "c", "d"]
    assert [at for _, at in fired] == pytest.approx([0.5, 2.0, 30.0, 86_400.0 * 3])


def test_tasks_sleeping_side_by_side_wake_in_order() -> None:
    async def main() -> list[tuple[int, float]]:
        loop = asyncio.get_running_loop()
        woke: list[tuple[int, float]] = []

        async def sleeper(seconds: int) -> None:
            await asyncio.sleep(seconds)
            woke.append((seconds, loop.time()))

        async with asyncio.TaskGroup() as group:
            for seconds in (5, 1, 3, 2, 4):
                group.create_task(sleeper(seconds))
        return woke

    woke = run_in_simulated_time(main())
    assert [seconds for seconds, _ in woke] == [1, 2, 3, 4, 5]
    assert [at for _, at in woke] == pytest.approx([1.0, 2.0, 3.0, 4.0, 5.0])


def test_a_timeout_fires_at_its_simulated_deadline() -> None:
    async def main() -> float:
        loop = asyncio.get_running_loop()
        await asyncio.sleep(1.0)
        try:
            async with asyncio.timeout(5.0):
                await asyncio.sleep(600)
        except TimeoutError:
            return loop.time()
        raise AssertionError("the sleep outlived its timeout")

    assert run_in_simulated_time(main()) == pytest.approx(6.0)


def test_the_result_and_the_error_of_main_come_back() -> None:
    async def answer() -> int:
        await asyncio.sleep(10)
        return 42

    async def fail() -> None:
        await asyncio.sleep(10)
        raise LookupError("from inside")

    assert run_in_simulated_time(answer()) == 42
    with pytest.raises(LookupError, match="from inside"):
        run_in_simulated_time(fail())


def test_a_g28_on_the_memory_link_takes_the_simulators_seconds() -> None:
    config = SimulatorConfig(homing_s=20.0)

    async def main() -> tuple[float, tuple[str, ...]]:
        loop = asyncio.get_running_loop()
        async with (
            serve_memory(config, Faults()) as server,
            marlin_aio.connect(server.url, timeout_s=2.0) as printer,
        ):
            start = loop.time()
            reply = await printer.home()
            return loop.time() - start, reply.lines

    began = time.monotonic()
    took_s, lines = run_in_simulated_time(main())
    # 20 s of homing (well past the 2 s timeout: its busy keepalives keep it alive), and a few turns of the loop.
    assert 20.0 <= took_s < 20.1
    assert any(line.startswith("X:0.00") for line in lines)
    assert time.monotonic() - began < took_s / 2


def test_work_in_a_thread_is_waited_for_in_real_time() -> None:
    # A thread's result reaches the loop from outside it: the clock may not jump past it to the timeout's timer,
    # and it moves with real time meanwhile.
    async def main() -> tuple[str, float]:
        loop = asyncio.get_running_loop()
        async with asyncio.timeout(60.0):
            result = await loop.run_in_executor(None, _slow, "done")
        return result, loop.time()

    result, now = run_in_simulated_time(main())
    assert result == "done"
    # Had the clock jumped past the thread to the timeout's timer, the timeout would have raised; it moved with
    # real time instead (about the thread's 0.05 s, counted from the loop's first wait for it: on a loaded machine
    # less, as the thread may start sleeping before the loop waits).
    assert now < 60.0


def _slow(result: str) -> str:
    time.sleep(0.05)  # in a worker thread: real time passes for it
    return result
