"""Streaming efficiency in simulated time: the protocol's share of the wire, which the machine's load cannot move.

    python -m benchmarks.streaming_sim            # about 5 s; also part of `python -m benchmarks --only streaming`

The real-time streaming rows (`--only streaming`) run a client process against `marlin-sim` on a pty: what a user
sees, but a busy machine stretches them (the issue measured 76.5 % to 90.6 % for the same code). Here the same
17,000-line file goes to the same simulated Marlin (250000 baud both ways, 1 ms of command loop a line, instant
moves, a 4-command buffer and a 128-byte receive buffer) over the in-memory link, on a `SimulatedTimeLoop`: the
clock moves only by the wire's and the firmware's own times, never by the host's CPU, so the figure is the
protocol's alone and the same on every run and every machine.

The share is the limit that binds over the time the stream took, from its first line to its end: the numbered
wire (every byte the client wrote, at 25,000 B/s) or the firmware's loop (1 ms a line), whichever is longer. The
whole-file check before the first line is left out: it runs in a thread, and while a thread works even this
loop's clock moves with real time.
"""

from __future__ import annotations

import asyncio
import sys
import tempfile
from pathlib import Path
from typing import Any

import marlin_aio
from benchmarks._files import write_moves
from marlin_aio.simulator import SimulatorConfig, run_in_simulated_time, serve_memory

Json = dict[str, Any]

BAUD = 250_000
WIRE_BYTES_PER_S = BAUD / 10
COMMAND_TIME_S = 0.001


async def _stream(path: Path, send_ahead: bool) -> Json:
    loop = asyncio.get_running_loop()
    config = SimulatorConfig(motion_time_scale=0.0, command_time_s=COMMAND_TIME_S, record_limit=None)
    async with serve_memory(config, baud_rate=BAUD) as server, marlin_aio.connect(server.url) as printer:
        # Timed from the first line: the file's check before it runs in a thread, during which even this loop's
        # clock moves with real time (`SimulatedTimeLoop`), so it is left out of a figure that load must not move.
        handle = await printer.start_print(path, send_ahead=send_ahead)
        started = loop.time()
        progress = await handle.wait()
        seconds = loop.time() - started
    return {
        "seconds": seconds,
        "lines": progress.lines_acked,
        "wire_bytes": progress.bytes_acked,
        "resends": progress.resends,
        "state": progress.state.value,
    }


def measure(lines: int, workdir: Path) -> Json:
    """Stream `lines` moves with send-ahead and with ping-pong in simulated time; the shares of the binding limit."""
    path = workdir / f"moves-{lines}.gcode"
    write_moves(path, lines)
    results: Json = {}
    for mode, send_ahead in (("send_ahead", True), ("ping_pong", False)):
        run = run_in_simulated_time(_stream(path, send_ahead))
        wire_limit_s = run["wire_bytes"] / WIRE_BYTES_PER_S
        loop_limit_s = run["lines"] * COMMAND_TIME_S
        run["numbered_wire_limit_s"] = wire_limit_s
        run["firmware_loop_limit_s"] = loop_limit_s
        run["share_of_binding_limit"] = max(wire_limit_s, loop_limit_s) / run["seconds"]
        run["complete"] = run["lines"] == lines and run["state"] == "done"
        results[mode] = run
    return results


def render(results: Json) -> list[str]:
    """The table of one measurement."""
    rows = [
        f"| {mode} | {r['seconds']:.3f} | {r['numbered_wire_limit_s']:.3f} | {r['firmware_loop_limit_s']:.3f} | "
        f"{r['share_of_binding_limit'] * 100:.2f} % | {'yes' if r['complete'] else '**no**'} |"
        for mode, r in results.items()
    ]
    return [
        "| mode | simulated s | numbered wire limit s | firmware loop limit s | share of the binding limit | every "
        "line, done |",
        "| --- | ---: | ---: | ---: | ---: | --- |",
        *rows,
    ]


def main() -> int:
    """Measure and print."""
    lines = 2_000 if "--quick" in sys.argv else 17_000
    with tempfile.TemporaryDirectory() as folder:
        results = measure(lines, Path(folder))
    print("\n".join(render(results)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
