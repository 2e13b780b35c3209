"""`marlin-temp watch --sim` in a real terminal: tmux runs it, we read the screen, press q, and check the terminal."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator

import pytest

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (.ci/run installs it)")


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


@pytest.fixture
def tmux() -> Iterator[Tmux]:
    server = Tmux()
    yield server
    subprocess.run(["tmux", "-L", server.socket, "kill-server"], capture_output=True, check=False)


def test_watch_shows_the_live_view_updates_and_restores_the_terminal_on_q(tmux: Tmux) -> None:
    command = (
        f"printf 'BEFORE-WATCH\\n'; {sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.3; "
        "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive: a dead pane is redrawn and loses its history
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", command)

    first = tmux.wait_for(lambda s: "heater" in s and "polls/s" in s and "•" in s, "the live view")
    assert "hotend" in first and "bed" in first
    assert "°C" in first
    assert "-60 s" in first and "now" in first
    assert "BEFORE-WATCH" not in first  # the view has the (alternate) screen to itself

    # The chart grows as readings arrive: the curve gets longer with each redraw.
    later = tmux.wait_for(lambda s: s.count("•") > first.count("•") + 5, "the chart to update")
    assert "polls/s" in later

    tmux.run("send-keys", "-t", "w", "q")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
    assert "MARLIN-EXIT=0" in after
    assert "BEFORE-WATCH" in after  # the screen from before is back
    assert "heater" not in after  # and the live view is gone from it
    assert "watched" in after and "readings" in after
