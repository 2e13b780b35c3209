"""Run any range of the fault campaign's seeds, core and client, in simulated time, across processes.

    python -m marlin_aio.simulator.sweep --core 0-19999 --client 0-9999 [--jobs N] [--no-actions] [--trace]

`--core` runs `_campaign.run_print(mixed_scenario(seed))` (the sans-I/O core against the simulated Marlin), and
`--client` runs `_clientcampaign.run_client_print(mixed_scenario(seed))` (the whole asyncio client on the memory
link), for each seed of its ranges (`0-999`, `5`, `1,7,976-980`). The runs are shared by `--jobs` processes (the
CPU count unless given); each seed is the same run whatever the process, so a failing seed printed here fails the
same way in a test. Every failing seed is printed as it is found, with its problems (and, with `--trace`, the
client link's last lines), then one summary line per campaign: runs, how the prints ended, failing seeds, the wall
time and the load average. `--no-actions` draws the scenarios as they were before the emergency writes and the
runout joined the draw (`mixed_scenario(seed, actions=False)`): the seeds found then are the same runs again.

The exit status is 1 if any seed failed, 0 otherwise.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing
import os
import sys
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

from marlin_aio.simulator._campaign import mixed_scenario, run_print

__all__ = ["SeedOutcome", "main", "parse_seeds", "run_seed", "sweep"]

#: How often a long sweep says how far it got (on stderr), so that one stopped early still tells what it ran.
PROGRESS_RUNS = 500

#: Seeds handed to a process at a time: large enough that the hand-over costs nothing beside the runs (a core run
#: takes about 30 ms, a client run about 60), small enough that the processes finish together.
CHUNK_SEEDS = 16


@dataclass(frozen=True, slots=True)
class SeedOutcome:
    """What one seed's run came to: how its print ended, and each broken invariant in words (none: it held)."""

    campaign: str  # "core" or "client"
    seed: int
    state: str  # the print's end: done, failed, cancelled (or running, for a run that never ended)
    problems: tuple[str, ...]
    error: str | None  # the print's error, for a print that failed
    blind_spot: bool
    trace: str = ""  # the client link's last lines, for a client run that failed


def parse_seeds(text: str) -> list[int]:
    """The seeds of `text`: comma-separated seeds and inclusive ranges (`0-999`, `5`, `1,7,976-980`).

    Raises:
        ValueError: a part is neither a seed nor a range of seeds, or a range runs backwards.
    """
    seeds: list[int] = []
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        try:
            low = int(first)
            high = int(last) if dash else low
        except ValueError:
            raise ValueError(f"{part.strip()!r} is not a seed or a range of seeds (write 5 or 0-999)") from None
        if high < low or low < 0:
            raise ValueError(f"the range {part.strip()!r} is empty: write the lower seed first (0-999)")
        seeds.extend(range(low, high + 1))
    return seeds


def run_seed(job: tuple[str, int, bool]) -> SeedOutcome:
    """Run one seed: `(campaign, seed, actions)`, the campaign being "core" or "client".

    Raises:
        ValueError: the campaign is neither "core" nor "client".
    """
    campaign, seed, actions = job
    scenario = mixed_scenario(seed, actions=actions)
    trace = ""
    if campaign == "core":
        result = run_print(scenario)
    elif campaign == "client":
        # Imported here: the client campaign imports the whole client, which a core sweep does not need.
        from marlin_aio.simulator._clientcampaign import run_client_print

        run = run_client_print(scenario)
        result, trace = run.result, run.trace
    else:
        raise ValueError(f"no campaign {campaign!r}: core or client")
    return SeedOutcome(
        campaign, seed, result.state.value, tuple(result.problems), result.error, result.blind_spot, trace
    )


def _quiet() -> None:
    # Every recovery is logged; thousands of runs' worth would only slow the processes down.
    logging.getLogger("marlin_aio").setLevel(logging.CRITICAL)


def sweep(campaign: str, seeds: Sequence[int], *, jobs: int, actions: bool = True) -> Iterator[SeedOutcome]:
    """Run `seeds` of `campaign` ("core" or "client") across `jobs` processes; yield each outcome in seed order.

    Raises:
        ValueError: the campaign is neither "core" nor "client" (from the first run).
    """
    work = [(campaign, seed, actions) for seed in seeds]
    if jobs <= 1:
        _quiet()
        yield from map(run_seed, work)
        return
    # `spawn` would import the package again in every process; `fork` shares it, and no thread runs here yet.
    context = multiprocessing.get_context("fork" if sys.platform == "linux" else None)
    with context.Pool(jobs, initializer=_quiet) as pool:
        yield from pool.imap(run_seed, work, chunksize=CHUNK_SEEDS)


def _report(
    campaign: str, label: str, outcomes: Iterable[SeedOutcome], *, with_trace: bool, started: float, total: int = 0
) -> list[SeedOutcome]:
    """Print each failing seed as it comes (and every `PROGRESS_RUNS` runs, on stderr, how far it got, of `total`),
    then the summary line; return the failing outcomes."""
    states: Counter[str] = Counter()
    failing: list[SeedOutcome] = []
    runs = blind = 0
    for outcome in outcomes:
        runs += 1
        states[outcome.state] += 1
        blind += outcome.blind_spot
        if outcome.problems:
            failing.append(outcome)
            print(f"{campaign} seed {outcome.seed} ({outcome.state}): " + "; ".join(outcome.problems), flush=True)
            if with_trace and outcome.trace:
                print(outcome.trace, flush=True)
        if runs % PROGRESS_RUNS == 0 and runs < total:
            print(
                f"{campaign}: {runs} of {total} runs, through seed {outcome.seed}; {len(failing)} failing seeds; "
                f"{time.monotonic() - started:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    elapsed = time.monotonic() - started
    load = " ".join(f"{value:.2f}" for value in os.getloadavg())
    ended = ", ".join(f"{count} {state}" for state, count in sorted(states.items()))
    print(
        f"{campaign} seeds {label}: {runs} runs ({ended}), {blind} in the blind spot; {len(failing)} failing seeds; "
        f"{elapsed:.0f} s wall; load average {load}",
        flush=True,
    )
    return failing


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (see the module's docstring); returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m marlin_aio.simulator.sweep",
        description="Run seeds of the fault campaign in simulated time and print the failing ones.",
    )
    parser.add_argument("--core", metavar="SEEDS", help="core campaign seeds: 0-19999, 5, 1,7,976-980")
    parser.add_argument("--client", metavar="SEEDS", help="client campaign seeds, as --core")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="processes (default: the CPU count)")
    parser.add_argument(
        "--actions",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="draw emergency writes and runouts (CI's draw; --no-actions: the draw before they joined)",
    )
    parser.add_argument("--trace", action="store_true", help="print a failing client run's last lines of the link")
    args = parser.parse_args(argv)
    if args.core is None and args.client is None:
        parser.error("give --core SEEDS, --client SEEDS or both")
    if args.jobs < 1:
        parser.error("--jobs must be 1 or more")
    failed = False
    for campaign, label in (("core", args.core), ("client", args.client)):
        if label is None:
            continue
        try:
            seeds = parse_seeds(label)
        except ValueError as error:
            parser.error(f"--{campaign}: {error}")
        started = time.monotonic()
        outcomes = sweep(campaign, seeds, jobs=args.jobs, actions=args.actions)
        failing = _report(campaign, label, outcomes, with_trace=args.trace, started=started, total=len(seeds))
        failed |= bool(failing)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
