"""The firmware's own requests (issue 25): `//action:` lines, prompts and `paused for user`.

The tracker (`HostRequests`) is fed events with no I/O at all; the client's part runs end to end against the
simulated printer on a real pty, which raises each request the way Marlin does (a filament runout at line N, M600,
a prompt, `//action:cancel` / `resume` / `disconnect`). Waits are on events or `until` (a bounded poll of a
condition), never fixed sleeps.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import pytest
from conftest import until

import marlin_aio
from marlin_aio.protocol import HostRequest, HostRequests, Prompt, classify_line
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_pty

LINES = 40


def feed(tracker: HostRequests, *lines: str) -> list[HostRequest]:
    requests = [tracker.receive(classify_line(line)) for line in lines]
    return [request for request in requests if request is not None]


# ------------------------------------------------------------------------------------------- the tracker, no I/O


def test_a_prompt_is_built_line_by_line_and_shown_whole() -> None:
    tracker = HostRequests()
    requests = feed(
        tracker,
        "//action:prompt_end",
        "//action:prompt_begin Paused",
        "//action:prompt_button PurgeMore",
        "//action:prompt_choice Continue",  # the older name of a button
    )
    assert requests == []
    assert tracker.prompt is None  # not shown yet
    (shown,) = feed(tracker, "//action:prompt_show")
    assert shown == HostRequest("prompt", "Paused", Prompt("Paused", ("PurgeMore", "Continue"), shown=True))
    assert tracker.prompt == Prompt("Paused", ("PurgeMore", "Continue"), shown=True)
    assert feed(tracker, "//action:prompt_end") == [HostRequest("prompt_closed")]
    assert tracker.prompt is None
    assert feed(tracker, "//action:prompt_end") == []  # nothing was open


def test_pause_requests_carry_their_reason_and_are_remembered() -> None:
    tracker = HostRequests()
    (paused,) = feed(tracker, "//action:paused filament_runout 0")
    assert paused.reason == "printer asked: filament_runout 0"
    assert tracker.last == paused
    feed(tracker, "//action:notification Heating done")  # told, but not a request to remember
    assert tracker.last == paused
    (cancel,) = feed(tracker, "//action:cancel")
    assert cancel.reason == "printer asked: cancel"
    assert tracker.last == cancel


def test_paused_for_user_starts_once_and_ends_with_an_ok() -> None:
    tracker = HostRequests()
    assert feed(tracker, "echo:busy: paused for user", "echo:busy: paused for user") == [
        HostRequest("paused_for_user", "paused for user")
    ]
    assert tracker.waiting_for_user
    feed(tracker, "ok")
    assert not tracker.waiting_for_user
    feed(tracker, "busy: paused for user", "echo:busy: processing")  # a bare busy line, then another wait
    assert not tracker.waiting_for_user


# ------------------------------------------------------------------------------------------- end to end


def gcode(lines: int = LINES) -> list[str]:
    return [f"G1 X{index % 100} Y{index % 50} F3000\n" for index in range(lines)]


def moves(sim: SimulatorServer) -> list[str]:
    return [command for command in sim.printer.executed if command.startswith("G1 ")]


@pytest.fixture
async def runout_sim() -> AsyncIterator[SimulatorServer]:
    """A printer whose filament runs out just before print line 10 (its moves take no time)."""
    async with serve_pty(SimulatorConfig(motion_time_scale=0), Faults(runout_at_line=10), time_scale=20) as server:
        yield server


async def test_a_runout_pauses_the_print_with_its_reason_and_the_answer_resumes_it(
    runout_sim: SimulatorServer,
) -> None:
    requests: list[HostRequest] = []
    async with marlin_aio.connect(runout_sim.url, timeout_s=5.0) as printer:
        printer.on_host_request(requests.append)
        handle = await printer.start_print(gcode())
        await until(lambda: printer.prompt is not None and printer.prompt.message == "Load Filament", "the prompt")
        assert printer.prompt is not None
        assert printer.prompt.buttons == ("Continue",)
        progress = handle.progress
        assert progress.state is marlin_aio.PrintState.PAUSED
        assert progress.paused_by == "printer asked: filament_runout 0"
        await until(lambda: printer.waiting_for_user, "busy: paused for user")
        assert not handle.finished
        await printer.answer_prompt(0)
        assert printer.prompt is None
        final = await asyncio.wait_for(handle.wait(), 30)
    assert final.state is marlin_aio.PrintState.DONE
    assert final.paused_by is None
    assert moves(runout_sim) == [line.strip() for line in gcode()]  # every line once, in order
    assert runout_sim.printer.prompt_answers == [0]
    actions = [request.action for request in requests]
    assert actions.index("paused") < actions.index("paused_for_user") < actions.index("resumed")
    prompts = [request.prompt.message for request in requests if request.prompt is not None]
    assert prompts == ["FilamentRunout T0", "Load Filament"]  # Marlin's runout prompt, then M600's


async def test_answer_prompt_checks_the_button_before_anything_is_written(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url, timeout_s=5.0) as printer:
        with pytest.raises(ValueError, match="no prompt is open"):
            await printer.answer_prompt(0)
        pty_sim.printer.open_prompt(pty_sim.now(), "Door open", ["Continue", "Cancel"])
        pty_sim.poke()
        await until(lambda: printer.prompt is not None, "the prompt")
        assert printer.prompt == Prompt("Door open", ("Continue", "Cancel"), shown=True)
        last_sent = printer.trace.last_sent
        for wrong in (2, -1, True):
            with pytest.raises(ValueError, match="has no button"):
                await printer.answer_prompt(wrong)
        assert printer.trace.last_sent == last_sent  # nothing was written
        assert printer.prompt is not None  # still open: nothing was answered
        await printer.answer_prompt(1)
        await until(lambda: pty_sim.printer.prompt_answers == [1], "the answer at the printer")
        assert pty_sim.printer.prompt is None


async def test_the_printer_cancelling_ends_the_print_as_cancelled(runout_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(runout_sim.url, timeout_s=5.0) as printer:
        handle = await printer.start_print(gcode())
        await until(lambda: printer.waiting_for_user, "the runout's M600")
        runout_sim.printer.host_action(runout_sim.now(), "cancel")
        runout_sim.poke()
        await until(lambda: handle.job.cancelling, "the cancel request")
        # The line held by M600 is still in flight: the print ends once it is answered, and nothing goes after it.
        await printer.answer_prompt(0)
        final = await asyncio.wait_for(handle.wait(), 30)
    assert final.state is marlin_aio.PrintState.CANCELLED
    assert final.cancelled_by == "printer asked: cancel"
    executed = moves(runout_sim)
    assert executed == [line.strip() for line in gcode()[: len(executed)]]  # in order, none twice
    assert len(executed) < LINES


async def test_pause_and_resume_requests_stop_and_restart_the_feed(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url, timeout_s=5.0) as printer:
        seen: list[str] = []
        printer.on_host_request(lambda request: seen.append(request.action))
        # Dwells that take simulated time, so the print is still running when the printer asks.
        handle = await printer.start_print(["G4 P200\n" for _ in range(200)])
        pty_sim.printer.host_action(pty_sim.now(), "pause")
        pty_sim.poke()
        await until(lambda: handle.progress.state is marlin_aio.PrintState.PAUSED, "the pause")
        assert handle.progress.paused_by == "printer asked: pause"
        assert printer.last_host_request == HostRequest("pause")
        pty_sim.printer.host_action(pty_sim.now(), "resume")
        pty_sim.poke()
        await until(lambda: handle.progress.state is marlin_aio.PrintState.RUNNING, "the resume")
        assert handle.progress.paused_by is None
        await until(lambda: seen[-2:] == ["pause", "resume"], "both requests told")
        await handle.cancel()


async def test_a_disconnect_request_ends_the_link_with_a_clear_message(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url, timeout_s=5.0) as printer:
        requests = printer.host_requests()
        # Scheduled before the printer says anything, so it subscribes before the line can be read.
        first = asyncio.ensure_future(anext(requests))
        pty_sim.printer.host_action(pty_sim.now(), "disconnect")
        pty_sim.poke()
        request = await asyncio.wait_for(first, 10)
        assert request.action == "disconnect"
        failure = await asyncio.wait_for(printer.wait_for_failure(), 10)
        assert isinstance(failure, marlin_aio.ConnectionLostError)
        assert "asked the host to disconnect" in str(failure)
        assert not printer.is_connected
        with pytest.raises(marlin_aio.ConnectionLostError, match="disconnect"):
            await anext(requests)
        with pytest.raises(marlin_aio.ConnectionLostError):
            await printer.send("M105")


async def test_m600_waits_for_the_user_until_answered(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url, timeout_s=5.0) as printer:
        change = asyncio.ensure_future(printer.send("M600"))
        await until(lambda: printer.waiting_for_user and printer.prompt is not None, "M600's wait")
        assert printer.prompt is not None
        assert printer.prompt.message == "Load Filament"
        assert not change.done()
        await printer.answer_prompt(0)
        await asyncio.wait_for(change, 10)
        assert not printer.waiting_for_user
        assert printer.last_host_request == HostRequest("resumed")


def test_the_simulator_command_line_sets_the_runout_line() -> None:
    from marlin_aio.simulator._options import build_parser, simulator_settings

    settings = simulator_settings(build_parser().parse_args(["--runout-at-line", "12"]))
    assert settings.faults.runout_at_line == 12
    assert simulator_settings(build_parser().parse_args([])).faults.runout_at_line is None
    with pytest.raises(SystemExit) as exited:
        build_parser().parse_args(["--runout-at-line", "0"])
    assert exited.value.code == 2


async def test_a_prompt_answered_during_a_print_leaves_every_callers_reply_its_own(runout_sim: SimulatorServer) -> None:
    # The answer (M876 S0, written at once for the emergency parser) is queued by Marlin and answered with its own
    # plain ok, in order: it must land on the M876, not on the G1 or M114 a caller sends at the same time.
    replies: list[tuple[str, marlin_aio.Reply]] = []
    stop = asyncio.Event()

    async def user() -> None:
        for index in range(1_000):
            command = "M114" if index % 2 else f"G1 Z{1 + index % 5}"
            replies.append((command, await printer.send(command)))
            if stop.is_set():
                return

    async with marlin_aio.connect(runout_sim.url, timeout_s=5.0) as printer:
        handle = await printer.start_print(gcode())
        task = asyncio.create_task(user())
        await until(lambda: printer.prompt is not None and printer.prompt.message == "Load Filament", "the prompt")
        await printer.answer_prompt(0)
        final = await asyncio.wait_for(handle.wait(), 30)
        stop.set()
        await asyncio.wait_for(task, 30)
        stats = printer.stats
    assert final.state is marlin_aio.PrintState.DONE
    assert [line for line in moves(runout_sim) if " Z" not in line] == [line.strip() for line in gcode()]
    assert runout_sim.printer.prompt_answers == [0]
    assert len(replies) >= 2
    for command, reply in replies:
        position = [line for line in reply.lines if line.startswith("X:")]
        # An M114 gets its one position line, a G1 none: a reply shifted by one command would show it.
        assert len(position) == (1 if command == "M114" else 0), (command, reply)
    assert stats.stray_oks == 0 and stats.failed == 0
