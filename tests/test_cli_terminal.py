"""`marlin-temp watch --sim` in a real terminal: tmux runs it, we read the screen, press q, and check the terminal."""

from __future__ import annotations

import sys

from tmux_screen import Tmux, needs_tmux

pytestmark = needs_tmux


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
