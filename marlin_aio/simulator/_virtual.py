"""Simulated time for a whole asyncio program: an event loop whose clock jumps to its next timer instead of
sleeping until it.

A client on the in-memory link (`serve_memory`) and the simulated printer behind it do no real I/O: everything
they do is a callback or a timer of one event loop. On `SimulatedTimeLoop` the clock (`loop.time()`) starts at 0
and, whenever nothing is ready to run, moves straight to the earliest timer: a G28 of 20 simulated seconds, an
M109 heating for two minutes, a 10 s command timeout all pass in the CPU time their callbacks take. Everything
that keeps time by the loop (`asyncio.sleep`, `asyncio.timeout`, `call_later`, the client's deadlines and
pollers, the simulator's thermal model) sees the same simulated seconds, so a run is also the same run every
time its inputs are.

Real I/O still works (the loop polls its file descriptors before each jump), but a wait on something outside
the loop (a thread, a subprocess, a real serial port) is not waited for: the clock jumps past it, and its
timeouts fire early. So this is for in-process links only; a pty or a TCP socket needs real time.
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Coroutine
from typing import Any, TypeVar

__all__ = ["SimulatedTimeLoop", "run_in_simulated_time"]

T = TypeVar("T")


class _JumpingSelector(selectors.BaseSelector):
    """A real selector that, asked to wait with nothing ready, moves the loop's clock by the wait instead."""

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
    """An event loop on simulated time: `time()` starts at 0 and jumps to the next timer when nothing is ready."""

    def __init__(self) -> None:
        self._now = 0.0
        super().__init__(_JumpingSelector(self))

    def time(self) -> float:
        """The simulated seconds since the loop was made."""
        return self._now

    def advance(self, seconds: float) -> None:
        """Move the clock on by `seconds` (what the selector does instead of waiting)."""
        self._now += seconds


def run_in_simulated_time(main: Coroutine[Any, Any, T]) -> T:
    """Run `main` to its end on a new `SimulatedTimeLoop`, as `asyncio.run` does on a real one, and return its
    result. For programs whose printer is served in memory (`serve_memory`): see the module's docstring."""
    with asyncio.Runner(loop_factory=SimulatedTimeLoop) as runner:
        return runner.run(main)
