"""The contender under test: marlin_aio, through its public API only, as an application would call it.

- `marlin_round_trips`: `send("M105")` back to back.
- `marlin_polling`: `poll_temperatures(interval_s)`, each reading read through `on_reading()`.
- `marlin_streaming`: `print_file()`, with and without send-ahead, at 250000 baud.
- `marlin_memory`: RSS sampled while `start_print()` streams a small and a big file.
- `marlin_many`: N `Printer`s on one event loop, each polled by its own `poll_temperatures()`.
- `farm_run`: `marlin-temp farm`'s own code (`marlin_aio.farm`), with or without its MQTT bridge.

Only a marlin_aio worker imports this module (see `_worker.py`). The farm's modules (and through them aiomqtt)
are imported by `farm_run` alone, so the single-printer runs do not pay for them.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import time
from pathlib import Path

import marlin_aio
from benchmarks._measure import (
    ANSWER_TIMEOUT_S,
    WARMUP_S,
    LagProbe,
    Meter,
    Result,
    RunFailedError,
    current_rss_bytes,
    interval_stats,
    many_summary,
    peak_rss_bytes,
    profiled,
    ru_maxrss_bytes,
    time_round_trips,
)

__all__ = ["farm_run", "marlin_many", "marlin_memory", "marlin_polling", "marlin_round_trips", "marlin_streaming"]


async def marlin_round_trips(spec: Result) -> Result:
    async with marlin_aio.connect(spec["url"]) as printer:
        with profiled(spec.get("profile")):
            return await time_round_trips(lambda: printer.send("M105"), spec["seconds"])


async def marlin_polling(spec: Result) -> Result:
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
    async with marlin_aio.connect(spec["url"], timeout_s=ANSWER_TIMEOUT_S * 2) as printer:
        with profiled(spec.get("profile")):
            # The stream is timed from its first line, as printcore's is (its file is parsed before its clock
            # starts): the whole-file check before it (`start_print`) is kept apart, as `check_s`.
            checking = time.perf_counter()
            handle = await printer.start_print(Path(spec["path"]), send_ahead=spec["send_ahead"])
            check_s = time.perf_counter() - checking
            meter = Meter()
            progress = await handle.wait()
            wall, cpu = meter.stop()
    return {
        "seconds": wall,
        "check_s": check_s,
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


async def marlin_many(spec: Result) -> Result:
    """N printers on one event loop, each polled by its own `poll_temperatures()`, each reading read through
    `on_reading()`."""
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


async def farm_run(spec: Result) -> Result:
    """`marlin-temp farm`'s own code, N printers polled at `interval_s`: with the MQTT bridge publishing each
    printer's telemetry at `rate_hz` to the broker on `broker_port` (client "bridge"), or without it ("plain")."""
    if spec.get("orjson") is False:
        sys.modules["orjson"] = None  # type: ignore[assignment]  # `import orjson` fails: the bridge uses json
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
            BridgeSettings(rate_hz=spec["rate_hz"], discovery=False, batch_telemetry=spec.get("batched", True)),
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
        with profiled(spec.get("profile")):
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
