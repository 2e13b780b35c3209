"""A lost answer costs a moment, never the queue: outside a print as inside, for one caller and for many.

Through the real client (`marlin_aio.connect`) on the in-memory link to the simulated Marlin at 250000 baud, in
simulated time (`run_in_simulated_time`), so a 5 s timeout costs nothing and the times asserted are the link's own.
"""

from __future__ import annotations

import asyncio

import pytest

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, run_in_simulated_time, serve_memory

BAUD = 250_000


async def _lost_g4(max_in_flight: int) -> tuple[list[marlin_aio.Reply | BaseException], float, list[str]]:
    faults = Faults()
    config = SimulatorConfig(motion_time_scale=0.0)
    async with serve_memory(config, faults, baud_rate=BAUD) as server:
        async with marlin_aio.connect(server.url, max_in_flight=max_in_flight) as printer:
            loop = asyncio.get_running_loop()
            faults.drop_ok_codes = frozenset({"G4"})  # G4 runs, prints nothing, and its ok never comes
            start = loop.time()
            texts = ["G4 P200", *(f"M118 U{k}" for k in range(5))]
            outcomes = await asyncio.gather(*(printer.send(t, timeout_s=5.0) for t in texts), return_exceptions=True)
            took = loop.time() - start
        return outcomes, took, [t for t in server.printer.executed if t.startswith(("G4", "M118"))]


@pytest.mark.parametrize("max_in_flight", [1, 8], ids=["ping-pong", "send-ahead"])
def test_a_lost_ok_outside_a_print_costs_a_moment_and_the_queue_goes_on(max_in_flight: int) -> None:
    # Before: nothing was written until G4's 5 s timeout; then every M118 failed unsent ("the printer stopped
    # answering") though the printer was well.
    outcomes, took, ran = run_in_simulated_time(_lost_g4(max_in_flight))
    g4, *users = outcomes
    assert isinstance(g4, marlin_aio.Reply) and g4.ok_lost  # it ran: a retry would run it twice
    for k, reply in enumerate(users):
        assert isinstance(reply, marlin_aio.Reply) and reply.lines == (f"U{k}",) and not reply.ok_lost
    assert ran == ["G4 P200", *(f"M118 U{k}" for k in range(5))]  # each once, in order
    assert took < 1.0  # the dwell's 0.2 s and a few round trips, not the 5 s timeout


async def _many(drop_ok: float, count: int) -> tuple[list[marlin_aio.Reply | BaseException], int]:
    faults = Faults()
    config = SimulatorConfig(motion_time_scale=0.0, seed=7)
    async with (
        serve_memory(config, faults, baud_rate=BAUD) as server,
        marlin_aio.connect(server.url, max_in_flight=8) as printer,
    ):
        faults.drop_ok_ratio = drop_ok
        outcomes = await asyncio.gather(
            *(printer.send(f"M118 U{k}", timeout_s=5.0) for k in range(count)), return_exceptions=True
        )
        return outcomes, printer.stats.lost_oks


def test_many_callers_on_a_link_that_loses_oks_each_get_their_own_answer_and_none_times_out() -> None:
    # Before: commands that ran waited their whole 5 s and failed with CommandTimeoutError, inviting a retry.
    outcomes, lost = run_in_simulated_time(_many(0.02, 300))
    assert lost > 0
    failures = [o for o in outcomes if not isinstance(o, marlin_aio.Reply)]
    assert failures == []
    for k, reply in enumerate(outcomes):
        assert isinstance(reply, marlin_aio.Reply)
        # Its own echo, or (its ok lost and the lines behind it unprovable) none: never another caller's.
        assert reply.lines in ((f"U{k}",), ()), (k, reply)
