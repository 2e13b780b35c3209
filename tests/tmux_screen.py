"""A real terminal for the tests: a tmux server of the test's own, whose screen the test reads (the `tmux` fixture
of conftest.py gives one and kills it after the test)."""

from __future__ import annotations

import shutil
import subprocess
import time
import uuid
from collections.abc import Callable

import pytest

#: Marks a test that needs tmux (.ci/run installs it).
needs_tmux = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (.ci/run installs it)")


class Tmux:
    """One tmux server of our own (its own socket), so nothing else on the machine is touched."""

    def __init__(self) -> None:
        self.socket = f"marlin-test-{uuid.uuid4().hex[:8]}"

    def run(self, *args: str) -> str:
        done = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True, text=True, check=True)
        return done.stdout

    def screen(self) -> str:
        return self.run("capture-pane", "-p", "-t", "w")

    def wait_for(self, condition: Callable[[str], bool], what: str, limit_s: float = 60.0) -> str:
        """Poll the screen until `condition` holds (bounded); the screen is the only signal a terminal gives."""
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            screen = self.screen()
            if condition(screen):
                return screen
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what}; the screen shows:\n{self.screen()}")
