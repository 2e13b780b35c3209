"""One verb, every door: a print cancelled through the socket's JSON-RPC, the CLI (`marlin-temp job cancel`), MQTT
and the OctoPrint API ends in the same state, through a real `marlin-temp serve` (or `farm`) process and the
simulator on a pty: the job cancelled (and saying by whom), its cancel script run once, the heaters off at the
printer. Also: the table is the only list of verbs each door offers."""

from __future__ import annotations

import asyncio
import json
import sys
import urllib.request
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from conftest import heaters_off, until
from test_farm import Broker, free_port
from test_serve import Served, raw_client, serving

import marlin_aio
from marlin_aio.farm.commands import ACTION_VERBS, UNQUEUED_ACTIONS
from marlin_aio.service import verbs
from marlin_aio.service.session import PRIORITY_METHODS

DOORS = ("socket", "cli", "mqtt", "http")


def moves(count: int) -> str:
    return "G28\n" + "".join(f"G1 X{i % 200} Y{(i * 7) % 200} F6000\n" for i in range(count))


async def _job_over_http(port: int, key: str, command: str) -> int:
    def post() -> int:
        request = urllib.request.Request(
            f"http://127.0.0.1:{port}/api/job",
            data=json.dumps({"command": command}).encode(),
            headers={"X-Api-Key": key, "Content-Type": "application/json"},
            method="POST",
        )
        with urllib.request.urlopen(request, timeout=60) as answer:
            return int(answer.status)

    return await asyncio.to_thread(post)


async def _job_over_mqtt(broker: Broker, printer: str, action: str) -> dict[str, Any]:
    async with aiomqtt.Client("127.0.0.1", broker.port, identifier="canceller") as client:
        await client.subscribe(f"marlin/{printer}/response", qos=1)
        await client.publish(f"marlin/{printer}/command", json.dumps({"id": 7, "action": action}), qos=1)
        async with asyncio.timeout(60):
            async for message in client.messages:
                answer: dict[str, Any] = json.loads(bytes(message.payload))
                if answer.get("id") == 7:
                    return answer
    raise AssertionError("no answer")


async def _job_over_cli(served: Served, printer: str, action: str) -> tuple[int, str]:
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "marlin_temp",
        "job",
        action,
        "--port",
        served.url(printer),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
        env=served.env(),
    )
    output, _ = await asyncio.wait_for(process.communicate(), 60)
    return process.returncode or 0, output.decode()


def _door_service(door: str, request: pytest.FixtureRequest) -> tuple[tuple[str, ...], str, str, int, Broker | None]:
    """The service a door's test runs: (its arguments, serve or farm, the printer's name, the OctoPrint API's port,
    the broker for MQTT's door)."""
    args: tuple[str, ...] = ("--sim", "--sim-speed", "50", "--interval", "0.05")
    command, printer_name, http_port = "serve", "sim", free_port()
    broker: Broker | None = None
    if door == "http":
        args += ("--octoprint", f"127.0.0.1:{http_port}")
    if door == "mqtt":
        broker = request.getfixturevalue("broker")
        args = ("--sims", "1", "--sim-speed", "50", "--interval", "0.05", "--broker", f"127.0.0.1:{broker.port}")
        args += ("--allow-commands",)
        command, printer_name = "farm", "sim1"
    return args, command, printer_name, http_port, broker


@pytest.mark.parametrize("door", DOORS)
async def test_a_cancel_through_each_door_ends_in_the_same_state(
    door: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text(moves(4_000))
    args, command, printer_name, http_port, broker = _door_service(door, request)
    async with serving(tmp_path, *args, command=command) as served, raw_client(served) as raw:
        async with marlin_aio.connect(served.url(printer_name)) as printer:
            await printer.set_temperatures(hotend=200, bed=60)
            handle = await printer.start_print(gcode)
            await until(lambda: handle.progress.lines_acked > 20, "the print under way")
            if door == "socket":
                answer = await raw.call("cancel", printer=printer_name)
                assert answer["result"]["job"]["state"] == "cancelled", answer
            elif door == "cli":
                code, output = await _job_over_cli(served, printer_name, "cancel")
                assert code == 0 and "part.gcode on sim: cancelled" in output, output
            elif door == "mqtt":
                assert broker is not None
                answer = await _job_over_mqtt(broker, printer_name, "cancel")
                assert answer["ok"] is True and answer["result"]["job"]["state"] == "cancelled", answer
            else:
                key = (served.socket.parent / "api-key").read_text().strip()
                assert await _job_over_http(http_port, key, "cancel") == 204
            final = await handle.wait()
            assert final.state is marlin_aio.PrintState.CANCELLED
            # The heaters off at the printer: its own report, polled by the service, says targets 0.
            await until(
                lambda: heaters_off(printer.latest),
                "the printer's targets read back 0",
            )
        job = (await raw.call("job", printer=printer_name))["result"]
    assert job["state"] == "cancelled" and job["file"] == "part.gcode"
    by = {"socket": "socket client", "cli": "socket client", "mqtt": "mqtt", "http": "octoprint"}[door]
    assert job["cancelled_by"].startswith(by), job
    assert job["resume_line"] > job["surely_run_line"] > 0
    # The cancel script ran once, whoever asked.
    ran = [line for line in served.lines if "cancel_script: part.gcode: ran M104 S0; M140 S0; M107" in line]
    assert len(ran) == 1, served.lines


@pytest.mark.parametrize("door", DOORS)
async def test_a_restart_through_each_door_prints_the_paused_file_again_with_the_heaters_on(
    door: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """OctoPrint's restart, a verb of the table: the paused job ends without its cancel script and the same file
    starts again from its first line, whichever door asked."""
    gcode = tmp_path / "part.gcode"
    gcode.write_text(moves(4_000))
    args, command, printer_name, http_port, broker = _door_service(door, request)
    async with (
        serving(tmp_path, *args, command=command) as served,
        raw_client(served) as raw,
        marlin_aio.connect(served.url(printer_name)) as printer,
    ):
        await printer.set_temperatures(hotend=200, bed=60)
        handle = await printer.start_print(gcode)
        await until(lambda: handle.progress.lines_acked > 20, "the print under way")
        refused = await raw.call("restart", printer=printer_name)
        assert "only a paused print" in refused["error"]["message"], refused  # running: pause it first
        first = (await raw.call("pause", printer=printer_name))["result"]
        if door == "socket":
            answer = await raw.call("restart", printer=printer_name)
            assert answer["result"]["state"] in ("starting", "printing"), answer
        elif door == "cli":
            code, output = await _job_over_cli(served, printer_name, "restart")
            assert code == 0 and "part.gcode on sim" in output, output
        elif door == "mqtt":
            assert broker is not None
            answer = await _job_over_mqtt(broker, printer_name, "restart")
            assert answer["ok"] is True, answer
        else:
            key = (served.socket.parent / "api-key").read_text().strip()
            assert await _job_over_http(http_port, key, "restart") == 204
        job = (await raw.call("job", printer=printer_name))["result"]
        assert job["id"] != first["id"] and job["file"] == "part.gcode" and job["active"], job
        # The heaters stay on: the print that starts again wants them (no cancel script ran).
        reading = await printer.read_temperatures()
        assert reading.hotend is not None and reading.hotend.target == 200
        assert reading.bed is not None and reading.bed.target == 60
        await raw.call("cancel", printer=printer_name)
    restarted = [line for line in served.lines if "cancel_script: part.gcode: ran nothing" in line]
    assert len(restarted) == 1, served.lines
    started = [line for line in served.lines if "print_started: printing part.gcode" in line]
    assert len(started) == 2, served.lines


def test_every_door_offers_the_verbs_of_the_table_and_nothing_else() -> None:
    """The socket's methods, MQTT's actions, the OctoPrint API's calls and what jumps the queue at each door are
    read from the one table: a door offers exactly the verbs the table says it does."""
    import re

    import marlin_aio.service.octoprint as octoprint
    from marlin_aio.service.server import Service

    offered = {door: {n for n, v in verbs.VERBS.items() if door in v.doors} for door in verbs.DOORS}
    service = Service([], Path("/nonexistent/s.sock"))
    # The owner's Unix socket alone decides the OctoPrint API's app keys: an app must never grant its own key.
    assert set(service.methods) == offered["socket"]
    assert offered["socket"] - offered["tcp"] == {"keys", "approve_key", "deny_key", "revoke_key"}
    assert not offered["mqtt"] & {"keys", "approve_key"} and not offered["http"] & {"keys", "approve_key"}
    assert set(ACTION_VERBS.values()) == offered["mqtt"]
    sources = "".join(path.read_text() for path in Path(octoprint.__file__).parent.glob("*.py"))
    http_calls = set(re.findall(r'\.verb\("([a-z_]+)"', sources))
    assert http_calls == offered["http"]
    assert {a for a, v in ACTION_VERBS.items() if verbs.VERBS[v].queue is verbs.Queue.URGENT} == UNQUEUED_ACTIONS
    assert PRIORITY_METHODS - {"cancel_request"} == verbs.urgent_verbs()
    assert {"emergency_stop", "pause", "resume", "cancel", "answer_prompt"} <= verbs.urgent_verbs()


def test_the_readme_lists_every_verb_of_the_table() -> None:
    readme = (Path(__file__).parent.parent / "README.md").read_text()
    for name, entry in verbs.VERBS.items():
        row = next((line for line in readme.splitlines() if line.startswith(f"| `{name}` |")), None)
        assert row is not None, f"the README's table of verbs has no row for {name}"
        doors = ", ".join(door for door in ("socket", "tcp", "mqtt", "http") if door in entry.doors)
        assert f"| {entry.queue.value} | {doors} |" in row, row


async def test_a_second_print_is_one_line_naming_the_running_job_and_stores_nothing(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text(moves(4_000))
    other = tmp_path / "other.gcode"
    other.write_text(moves(10))
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        handle = await printer.start_print(gcode)
        await until(lambda: handle.progress.lines_acked > 5, "the first print under way")
        uploads = served.socket.parent / "uploads"
        before = sorted(path.name for path in uploads.iterdir()) if uploads.exists() else []
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "print",
            str(other),
            "--port",
            served.url(),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=served.env(),
        )
        out, err = await asyncio.wait_for(process.communicate(), 60)
        lines = err.decode().strip().splitlines()
        assert process.returncode == 4, (out, err)
        assert len(lines) == 1 and "a print is already running" in lines[0] and "part.gcode" in lines[0], lines
        assert "marlin-temp job cancel" in lines[0]
        after = sorted(path.name for path in uploads.iterdir()) if uploads.exists() else []
        assert after == before  # nothing of the refused file was stored
        # A raw client that skips the check and uploads anyway is refused at its first piece: nothing stored.
        async with raw_client(served) as raw:
            answer = await raw.call("upload", printer="sim", lines=["G28"], name="sneaky.gcode")
            assert "a print is already running" in answer["error"]["message"], answer
        assert (sorted(path.name for path in uploads.iterdir()) if uploads.exists() else []) == before
        await handle.cancel()


async def test_a_print_sent_by_the_cli_keeps_its_name_everywhere_and_its_copy_is_removed(tmp_path: Path) -> None:
    gcode = tmp_path / "benchy [bold]part.gcode"  # a name rich would read as markup
    gcode.write_text(moves(30))
    async with serving(tmp_path) as served, raw_client(served) as raw:
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "print",
            str(gcode),
            "--port",
            served.url(),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=served.env(),
        )
        out, err = await asyncio.wait_for(process.communicate(), 120)
        assert process.returncode == 0, (out, err)
        job = (await raw.call("job", printer="sim"))["result"]
        assert job["file"] == "benchy [bold]part.gcode" and job["state"] == "done", job
        assert job["started_by"].startswith("socket client")
        await until(lambda: any("print_finished" in line for line in served.lines), "the end told")
        told = [line for line in served.lines if "print_started" in line or "print_finished" in line]
        assert told and all("benchy [bold]part.gcode" in line for line in told), told
        assert not any("sent" in line and ".gcode" in line for line in served.lines), served.lines
        uploads = served.socket.parent / "uploads"
        assert not (uploads.exists() and [p.name for p in uploads.iterdir() if not p.name.startswith(".")]), list(
            uploads.iterdir()
        )  # the service's copy went with its job
        # `marlin-temp job` says it as it is, with no markup read into the name.
        status = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "job",
            "--port",
            served.url(),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=served.env(),
        )
        out, err = await asyncio.wait_for(status.communicate(), 120)
        assert status.returncode == 0 and "benchy [bold]part.gcode" in out.decode(), (out, err)


async def test_the_farm_ends_a_print_on_sigterm_as_serve_does(tmp_path: Path, broker: Broker) -> None:
    """`marlin-temp farm` is the service plus its bridge: its SIGTERM runs the same life cycle as serve's."""
    gcode = tmp_path / "part.gcode"
    gcode.write_text(moves(4_000))
    args = ("--sims", "1", "--sim-speed", "50", "--interval", "0.05", "--broker", f"127.0.0.1:{broker.port}")
    async with serving(tmp_path, *args, command="farm") as served, marlin_aio.connect(served.url("sim1")) as printer:
        handle = await printer.start_print(gcode)
        await until(lambda: handle.progress.lines_acked > 20, "the print under way")
    # serving() sent SIGTERM and saw exit 0: the print was stopped with its cancel script, then the farm left.
    stopped = [line for line in served.lines if "print_stopped" in line]
    assert len(stopped) == 1 and "cancel script run (M104 S0; M140 S0; M107)" in stopped[0], served.lines
    record = json.loads((served.socket.parent / "jobs" / "sim1.json").read_text())
    assert record["state"] == "stopped" and record["surely_run"] > 20, record


async def test_a_served_cancel_with_an_empty_script_keeps_the_heaters(tmp_path: Path) -> None:
    """`print --keep-heaters` through the service: `cancel(())` replaces the job's script with none."""
    gcode = tmp_path / "part.gcode"
    gcode.write_text(moves(4_000))
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        await printer.set_temperatures(hotend=200, bed=60)
        handle = await printer.start_print(gcode)
        await until(lambda: handle.progress.lines_acked > 20, "the print under way")
        final = await handle.cancel(())
        assert final.state is marlin_aio.PrintState.CANCELLED
        reading = await printer.read_temperatures()
        assert reading.hotend is not None and reading.hotend.target == 200
        assert reading.bed is not None and reading.bed.target == 60
    assert any("cancel_script: part.gcode: ran nothing" in line for line in served.lines), served.lines


@pytest.mark.parametrize("door", ["tcp", "mqtt", "http"])
async def test_only_the_owners_socket_decides_app_keys(door: verbs.Door) -> None:
    # An app that asks for a key must never be the one that grants it: a TCP client (another machine), an MQTT
    # command or the HTTP API itself are told there is no such method, and the request still waits.
    from marlin_aio.farm.supervisor import Farm, PrinterSpec
    from marlin_aio.protocol.rpc import METHOD_NOT_FOUND, RpcError

    owner = verbs.FarmOwner(Farm([PrinterSpec("sim", None, sim=True)], lambda event: None), ())
    asked = owner.app_keys.request("Some App")
    for name, params in (("approve_key", {"token": asked.token}), ("keys", {}), ("revoke_key", {"key": "Some App"})):
        with pytest.raises(RpcError) as refused:
            await verbs.call(owner, name, params, verbs.Caller(door, "someone"))
        assert refused.value.code == METHOD_NOT_FOUND
    assert [request.token for request in owner.app_keys.pending()] == [asked.token]
    params = {"token": asked.token, "printer": "sim"}
    approved = await verbs.call(owner, "approve_key", params, verbs.Caller("socket", "owner"))
    assert approved == {"token": asked.token, "app": "Some App", "user": "", "approved": True}


def test_an_app_key_request_token_can_be_typed_as_an_argument() -> None:
    # A token of `secrets.token_urlsafe` once began with `-`, and `marlin-temp keys approve -eiK...` was read as an
    # option (exit 2): tokens are hexadecimal now.
    from marlin_aio.service.appkeys import AppKeys

    clock = [0.0]
    keys = AppKeys(None, clock=lambda: clock[0])
    tokens = []
    for i in range(200):
        clock[0] = 7.0 * i  # under the rate bound
        tokens.append(keys.request(f"app {i}").token)
    assert all(token.isalnum() and not token.startswith("-") for token in tokens)


def test_requests_for_app_keys_are_bounded_in_rate_and_in_number_waiting() -> None:
    # The endpoint needs no key and each request is a line on the owner's console: a flood is refused (429 at the
    # HTTP door) before it can push out the request someone is about to approve.
    from marlin_aio.service.appkeys import MAX_PENDING, MAX_REQUESTS_PER_MINUTE, AppKeys, TooManyRequestsError

    clock = [100.0]
    keys = AppKeys(None, clock=lambda: clock[0])
    first = keys.request("Home Assistant")
    for i in range(MAX_REQUESTS_PER_MINUTE - 1):
        keys.request(f"flood {i}")
    with pytest.raises(TooManyRequestsError):
        keys.request("one too many")
    assert first.token in [request.token for request in keys.pending()]
    clock[0] += 60.0  # a minute later, requests are taken again; the waiting ones stay bounded
    for i in range(MAX_REQUESTS_PER_MINUTE):
        keys.request(f"later {i}")
    assert len(keys.pending()) == MAX_PENDING
