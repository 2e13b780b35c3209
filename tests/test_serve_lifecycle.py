"""The service's life cycle through real processes: a `marlin-sim` process on a pty (so the printer outlives the
service), a `marlin-temp serve` process holding it, and a `marlin-temp print --port serve:p` process printing through
it; then the service is stopped (SIGTERM) or killed (SIGKILL, then started again).

What the simulator ran is read back from the printer itself once the service is gone: every line of the file is a
move to a position of its own (`G1 X<n % 200> Y<n // 200>`), so M114's position names the last line it ran.
"""

from __future__ import annotations

import asyncio
import json
import re
import signal
import sys
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import until
from test_serve import _read_lines, raw_client, sim_process

import marlin_aio
from marlin_aio.service import SOCKET_ENV

#: Lines of the test print: far more than run before the service is stopped.
PRINT_LINES = 20_000


@pytest.fixture
def sim_port() -> Iterator[str]:
    """A simulated printer on a pty of its own process, moves instant (so a move acknowledged has run)."""
    with sim_process("--motion-time-scale", "0") as path:
        yield path


def _part(path: Path) -> Path:
    path.write_text("".join(f"G1 X{line % 200} Y{line // 200} F6000\n" for line in range(1, PRINT_LINES + 1)))
    return path


@dataclass
class Service:
    """A `marlin-temp serve` process and the lines it printed."""

    socket: Path
    process: asyncio.subprocess.Process
    lines: list[str]
    reader: asyncio.Task[None]

    @property
    def url(self) -> str:
        return f"serve:p@{self.socket}"

    def said(self, text: str) -> list[str]:
        return [line for line in self.lines if text in line]


@asynccontextmanager
async def service(tmp_path: Path, port: str) -> AsyncIterator[Service]:
    """`marlin-temp serve --port p=PORT` on a socket in `tmp_path`, ready and connected; killed if still running
    at the end (the test ends it as it means to)."""
    socket = tmp_path / "run" / "serve.sock"
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "marlin_temp",
        "serve",
        "--socket",
        str(socket),
        "--no-log",
        "--port",
        f"p={port}",
        "--interval",
        "0.05",
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stderr is not None
    lines: list[str] = []
    served = Service(socket, process, lines, asyncio.create_task(_read_lines(process.stderr, lines)))
    try:
        await until(
            lambda: bool(served.said(": connected:")) or served.reader.done(), "the service to connect", limit_s=150
        )
        assert served.said(": connected:"), lines
        yield served
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
        await served.reader


async def _start_print(served: Service, gcode: Path, tmp_path: Path) -> asyncio.subprocess.Process:
    """Heaters on, then `marlin-temp print --port serve:p` in a process of its own; returned once the service's
    record says over 300 lines ran (past the first bounds of the feed)."""
    env = {**__import__("os").environ, SOCKET_ENV: str(served.socket)}
    heat = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "marlin_temp", "set", "--port", served.url, "--hotend", "200", "--bed", "60", env=env
    )
    assert await heat.wait() == 0
    printing = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "marlin_temp",
        "print",
        "--port",
        served.url,
        str(gcode),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    record = served.socket.parent / "jobs" / "p.json"

    def surely_run() -> int:
        try:
            return int(json.loads(record.read_text())["surely_run"])
        except (OSError, ValueError, KeyError):
            return 0

    await until(
        lambda: surely_run() > 300 or printing.returncode is not None, "the print to run 300 lines", limit_s=150
    )
    assert printing.returncode is None
    # The record is of the running print, owner-only.
    assert record.stat().st_mode & 0o777 == 0o600
    assert json.loads(record.read_text())["state"] == "running"
    return printing


async def _printer_state(port: str) -> tuple[int, dict[str, float | None]]:
    """The last line of the test print the simulator ran, and its heaters' targets, from the printer itself."""
    async with marlin_aio.connect(port) as printer:
        reply = await printer.send("M114")
        position = re.search(r"X:(\d+)\.\d+ Y:(\d+)\.\d+", " ".join(reply.lines) + " " + reply.ok.payload)
        assert position is not None, reply
        reading = await printer.read_temperatures()
    targets = {key: heater.target for key, heater in reading.temperatures.heaters.items()}
    return int(position[2]) * 200 + int(position[1]), targets


def _resume_line(output: str) -> int:
    found = re.findall(r"--from-line (\d+)", output)
    assert found, output
    return int(found[-1])


async def test_sigterm_mid_print_stops_it_turns_the_heaters_off_and_tells_the_exact_resume_line(
    tmp_path: Path, sim_port: str
) -> None:
    gcode = _part(tmp_path / "part.gcode")
    async with service(tmp_path, sim_port) as served:
        printing = await _start_print(served, gcode, tmp_path)
        served.process.send_signal(signal.SIGTERM)
        code = await asyncio.wait_for(served.process.wait(), 40)
        assert printing.stderr is not None
        output = (await asyncio.wait_for(printing.stderr.read(), 30)).decode()
        await printing.wait()
    assert code == 0, served.lines
    ran, targets = await _printer_state(sim_port)
    assert ran > 300
    assert targets == {"T": 0.0, "B": 0.0}, targets
    # The client heard where the print stopped: every line in flight was answered, so exactly the next one.
    assert "the service stopped (SIGTERM)" in output, output
    assert _resume_line(output) == ran + 1, output
    assert printing.returncode == 130
    # The operator too, and the record says it stopped there.
    assert served.said("print_stopped"), served.lines
    record = json.loads((served.socket.parent / "jobs" / "p.json").read_text())
    assert record["state"] == "stopped"
    assert record["surely_run"] == ran


async def test_after_sigkill_mid_print_the_restarted_service_reports_the_job_and_turns_the_heaters_off(
    tmp_path: Path, sim_port: str
) -> None:
    gcode = _part(tmp_path / "part.gcode")
    async with service(tmp_path, sim_port) as served:
        printing = await _start_print(served, gcode, tmp_path)
        served.process.send_signal(signal.SIGKILL)
        await served.process.wait()
        assert printing.stderr is not None
        output = (await asyncio.wait_for(printing.stderr.read(), 30)).decode()
        await printing.wait()
    ran, targets = await _printer_state(sim_port)
    assert ran > 300
    assert targets == {"T": 200.0, "B": 60.0}, "killed, the service could not turn them off"
    # The client: the service went away; its resume line is past every line the printer ran.
    assert "the service went away" in output, output
    told = _resume_line(output)
    assert told > ran, output

    async with service(tmp_path, sim_port) as again:
        await until(lambda: bool(again.said("heaters_off")), "the heaters turned off", limit_s=150)
        reported = again.said("interrupted_job")
        assert len(reported) == 1, again.lines
        async with raw_client(again) as client:  # type: ignore[arg-type]
            status = (await client.call("status", printer="p"))["result"]
        job = status["interrupted_job"]
        assert job["state"] == "killed"
        assert job["resume_line"] > ran
        assert job["surely_run"] <= ran
        assert f"--from-line {job['resume_line']}" in reported[0]
        async with marlin_aio.connect(again.url) as printer:
            reading = await printer.read_temperatures()
        assert {key: h.target for key, h in reading.temperatures.heaters.items()} == {"T": 0.0, "B": 0.0}
        again.process.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(again.process.wait(), 30) == 0


def test_a_bounded_job_feeds_no_line_past_its_bound_and_reports_the_bound_as_what_may_have_run() -> None:
    from marlin_aio.protocol import PrintJob
    from marlin_aio.protocol.rpc import progress_from_json, progress_to_json

    job = PrintJob(["G1 X1", "; a comment", "G1 X2", "", "G1 X3", "G1 X4"])
    job.feed_limit = 3
    fed = [job.next_command(), job.next_command()]
    assert [item[:2] for item in fed if item] == [("G1 X1", 1), ("G1 X2", 3)]
    assert job.next_command() is None  # line 5 is past the bound: read, held, not fed
    assert job.held_line == 5 and not job.exhausted
    assert job.progress(0.0).may_have_run_through == 3  # the bound: lines up to it may go before the next report
    job.feed_limit = 10
    assert (job.next_command() or ())[:2] == ("G1 X3", 5)  # the held line, once the bound is past it
    assert (job.next_command() or ())[:2] == ("G1 X4", 6)
    assert job.next_command() is None and job.exhausted
    # Nothing more will be fed: the last line written (as the connection writes them).
    for line in (1, 3, 5):
        job.sent(line)
    assert job.progress(0.0).may_have_run_through == 5  # line 6 was fed and never written: it did not run
    job.sent(6)
    assert job.progress(0.0).may_have_run_through == 6
    # On the wire, and from a service that does not send it.
    told = progress_to_json(job.progress(0.0))
    assert progress_from_json(told).may_have_run_through == 6
    del told["may_have_run_through"]
    assert progress_from_json(told).may_have_run_through is None


def test_an_unbounded_job_reports_the_last_line_written() -> None:
    from marlin_aio.protocol import PrintJob

    job = PrintJob(["G1 X1", "G1 X2", "G1 X3"])
    for _ in range(2):
        item = job.next_command()
        assert item is not None
        job.sent(item[1])
    job.next_command()  # read, not written (a print that stops now drops it)
    assert job.progress(0.0).may_have_run_through == 2


def test_the_journal_keeps_one_owner_only_record_per_printer_replaced_whole(tmp_path: Path) -> None:
    from marlin_aio.service.journal import JobRecord, Journal

    journal = Journal(tmp_path / "jobs")
    assert journal.read("a/b") is None
    record = JobRecord("a/b", "part.gcode", "running", surely_run=10, may_have_run_through=210)
    journal.write(record)
    assert journal.read("a/b") == record
    assert [p.name for p in (tmp_path / "jobs").iterdir()] == ["a%2Fb.json"]  # one file, no temporary left
    assert journal.path_of("a/b").stat().st_mode & 0o777 == 0o600
    assert record.resume_line == 211  # not drained: after every line that may have run
    assert record.with_state("stopped").resume_line == 11  # drained to its end: the next line exactly
    journal.path_of("a/b").write_text("{not json")
    assert journal.read("a/b") is None  # unreadable: ignored (and logged), never a crash at start
