"""`marlin-temp serve` as a real process with the simulator, driven through its socket: by the library's
`ServedPrinter` (`serve:NAME`), by raw JSON-RPC as a program in any language would, and by the CLI.

Each test starts its own service on a socket in its own temporary folder (`$MARLIN_SERVE_SOCKET` for the
children), waits for its "serving" line (no timer), and stops it with SIGTERM.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import signal
import stat
import sys
import textwrap
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from conftest import until
from test_farm import Broker
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.protocol import rpc
from marlin_aio.service import SOCKET_ENV, service_holding
from marlin_temp.main import app

runner = CliRunner()


@dataclass
class Served:
    socket: Path
    process: asyncio.subprocess.Process
    lines: list[str]

    def url(self, name: str = "sim") -> str:
        return f"serve:{name}@{self.socket}"

    def env(self) -> dict[str, str]:
        return {**os.environ, SOCKET_ENV: str(self.socket)}


async def _read_lines(stream: asyncio.StreamReader, lines: list[str]) -> None:
    while line := await stream.readline():
        lines.append(line.decode(errors="replace").rstrip("\n"))


@contextlib.asynccontextmanager
async def serving(tmp_path: Path, *args: str, command: str = "serve") -> AsyncIterator[Served]:
    """A `marlin-temp serve` process on a socket in `tmp_path`, ready (it said "serving" and its printers are
    connected) until the block ends; then SIGTERM, and it must exit 0."""
    path = tmp_path / "run" / "serve.sock"
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "marlin_temp",
        command,
        "--socket",
        str(path),
        *(("--log-dir", str(tmp_path / "logs")) if command == "serve" else ()),
        *(args or ("--sim", "--sim-speed", "50", "--interval", "0.05")),
        stderr=asyncio.subprocess.PIPE,
        env={**os.environ, SOCKET_ENV: str(path)},
    )
    assert process.stderr is not None
    lines: list[str] = []
    reader = asyncio.create_task(_read_lines(process.stderr, lines))
    served = Served(path, process, lines)
    try:
        ready = "serving" if command == "serve" else "shared at"
        await until(lambda: any(ready in line for line in lines) or reader.done(), "the service to listen")
        assert any(ready in line for line in lines), lines
        expected = sum(1 for arg in args if arg.startswith("--port")) or 1
        await until(lambda: sum(": connected:" in line for line in lines) >= expected, "the printers to connect")
        yield served
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGTERM)
        code = await asyncio.wait_for(process.wait(), 30)
        await reader
    assert code == 0, lines
    assert not path.exists(), "the socket is removed when the service stops"


class RawClient:
    """JSON-RPC by hand: what a client in another language does."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.next_id = 0
        self.notifications: list[dict[str, Any]] = []

    async def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        self.writer.write(rpc.encode_message(rpc.request(self.next_id, method, params)))
        return await self.answer(self.next_id)

    async def answer(self, request_id: object) -> dict[str, Any]:
        while True:
            message = json.loads(await asyncio.wait_for(self.reader.readline(), 30))
            if "method" in message:
                self.notifications.append(message)
            elif message.get("id") == request_id:
                return dict(message)

    async def raw(self, data: bytes) -> dict[str, Any]:
        self.writer.write(data)
        return await self.answer(None)


@contextlib.asynccontextmanager
async def raw_client(served: Served) -> AsyncIterator[RawClient]:
    reader, writer = await asyncio.open_unix_connection(str(served.socket), limit=4 << 20)
    try:
        yield RawClient(reader, writer)
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()


PRINT_CLIENT = textwrap.dedent(
    """
    import asyncio, sys
    import marlin_aio

    async def main():
        async with marlin_aio.connect(sys.argv[1]) as printer:
            handle = await printer.start_print(sys.argv[2])
            print("started", handle.progress.state.value, flush=True)
        # The client is gone from here on: the print must go on in the service.

    asyncio.run(main())
    """
)


def _gcode(path: Path, lines: int) -> Path:
    path.write_text("".join(f"G1 X{i % 100} F6000 ; move {i}\nG4 P5\n" for i in range(lines // 2)))
    return path


async def test_a_print_outlives_the_client_that_started_it_while_another_client_follows_readings(
    tmp_path: Path,
) -> None:
    gcode = _gcode(tmp_path / "part.gcode", 400)
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as watcher:
        assert type(watcher).__name__ == "ServedPrinter"
        assert isinstance(watcher, marlin_aio.Printer)
        starter = await asyncio.create_subprocess_exec(
            sys.executable, "-c", PRINT_CLIENT, served.url(), str(gcode), stdout=asyncio.subprocess.PIPE
        )
        out, _ = await starter.communicate()
        assert starter.returncode == 0
        assert out.decode().startswith("started running")
        # The starter has exited; the print runs on, and the watcher's readings keep coming meanwhile.
        readings: list[marlin_aio.TemperatureReading] = []
        async with raw_client(served) as control:
            async for reading in watcher.temperature_readings():
                readings.append(reading)
                status = (await control.call("status", printer="sim"))["result"]
                if status["print"]["state"] != "running":
                    break
            assert status["print"]["state"] == "done", status
            assert status["print"]["lines_acked"] == 400
            assert status["print"]["file"] == "part.gcode"
        assert len(readings) >= 5
        assert all(r.hotend is not None for r in readings)


async def test_two_clients_starting_prints_the_second_is_refused(tmp_path: Path) -> None:
    gcode = _gcode(tmp_path / "long.gcode", 2000)
    async with (
        serving(tmp_path) as served,
        marlin_aio.connect(served.url()) as first,
        marlin_aio.connect(served.url()) as second,
    ):
        handle = await first.start_print(gcode)
        with pytest.raises(RuntimeError, match="a print is already running"):
            await second.start_print(gcode)
        # The second client may still pause and cancel the print it did not start (one printer, shared).
        progress = await handle.cancel()
        assert progress.state is marlin_aio.PrintState.CANCELLED
        assert progress.lines_acked < 2000


async def test_each_reply_reaches_its_own_caller_across_clients(tmp_path: Path) -> None:
    async with (
        serving(tmp_path) as served,
        marlin_aio.connect(served.url()) as a,
        marlin_aio.connect(served.url()) as b,
    ):

        async def echo(printer: marlin_aio.Printer, tag: str, n: int) -> list[str]:
            # Not `M118 A1...`: M118 reads a leading A1 as "prefix with //".
            replies = [await printer.send(f"M118 reply-{tag}-{i}") for i in range(n)]
            return [reply.lines[0] for reply in replies]

        got_a, got_b = await asyncio.gather(echo(a, "a", 30), echo(b, "b", 30))
        assert got_a == [f"reply-a-{i}" for i in range(30)]
        assert got_b == [f"reply-b-{i}" for i in range(30)]


async def test_errors_are_the_librarys_own(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        with pytest.raises(ValueError, match="above the limit"):
            await printer.set_temperatures(hotend=900)  # refused before it leaves this process
        with pytest.raises(marlin_aio.PortNotFoundError, match=r"no printer named 'nope'.*it has: sim"):
            async with marlin_aio.connect(served.url("nope")):
                pass
    with pytest.raises(marlin_aio.PortNotFoundError, match="no marlin-temp serve is listening"):
        async with marlin_aio.connect(f"serve:sim@{tmp_path / 'none.sock'}"):
            pass


async def test_an_emergency_stop_through_the_service_halts_the_printer_for_every_client(tmp_path: Path) -> None:
    async with (
        serving(tmp_path) as served,
        marlin_aio.connect(served.url()) as stopper,
        marlin_aio.connect(served.url()) as other,
    ):
        events: list[marlin_aio.LinkEvent] = []
        other.on_link_event(events.append)
        stopper.emergency_stop()
        error = await asyncio.wait_for(other.wait_for_failure(), 30)
        assert isinstance(error, marlin_aio.PrinterHaltedError)
        with pytest.raises(marlin_aio.PrinterHaltedError):
            await other.send("M105")
        assert not other.is_connected
        await until(lambda: [e.kind for e in events] == ["halted"], "the halted event")
        # A halted board needs a reset (its button, or a USB bridge's DTR on the next open): until then the service
        # keeps trying, and a client that opens is told why in one line.
        with pytest.raises(marlin_aio.ConnectError, match=r"not connected now \(emergency stop"):
            async with marlin_aio.connect(served.url()):
                pass


async def test_garbage_and_misbehaving_clients_get_one_error_and_nobody_else_notices(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, raw_client(served) as bad, marlin_aio.connect(served.url()) as good:
        cases: list[tuple[bytes, int]] = [
            (b"\xff\xfe not json\n", rpc.PARSE_ERROR),
            (b"[1, 2, 3]\n", rpc.INVALID_REQUEST),
            (b'{"jsonrpc": "2.0", "id": null, "method": 5}\n', rpc.INVALID_REQUEST),
            (b"[" * 50_000 + b"\n", rpc.PARSE_ERROR),
        ]
        for data, code in cases:
            answer = await bad.raw(data)
            assert answer["error"]["code"] == code, (data[:40], answer)
        answer = await bad.call("no_such_method")
        assert answer["error"]["code"] == rpc.METHOD_NOT_FOUND
        answer = await bad.call("send", printer="sim", command=5)
        assert answer["error"]["code"] == rpc.INVALID_PARAMS
        answer = await bad.call("send", printer="sim", command="M104 S1\nM140 S100")
        assert answer["error"]["data"]["type"] == "ValueError"  # a newline inside a command: nothing written
        answer = await bad.call("start_print", printer="sim", path="relative.gcode")
        assert "absolute path" in answer["error"]["message"]
        # The well-behaved client never noticed.
        reply = await good.send("M118 still here")
        assert reply.lines == ("still here",)
        # A line past the size limit: one error, then that client is let go; the other goes on.
        bad.writer.write(b"x" * (rpc.MAX_MESSAGE_BYTES + 10) + b"\n")
        answer = await bad.answer(None)
        assert "at most" in answer["error"]["message"]
        assert await bad.reader.read() == b""  # closed by the service
        assert (await good.send("M118 and still")).lines == ("and still",)


async def test_a_client_that_leaves_mid_request_costs_nothing(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as good:
        async with raw_client(served) as leaver:
            leaver.writer.write(rpc.encode_message(rpc.request(1, "send", {"printer": "sim", "command": "G4 S1"})))
            await leaver.writer.drain()
        reply = await good.send("M118 after")
        assert reply.lines == ("after",)


async def test_late_joiners_get_history_and_the_socket_is_the_owners_alone(tmp_path: Path) -> None:
    async with serving(tmp_path) as served:
        mode = served.socket.stat().st_mode
        assert stat.S_ISSOCK(mode) and stat.S_IMODE(mode) == 0o600
        assert stat.S_IMODE(served.socket.parent.stat().st_mode) == 0o700
        async with marlin_aio.connect(served.url()) as printer:
            await printer.send("M118 for the record")
            await until(lambda: printer.latest is not None, "a reading")
        async with raw_client(served) as late:
            history = (await late.call("history", printer="sim", seconds=60))["result"]
            assert history["readings"], "readings kept for clients that join later"
            texts = [line["text"] for line in history["console"]]
            assert "M118 for the record" in texts and "for the record" in texts
            assert any(text.startswith("connected:") for text in texts)


async def test_a_second_service_on_the_same_socket_is_refused(tmp_path: Path) -> None:
    async with serving(tmp_path) as served:
        second = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "serve",
            "--sim",
            "--socket",
            str(served.socket),
            stderr=asyncio.subprocess.PIPE,
        )
        _, err = await asyncio.wait_for(second.communicate(), 60)
        assert second.returncode == 2
        assert "already running" in err.decode()
        assert served.process.returncode is None


async def test_cli_commands_use_a_served_printer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    async with serving(tmp_path) as served:
        url = served.url()
        result = await asyncio.to_thread(runner.invoke, app, ["send", "--port", url, "M118 hello"])
        assert result.exit_code == 0, result.output
        assert "hello" in result.output
        result = await asyncio.to_thread(runner.invoke, app, ["set", "--port", url, "--hotend", "abc"])
        assert result.exit_code == 2
        result = await asyncio.to_thread(
            runner.invoke, app, ["set", "--port", url, "--hotend", "40", "--wait", "--timeout", "30"]
        )
        assert result.exit_code == 0, result.output
        assert "reached" in result.output
        log = tmp_path / "served.csv"
        result = await asyncio.to_thread(
            runner.invoke, app, ["log", "--port", url, "--duration", "1.5", "--interval", "0.1", "-o", str(log)]
        )
        assert result.exit_code == 0, result.output
        assert len(log.read_text().splitlines()) > 3
        # A print from the CLI: its plan of the file is sent to the service, which prints it.
        gcode = _gcode(tmp_path / "cli.gcode", 100)
        result = await asyncio.to_thread(runner.invoke, app, ["print", "--port", url, str(gcode)])
        assert result.exit_code == 0, result.output
        assert "done: 100 commands" in result.output


@contextlib.contextmanager
def sim_process(*options: str) -> Iterator[str]:
    """A simulated printer on a pty of its own process (`marlin-sim --sim-speed 50` and `options`), so that it
    outlives a service that holds it; yields the pty's path."""
    import subprocess

    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_aio.simulator", "--sim-speed", "50", *options], stdout=subprocess.PIPE, text=True
    )
    assert process.stdout is not None
    path = process.stdout.readline().strip()
    try:
        yield path
    finally:
        process.terminate()
        process.wait(10)


@pytest.fixture
def pty_sim_path() -> Iterator[str]:
    """A simulated printer on a pty of its own process (`marlin-sim`), for a service to hold."""
    with sim_process() as path:
        yield path


async def test_a_command_asked_for_a_port_the_service_holds_goes_through_the_service(
    tmp_path: Path, pty_sim_path: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    async with serving(tmp_path, "--port", f"bench={pty_sim_path}", "--interval", "0.05") as served:
        monkeypatch.setenv(SOCKET_ENV, str(served.socket))
        assert service_holding(pty_sim_path) == "serve:bench"
        result = await asyncio.to_thread(runner.invoke, app, ["send", "--port", pty_sim_path, "M118 via service"])
        assert result.exit_code == 0, result.output
        assert "held by marlin-temp serve" in result.output
        assert "via service" in result.output


def test_served_ports_parse() -> None:
    from marlin_aio.aio.servicepaths import default_socket_path, parse_served_port

    assert parse_served_port("serve:a@/x/y.sock") == ("a", "/x/y.sock")
    assert parse_served_port("serve:") == (None, str(default_socket_path()))
    assert parse_served_port("serve:a@tcp://127.0.0.1:7125") == ("a", "tcp://127.0.0.1:7125")
    assert parse_served_port("serve:/run/x.sock") == (None, "/run/x.sock")
    with pytest.raises(ValueError, match="serve:NAME"):
        parse_served_port("/dev/ttyUSB0")


def test_a_socket_path_nobody_listens_at_is_one_error_line(tmp_path: Path) -> None:
    result = runner.invoke(app, ["send", "--port", f"serve:sim@{tmp_path / 'x.sock'}", "M105"])
    assert result.exit_code != 0
    assert "no marlin-temp serve is listening" in result.output
    assert len(result.output.strip().splitlines()) == 1


async def test_the_service_logs_every_printer_with_the_prints_file_and_line(tmp_path: Path) -> None:
    gcode = _gcode(tmp_path / "logged.gcode", 600)
    # Polled every 10 ms, logged every 50: the rows keep the log's schedule, not the polls'.
    args = ("--sim", "--sim-speed", "50", "--interval", "0.01", "--log-interval", "0.05")
    async with serving(tmp_path, *args) as served, marlin_aio.connect(served.url()) as printer:
        handle = await printer.start_print(gcode)
        await handle.wait()
        logs = tmp_path / "logs"

        def rows() -> list[dict[str, Any]]:
            files = list(logs.glob("sim-*.jsonl"))
            return [json.loads(line) for f in files for line in f.read_text().splitlines()]

        await until(lambda: any("print" in row for row in rows()), "a logged row with the print")
        printing = [row["print"] for row in rows() if "print" in row]
        assert {p["file"] for p in printing} == {"logged.gcode"}
        lines = [p["line"] for p in printing]
        assert lines == sorted(lines) and 0 <= lines[0] <= lines[-1] <= 600
        assert all(row["heaters"]["hotend"]["actual_c"] > 0 for row in rows())
        times = [row["epoch_s"] for row in rows()]
        assert len(times) > 3 and min(b - a for a, b in itertools.pairwise(times)) >= 0.024  # half an interval
    # The file is the `log --format jsonl` format: `plot` reads it.
    log_file = next((tmp_path / "logs").glob("sim-*.jsonl"))
    result = runner.invoke(app, ["plot", str(log_file), "--show"])
    assert result.exit_code == 0, result.output


async def test_the_farm_is_the_service_plus_its_bridge(tmp_path: Path, broker: Broker) -> None:
    # One supervisor: while the farm publishes to MQTT, its printers are reached through its socket as well.
    args = ("--sims", "1", "--sim-speed", "50", "--broker", f"127.0.0.1:{broker.port}", "--interval", "0.05")
    async with serving(tmp_path, *args, command="farm") as served, marlin_aio.connect(served.url("sim1")) as printer:
        assert (await printer.send("M118 through the farm")).lines == ("through the farm",)
        await until(lambda: printer.latest is not None, "a reading from the farm's poller")


async def test_the_tcp_listener_takes_only_clients_with_the_token(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import socket as sockets

    with sockets.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    token = "a-token-of-twenty-chars"
    monkeypatch.setenv("MARLIN_SERVE_TOKEN", token)
    args = ("--sim", "--sim-speed", "50", "--interval", "0.05", "--tcp", str(port))
    async with serving(tmp_path, *args) as served:
        url = f"serve:sim@tcp://127.0.0.1:{port}"
        async with marlin_aio.connect(url) as printer:
            assert (await printer.send("M118 over tcp")).lines == ("over tcp",)
        # Without the token, or with a wrong one: one error line, then the connection closes; nothing ran.
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(rpc.encode_message(rpc.request(1, "send", {"printer": "sim", "command": "M118 sneaky"})))
        answer = json.loads(await asyncio.wait_for(reader.readline(), 30))
        assert "auth" in answer["error"]["message"]
        assert await asyncio.wait_for(reader.read(), 30) == b""
        writer.close()
        monkeypatch.setenv("MARLIN_SERVE_TOKEN", "not-the-token-at-all")
        with pytest.raises(marlin_aio.PortPermissionError, match="wrong token"):
            async with marlin_aio.connect(url):
                pass
        async with raw_client(served) as local:  # the owner-only socket needs no token
            history = (await local.call("history", printer="sim", seconds=60))["result"]
            texts = [line["text"] for line in history["console"]]
            assert "over tcp" in texts and not any("sneaky" in text for text in texts)


async def test_an_emergency_stop_gets_through_a_client_with_every_request_slot_taken(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, raw_client(served) as busy, marlin_aio.connect(served.url()) as other:
        halted = asyncio.Event()
        other.on_link_event(lambda event: halted.set() if event.kind == "halted" else None)
        for number in range(40):  # more than a client may have under way: the last ones are refused as busy
            params = {"printer": "sim", "command": "G4 S5"}
            busy.writer.write(rpc.encode_message(rpc.request(100 + number, "send", params)))
        busy.writer.write(rpc.encode_message(rpc.request(1, "emergency_stop", {"printer": "sim"})))
        answer = await busy.answer(1)
        assert answer.get("result", "refused") is None, answer
        await asyncio.wait_for(halted.wait(), 30)


async def test_two_cancels_run_the_script_once_and_a_client_leaving_mid_cancel_does_not_stop_it(
    tmp_path: Path,
) -> None:
    gcode = _gcode(tmp_path / "long.gcode", 4000)
    script = ["G91", "G1 Z5", "G90"]
    async with (
        serving(tmp_path) as served,
        marlin_aio.connect(served.url()) as a,
        marlin_aio.connect(served.url()) as b,
    ):
        start = (await a.position())["Z"]
        handle = await a.start_print(gcode)
        # One client asks and leaves at once; another asks too: the script runs once, to its end.
        async with raw_client(served) as leaver:
            leaver.writer.write(rpc.encode_message(rpc.request(1, "cancel", {"printer": "sim", "script": script})))
            await leaver.writer.drain()
        await b.call("cancel", script=script)  # type: ignore[attr-defined]
        assert (await handle.wait()).state is marlin_aio.PrintState.CANCELLED
        assert (await a.position())["Z"] == pytest.approx(start + 5)


async def test_a_send_given_up_by_its_caller_never_runs(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        # 0.4 s at 50x: holds the queue far longer than the caller waits, even on a loaded machine.
        dwell = asyncio.create_task(printer.send("G4 S20"))
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(printer.send("M118 given up"), 0.01)
        await dwell
        assert (await printer.send("M118 after")).lines == ("after",)
        async with raw_client(served) as reader:
            history = (await reader.call("history", printer="sim", seconds=60))["result"]
        texts = [line["text"] for line in history["console"]]
        assert "after" in texts and "given up" not in texts


async def test_bad_timeouts_and_passwords_in_the_console(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, raw_client(served) as client:
        for timeout in ("NaN", "Infinity", "1e308", "-1"):
            params = f'{{"printer":"sim","command":"M105","timeout_s":{timeout}}}'
            line = f'{{"jsonrpc":"2.0","id":7,"method":"send","params":{params}}}\n'
            answer = await client.raw(line.encode()) if timeout in ("NaN", "Infinity") else None
            if answer is not None:
                assert answer["error"]["code"] == rpc.PARSE_ERROR
            else:
                client.writer.write(line.encode())
                answer = await client.answer(7)
                assert answer["error"]["code"] == rpc.INVALID_PARAMS, answer
        await client.call("send", printer="sim", command="M512 P1234 S9999")
        history = (await client.call("history", printer="sim", seconds=60))["result"]
        assert not any("9999" in line["text"] or "1234" in line["text"] for line in history["console"])


async def test_a_stopped_service_fails_its_clients_waits_within_the_silence_bound(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import marlin_aio.aio.rpcclient as rpcclient

    monkeypatch.setattr(rpcclient, "SILENCE_S", 2.0)
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        served.process.send_signal(signal.SIGSTOP)
        try:
            with pytest.raises(marlin_aio.ConnectionLostError, match="has said nothing for"):
                await asyncio.wait_for(printer.send("M105"), 30)
        finally:
            served.process.send_signal(signal.SIGCONT)


async def test_a_socket_folder_others_may_enter_or_a_file_in_the_way_is_refused(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o755)
    shared.chmod(0o755)
    victim = tmp_path / "mine" / "notes.txt"
    victim.parent.mkdir(mode=0o700)
    victim.write_text("keep me")
    for socket_path, words in ((shared / "s.sock", "others may enter it"), (victim, "is not a socket")):
        result = await asyncio.to_thread(
            runner.invoke, app, ["serve", "--sim", "--socket", str(socket_path), "--no-log", "--duration", "5"]
        )
        assert result.exit_code != 0
        assert words in result.output
    assert victim.read_text() == "keep me"


def test_a_registry_left_by_a_killed_service_is_not_believed(tmp_path: Path) -> None:
    socket_path = tmp_path / "serve.sock"
    registry = {"pid": 2**22 + 12345, "socket": str(socket_path), "printers": {"a": "/dev/ttyUSB7"}}
    (tmp_path / "serve.json").write_text(json.dumps(registry))
    assert service_holding("/dev/ttyUSB7", socket_path) is None
    registry["pid"] = os.getpid()
    (tmp_path / "serve.json").write_text(json.dumps(registry))
    assert service_holding("/dev/ttyUSB7", socket_path) == f"serve:a@{socket_path}"


def test_serve_help_says_where_things_live_and_which_extra_to_install() -> None:
    result = runner.invoke(app, ["serve", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    for words in ("$MARLIN_SERVE_SOCKET", "serve.json", "uploads/", "--log-dir", "pip install 'marlin-aio[serve]'"):
        assert words in result.output, words
