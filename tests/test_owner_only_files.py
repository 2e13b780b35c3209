"""Every file `marlin-temp serve` writes is readable by its owner only (issue 33): the wire log, the temperature logs,
uploads, serve.json, the API key and the TCP token are 0600 and the folders made for them 0700, whatever the umask;
an existing wire log or temperature log that others could read is made 0600 as it is opened, and the user is told.

Through a real `marlin-temp serve` process over the simulator (`serving()`), run under a umask of 0, so that only
the modes the service asks for at creation can make the files private; and `WireLog` and `TemperatureLog` directly.
"""

from __future__ import annotations

import contextlib
import logging
import os
import stat
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import until
from test_serve import raw_client, serving
from test_serve_octoprint import _free_port
from typer.testing import CliRunner

from marlin_aio import HeaterReading, TemperatureReading, Temperatures
from marlin_aio.aio import WireLog
from marlin_aio.protocol import ReadingSource
from marlin_temp.logs.files import TemperatureLog
from marlin_temp.main import app


@contextlib.contextmanager
def umask(mask: int) -> Iterator[None]:
    """This process's umask (and that of the processes it starts) is `mask` inside the block."""
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def modes_under(*roots: Path) -> dict[Path, tuple[str, int]]:
    """Every file, folder and socket under `roots` (the roots included): its kind and permission bits."""
    found: dict[Path, tuple[str, int]] = {}
    for root in roots:
        for path in [root, *root.rglob("*")] if root.is_dir() else [root]:
            mode = path.lstat().st_mode
            kind = "folder" if stat.S_ISDIR(mode) else "socket" if stat.S_ISSOCK(mode) else "file"
            assert stat.S_ISDIR(mode) or stat.S_ISSOCK(mode) or stat.S_ISREG(mode), f"{path}: a link or a device?"
            found[path] = (kind, stat.S_IMODE(mode))
    return found


def not_owner_only(found: dict[Path, tuple[str, int]]) -> list[str]:
    """What in `found` others may read or enter: folders must be 0700, files and sockets 0600."""
    return [
        f"{path} ({kind} {mode:o})"
        for path, (kind, mode) in sorted(found.items())
        if mode != (0o700 if kind == "folder" else 0o600)
    ]


def log_rows(folder: Path) -> int:
    return sum(len(path.read_text().splitlines()) for path in folder.glob("*.jsonl")) if folder.is_dir() else 0


async def test_every_file_and_folder_the_service_writes_is_its_owners_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    wire = tmp_path / "wire.log"
    log_dir = tmp_path / "logs" / "by" / "day"  # three levels the service makes (the last --log-dir is the one used)
    for env in ("MARLIN_SERVE_API_KEY", "MARLIN_SERVE_TOKEN"):
        monkeypatch.delenv(env, raising=False)  # so the service makes its own api-key and token files
    args = ["--sim", "--sim-speed", "50", "--interval", "0.05", "--log-dir", str(log_dir), "--log-interval", "0.1"]
    args += ["--wire-log", str(wire), "--tcp", f"127.0.0.1:{_free_port()}", "--octoprint", f"127.0.0.1:{_free_port()}"]
    with umask(0):
        async with serving(tmp_path, *args) as served, raw_client(served) as client:
            folder = served.socket.parent
            # An upload finished (a file in uploads/) and one under way (its .part file).
            done = await client.call("upload", lines=["G28", "G1 X10"], done=True)
            assert "result" in done, done
            started = await client.call("upload", lines=["G28"])
            assert "result" in started, started
            # A few seconds of polling: rows in the day's log, lines both ways in the wire log.
            await until(lambda: log_rows(log_dir) >= 20, "rows in the temperature log", limit_s=30)
            await until(lambda: " > " in wire.read_text() and " < " in wire.read_text(), "the wire log's lines")
            running = modes_under(folder, tmp_path / "logs", wire)
        stopped = modes_under(folder, tmp_path / "logs", wire)
    names = {path.relative_to(tmp_path).as_posix() for path in running}
    expected = {"run", "run/serve.sock", "run/serve.json", "run/api-key", "run/token", "run/uploads", "wire.log"}
    assert expected <= names, names
    assert {"logs", "logs/by", "logs/by/day"} <= names
    assert any(name.endswith(".jsonl") for name in names) and any(name.endswith(".part") for name in names), names
    assert any(name.startswith("run/uploads/") and name.endswith(".gcode") for name in names), names
    assert not_owner_only(running) == []
    assert not_owner_only(stopped) == []


def test_an_existing_wire_log_others_could_read_is_made_owner_only_and_the_user_is_told(tmp_path: Path) -> None:
    wire = tmp_path / "wire.log"
    wire.write_text("an earlier session\n")
    wire.chmod(0o644)
    result = CliRunner().invoke(app, ["send", "--sim", "--wire-log", str(wire), "M105"])
    assert result.exit_code == 0, result.output
    assert f"--wire-log {wire} is readable by others (644): it is made owner-only (600)" in result.output
    assert stat.S_IMODE(wire.stat().st_mode) == 0o600
    text = wire.read_text()
    assert text.startswith("an earlier session\n") and " > " in text  # appended to, not replaced


def test_a_wire_log_is_made_owner_only_whatever_the_umask(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    fresh, shared = tmp_path / "fresh.log", tmp_path / "shared.log"
    shared.write_text("kept\n")
    shared.chmod(0o664)
    with umask(0), caplog.at_level(logging.WARNING, logger="marlin_aio"):
        for path in (fresh, shared):
            session = WireLog(path).connection("/dev/ttyUSB0", 250000)
            session.line(time.time(), "sent", "M105")
            session.end("closed")
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o600
    assert stat.S_IMODE(shared.stat().st_mode) == 0o600
    assert shared.read_text().startswith("kept\n") and "> M105" in shared.read_text()
    warned = [record.getMessage() for record in caplog.records]
    assert warned == [f"the wire log {shared} was readable by others (664): made it owner-only (600)"]


async def test_a_temperature_log_is_made_owner_only_whatever_the_umask(tmp_path: Path) -> None:
    reading = TemperatureReading(Temperatures({"T": HeaterReading(21.5, 0.0, 0)}), 0.0, time.time(), ReadingSource.POLL)
    fresh, shared = tmp_path / "fresh.csv", tmp_path / "shared.csv"
    shared.touch()
    shared.chmod(0o644)
    with umask(0):
        for path in (fresh, shared):
            async with TemperatureLog(path) as log:
                log.add(reading)
            assert log.tightened_from == (None if path is fresh else 0o644)
            assert stat.S_IMODE(path.stat().st_mode) == 0o600
            assert len(path.read_text().splitlines()) == 2  # the header and the row
