"""The README's example script, run as a user would: it starts the simulator in its own process on a pty."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).parent.parent / "examples" / "poll_and_heat.py"


def test_poll_and_heat_accounts_for_every_command() -> None:
    result = subprocess.run(
        [sys.executable, str(EXAMPLE), "--seconds", "3", "--time-scale", "60", "--hotend", "150", "--bed", "50"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "every command accounted for" in result.stdout
    assert "targets reached" in result.stdout
    assert "0 failed" in result.stdout
    polls = next(line for line in result.stdout.splitlines() if line.startswith("readings:"))
    # Not a timing goal (that is the benchmarks' job): just that polling ran and produced readings.
    assert int(polls.split("(")[1].split()[0]) > 50
