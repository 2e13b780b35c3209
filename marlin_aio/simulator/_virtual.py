"""Simulated time for a whole asyncio program: an event loop whose clock jumps to its next timer instead of
sleeping until it.

A client on the in-memory link (`serve_memory`) and the simulated printer behind it do no real I/O: everything
they do is a callback or a timer of one event loop. On `SimulatedTimeLoop` the clock (`loop.time()`) starts at 0
and, whenever nothing is ready to run, moves straight to the earliest timer: a G28 of 20 simulated seconds, an
M109 heating for two minutes, a 10 s command timeout all pass in the CPU time their callbacks take. Everything
that keeps time by the loop (`asyncio.sleep`, `asyncio.timeout`, `call_later`, the client's deadlines and
pollers, the simulator's thermal model) sees the same simulated seconds, so a run is also the same run every
time its inputs are.

Work the loop hands to a thread (`run_in_executor`, and so `getaddrinfo` and the default executor's shutdown
when the loop closes) is waited for: while some is under way, the clock moves with real time, as on any loop.
Real I/O still works (the loop polls its file descriptors before each jump), but a wait on anything else outside
the loop (a thread of your own, a subprocess, a real serial port) is not waited for: the clock jumps past it, and
its timeouts fire early. So this is for in-process links only; a pty or a TCP socket needs real time.
"""

from __future__ import annotations

import asyncio
import selectors
import time
from collections.abc import Callable, Coroutine
from concurrent.futures import Executor
from typing import Any, TypeVar, TypeVarTuple

__all__ = ["SimulatedTimeLoop", "run_in_simulated_time"]

T = TypeVar("T")
Ts = TypeVarTuple("Ts")


class _JumpingSelector(selectors.BaseSelector):
    """A real selector that, asked to wait with nothing ready, moves the loop's clock by the wait instead (or,
    while the loop's threads work, waits for real and moves the clock by the time that passed)."""

    def __init__(self, loop: SimulatedTimeLoop) -> None:
        self._real = selectors.DefaultSelector()
        self._loop = loop

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._real.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.modify(fileobj, events, data)

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if self._loop.threads_working:
            # A thread's result comes through the self-pipe (call_soon_threadsafe): wait for it, or for the next
            # timer, in real time.
            started = time.monotonic()
            ready = self._real.select(timeout)
            self._loop.advance(timeout if not ready and timeout is not None else time.monotonic() - started)
            return ready
        ready = self._real.select(0)
        if ready or timeout == 0:
            return ready
        if timeout is None:
            # No timer at all: only outside input can wake the loop (the self-pipe of call_soon_threadsafe).
            return self._real.select(None)
        self._loop.advance(timeout)
        return []

    def get_map(self) -> Any:
        return self._real.get_map()

    def close(self) -> None:
        self._real.close()


class SimulatedTimeLoop(asyncio.SelectorEventLoop):
    """An event loop on simulated time: `time()` starts at 0 and jumps to the next timer when nothing is ready
    (and moves with real time while work handed to a thread with `run_in_executor` is under way)."""

    def __init__(self) -> None:
        self._now = 0.0
        self._threads_working = 0
        super().__init__(_JumpingSelector(self))

    def time(self) -> float:
        """The simulated seconds since the loop was made."""
        return self._now

    def advance(self, seconds: float) -> None:
        """Move the clock on by `seconds` (what the selector does instead of waiting)."""
        self._now += seconds

    @property
    def threads_working(self) -> bool:
        """True while work handed to a thread (`run_in_executor`, the default executor's shutdown) is under way."""
        return self._threads_working > 0

    def run_in_executor(self, executor: Executor | None, func: Callable[[*Ts], T], *args: *Ts) -> asyncio.Future[T]:
        """As on any loop; until `func` returns, the clock moves with real time (see the module's docstring)."""
        future = super().run_in_executor(executor, func, *args)
        self._threads_working += 1
        future.add_done_callback(self._thread_done)
        return future

    async def shutdown_default_executor(self, *args: Any, **kwargs: Any) -> None:
        """As on any loop, waiting in real time for the executor's threads to end (Python 3.12 bounds that wait
        by a timer, which simulated time would otherwise jump to)."""
        self._threads_working += 1
        try:
            await super().shutdown_default_executor(*args, **kwargs)
        finally:
            self._threads_working -= 1

    def _thread_done(self, future: asyncio.Future[Any]) -> None:
        self._threads_working -= 1


def run_in_simulated_time(main: Coroutine[Any, Any, T]) -> T:
    """Run `main` to its end on a new `SimulatedTimeLoop`, as `asyncio.run` does on a real one, and return its
    result (or raise what it raised). For programs whose printer is served in memory (`serve_memory`): see the
    module's docstring."""
    with asyncio.Runner(loop_factory=SimulatedTimeLoop) as runner:
        return runner.run(main)
