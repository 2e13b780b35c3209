"""The seeded fault campaign (issue 8), in simulated time: the protocol core against the simulated firmware.

Every run prints a generated file with 100 Hz polling and a user's commands going on, under a seeded mix of
corrupted lines, lost oks and noise, in send-ahead and ping-pong, with and without ADVANCED_OK; see
`marlin_aio.simulator._campaign` for what each run checks.
"""

from __future__ import annotations

from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.printjob import PrintState
from marlin_aio.simulator._campaign import CampaignResult, Scenario, run_print

SEEDS = range(200)
CORRUPT = (0.0, 0.005, 0.02, 0.05)
DROP_OK = (0.0, 0.005, 0.01, 0.02)
NOISE = (0.0, 0.01, 0.05)


def scenarios() -> list[Scenario]:
    """200 seeds; each seed picks its mode (send-ahead or ping-pong, plain ok or ADVANCED_OK, 50 seeds each) and
    its fault mix; one seed in ten also resets the board or silences it mid-print, which must end the print with
    a diagnosis."""
    runs = []
    for seed in SEEDS:
        mishap = seed % 10
        runs.append(
            Scenario(
                seed=seed,
                send_ahead=seed % 2 == 0,
                advanced_ok=(seed // 2) % 2 == 1,
                corrupt=CORRUPT[(seed // 4) % 4],
                drop_ok=DROP_OK[(seed // 16) % 4],
                noise=NOISE[seed % 3],
                reset_at_line=150 + seed if mishap == 3 else None,
                silent_at_line=150 + seed if mishap == 7 else None,
            )
        )
    return runs


@pytest.fixture(scope="module")
def campaign() -> list[CampaignResult]:
    return [run_print(scenario) for scenario in scenarios()]


def test_the_campaign_covers_every_mode_and_mishap(campaign: list[CampaignResult]) -> None:
    modes = Counter((r.scenario.send_ahead, r.scenario.advanced_ok) for r in campaign)
    assert len(campaign) == 200 and set(modes.values()) == {50}
    assert sum(r.scenario.reset_at_line is not None for r in campaign) == 20
    assert sum(r.scenario.silent_at_line is not None for r in campaign) == 20
    # Polls and user commands ran alongside every print.
    assert all(r.poll_replies > 0 and r.user_replies > 0 for r in campaign)


def test_every_line_runs_exactly_once_in_order_or_the_print_stops_with_a_diagnosis(
    campaign: list[CampaignResult],
) -> None:
    assert [(r.scenario, problem) for r in campaign for problem in r.problems] == []
    for result in campaign:
        assert result.executed_in_order
        if result.scenario.reset_at_line is not None:
            assert result.state is PrintState.FAILED and result.error is not None and "reset" in result.error
        elif result.scenario.silent_at_line is not None:
            assert result.state is PrintState.FAILED and result.error is not None and "stalled" in result.error
        else:
            assert result.state is PrintState.DONE and result.lines_executed == result.scenario.lines


def test_no_reply_is_ever_handed_to_the_wrong_command_and_nothing_hangs(campaign: list[CampaignResult]) -> None:
    assert sum(r.wrong_replies for r in campaign) == 0
    assert sum(r.unfinished_commands for r in campaign) == 0
    assert sum(r.user_replies for r in campaign) > 1000  # the check had plenty to look at


@pytest.mark.parametrize("send_ahead", [True, False])
def test_a_reset_mid_print_stops_it_with_a_diagnosis_and_replays_nothing(send_ahead: bool) -> None:
    result = run_print(Scenario(seed=3, send_ahead=send_ahead, reset_at_line=200, drop_ok=0.01, corrupt=0.01))
    assert result.state is PrintState.FAILED
    assert result.error is not None and "reset" in result.error and "print stopped" in result.error
    assert result.executed_in_order
    assert result.unfinished_commands == 0


@pytest.mark.parametrize("send_ahead", [True, False])
def test_a_printer_that_falls_silent_stalls_the_print_with_a_diagnosis(send_ahead: bool) -> None:
    result = run_print(Scenario(seed=4, send_ahead=send_ahead, silent_at_line=200))
    assert result.state is PrintState.FAILED
    assert result.error is not None and "stalled" in result.error
    assert result.executed_in_order
    assert result.unfinished_commands == 0
    # Everything the user had queued failed at once instead of one timeout after another.
    assert result.end_s < 200 * 0.01 + 3 * result.scenario.timeout_s
    assert Counter(result.failures_by_kind)["CommandTimeoutError"] > 0


@pytest.mark.xfail(
    strict=True,
    reason="issue 8 defect 7 is open: with bytes arriving as a UART delivers them, a line error makes the firmware "
    "throw away its receive buffer while the rest of a line is still on the wire; that rest arrives as an unnumbered "
    "fragment, which Marlin runs (a second execution) or answers with 'Unknown command' and an ok that answers "
    "nothing. Ping-pong never has a line on the wire behind a rejected one.",
)
def test_send_ahead_survives_a_noisy_link_when_bytes_arrive_as_a_uart_delivers_them() -> None:
    results = [
        run_print(Scenario(seed=seed, corrupt=0.02, chunk_bytes=16, poll_interval_s=None, user_interval_s=None))
        for seed in range(20)
    ]
    assert [r.problems for r in results if r.problems] == []


def test_ping_pong_survives_a_noisy_link_when_bytes_arrive_as_a_uart_delivers_them() -> None:
    results = [
        run_print(Scenario(seed=seed, corrupt=0.02, send_ahead=False, chunk_bytes=16, user_interval_s=None))
        for seed in range(20)
    ]
    assert [r.problems for r in results if r.problems] == []
    assert all(r.state is PrintState.DONE for r in results)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    send_ahead=st.booleans(),
    advanced_ok=st.booleans(),
    corrupt=st.floats(0.0, 0.08),
    drop_ok=st.floats(0.0, 0.05),
    noise=st.floats(0.0, 0.08),
    user_interval_s=st.sampled_from([0.003, 0.02, 0.05]),
)
def test_any_mix_of_lost_oks_noise_and_resends_hands_no_command_another_ones_reply(
    seed: int,
    send_ahead: bool,
    advanced_ok: bool,
    corrupt: float,
    drop_ok: float,
    noise: float,
    user_interval_s: float,
) -> None:
    result = run_print(
        Scenario(
            seed=seed,
            lines=80,
            send_ahead=send_ahead,
            advanced_ok=advanced_ok,
            corrupt=corrupt,
            drop_ok=drop_ok,
            noise=noise,
            user_interval_s=user_interval_s,
        )
    )
    assert result.wrong_replies == 0, result.problems
    assert result.executed_in_order
    assert result.unfinished_commands == 0
    # A print that stops must say why; that every noisy link carries the print is the next test's (defect 2).
    assert result.state is PrintState.DONE or result.error


@pytest.mark.xfail(
    strict=True,
    reason="issue 8 defect 2 is open: with heavy corruption and lost oks, a rejection of the line after one whose ok "
    "was lost is taken for a stale one, and the print stalls while the printer waits for that line",
)
def test_a_lost_ok_followed_by_a_line_rejected_twice_does_not_stall_the_print() -> None:
    # Found by the property above (hypothesis): seed 188388, send-ahead, plain oks.
    result = run_print(Scenario(seed=188388, lines=80, corrupt=0.0625, drop_ok=0.03125, noise=0.0))
    assert result.state is PrintState.DONE, result.error
