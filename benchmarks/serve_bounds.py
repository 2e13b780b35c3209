"""`python -m benchmarks.serve_bounds`: what a client piling up unread `history` answers costs the other clients.

    python -m benchmarks.serve_bounds            # 4 rounds of 4 s each way, after 30 s of history (~1.5 min)
    python -m benchmarks.serve_bounds --quick    # 2 rounds of 2 s, after 10 s of history

One simulated printer (`marlin-sim`, unpaced, on a pty) held by a `marlin-temp serve` that polls it every 10 ms
until its history holds that many seconds of readings (3,000 after 30 s: a full `history` answer, ~450 KB). Then a
polite client (`ServedPrinter`) makes M105 round trips back to back, in rounds alternating alone and beside a
hostile client that asks for the whole history again and again and reads none of the answers (issue 33: on main
24a5b95 that held the polite client's round trips for 10 s). Printed: the polite client's median round trip each
way and their ratio, how many history requests the hostile client got written, and one `history` answer's time
asked alone (the median of 20). The load average is printed with it: on a shared machine, compare the ratio.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path

import marlin_aio
from benchmarks._procs import UNPACED, simulator
from benchmarks.serve import serving


def _history_request(number: int) -> bytes:
    # By hand, as a program in any language would: the service's wire format is JSON-RPC 2.0, one object a line.
    request = {"jsonrpc": "2.0", "id": number, "method": "history", "params": {"printer": "bench", "seconds": 3600}}
    return json.dumps(request).encode() + b"\n"


async def _round_trips_s(printer: marlin_aio.Printer, seconds: float) -> list[float]:
    times = []
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        start = time.perf_counter()
        await printer.send("M105")
        times.append(time.perf_counter() - start)
    return times


@contextlib.asynccontextmanager
async def _flooding(socket: str) -> AsyncIterator[list[int]]:
    """The hostile client, for the block: history requests written as fast as the service takes them."""
    written = [0]
    request = _history_request(1)

    async def flood() -> None:
        while True:  # reconnecting if the service lets it go
            reader, writer = await asyncio.open_unix_connection(socket)
            writer.transport.pause_reading()  # type: ignore[attr-defined]  # reads no answer
            with contextlib.suppress(OSError):
                while True:
                    writer.write(request * 20)
                    written[0] += 20
                    await writer.drain()
            writer.close()
            del reader

    task = asyncio.create_task(flood())
    try:
        yield written
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def _history_s(socket: str) -> tuple[float, int]:
    """One `history` answer's time asked alone (median of 20) and its size in bytes."""
    reader, writer = await asyncio.open_unix_connection(socket, limit=4 << 20)
    times = []
    size = 0
    try:
        for number in range(20):
            start = time.perf_counter()
            writer.write(_history_request(number))
            while '"id"' not in (line := (await reader.readline()).decode()):
                pass  # a notification (`alive`)
            times.append(time.perf_counter() - start)
            size = len(line)
    finally:
        writer.close()
    return statistics.median(times), size


async def measure(rounds: int, seconds: float, history_s: float) -> None:
    with simulator(UNPACED) as sim, tempfile.TemporaryDirectory() as folder:
        async with serving({"bench": sim.url}, Path(folder), "--interval", "0.01", "--no-log") as (socket, _):
            await asyncio.sleep(history_s)  # the service gathers its history: what is measured is its size
            one_s, size = await _history_s(socket)
            alone: list[float] = []
            beside: list[float] = []
            asked = 0
            async with marlin_aio.connect(f"serve:bench@{socket}") as printer:
                for _ in range(rounds):
                    alone += await _round_trips_s(printer, seconds)
                    async with _flooding(socket) as written:
                        beside += await _round_trips_s(printer, seconds)
                        asked += written[0]
    alone_ms, beside_ms = statistics.median(alone) * 1e3, statistics.median(beside) * 1e3
    print(f"load {os.getloadavg()[0]:.2f}; history answer alone: {one_s * 1e3:.2f} ms, {size:,} bytes")
    print(f"polite M105 round trip, median: alone {alone_ms:.3f} ms ({len(alone):,} samples), beside the hostile")
    print(f"client {beside_ms:.3f} ms ({len(beside):,} samples): {beside_ms / alone_ms:.2f}x; it asked {asked:,} times")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.serve_bounds", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="2 rounds of 2 s, after 10 s of history")
    args = parser.parse_args(argv)
    if args.quick:
        asyncio.run(measure(2, 2.0, 10.0))
    else:
        asyncio.run(measure(4, 4.0, 30.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
