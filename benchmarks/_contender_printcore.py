"""Printrun's printcore (client "printcore"), the host library behind Pronterface, driven headless the way
Pronterface drives it (`PrintcoreSession`): round trips with `send_now()`, polling as fast as it allows, and
streaming with `startprint()`.

printrun is optional (`pip install --no-deps printrun`); the orchestrator skips this contender when it is missing.
It is imported through `importlib` because it has no type information for mypy to read.
"""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable

from benchmarks._measure import ANSWER_TIMEOUT_S, QUIET_S, WARMUP_S, Meter, Result, RunFailedError, interval_stats

__all__ = ["PrintcoreSession", "printcore_polling", "printcore_round_trips", "printcore_streaming"]


class PrintcoreSession:
    """Printrun's `printcore`, driven headless the way Pronterface drives it.

    `printcore(port, baud)` opens the port and starts a reader and a sender thread; `onlinecb` fires once the
    printer answered its first M105. `send_now()` queues a command for the sender thread; every line read calls
    `recvcb`, and `ok ... T:` lines also call `tempcb`. `startprint(LightGCode(lines))` streams a file in its own
    thread, numbered and checksummed, one line per `ok`; `endcb` fires when the last line was answered.
    """

    def __init__(self, url: str) -> None:
        self.module = importlib.import_module("printrun.printcore")
        self.online = threading.Event()
        self.answered = threading.Event()
        self.finished = threading.Event()
        self.on_temperature: Callable[[float], None] | None = None
        core = self.module.printcore()
        core.onlinecb = self.online.set
        core.tempcb = self._tempcb
        core.endcb = self.finished.set
        core.errorcb = self._errorcb
        self.errors: list[str] = []
        self.core = core
        core.connect(url, 250_000)
        if not self.online.wait(10.0):
            self.close()
            raise RunFailedError("printcore: the printer did not come online within 10 s")
        # printcore's own start-up M105 is answered after it went online: let that answer pass before measuring.
        time.sleep(QUIET_S)
        self.answered.clear()

    def _tempcb(self, line: str) -> None:
        if self.on_temperature is not None:
            self.on_temperature(time.monotonic())
        self.answered.set()

    def _errorcb(self, message: str) -> None:
        self.errors.append(str(message)[:200])

    def round_trip(self) -> None:
        self.answered.clear()
        self.core.send_now("M105")
        if not self.answered.wait(ANSWER_TIMEOUT_S):
            raise RunFailedError(f"printcore: no answer to M105 within {ANSWER_TIMEOUT_S} s; errors: {self.errors}")

    def close(self) -> None:
        self.core.disconnect()


def printcore_round_trips(spec: Result) -> Result:
    session = PrintcoreSession(spec["url"])
    try:
        deadline = time.perf_counter() + WARMUP_S
        while time.perf_counter() < deadline:
            session.round_trip()
        count = 0
        meter = Meter()
        end = meter.start + spec["seconds"]
        while time.perf_counter() < end:
            session.round_trip()
            count += 1
        wall, cpu = meter.stop()
    finally:
        session.close()
    return {"round_trips": count, "wall_s": wall, "cpu_s": cpu, **meter.split()}


def printcore_polling(spec: Result) -> Result:
    """printcore polling as fast as it allows: M105, wait for its `ok T:`, M105 again, for `seconds`."""
    session = PrintcoreSession(spec["url"])
    times: list[float] = []
    try:
        session.on_temperature = times.append
        meter = Meter()
        end = meter.start + spec["seconds"]
        while time.perf_counter() < end:
            session.round_trip()
        wall, cpu = meter.stop()
        session.on_temperature = None
    finally:
        session.close()
    return {
        "readings": len(times),
        "other_readings": 0,
        "timeouts": 0,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
    } | (interval_stats(times))


def printcore_streaming(spec: Result) -> Result:
    gcoder = importlib.import_module("printrun.gcoder")
    from marlin_aio.protocol import encode_command

    with open(spec["path"]) as source:
        lines = source.read().splitlines()
    gcode = gcoder.LightGCode(lines)
    session = PrintcoreSession(spec["url"])
    try:
        meter = Meter()
        if not session.core.startprint(gcode):
            raise RunFailedError("printcore: startprint refused (offline or already printing)")
        # Bounded: three times the slowest plausible rate, as the orchestrator also enforces.
        if not session.finished.wait(spec["timeout_s"]):
            raise RunFailedError(f"printcore: the print did not finish within {spec['timeout_s']:.0f} s")
        wall, cpu = meter.stop()
    finally:
        session.close()
    # printcore numbers from N0 after its `M110 N-1`; these are the bytes it put on the wire for the file.
    wire_bytes = sum(len(encode_command(line, number)) for number, line in enumerate(lines))
    return {
        "seconds": wall,
        "cpu_s": cpu,
        **meter.split(),
        "lines": len(lines),
        "file_bytes": sum(len(line) + 1 for line in lines),
        "wire_bytes": wire_bytes,
        "resends": 0,
        "state": "done",
        "errors": session.errors,
    }
