"""Start-up: what a program pays before it does anything, against what Python and the design card's libraries cost.

    python -m benchmarks.startup          # also a scenario of the suite: python -m benchmarks --only startup

Each command runs as a fresh process, the commands interleaved round by round (so a busy moment hits them all),
30 rounds (10 with --quick); a command's figure is its fastest run, the one least disturbed by the machine (the
median is kept beside it). The rows:

- `python -c pass`: the interpreter alone, the unit of the issue's targets.
- `import asyncio`: what any asyncio client pays.
- `import marlin_aio`: the package's names resolve on first use (`marlin_aio._lazy`), so this is nearly free;
- `import marlin_aio; marlin_aio.connect`: what a program that connects pays (the client and the core, no
  simulator, no service client).
- `typer floor --help`: a two-command typer app with rich help (`benchmarks/_typer_floor.py`), the floor of any
  CLI built with typer and rich;
- `marlin-temp --help`.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

Json = dict[str, Any]

_HERE = Path(__file__).resolve().parent

COMMANDS: dict[str, list[str]] = {
    "pass": [sys.executable, "-c", "pass"],
    "import asyncio": [sys.executable, "-c", "import asyncio"],
    "import marlin_aio": [sys.executable, "-c", "import marlin_aio"],
    "import marlin_aio + connect": [sys.executable, "-c", "import marlin_aio; marlin_aio.connect"],
    "typer floor --help": [sys.executable, str(_HERE / "_typer_floor.py"), "--help"],
    "marlin-temp --help": [sys.executable, "-m", "marlin_temp", "--help"],
}


def measure(rounds: int, log: Callable[[str], None]) -> Json:
    """Time every command `rounds` times, interleaved; the fastest and the median of each, in seconds."""
    env = dict(os.environ, COLUMNS="100", NO_COLOR="1")
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    load_before = os.getloadavg()[0]
    for _ in range(rounds):
        for name, command in COMMANDS.items():
            started = time.perf_counter()
            subprocess.run(command, env=env, stdout=subprocess.DEVNULL, check=True, cwd=_HERE.parent)
            times[name].append(time.perf_counter() - started)
    load = (load_before + os.getloadavg()[0]) / 2
    best = {name: min(values) for name, values in times.items()}
    median = {name: statistics.median(values) for name, values in times.items()}
    log("  " + ", ".join(f"{name} {best[name] * 1e3:.0f} ms" for name in COMMANDS) + f" (load {load:.2f})")
    ratios = {
        "import_vs_pass": best["import marlin_aio"] / best["pass"],
        "connect_vs_pass": best["import marlin_aio + connect"] / best["pass"],
        "connect_vs_asyncio": best["import marlin_aio + connect"] / best["import asyncio"],
        "help_vs_pass": best["marlin-temp --help"] / best["pass"],
        "help_vs_typer_floor": best["marlin-temp --help"] / best["typer floor --help"],
        "typer_floor_vs_pass": best["typer floor --help"] / best["pass"],
    }

    def target(name: str, goal: str, measured: float, limit: float) -> Json:
        return {"name": name, "goal": goal, "measured": measured, "unit": "x", "met": measured <= limit}

    targets = [
        target("import marlin_aio vs python -c pass", "<= 3x", ratios["import_vs_pass"], 3.0),
        target("marlin-temp --help vs python -c pass", "<= 6x", ratios["help_vs_pass"], 6.0),
        target("marlin-temp --help vs the typer floor", "<= 1.3x", ratios["help_vs_typer_floor"], 1.3),
    ]
    return {
        "settings": {"rounds": rounds, "python": sys.version.split()[0]},
        "best_s": best,
        "median_s": median,
        "ratios": ratios,
        "load": load,
        "targets": targets,
    }


def render(entry: Json) -> list[str]:
    """The table of one measurement."""
    best, median, ratios = entry["best_s"], entry["median_s"], entry["ratios"]
    rows = [
        f"| `{name}` | {best[name] * 1e3:.1f} ms | {median[name] * 1e3:.1f} ms | {best[name] / best['pass']:.2f}x |"
        for name in best
    ]
    return [
        "| command | fastest | median | / `python -c pass` |",
        "| --- | ---: | ---: | ---: |",
        *rows,
        "",
        f"`marlin-temp --help` is {ratios['help_vs_typer_floor']:.2f}x the typer floor, which is itself "
        f"{ratios['typer_floor_vs_pass']:.2f}x `python -c pass`; connecting costs "
        f"{ratios['connect_vs_asyncio']:.2f}x `import asyncio`. {entry['settings']['rounds']} rounds, "
        f"load {entry['load']:.2f}.",
    ]


def main() -> None:
    """Measure and print the table."""
    quick = "--quick" in sys.argv
    entry = measure(10 if quick else 30, lambda text: print(text, file=sys.stderr))
    print("\n".join(render(entry)))
    for t in entry["targets"]:
        print(f"{t['name']}: {t['measured']:.2f}x (goal {t['goal']}): {'met' if t['met'] else 'NOT met'}")


if __name__ == "__main__":
    main()
