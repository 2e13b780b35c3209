"""The client side of one benchmark run, in a process of its own: `python -m benchmarks._worker '<json spec>'`.

The orchestrator starts the simulated printer in one process and this worker in another, so the CPU time and the
peak RSS a worker reports are the client's alone (`time.process_time()` counts every thread of the process, which
matters for printcore's reader and sender threads). A worker prints one line `BENCHMARK-RESULT {...}` on stdout
at the end and exits; anything else it prints is left to the log.

This module is only the dispatch: which contender's function runs a (scenario, client) pair. The contenders live
one to a module (`_contender_marlin_aio.py`, `_contender_floor.py`, `_contender_pyserial.py`,
`_contender_printcore.py`) and measure with `_measure.py`. A worker imports only the module of the contender it
runs, so no run pays another contender's imports (printcore's, or marlin_aio's in a baseline's run).

Every loop a contender runs is bounded in time: a contender that stops getting answers fails its run instead of
hanging.
"""

from __future__ import annotations

import asyncio
import importlib
import json
import sys
from collections.abc import Callable, Coroutine
from typing import Any

from benchmarks._measure import Result, peak_rss_bytes, ru_maxrss_bytes

__all__ = ["ASYNC_TASKS", "RESULT_MARKER", "THREAD_TASKS", "main", "run"]

RESULT_MARKER = "BENCHMARK-RESULT "

MARLIN_AIO = "benchmarks._contender_marlin_aio"
FLOOR = "benchmarks._contender_floor"
PYSERIAL = "benchmarks._contender_pyserial"
PRINTCORE = "benchmarks._contender_printcore"

#: (scenario, client) -> (the contender's module, the coroutine function that runs it in `asyncio.run`).
ASYNC_TASKS: dict[tuple[str, str], tuple[str, str]] = {
    ("roundtrips", "marlin_aio"): (MARLIN_AIO, "marlin_round_trips"),
    ("roundtrips", "floor"): (FLOOR, "floor_round_trips"),
    ("roundtrips", "lean_floor"): (FLOOR, "lean_floor_round_trips"),
    ("polling", "lean_floor"): (FLOOR, "lean_floor_polling"),
    ("polling", "floor"): (FLOOR, "floor_polling"),
    ("polling", "marlin_aio"): (MARLIN_AIO, "marlin_polling"),
    ("streaming", "marlin_aio"): (MARLIN_AIO, "marlin_streaming"),
    ("memory", "marlin_aio"): (MARLIN_AIO, "marlin_memory"),
    ("many", "marlin_aio"): (MARLIN_AIO, "marlin_many"),
    ("many", "lean_floor"): (FLOOR, "lean_floor_many"),
    ("farm", "bridge"): (MARLIN_AIO, "farm_run"),
    ("farm", "plain"): (MARLIN_AIO, "farm_run"),
}
#: (scenario, client) -> (the contender's module, the plain function that runs it on this thread).
THREAD_TASKS: dict[tuple[str, str], tuple[str, str]] = {
    ("roundtrips", "pyserial"): (PYSERIAL, "pyserial_round_trips"),
    ("roundtrips", "printcore"): (PRINTCORE, "printcore_round_trips"),
    ("polling", "printcore"): (PRINTCORE, "printcore_polling"),
    ("streaming", "printcore"): (PRINTCORE, "printcore_streaming"),
}


def _load(where: tuple[str, str]) -> Any:
    module, function = where
    return getattr(importlib.import_module(module), function)


def run(spec: Result) -> Result:
    """Run one spec ({"scenario", "client", "url", ...}) and return its measurements."""
    key = (spec["scenario"], spec["client"])
    if key in ASYNC_TASKS:
        coroutine_function: Callable[[Result], Coroutine[Any, Any, Result]] = _load(ASYNC_TASKS[key])
        if spec.get("loop") == "uvloop":
            import uvloop  # a dev dependency; only its rows ask for it

            result: Result = uvloop.run(coroutine_function(spec))
            return result
        return asyncio.run(coroutine_function(spec))
    if key in THREAD_TASKS:
        function: Callable[[Result], Result] = _load(THREAD_TASKS[key])
        return function(spec)
    raise ValueError(f"no such benchmark task: {key}")


def main(argv: list[str]) -> int:
    spec = json.loads(argv[1])
    result = run(spec)
    result.setdefault("peak_rss_bytes", peak_rss_bytes())
    result.setdefault("ru_maxrss_bytes", ru_maxrss_bytes())
    print(RESULT_MARKER + json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
