"""`python -m benchmarks.noisy`: print times on a noisy link, send-ahead against ping-pong, in the same run.

    python -m benchmarks.noisy                       # 4,001 G1 lines at 0.5% and 2% corruption, seeds 7, 8, 9
    python -m benchmarks.noisy --lines 2000 --corrupt 0.01 --seeds 1 2

The simulated printer runs on a real pseudo-terminal at 250000 baud (`marlin-sim --baud 250000
--motion-time-scale 0 --corrupt-rx R --seed S`), so the client's whole serial stack is timed. For each corruption
rate and seed it prints both modes' outcome (DONE with every line run once in order, or the error), wall time and
resends, and the ratio of the two times. A send-ahead run can stop with "ran out of place": the firmware ran the
tail of a line its flush cut in two, which no host can prevent with lines on the wire (see README, Printing a file).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import time
from dataclasses import dataclass

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, serve_pty


def line(index: int) -> str:
    """Line `index` of the file: a short move, as in the streaming tests."""
    return f"G1 X{(index * 0.5) % 200:.3f} Y{(index * 0.37) % 200:.3f} E{index * 0.0123:.4f}"


@dataclass(frozen=True)
class Run:
    """One print's outcome."""

    state: str
    exact: bool
    seconds: float
    resends: int
    error: str


async def print_once(lines: int, corrupt: float, seed: int, *, send_ahead: bool) -> Run:
    """Print `lines` lines on a fresh simulated printer with this corruption rate and seed."""
    # An instant command loop, as when the figures in BENCHMARKS.md were measured (the wire bounds these runs).
    config = SimulatorConfig(motion_time_scale=0, seed=seed, command_time_s=0.0, report_time_s=0.0)
    async with serve_pty(config, Faults(corrupt_rx_ratio=corrupt), baud_rate=250_000) as server:
        async with marlin_aio.connect(server.url) as printer:
            started = time.perf_counter()
            error = ""
            try:
                progress = await printer.print_file((line(i) + "\n" for i in range(lines)), send_ahead=send_ahead)
                state, resends = progress.state.name, progress.resends
            except marlin_aio.MarlinError as exc:
                state, resends, error = "FAILED", printer.stats.resend_requests, str(exc)
            seconds = time.perf_counter() - started
        executed = [c for c in server.printer.executed if c.startswith("G1 ")]
    return Run(state, executed == [line(i) for i in range(lines)], seconds, resends, error)


async def main_async(lines: int, rates: list[float], seeds: list[int]) -> None:
    """Run every rate and seed in both modes and print one row each."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"noisy link: {lines} G1 lines at 250000 baud on a pty (load average {load:.2f} at the start)")
    print(f"  {'corrupt':>7} {'seed':>4}  {'ping-pong':<28} {'send-ahead':<28} {'ratio':>6}")
    for rate in rates:
        for seed in seeds:
            pong = await print_once(lines, rate, seed, send_ahead=False)
            ahead = await print_once(lines, rate, seed, send_ahead=True)
            ratio = pong.seconds / ahead.seconds if ahead.state == "DONE" and pong.state == "DONE" else float("nan")
            print(f"  {rate:>7.3%} {seed:>4}  {_cell(pong):<28} {_cell(ahead):<28} {ratio:>5.2f}x")
            for name, run in (("ping-pong", pong), ("send-ahead", ahead)):
                if run.error:
                    print(f"      {name}: {run.error[:160]}")


def _cell(run: Run) -> str:
    exact = "exact" if run.exact else "NOT exact"
    return f"{run.state} {exact} {run.seconds:5.2f} s {run.resends:>3} rs"


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments and run."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.noisy", description=__doc__.split("\n")[0])
    parser.add_argument("--lines", type=int, default=4001)
    parser.add_argument("--corrupt", type=float, nargs="+", default=[0.005, 0.02])
    parser.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    arguments = parser.parse_args(argv)
    asyncio.run(main_async(arguments.lines, arguments.corrupt, arguments.seeds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
