"""The service's edges found by trying it as a new user and attacking it as a print farm would, each through a real
`marlin-temp serve` process: prints only from regular files (a FIFO or /dev/zero is refused and jams nothing), a
target for a heater the printer lacks refused from every door, and a locked printer on --port unlocked with
$MARLIN_PASSWORD as every other command does."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_serve import raw_client, serving, sim_process

import marlin_aio


async def test_a_fifo_or_dev_zero_is_refused_and_jams_nothing(tmp_path: Path) -> None:
    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    good = tmp_path / "good.gcode"
    good.write_text("G28\nG1 X10\n")
    async with serving(tmp_path) as served, raw_client(served) as raw:
        for path in (fifo, Path("/dev/zero"), tmp_path):
            answer = await raw.call("start_print", printer="sim", path=str(path))
            assert "not a regular file" in answer["error"]["message"], answer
        job = (await raw.call("job", printer="sim"))["result"]
        assert job is None  # nothing was started, nothing holds the printer
        # The printer is free: a real file prints to the end, and the service still stops on SIGTERM (serving()).
        async with marlin_aio.connect(served.url()) as printer:
            handle = await printer.start_print(good)
            assert (await handle.wait()).state is marlin_aio.PrintState.DONE


async def test_a_target_for_a_heater_the_printer_lacks_is_refused_before_anything_is_sent(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, raw_client(served) as raw:
        await raw.call("status", printer="sim")
        answer = await raw.call("set_temperatures", printer="sim", hotend=200, tool=9)
        assert answer["error"]["data"]["type"] == "ValueError"
        assert "has no hotend 9 (it has 1 hotend, bed)" in answer["error"]["message"], answer
        answer = await raw.call("set_temperatures", printer="sim", chamber=40)
        assert "has no chamber" in answer["error"]["message"], answer
        status = (await raw.call("status", printer="sim"))["result"]
        assert status["latest"]["heaters"]["T"][1] == 0  # no target reached the printer


@pytest.fixture
def locked_sim_path() -> Iterator[str]:
    """A simulated printer locked with PASSWORD_FEATURE (password 1234), on a pty of its own process."""
    with sim_process("--password", "1234") as path:
        yield path


async def test_serve_port_unlocks_a_locked_printer_with_marlin_password(
    tmp_path: Path, locked_sim_path: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MARLIN_PASSWORD", "1234")
    async with (
        serving(tmp_path, "--port", f"locked={locked_sim_path}", "--interval", "0.05") as served,
        marlin_aio.connect(served.url("locked")) as printer,
    ):
        assert (await printer.send("M118 unlocked")).lines == ("unlocked",)
    assert not any("1234" in line for line in served.lines)  # never printed


@pytest.mark.skipif(os.geteuid() != 0, reason="making a folder another user owns needs root")
def test_a_socket_folder_another_user_made_first_is_one_clear_line(tmp_path: Path) -> None:
    folder = tmp_path / "taken"
    folder.mkdir(mode=0o755)
    os.chown(folder, 65534, 65534)  # as another local user would make it first under /tmp
    result = subprocess.run(
        [sys.executable, "-m", "marlin_temp", "serve", "--sim", "--no-log", "--socket", str(folder / "serve.sock")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0 and len(lines) == 1, result.stderr
    assert "belongs to user" in lines[0] and "65534" in lines[0] and "--socket" in lines[0], lines
    assert not (folder / "serve.sock").exists()
