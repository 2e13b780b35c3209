"""`--profile DIR`: sample marlin_aio's runs with py-spy (or cProfile without it) and sum the stacks up as text.

py-spy samples from outside the process, so the client runs unmodified; it still slows it a little, so a profiled
invocation's numbers are for reading the profile, not for the tables. `--format raw` writes collapsed stacks
(`frame;frame;frame count` per line, what flamegraph tools read), and `summarise()` turns them into the share of
samples each function is on the stack for (inclusive) and at the top of it (self).
"""

from __future__ import annotations

import collections
import shutil
import sys
from pathlib import Path

__all__ = ["py_spy", "summarise", "wrapper"]


def py_spy() -> str | None:
    """The py-spy executable: next to this Python (a venv) or on PATH; None when not installed."""
    beside = Path(sys.executable).parent / "py-spy"
    if beside.exists():
        return str(beside)
    return shutil.which("py-spy")


def wrapper(output: Path) -> list[str]:
    """The command prefix that records a py-spy profile of the worker into `output` (collapsed stacks).

    Raises:
        RuntimeError: py-spy is not installed.
    """
    executable = py_spy()
    if executable is None:
        raise RuntimeError("py-spy is not installed: pip install py-spy")
    return [executable, "record", "--rate", "1000", "--format", "raw", "--output", str(output), "--"]


def _function(frame: str) -> str:
    # "Printer._on_data (marlin_aio/client.py:681)" -> "Printer._on_data (marlin_aio/client.py)"
    name, _, where = frame.partition(" (")
    return f"{name} ({where.rsplit(':', 1)[0]})" if where else name


# Frames at the top of the stack while a thread waits: the event loop in select/epoll (for the printer's answer
# or the next timer) and an idle executor thread. py-spy does not always recognise these as idle.
WAITING = frozenset(
    {
        "EpollSelector.select (selectors.py)",
        "SelectSelector.select (selectors.py)",
        "PollSelector.select (selectors.py)",
        "_worker (concurrent/futures/thread.py)",
    }
)


def summarise(raw: Path, top: int = 40) -> str:
    """The functions most often on the stack (inclusive) and at its top (self), as shares of the busy samples.

    Busy samples are those not waiting (see `WAITING`); the waiting share is given once at the head.
    """
    inclusive: collections.Counter[str] = collections.Counter()
    leaf: collections.Counter[str] = collections.Counter()
    total = waiting = 0
    for line in raw.read_text().splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        count = int(count_text)
        total += count
        frames = [_function(frame) for frame in stack.split(";")]
        if frames[-1] in WAITING:
            waiting += count
            continue
        leaf[frames[-1]] += count
        for name in set(frames):
            inclusive[name] += count
    busy = total - waiting
    if busy == 0:
        return f"{raw.name}: no busy samples ({total} in all)\n"
    lines = [
        f"{raw.name}: {total} samples, {waiting / total:.1%} waiting (select/epoll, idle threads); "
        f"shares below are of the {busy} busy samples",
        "",
        "inclusive (on the stack):",
    ]
    lines += [f"  {n / busy:6.1%}  {name}" for name, n in inclusive.most_common(top)]
    lines += ["", "self (top of the stack):"]
    lines += [f"  {n / busy:6.1%}  {name}" for name, n in leaf.most_common(top // 2)]
    return "\n".join(lines) + "\n"
