"""The firmware's own requests through `marlin-temp serve`: an in-process `Service` (the socket real, the printer
the farm's simulator), reached by `ServedPrinter` (`serve:NAME`) and by raw JSON-RPC.

A runout during a served print pauses it in the service; every client hears the prompts and the pause (the
`requests` topic, `ServedPrinter.prompt`, `host_requests()`); one answers and the print ends with every line once.
`answer_prompt` with no prompt open, a button the prompt does not have or an index that is no number is an error
and writes nothing. The CLI's code paths (`print`, `watch`'s answer) use only `Printer`'s API, so through
`--port serve:NAME` they show and answer the same prompts.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from conftest import heaters_off, until

import marlin_aio
from marlin_aio.farm.supervisor import PrinterSpec
from marlin_aio.protocol import HostRequest, Prompt, rpc
from marlin_aio.service import Service
from marlin_aio.simulator import SimulatorServer
from marlin_temp.common.connect import Exit
from marlin_temp.common.model import AnswerPrompt, WatchModel
from marlin_temp.watch.command import _outcome

LINES = 30
FILAMENT_CHANGE = "filament change: load filament, then press 1 Continue"
PAUSED_BY = "paused: printer asked: filament_runout 0"


@contextlib.asynccontextmanager
async def service_at(path: Path) -> AsyncIterator[Service]:
    """A service with one simulated printer ("sim"), connected."""
    # Polled slowly: the farm's simulator keeps the last 1000 commands only, and the test reads the print's moves.
    service = Service([PrinterSpec("sim", None, sim=True, sim_speed=50, poll_interval_s=0.2)], path)
    task = asyncio.create_task(service.run())
    try:
        await asyncio.wait_for(service.ready.wait(), 30)
        await until(lambda: service.farm.printers["sim"].link_up, "the printer connected")
        yield service
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def sim_of(service: Service) -> SimulatorServer:
    return service.farm.sims["sim"]


def gcode() -> list[str]:
    return [f"G1 X{index % 10} Y{index % 5} F6000" for index in range(LINES)]


def moves(sim: SimulatorServer) -> list[str]:
    return [command for command in sim.printer.executed if command.startswith("G1 ")]


class RawClient:
    """JSON-RPC by hand, keeping the notifications it reads on the way."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.next_id = 0
        self.notifications: list[dict[str, Any]] = []

    async def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        self.writer.write(rpc.encode_message(rpc.request(self.next_id, method, params)))
        while True:
            message = json.loads(await asyncio.wait_for(self.reader.readline(), 30))
            if "method" in message:
                self.notifications.append(message)
            elif message.get("id") == self.next_id:
                return dict(message)

    async def notification(self, method: str, condition: Any) -> dict[str, Any]:
        """The first notification `method` (read so far or from now) whose params satisfy `condition`."""
        while True:
            for message in self.notifications:
                if message["method"] == method and condition(message["params"]):
                    return message["params"]  # type: ignore[no-any-return]
            self.notifications.append(json.loads(await asyncio.wait_for(self.reader.readline(), 30)))


@contextlib.asynccontextmanager
async def raw_client(path: Path) -> AsyncIterator[RawClient]:
    reader, writer = await asyncio.open_unix_connection(str(path))
    try:
        yield RawClient(reader, writer)
    finally:
        writer.close()


async def test_a_runout_in_a_served_print_is_heard_answered_and_the_print_ends_with_every_line_once(
    tmp_path: Path,
) -> None:
    path = tmp_path / "s.sock"
    async with service_at(path) as service:
        sim = sim_of(service)
        sim.printer.faults.runout_at_line = 10
        async with marlin_aio.connect(f"serve:sim@{path}") as printer, raw_client(path) as other:
            assert (await other.call("subscribe", printer="sim", topics=["requests"]))["result"]["subscribed"] == [
                "requests"
            ]
            heard: list[HostRequest] = []
            printer.on_host_request(heard.append)
            read: list[HostRequest] = []

            async def read_requests() -> None:
                async for request in printer.host_requests():
                    read.append(request)

            # It registers at its first step, at start_print's first await: long before line 10 is reached.
            reader = asyncio.create_task(read_requests())
            handle = await printer.start_print(gcode())
            await until(
                lambda: printer.prompt is not None and printer.prompt.message == "Load Filament", "the served prompt"
            )
            assert printer.prompt == Prompt("Load Filament", ("Continue",), shown=True)
            await until(lambda: handle.progress.state is marlin_aio.PrintState.PAUSED, "the served print paused")
            assert handle.progress.paused_by == "printer asked: filament_runout 0"
            await until(lambda: printer.waiting_for_user, "the wait for the user told")
            last = printer.last_host_request
            assert last is not None and last.action == "paused"
            # Another client (any program) hears the same, with the state after each request.
            told = await other.notification("request", lambda p: (p["request"] or {}).get("action") == "prompt")
            assert told["printer"] == "sim"
            status = (await other.call("status", printer="sim"))["result"]
            assert status["prompt"] == {"message": "Load Filament", "buttons": ["Continue"]}
            assert status["waiting_for_user"] is True
            assert not handle.finished
            await printer.answer_prompt(0)
            assert printer.prompt is None
            final = await asyncio.wait_for(handle.wait(), 60)
            await until(lambda: not printer.waiting_for_user, "the wait's end told")
            closed = await other.notification("request", lambda p: p["prompt"] is None and not p["waiting_for_user"])
            assert closed["request"] is None or closed["request"]["action"] != "prompt"
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader
        assert final.state is marlin_aio.PrintState.DONE
        assert final.paused_by is None
        assert moves(sim) == gcode()  # every line once, in order
        assert sim.printer.prompt_answers == [0]
    actions = [request.action for request in heard]
    assert actions.index("paused") < actions.index("paused_for_user") < actions.index("resumed")
    assert [r.prompt.message for r in heard if r.prompt is not None] == ["FilamentRunout T0", "Load Filament"]
    assert [r.action for r in read] == actions  # host_requests() yields what on_host_request is told


async def test_answer_prompt_errors_write_nothing(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    async with service_at(path) as service:
        sim = sim_of(service)
        async with marlin_aio.connect(f"serve:sim@{path}") as printer, raw_client(path) as raw:
            with pytest.raises(ValueError, match="no prompt is open"):
                await printer.answer_prompt(0)
            with pytest.raises(ValueError, match="button is a number"):
                await printer.answer_prompt(-1)
            answer = await raw.call("answer_prompt", printer="sim", index=0)
            assert answer["error"]["data"]["type"] == "ValueError"
            sim.printer.open_prompt(sim.now(), "Door open", ["Continue", "Cancel"])
            sim.poke()
            await until(lambda: printer.prompt is not None, "the prompt told")
            assert printer.prompt == Prompt("Door open", ("Continue", "Cancel"), shown=True)
            for wrong in ("1", 1.0, True, None):
                answer = await raw.call("answer_prompt", printer="sim", index=wrong)
                assert answer["error"]["code"] == rpc.INVALID_PARAMS, (wrong, answer)
            answer = await raw.call("answer_prompt", printer="sim", index=2)
            assert answer["error"]["data"]["type"] == "ValueError"
            assert "has no button 2" in answer["error"]["message"]
            with pytest.raises(ValueError, match="has no button 5"):
                await printer.answer_prompt(5)
            assert sim.printer.prompt_answers == []  # nothing reached the printer
            assert printer.prompt is not None  # still open
            answered = await raw.call("answer_prompt", printer="sim", index=1)
            assert answered["result"] == {"answered": 1, "button": "Cancel"}
            await until(lambda: sim.printer.prompt_answers == [1], "the answer at the printer")
            await until(lambda: printer.prompt is None, "the prompt closed for every client")
            status = (await raw.call("status", printer="sim"))["result"]
            assert status["prompt"] is None


async def test_print_through_the_service_says_why_the_printer_paused_and_watch_answers_it(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    gcode = tmp_path / "part.gcode"
    gcode.write_text("; part\n" + "".join(f"{line}\n" for line in gcode_lines()))
    async with service_at(path) as service:
        sim = sim_of(service)
        sim.printer.faults.runout_at_line = 10
        process = await asyncio.create_subprocess_exec(
            *(sys.executable, "-m", "marlin_temp", "print", str(gcode), "--port", f"serve:sim@{path}"),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        assert process.stdout is not None
        said: list[str] = []
        try:
            async with asyncio.timeout(60):
                # Both, in either order: the prompt comes with its request, the pause with the next progress told.
                while FILAMENT_CHANGE not in said or PAUSED_BY not in said:
                    said.append((await process.stdout.readline()).decode().strip())
                    assert said[-1] or not process.stdout.at_eof(), said
            async with marlin_aio.connect(f"serve:sim@{path}") as printer:
                await until(lambda: printer.prompt is not None, "the prompt told to a second client")
                # What watch does with the key 1 while the prompt shows (through the same Printer API).
                notice = await _outcome(printer, AnswerPrompt(0, "Continue"), WatchModel())
                assert notice.title == "answered the printer: Continue (M876 S0)" and not notice.error
            _, errors = await asyncio.wait_for(process.communicate(), 60)
        finally:
            if process.returncode is None:
                process.kill()
                await process.wait()
        assert process.returncode == Exit.OK, errors.decode()
        assert f"done: {LINES} commands" in errors.decode()
        assert moves(sim) == gcode_lines()
        assert sim.printer.prompt_answers == [0]


def gcode_lines() -> list[str]:
    return [f"G1 X{index} Y{index % 9}" for index in range(LINES)]


async def test_host_requests_of_a_served_printer_end_with_the_error_when_its_printer_halts(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    async with service_at(path) as service, marlin_aio.connect(f"serve:sim@{path}") as printer:
        sim = sim_of(service)
        requests = printer.host_requests()
        # Registered at its first step, in the loop's next turn: long before the printer's line comes back.
        first = asyncio.ensure_future(anext(requests))
        sim.printer.host_action(sim.now(), "notification", "hello")
        sim.poke()
        told = await asyncio.wait_for(first, 30)
        assert (told.action, told.argument) == ("notification", "hello")
        following = asyncio.ensure_future(anext(requests))
        owned = service.farm.printers["sim"].printer
        assert owned is not None
        owned.emergency_stop()  # halted: the service tells, the reader ends
        with pytest.raises(marlin_aio.MarlinError):
            await asyncio.wait_for(following, 30)
        await requests.aclose()


def test_the_firmwares_requests_and_the_print_pause_round_trip_as_json() -> None:
    prompt = Prompt("Load Filament", ("Continue", "Purge"), shown=True)
    request = HostRequest("prompt", "Load Filament", prompt)
    params = rpc.requests_to_json(request, prompt, True, HostRequest("paused", "filament_runout 0"))
    assert json.loads(rpc.encode_message(params)) == params
    assert params["prompt"] == {"message": "Load Filament", "buttons": ["Continue", "Purge"]}
    assert rpc.host_request_from_json(params["request"]) == request
    assert rpc.prompt_from_json(params["prompt"]) == prompt
    assert rpc.host_request_from_json(params["last_host_request"]) == HostRequest("paused", "filament_runout 0")
    assert rpc.host_request_from_json(None) is None and rpc.prompt_from_json(None) is None
    bad: object
    for bad in ({"buttons": []}, "Load", {"message": "x", "buttons": "Continue"}):
        with pytest.raises(rpc.RpcError):
            rpc.prompt_from_json(bad)
    for bad in ({"argument": "x"}, [], {"action": 3}):
        with pytest.raises(rpc.RpcError):
            rpc.host_request_from_json(bad)
    progress = marlin_aio.PrintProgress(
        marlin_aio.PrintState.PAUSED, 10, 9, 30, 200, 220, 700, 1.5, 0, 9, paused_by="printer asked: filament_runout 0"
    )
    assert rpc.progress_from_json(rpc.progress_to_json(progress)) == progress
    older = {key: value for key, value in rpc.progress_to_json(progress).items() if not key.endswith("_by")}
    assert rpc.progress_from_json(older).paused_by is None  # a service without them: none


async def test_a_print_the_printer_cancels_runs_the_jobs_cancel_script_as_any_door_does(tmp_path: Path) -> None:
    """//action:cancel from the printer's screen ends the service's job as a door's cancel does: cancelled, by the
    printer, its cancel script run (the heaters off)."""
    path = tmp_path / "s.sock"
    long_print = tmp_path / "long.gcode"
    long_print.write_text("".join(f"G1 X{i % 10} Y{i % 5} F6000\n" for i in range(5_000)))
    async with service_at(path) as service, marlin_aio.connect(f"serve:sim@{path}") as printer:
        sim = sim_of(service)
        await printer.set_temperatures(hotend=200, bed=60)
        handle = await printer.start_print(long_print)
        await until(lambda: handle.progress.lines_acked > 10, "the print under way")
        sim.printer.host_action(sim.now(), "cancel")
        sim.poke()
        await handle.wait()
        farm_printer = service.farm.printers["sim"]
        await until(lambda: farm_printer.job is not None and farm_printer.job.ended_s is not None, "the job ended")
        job = farm_printer.job
        assert job is not None and job.state.value == "cancelled" and "printer asked" in str(job.cancelled_by), job
        assert {"M104 S0", "M140 S0", "M107"} <= set(sim.printer.executed)  # the script reached the printer
        await until(
            lambda: heaters_off(printer.latest),
            "the printer's targets read back 0",
        )
