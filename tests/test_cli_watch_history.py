"""`watch`'s history, window key, footer latency and short terminals (issue 25).

The history (`common.history`) and the model are pure: fed readings by hand on a clock of their own, hours of them
in a fraction of a second. The footer's latency is checked end to end against the simulated printer on a pty (the
poller's round trips must reach it, and a slow G28 must age out of its "worst"), driven by the readings as they
arrive, never by a sleep. Short terminals are rendered with a recording Console at 120 to 30 columns and 12 rows,
and once for real under tmux at 30x12.
"""

from __future__ import annotations

import math
import sys
import tracemalloc

import pytest
from conftest import until
from rich.console import Console
from test_cli_watch_keys import MODELS, heating, reading, sized
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.common.chart import Curve, time_chart
from marlin_temp.common.history import BUCKETS, RAW_LIMIT, HeaterHistory
from marlin_temp.common.model import Notice, WatchControls, WatchModel
from marlin_temp.common.render import chart, watch_view, window_label
from marlin_temp.main import app
from marlin_temp.watch.command import _Baseline, _update_link_stats

# ------------------------------------------------------------------------------------------- history (pure)


def test_history_memory_stays_bounded_over_hours() -> None:
    history = HeaterHistory()
    # A burst at 1,000 Hz: the raw minute is capped by count too, whatever the poll rate.
    for step in range(30_000):
        history.add(step / 1000, 200.0, 200.0)
    assert len(history.raw) == RAW_LIMIT
    # Then 13 hours at 2 Hz (the buckets' count does not depend on the rate; hours of 100 Hz take minutes to feed).
    start = 30.0
    for step in range(13 * 3600 * 2):
        history.add(start + step / 2, 200.0 + math.sin(step / 100), 200.0)
    assert history.bucket_counts() == (BUCKETS, BUCKETS, BUCKETS)
    assert len(history.raw) <= 60 * 2 + 1
    # Another hour: every structure is full, so memory no longer grows.
    now = start + 13 * 3600
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for step in range(3600 * 2):
            history.add(now + step / 2, 200.0 + math.sin(step / 100), 200.0)
        after, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert history.bucket_counts() == (BUCKETS, BUCKETS, BUCKETS)
    assert after - before < 32_000


def test_the_model_keeps_the_last_minute_as_read_at_100_hz() -> None:
    model = WatchModel()
    for step in range(3 * 60 * 100):  # three minutes at 100 Hz
        model.add(reading("T:200.00 /200.00 B:60.00 /60.00 @:0 B@:0", step / 100))
    for key in ("T", "B"):
        series = model.series[key]
        assert 5_990 <= len(series) <= 6_001  # the last 60 s, trimmed as it goes
        assert series[0][0] >= model.latest_time - 60.0
        assert model.history[key].bucket_counts()[0] <= 180


def _spiked(hours: float, spike_at_s: float) -> HeaterHistory:
    """`hours` of 10 Hz readings at 200 C with one reading of 250 C at `spike_at_s`."""
    history = HeaterHistory()
    for step in range(int(hours * 3600 * 10)):
        time_s = step / 10
        history.add(time_s, 250.0 if abs(time_s - spike_at_s) < 0.05 else 200.0, 200.0)
    return history


def test_downsampled_history_keeps_each_columns_range_and_stays_small() -> None:
    history = _spiked(2.0, spike_at_s=3600.0)  # a spike half an hour into the last hour
    now = 2 * 3600 - 0.1
    hour = history.points(now - 3600, column_s=3600 / 73)  # an 80-column chart: 10 s buckets
    assert max(actual for _, actual, _ in hour) == 250.0  # one reading, and the hour's chart still shows it
    assert min(actual for _, actual, _ in hour) == 200.0
    assert len(hour) <= 2 * 360 + 8  # a bucket is two points: 360 of 10 s, and the open buckets
    assert min(time_s for time_s, _, _ in hour) < now - 3600 + 10  # it reaches back to the window's start
    minute = history.points(now - 60, column_s=60 / 73)  # as read: 10 Hz for 60 s
    assert 595 <= len(minute) <= 601 and all(actual == 200.0 for _, actual, _ in minute)
    # A column narrower than the 10 s buckets asks for the 1 s ones, which hold only 12 min: the hour falls back
    # to the 10 s buckets rather than leave most of it empty.
    wide = history.points(now - 3600, column_s=5.0)
    assert min(time_s for time_s, _, _ in wide) < now - 3600 + 10
    # The newest points come from the open buckets: the chart runs up to the latest reading.
    assert max(time_s for time_s, _, _ in hour) == now


def test_a_column_of_the_chart_spans_the_range_of_its_readings() -> None:
    # Two readings in one column, 100 C and 200 C: the column is drawn from one to the other, not only the last.
    curve = Curve("hotend", [(0.0, 100.0, None), (0.1, 200.0, None), (30.0, 150.0, None)])
    console = Console(record=True, width=60)
    console.print(time_chart([curve], 0.0, 60.0, width=60, height=9, time_labels=("", "")))
    rows = [line[6:] for line in console.export_text().splitlines() if line[5:6] in ("┤", "│")]
    first_column = [row[0] for row in rows]
    assert first_column.count("•") >= 3  # 100 to 200 C over rows of 37.5 C
    assert sum(row.count("•") for row in rows) == first_column.count("•") + 1  # the one reading at 30 s


# ------------------------------------------------------------------------------------------- the window key


def test_w_steps_the_window_and_the_time_axis_says_it() -> None:
    model = WatchModel()
    controls = WatchControls()
    for step in range(600):
        model.add(reading("T:200.00 /200.00 B:60.00 /60.00 @:0 B@:0", step))  # ten minutes at 1 Hz

    def axis() -> str:
        console = Console(record=True, width=80)
        console.print(chart(model, width=80, height=6))
        return next(line for line in console.export_text().splitlines() if line.rstrip().endswith("now"))

    assert axis().split()[0] == "-60"
    seen = []
    for _ in range(4):
        assert controls.press("w", model) is None  # nothing to send
        seen.append((model.window_s, axis().split()[0:2]))
    assert seen == [
        (600.0, ["-10", "min"]),
        (3600.0, ["-1", "h"]),
        (21600.0, ["-6", "h"]),
        (60.0, ["-60", "s"]),
    ]
    assert "w window" in controls.help_items()


def test_a_window_of_its_own_joins_the_cycle() -> None:
    model = WatchModel(window_s=120)
    assert [model.next_window() for _ in range(5)] == [600.0, 3600.0, 21600.0, 60.0, 120.0]
    assert [window_label(s) for s in (5, 90, 120, 5400, 7200, 43200)] == [
        "5 s",
        "90 s",
        "2 min",
        "90 min",
        "2 h",
        "12 h",
    ]


def test_the_window_option_says_its_default_and_refuses_too_long_a_window() -> None:
    runner = CliRunner()
    text = " ".join(runner.invoke(app, ["watch", "--help"], env={"COLUMNS": "120"}).output.replace("│", " ").split())
    assert "default 60" in text and "1 min, 10 min, 1 h and 6 h" in text
    result = runner.invoke(app, ["watch", "--sim", "--window", "50000"])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "--window" in lines[0] and "43200" in lines[0]


def test_a_long_window_shows_the_heat_up_of_hours_ago() -> None:
    model = WatchModel()
    for step in range(2 * 3600):  # two hours at 1 Hz: heated from 25 C at the start, held at 200 since
        actual = min(25.0 + step, 200.0)
        model.add(reading(f"T:{actual:.2f} /200.00 B:25.00 /0.00 @:0 B@:0", step))
    model.window_s = 6 * 3600.0

    def dots_below_150(text: str) -> int:
        rows = [line for line in text.splitlines() if line[5:6] in ("┤", "│")]
        # The rows of 0 to 125 C (the top of 300 in 12 rows: each 27 C), less the bed's row at 25 C.
        return sum(row[6:].count("•") for row in rows[6:-2])

    console = Console(record=True, width=80)
    console.print(chart(model, width=80, height=12))
    assert dots_below_150(console.export_text()) >= 3  # the heat-up two hours ago
    model.window_s = 60.0
    console = Console(record=True, width=80)
    console.print(chart(model, width=80, height=12))
    assert dots_below_150(console.export_text()) == 0  # the last minute: held at 200


# ------------------------------------------------------------------------------------------- footer latency


def test_the_worst_latency_ages_out_and_the_median_is_of_the_polls() -> None:
    model = WatchModel()
    model.add_latency(0.5, 0.002)  # the handshake
    model.add_latency(5.0, 6.0)  # a G28: 6 s
    for step in range(5, 2000):  # polls at 100 Hz, 0.3 ms each
        time_s = step / 100 + 0.0001
        model.add(reading("T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0", time_s))
        model.add_latency(time_s, 0.0003)
        if time_s < 14.9:
            assert model.link().latency_worst_ms == 6000.0
    link = model.link()
    assert link.latency_worst_ms == pytest.approx(0.3)  # 15 s after the G28 it is no longer the worst
    assert link.latency_median_ms == pytest.approx(0.3)
    console = Console(record=True, width=120)
    console.print(watch_view(model, "/dev/pts/1", "Marlin", width=120))
    assert "latency 0.3 ms median  worst 0.3 ms of 10 s" in console.export_text()


def test_without_new_round_trips_the_old_ones_age_out_by_the_readings() -> None:
    model = WatchModel()
    model.add_latency(1.0, 6.0)
    model.add(reading("T:25.00 /0.00 @:0", 5.0))
    assert model.link().latency_worst_ms == 6000.0
    model.add(reading("T:25.00 /0.00 @:0", 12.0))
    assert model.link().latency_median_ms is None and model.link().latency_worst_ms is None


async def test_the_footer_latency_follows_the_polls_and_a_g28_ages_out() -> None:
    # G28 takes 40 simulated s: 2 real s at 20x, far longer than any poll however loaded the machine.
    async with (
        serve_pty(SimulatorConfig(homing_s=40.0), time_scale=20) as sim,
        marlin_aio.connect(sim.url, timeout_s=10.0) as printer,
    ):
        model = WatchModel(latency_window_s=1.0)  # a shorter window: the test waits for it to pass
        stop = printer.on_reading(model.add)
        baseline = _Baseline.now(model, printer)
        handshake = len(printer.round_trips)
        since = _update_link_stats(model, printer, 0.0, baseline)
        async with printer.poll_temperatures(0.01):
            # The polls' round trips reach the footer (they never did: the link recorded only awaited commands).
            await until(lambda: len(printer.round_trips) >= handshake + 30, "the polls' round trips", limit_s=20)
            since = _update_link_stats(model, printer, since, baseline)
            assert model.link().latency_median_ms is not None
            reply = await printer.send("G28")
            assert reply.latency_s > 1.0
            since = _update_link_stats(model, printer, since, baseline)
            worst = model.link().latency_worst_ms
            assert worst is not None and worst >= reply.latency_s * 1000 - 1e-6
            # The window passes by the readings' clock: from then on the G28 is no longer the worst.
            await until(lambda: (model.latest_time or 0.0) > reply.answered_s + 1.5, "readings a window after the G28")
            since = _update_link_stats(model, printer, since, baseline)
        stop()
        link = model.link()
        assert link.latency_worst_ms is not None and link.latency_worst_ms < reply.latency_s * 1000 / 2
        assert link.latency_median_ms is not None and link.latency_median_ms < reply.latency_s * 1000 / 2


# ------------------------------------------------------------------------------------------- short terminals


@pytest.mark.parametrize("width", [120, 80, 60, 40, 30])
@pytest.mark.parametrize("name", list(MODELS))
def test_at_12_rows_the_keys_stay_on_screen(width: int, name: str) -> None:
    model = heating(MODELS[name])

    def rendered(controls: WatchControls) -> list[str]:
        console = Console(record=True, width=width, height=12)
        console.print(
            watch_view(model, "/dev/pts/12 (simulated)", "Marlin 2.1.2.4", width=width, height=12, controls=controls)
        )
        lines = console.export_text().splitlines()
        assert len(lines) <= 11  # one line spare for the cursor
        assert all(len(line.rstrip()) <= width for line in lines)
        return lines

    plain = rendered(WatchControls())
    assert "q quit" in plain[-1]
    assert any(line.startswith("hotend") or line.strip().startswith("hotend ") for line in plain)
    # A long reply: the keys stay, with the reply's last line.
    replied = WatchControls()
    replied.notice = Notice("> M503", tuple(f"echo: line {n}" for n in range(8)))
    lines = rendered(replied)
    assert "q quit" in lines[-1] and any("echo: line 7" in line for line in lines)
    # An input line open: it and how to leave it stay.
    typing = WatchControls()
    typing.press("h", model)
    typing.press("2", model)
    lines = rendered(typing)
    assert any("hotend target °C: 2" in line for line in lines) and "Esc cancels" in " ".join(lines)


def test_the_keys_shorten_to_one_line_rather_than_go() -> None:
    model = heating(MODELS["two hotends, bed, chamber"])  # a table of 6 lines at 30 columns
    controls = WatchControls()
    controls.notice = Notice("> M114", ("X:0.00 Y:0.00 Z:0.00", "ok"))
    console = Console(record=True, width=30, height=12)
    console.print(watch_view(model, "/dev/pts/12", "Marlin 2.1.2.4", width=30, height=12, controls=controls))
    lines = console.export_text().splitlines()
    assert len(lines) <= 11
    assert lines[-1].strip() == "h b o +/- 1-4 f : w  q quit"  # 1-4: the four default presets
    assert "> M114" in lines


@needs_tmux
def test_at_30x12_the_live_view_shows_its_keys_and_q_quits(tmux: Tmux) -> None:
    command = (
        f"{sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.3; echo MARLIN-EXIT=$?; sleep 600"
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "30", "-y", "12", sized(command, 30, 12))
    screen = tmux.wait_for(lambda s: "q quit" in s and "polls/s" in s, "the live view with its keys")
    shown = [line for line in screen.splitlines() if line.strip()]
    assert "q quit" in shown[-1] and "h hotend" in screen  # at the bottom, whole
    assert any(line.startswith("hotend") for line in shown) and any(line.startswith("bed") for line in shown)
    assert all(len(line.rstrip()) <= 30 for line in shown)
    tmux.run("send-keys", "-t", "w", "q")
    assert "MARLIN-EXIT=0" in tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")


@needs_tmux
def test_w_changes_the_window_in_the_live_view(tmux: Tmux) -> None:
    command = (
        f"{sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.3; echo MARLIN-EXIT=$?; sleep 600"
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "80", "-y", "30", sized(command, 80, 30))
    tmux.wait_for(lambda s: "-60 s" in s and "w window" in s, "the one-minute chart")
    tmux.run("send-keys", "-t", "w", "w")
    tmux.wait_for(lambda s: "-10 min" in s, "the ten-minute chart")
    tmux.run("send-keys", "-t", "w", "q")
    assert "MARLIN-EXIT=0" in tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
