"""`python -m benchmarks`: run the benchmark suite, write the results file, print the tables.

    python -m benchmarks                      # everything, 3 runs each (about 13 minutes on 2 cores)
    python -m benchmarks --quick              # smoke run: ~3 s per run, 1 run each, a 20 MB "big" file
    python -m benchmarks --only polling       # one scenario (repeatable); others in the results file are kept
    python -m benchmarks --report             # print the tables of the results file again, run nothing
    python -m benchmarks --profile DIR        # also profile marlin_aio's runs (py-spy, else cProfile) into DIR

printcore (Printrun) is a baseline only when it is installed: `pip install --no-deps printrun`.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import math
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks._procs import BenchmarkRunError
from benchmarks._profile import py_spy
from benchmarks._report import machine_info, render
from benchmarks._scenarios import SCENARIOS, Settings, run_scenario

_HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = _HERE / "results.json"
QUICK_OUTPUT = _HERE / "results-quick.json"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="marlin_aio against its baselines on the simulated printer, side by side: ratios, not times.",
    )
    parser.add_argument("--quick", action="store_true", help="short smoke run (~3 s per run, 1 run each)")
    parser.add_argument(
        "--only",
        action="append",
        choices=sorted(SCENARIOS),
        metavar="NAME",
        help=f"run only this scenario (repeatable): {', '.join(SCENARIOS)}",
    )
    parser.add_argument("--runs", type=int, help="runs per contender (default 3, or 1 with --quick)")
    parser.add_argument(
        "--output",
        type=Path,
        help=f"results file (default {DEFAULT_OUTPUT.relative_to(_HERE.parent)}, "
        f"or {QUICK_OUTPUT.relative_to(_HERE.parent)} with --quick)",
    )
    parser.add_argument("--report", action="store_true", help="print the tables of the results file; run nothing")
    parser.add_argument(
        "--profile",
        type=Path,
        metavar="DIR",
        help="profile marlin_aio's runs into DIR with py-spy (pip install py-spy) or else cProfile; "
        "results then go to DIR/results.json",
    )
    return parser


def _load(path: Path) -> dict[str, Any] | None:
    try:
        with path.open() as file:
            loaded: dict[str, Any] = json.load(file)
            return loaded
    except (OSError, ValueError):
        return None


def _finite(value: Any) -> Any:
    """The results with NaN (a ratio to a baseline that did not run) as null, so the file is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def main(argv: Sequence[str] | None = None) -> int:
    arguments = _parser().parse_args(argv)
    output: Path = arguments.output or (QUICK_OUTPUT if arguments.quick else DEFAULT_OUTPUT)
    if arguments.profile is not None and arguments.output is None:
        output = arguments.profile / "results.json"  # profiled runs are slower: keep them out of the results
    if arguments.report:
        results = _load(output)
        if results is None:
            print(f"no results in {output}: run python -m benchmarks first", file=sys.stderr)
            return 1
        print(render(results))
        return 0
    runs = arguments.runs if arguments.runs is not None else (1 if arguments.quick else 3)
    if runs < 1:
        print("--runs must be at least 1", file=sys.stderr)
        return 2
    printcore = importlib.util.find_spec("printrun") is not None
    uvloop = importlib.util.find_spec("uvloop") is not None
    if not uvloop:
        print("uvloop not installed: pip install -e '.[dev]' (its rows are skipped)", file=sys.stderr)
    if not printcore:
        print("printcore not installed: pip install --no-deps printrun (its baseline is skipped)", file=sys.stderr)
    if arguments.profile is not None:
        how = "py-spy" if py_spy() is not None else "cProfile (py-spy not installed: pip install py-spy)"
        print(f"profiling marlin_aio's runs with {how} into {arguments.profile}", file=sys.stderr)
    names = [name for name in SCENARIOS if not arguments.only or name in arguments.only]
    # Scenarios not run now are kept from the previous results, each with its own date and machine.
    previous = _load(output) if arguments.only else None
    scenarios: dict[str, Any] = dict(previous["scenarios"]) if previous and not previous.get("quick") else {}
    machine = machine_info()
    with tempfile.TemporaryDirectory(prefix="marlin-aio-bench-") as workdir:
        settings = Settings(
            quick=arguments.quick,
            runs=runs,
            workdir=Path(workdir),
            printcore=printcore,
            profile_dir=arguments.profile,
            uvloop=uvloop,
        )
        try:
            for name in names:
                scenarios[name] = run_scenario(name, settings) | {"machine": machine}
        except BenchmarkRunError as exc:
            print(f"benchmark failed: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print("interrupted; every simulator was stopped", file=sys.stderr)
            return 130
    ordered = {name: scenarios[name] for name in SCENARIOS if name in scenarios}
    results = {"command": "python -m benchmarks", "quick": arguments.quick, "machine": machine, "scenarios": ordered}
    output.parent.mkdir(parents=True, exist_ok=True)
    with output.open("w") as file:
        json.dump(_finite(results), file, indent=1, allow_nan=False)
        file.write("\n")
    print(render({**results, "scenarios": {name: ordered[name] for name in names}}))
    with contextlib.suppress(ValueError):
        print(f"\nresults: {output.relative_to(Path.cwd())}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
