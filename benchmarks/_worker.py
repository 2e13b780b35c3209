"""The client side of one benchmark run, in a process of its own: `python -m benchmarks._worker '<json spec>'`.

The orchestrator starts the simulated printer in one process and this worker in another, so the CPU time and the
peak RSS a worker reports are the client's alone (`time.process_time()` counts every thread of the process, which
matters for printcore's reader and sender threads). A worker imports only what its contender needs, prints one
line `BENCHMARK-RESULT {...}` on stdout at the end and exits; anything else it prints is left to the log.

Every loop here is bounded in time: a contender that stops getting answers fails its run instead of hanging.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import itertools
import json
import math
import os
import resource
import statistics
import sys
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from pathlib import Path
from typing import Any

RESULT_MARKER = "BENCHMARK-RESULT "
# Before each measured window: the same short warm-up for every contender (imports, caches, the first replies).
WARMUP_S = 0.5
# How long the boot banner of the simulated printer takes to arrive and be thrown away.
QUIET_S = 0.3
# A single answer that takes longer than this means the run is broken, not slow.
ANSWER_TIMEOUT_S = 5.0

Result = dict[str, Any]


class RunFailedError(RuntimeError):
    """The contender could not complete the run (no answer, not online, print failed)."""


class Meter:
    """Wall time and this process's CPU time (all threads) from construction to `stop()`."""

    def __init__(self) -> None:
        self._times = os.times()
        self._cpu = time.process_time()
        self.start = time.perf_counter()
        self._split = {"cpu_user_s": math.nan, "cpu_system_s": math.nan}

    def stop(self) -> tuple[float, float]:
        """Return (wall seconds, CPU seconds: user and system, every thread)."""
        wall, cpu, times = time.perf_counter() - self.start, time.process_time() - self._cpu, os.times()
        self._split = {"cpu_user_s": times.user - self._times.user, "cpu_system_s": times.system - self._times.system}
        return wall, cpu

    def split(self) -> dict[str, float]:
        """The CPU time of the measured window as user and system (kernel) seconds."""
        return dict(self._split)


def ru_maxrss_bytes() -> int:
    """`ru_maxrss` of this process (kilobytes on Linux).

    On Linux it is not this program's alone: across fork and exec the kernel keeps the larger of the old and the
    new address space's high-water mark, so a worker started by a 30 MB orchestrator reports at least 30 MB.
    """
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def peak_rss_bytes() -> int:
    """Peak RSS of this process image: `VmHWM` (the high-water mark of the address space exec made), falling back
    to `ru_maxrss` where there is no /proc."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return ru_maxrss_bytes()


def current_rss_bytes() -> int:
    """Resident set size now, from /proc (0 where there is no /proc)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def interval_stats(times_s: list[float]) -> dict[str, float]:
    """Median, 99th percentile (nearest rank) and worst of the gaps between consecutive times, in milliseconds."""
    gaps = sorted(b - a for a, b in itertools.pairwise(times_s))
    if not gaps:
        return {"interval_median_ms": math.nan, "interval_p99_ms": math.nan, "interval_max_ms": math.nan}
    p99 = gaps[max(0, math.ceil(0.99 * len(gaps)) - 1)]
    return {
        "interval_median_ms": statistics.median(gaps) * 1000,
        "interval_p99_ms": p99 * 1000,
        "interval_max_ms": gaps[-1] * 1000,
    }


@contextlib.contextmanager
def profiled(path: str | None) -> Iterator[None]:
    """cProfile the block into `path` (pstats format) when a path is given; otherwise do nothing."""
    if not path:
        yield
        return
    import cProfile

    profile = cProfile.Profile()
    profile.enable()
    try:
        yield
    finally:
        profile.disable()
        profile.dump_stats(path)


# ------------------------------------------------------------------------------------------------ marlin_aio


async def _time_round_trips(round_trip: Callable[[], Awaitable[object]], seconds: float) -> Result:
    """Warm up, then count `round_trip()`s back to back for `seconds`, with the CPU they took: every contender of
    the round-trip scenario is measured by this one loop."""
    deadline = time.perf_counter() + WARMUP_S
    while time.perf_counter() < deadline:
        await round_trip()
    count = 0
    meter = Meter()
    end = meter.start + seconds
    while time.perf_counter() < end:
        await round_trip()
        count += 1
    wall, cpu = meter.stop()
    return {"round_trips": count, "wall_s": wall, "cpu_s": cpu, **meter.split()}


async def marlin_round_trips(spec: Result) -> Result:
    import marlin_aio

    async with marlin_aio.connect(spec["url"]) as printer:
        with profiled(spec.get("profile")):
            return await _time_round_trips(lambda: printer.send("M105"), spec["seconds"])


async def marlin_polling(spec: Result) -> Result:
    import marlin_aio

    async with marlin_aio.connect(spec["url"]) as printer:
        poll_times: list[float] = []
        other_readings = 0

        def collect(reading: marlin_aio.TemperatureReading) -> None:
            # Read what was polled, as an application would (the parse is lazy: unread, it is never paid), through
            # the callback API: no queue and no task wake-up per reading.
            nonlocal other_readings
            if reading.source == "poll":
                hotend = reading.hotend
                assert hotend is not None and hotend.actual == hotend.actual
                poll_times.append(reading.monotonic_s)
            else:
                other_readings += 1

        stop = printer.on_reading(collect)
        try:
            with profiled(spec.get("profile")):
                meter = Meter()
                async with printer.poll_temperatures(interval_s=spec["interval_s"]):
                    await asyncio.sleep(spec["seconds"])
                wall, cpu = meter.stop()
        finally:
            stop()
        timeouts = printer.stats.timeouts
    return {
        "readings": len(poll_times),
        "other_readings": other_readings,
        "timeouts": timeouts,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        **interval_stats(poll_times),
    }


async def marlin_streaming(spec: Result) -> Result:
    import marlin_aio

    async with marlin_aio.connect(spec["url"], timeout_s=ANSWER_TIMEOUT_S * 2) as printer:
        with profiled(spec.get("profile")):
            meter = Meter()
            progress = await printer.print_file(Path(spec["path"]), send_ahead=spec["send_ahead"])
            wall, cpu = meter.stop()
    return {
        "seconds": wall,
        "cpu_s": cpu,
        **meter.split(),
        "lines": progress.lines_acked,
        "file_bytes": progress.source_bytes_acked,
        "wire_bytes": progress.bytes_acked,
        "resends": progress.resends,
        "state": progress.state.value,
    }


async def marlin_memory(spec: Result) -> Result:
    """Stream a file for at most `cap_s` seconds, sampling RSS against the bytes acknowledged so far."""
    import marlin_aio

    samples: list[tuple[float, int, int]] = []  # (seconds since the stream started, source bytes acked, RSS)
    async with marlin_aio.connect(spec["url"], timeout_s=ANSWER_TIMEOUT_S * 2) as printer:
        scan_start = time.perf_counter()
        handle = await printer.start_print(Path(spec["path"]))  # scans (validates) the whole file first
        start = time.perf_counter()
        scan_s = start - scan_start
        baseline = current_rss_bytes()
        deadline = start + spec["cap_s"]
        # One waiter for the whole stream: a new wait per sample would itself grow the heap by a task each time.
        done = asyncio.ensure_future(handle.wait())
        while not done.done() and time.perf_counter() < deadline:
            samples.append((time.perf_counter() - start, handle.progress.source_bytes_acked, current_rss_bytes()))
            await asyncio.wait([done], timeout=min(0.25, max(deadline - time.perf_counter(), 0.0)))
        finished = done.done()
        if not finished:
            await asyncio.wait_for(handle.cancel(), ANSWER_TIMEOUT_S)
        progress = await done
        samples.append((time.perf_counter() - start, progress.source_bytes_acked, current_rss_bytes()))
    return {
        "finished": finished,
        "scan_s": scan_s,
        "stream_s": progress.elapsed_s,
        "lines": progress.lines_acked,
        "streamed_bytes": progress.source_bytes_acked,
        "file_bytes": spec["file_bytes"],
        "peak_rss_bytes": peak_rss_bytes(),
        "ru_maxrss_bytes": ru_maxrss_bytes(),
        "rss_before_stream_bytes": baseline,
        "stream_rss_max_bytes": max(rss for _, _, rss in samples),
        "samples": samples,
    }


# ------------------------------------------------------------------------------------------------ baselines


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
    import serial_asyncio_fast

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
    import serial_asyncio_fast

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
        return await _time_round_trips(round_trip, spec["seconds"])
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


async def floor_round_trips(spec: Result) -> Result:
    async with floor_link(spec["url"]) as round_trip:
        return await _time_round_trips(round_trip, spec["seconds"])


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


def pyserial_round_trips(spec: Result) -> Result:
    """Blocking pyserial: `write(b"M105\\n")`, then `readline()`."""
    import serial

    port = serial.Serial(spec["url"], 250_000, timeout=ANSWER_TIMEOUT_S)
    try:
        time.sleep(QUIET_S)
        port.reset_input_buffer()

        def round_trip() -> None:
            port.write(b"M105\n")
            if not port.readline().endswith(b"\n"):
                raise RunFailedError("pyserial: no answer to M105")

        deadline = time.perf_counter() + WARMUP_S
        while time.perf_counter() < deadline:
            round_trip()
        count = 0
        meter = Meter()
        end = meter.start + spec["seconds"]
        while time.perf_counter() < end:
            round_trip()
            count += 1
        wall, cpu = meter.stop()
    finally:
        port.close()
    return {"round_trips": count, "wall_s": wall, "cpu_s": cpu, **meter.split()}


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


# ------------------------------------------------------------------------------------------------ many printers


class LagProbe:
    """How late the event loop runs a timer: one callback every `interval_s`, each recording how long after its
    due time it ran. A loop that keeps up with its printers runs it within about a millisecond (epoll's grain)."""

    def __init__(self, interval_s: float = 0.01) -> None:
        self._loop = asyncio.get_running_loop()
        self._interval = interval_s
        self.lags_s: list[float] = []
        self._due = self._loop.time() + interval_s
        self._timer = self._loop.call_at(self._due, self._tick)

    def _tick(self) -> None:
        now = self._loop.time()
        self.lags_s.append(now - self._due)
        self._due = max(self._due + self._interval, now)
        self._timer = self._loop.call_at(self._due, self._tick)

    def stop(self) -> dict[str, float]:
        """Stop probing; the lag's median, p99 and worst in milliseconds."""
        self._timer.cancel()
        lags = sorted(self.lags_s)
        if not lags:
            return {"lag_median_ms": math.nan, "lag_p99_ms": math.nan, "lag_max_ms": math.nan}
        return {
            "lag_median_ms": statistics.median(lags) * 1000,
            "lag_p99_ms": lags[max(0, math.ceil(0.99 * len(lags)) - 1)] * 1000,
            "lag_max_ms": lags[-1] * 1000,
        }


def many_summary(per_printer: list[list[float]], wall: float) -> Result:
    """Readings per second of each printer (the slowest and the median) and the poll intervals of all printers
    pooled: a printer that falls behind shows in the p99 whichever it is."""
    rates = sorted(len(times) / wall for times in per_printer)
    gaps = sorted(b - a for times in per_printer for a, b in itertools.pairwise(times))
    p99 = gaps[max(0, math.ceil(0.99 * len(gaps)) - 1)] * 1000 if gaps else math.nan
    return {
        "readings": sum(len(times) for times in per_printer),
        "readings_per_s_min": rates[0] if rates else math.nan,
        "readings_per_s_median": statistics.median(rates) if rates else math.nan,
        "interval_median_ms": statistics.median(gaps) * 1000 if gaps else math.nan,
        "interval_p99_ms": p99,
        "interval_max_ms": gaps[-1] * 1000 if gaps else math.nan,
    }


async def marlin_many(spec: Result) -> Result:
    """N printers on one event loop, each polled by its own `poll_temperatures()`, each reading read through
    `on_reading()`."""
    import marlin_aio

    printers = [marlin_aio.Printer(url) for url in spec["urls"]]
    per_printer: list[list[float]] = [[] for _ in printers]
    try:
        await asyncio.gather(*(printer.open() for printer in printers))
        for printer, times in zip(printers, per_printer, strict=True):

            def collect(reading: marlin_aio.TemperatureReading, times: list[float] = times) -> None:
                if reading.source == "poll":
                    hotend = reading.hotend
                    assert hotend is not None and hotend.actual == hotend.actual
                    times.append(reading.monotonic_s)

            printer.on_reading(collect)
        with profiled(spec.get("profile")):
            async with contextlib.AsyncExitStack() as polls:
                meter = Meter()
                probe = LagProbe()
                for printer in printers:
                    await polls.enter_async_context(printer.poll_temperatures(interval_s=spec["interval_s"]))
                await asyncio.sleep(spec["seconds"])
                lag = probe.stop()
                wall, cpu = meter.stop()
        timeouts = sum(printer.stats.timeouts for printer in printers)
    finally:
        await asyncio.gather(*(printer.close() for printer in printers), return_exceptions=True)
    return {
        "printers": len(printers),
        "timeouts": timeouts,
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        **lag,
        **many_summary(per_printer, wall),
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


# ------------------------------------------------------------------------------------------------ farm over MQTT


async def farm_run(spec: Result) -> Result:
    """`marlin-temp farm`'s own code, N printers polled at `interval_s`: with the MQTT bridge publishing each
    printer's telemetry at `rate_hz` to the broker on `broker_port` (client "bridge"), or without it ("plain")."""
    from marlin_aio.farm.bridge import Bridge, BridgeSettings, BrokerSettings
    from marlin_aio.farm.supervisor import Farm, FarmEvent, PrinterSpec

    specs = [PrinterSpec(f"p{i + 1}", url, poll_interval_s=spec["interval_s"]) for i, url in enumerate(spec["urls"])]
    bridge: Bridge | None = None

    def on_event(event: FarmEvent) -> None:
        if bridge is not None:
            bridge.on_event(event)

    farm = Farm(specs, on_event)
    if spec["client"] == "bridge":
        bridge = Bridge(
            farm,
            BrokerSettings(port=spec["broker_port"]),
            BridgeSettings(rate_hz=spec["rate_hz"], discovery=False),
        )
    tasks = [asyncio.create_task(farm.run())]
    if bridge is not None:
        tasks.append(asyncio.create_task(bridge.run()))
    try:
        deadline = time.perf_counter() + 60
        while not all(p.link_up for p in farm.printers.values()) or (bridge is not None and not bridge.connected):
            if time.perf_counter() > deadline:
                down = [p.name for p in farm.printers.values() if not p.link_up]
                errors = {p.last_error for p in farm.printers.values() if p.last_error}
                raise RunFailedError(
                    f"not connected within 60 s: printers {down}, broker {bridge.connected if bridge else '-'}; "
                    f"errors {sorted(errors)[:3]}"
                )
            await asyncio.sleep(0.05)  # polling a condition (all connected), bounded
        await asyncio.sleep(WARMUP_S)
        readings_before = sum(p.readings for p in farm.printers.values())
        published_before = bridge.published if bridge is not None else 0
        window_start = time.time()
        meter = Meter()
        await asyncio.sleep(spec["seconds"])
        wall, cpu = meter.stop()
        window_end = time.time()
        readings = sum(p.readings for p in farm.printers.values()) - readings_before
        published = (bridge.published if bridge is not None else 0) - published_before
        reconnects = sum(p.connections - 1 for p in farm.printers.values())
    finally:
        for task in tasks:
            task.cancel()
        # Bounded: a cleanup that hangs must fail the run with a reason, not the orchestrator's timeout.
        _, pending = await asyncio.wait(tasks, timeout=15)
        if pending:
            for task in pending:
                task.print_stack(file=sys.stderr)
            print("farm cleanup did not end within 15 s (stacks above)", file=sys.stderr, flush=True)
            os._exit(3)  # the loop cannot be closed with these tasks in it: end the process, not the run's patience
    return {
        "printers": len(specs),
        "wall_s": wall,
        "cpu_s": cpu,
        **meter.split(),
        "readings": readings,
        "published": published,
        "telemetry_dropped": bridge.telemetry_dropped if bridge is not None else 0,
        "events_lost": bridge.events_lost if bridge is not None else 0,
        "reconnects": reconnects,
        "window_start": window_start,
        "window_end": window_end,
    }


# ------------------------------------------------------------------------------------------------ entry point

ASYNC_TASKS = {
    ("roundtrips", "marlin_aio"): marlin_round_trips,
    ("roundtrips", "floor"): floor_round_trips,
    ("roundtrips", "lean_floor"): lean_floor_round_trips,
    ("polling", "lean_floor"): lean_floor_polling,
    ("polling", "floor"): floor_polling,
    ("polling", "marlin_aio"): marlin_polling,
    ("streaming", "marlin_aio"): marlin_streaming,
    ("memory", "marlin_aio"): marlin_memory,
    ("many", "marlin_aio"): marlin_many,
    ("many", "lean_floor"): lean_floor_many,
    ("farm", "bridge"): farm_run,
    ("farm", "plain"): farm_run,
}
THREAD_TASKS = {
    ("roundtrips", "pyserial"): pyserial_round_trips,
    ("roundtrips", "printcore"): printcore_round_trips,
    ("polling", "printcore"): printcore_polling,
    ("streaming", "printcore"): printcore_streaming,
}


def run(spec: Result) -> Result:
    """Run one spec ({"scenario", "client", "url", ...}) and return its measurements."""
    key = (spec["scenario"], spec["client"])
    if key in ASYNC_TASKS:
        return asyncio.run(ASYNC_TASKS[key](spec))
    if key in THREAD_TASKS:
        return THREAD_TASKS[key](spec)
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
