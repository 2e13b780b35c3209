"""`python -m benchmarks.soak`: the fault campaign of the test suite over thousands of seeds, with the counts.

    python -m benchmarks.soak                    # 4,000 seeds on every core (about 4 minutes on 2 cores)
    python -m benchmarks.soak --seeds 20000 --first 100000 --jobs 2

Each seed draws its own run from the fault space the tests cover (send-ahead or ping-pong, plain ok or ADVANCED_OK,
up to 5% corrupted lines, 2% lost oks, 5% noise, bytes arriving 16 at a time, 100 Hz polls, a user's commands, and
one run in ten a reset or a silence), runs a 400-line print in simulated time (`marlin_aio.simulator._campaign`)
and checks the invariants of issue 8. It prints how many runs were exact, how many stopped with which diagnosis,
and every broken invariant with the seed that shows it (rerun one with `--seeds 1 --first SEED`). Exit status 1
when any invariant broke.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

from marlin_aio import PrintState
from marlin_aio.simulator import Scenario, run_print


@dataclass(frozen=True)
class Outcome:
    """What one seed's run came to, small enough to send between processes."""

    seed: int
    mode: str
    outcome: str  # "exact", "stopped: reset", "stopped: silence", "stopped: cut line ran", or "BROKEN"
    wrong_replies: int
    unfinished: int
    user_replies: int
    poll_replies: int
    lines: int
    problems: tuple[str, ...]


def scenario_for(seed: int) -> Scenario:
    """The run a seed stands for: its mode and fault mix drawn from the seed itself."""
    draw = random.Random(seed)
    mishap = draw.random()
    start = draw.randrange(50, 350)
    return Scenario(
        seed=seed,
        send_ahead=draw.random() < 0.5,
        advanced_ok=draw.random() < 0.5,
        corrupt=draw.choice((0.0, draw.uniform(0.0, 0.05))),
        drop_ok=draw.choice((0.0, draw.uniform(0.0, 0.02))),
        noise=draw.choice((0.0, draw.uniform(0.0, 0.05))),
        user_interval_s=draw.choice((0.003, 0.02, 0.05)),
        reset_at_line=start if mishap < 0.05 else None,
        silent_at_line=start if 0.05 <= mishap < 0.10 else None,
        chunk_bytes=16,
    )


def run_seed(seed: int) -> Outcome:
    """Run one seed and sum it up."""
    scenario = scenario_for(seed)
    result = run_print(scenario)
    mode = ("send-ahead" if scenario.send_ahead else "ping-pong") + (
        ", ADVANCED_OK" if scenario.advanced_ok else ", plain ok"
    )
    if result.problems:
        outcome = "BROKEN"
    elif result.state is PrintState.DONE:
        outcome = "exact"
    elif result.fragments_run:
        outcome = "stopped: cut line ran"
    elif scenario.reset_at_line is not None:
        outcome = "stopped: reset"
    else:
        outcome = "stopped: silence"
    return Outcome(
        seed,
        mode,
        outcome,
        result.wrong_replies,
        result.unfinished_commands,
        result.user_replies,
        result.poll_replies,
        result.lines_executed,
        tuple(result.problems),
    )


def main(argv: list[str] | None = None) -> int:
    """Run the soak and print the counts; return the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.soak", description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=4000, help="how many seeds (default 4000)")
    parser.add_argument("--first", type=int, default=1_000_000, help="the first seed (default 1000000)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    arguments = parser.parse_args(argv)
    if arguments.seeds < 1 or arguments.jobs < 1:
        parser.error("--seeds and --jobs must be at least 1")
    seeds = range(arguments.first, arguments.first + arguments.seeds)
    started = time.perf_counter()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    outcomes: list[Outcome] = []
    with ProcessPoolExecutor(arguments.jobs) as pool:
        for done, outcome in enumerate(pool.map(run_seed, seeds, chunksize=16), start=1):
            outcomes.append(outcome)
            if done % 500 == 0:
                print(f"  {done} of {len(seeds)} seeds", file=sys.stderr, flush=True)
    elapsed = time.perf_counter() - started

    by_mode: dict[str, Counter[str]] = {}
    for outcome in outcomes:
        by_mode.setdefault(outcome.mode, Counter())[outcome.outcome] += 1
    print(
        f"soak: {len(outcomes)} seeds from {arguments.first}, {arguments.jobs} processes, {elapsed:.0f} s "
        f"(load average {load:.2f} at the start)"
    )
    print(f"  {'mode':<26} {'runs':>6} {'exact':>6} {'reset':>6} {'silence':>8} {'cut ran':>8} {'BROKEN':>7}")
    for mode in sorted(by_mode):
        counts = by_mode[mode]
        print(
            f"  {mode:<26} {sum(counts.values()):>6} {counts['exact']:>6} {counts['stopped: reset']:>6} "
            f"{counts['stopped: silence']:>8} {counts['stopped: cut line ran']:>8} {counts['BROKEN']:>7}"
        )
    print(
        f"  lines run {sum(o.lines for o in outcomes):,}; user replies checked "
        f"{sum(o.user_replies for o in outcomes):,}, polls {sum(o.poll_replies for o in outcomes):,}; "
        f"wrong replies {sum(o.wrong_replies for o in outcomes)}; commands never finished "
        f"{sum(o.unfinished for o in outcomes)}"
    )
    broken = [o for o in outcomes if o.outcome == "BROKEN"]
    for outcome in broken[:20]:
        print(f"  BROKEN seed {outcome.seed} ({outcome.mode}): {outcome.problems[0]}")
    return 1 if broken else 0


if __name__ == "__main__":
    raise SystemExit(main())
