"""`marlin-temp print` through CliRunner and a real process, against the simulated printer."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from marlin_aio.simulator import Faults, SimulatorConfig, serve_pty
from marlin_temp.connect import Exit
from marlin_temp.main import app

runner = CliRunner()


def write_gcode(path: Path, lines: int) -> Path:
    path.write_text(
        "; test part\n" + "".join(f"G1 X{(i * 0.5) % 200:.3f} Y{(i * 0.37) % 200:.3f}\n" for i in range(lines))
    )
    return path


def test_print_streams_the_file_and_reports(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 2_000)
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50"])
    assert result.exit_code == 0, result.output
    assert "done: 2000 commands" in result.output
    assert "ping-pong" in result.output  # the default: no link fault can run a line twice


@pytest.mark.parametrize("option", ["--send-ahead", "--window=96"])
def test_print_send_ahead(tmp_path: Path, option: str) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 300)
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50", option])
    assert result.exit_code == 0, result.output
    assert "send-ahead" in result.output and "done: 300 commands" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["print", "/no/such/file.gcode", "--sim"], "no such file"),
        (["print", "{bad}", "--sim"], "line 2: command contains non-ASCII"),
        (["print", "{good}", "--sim", "--ping-pong", "--window", "64"], "do not combine"),
    ],
)
def test_print_bad_input_exits_2_with_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    bad = tmp_path / "bad.gcode"
    bad.write_text("G28\nM117 h\u00e9llo\n")
    good = write_gcode(tmp_path / "good.gcode", 3)
    args = [a.replace("{bad}", str(bad)).replace("{good}", str(good)) for a in args]
    result = runner.invoke(app, args)
    assert result.exit_code == Exit.USAGE, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], result.output


async def test_a_stalled_print_exits_9_with_the_diagnosis(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 3_000)
    faults = Faults(silent_after_lines=1_500)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), faults, time_scale=50) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url, "--timeout", "1"])
    assert result.exit_code == Exit.TIMEOUT, result.output
    assert "print stalled at line" in result.output
    assert "silent" in result.output
    assert "last lines sent (>>) and received (<<)" in result.output
    assert result.output.count(">>") >= 5


def test_ctrl_c_without_a_terminal_cancels_cleanly(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 50_000)
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_temp", "print", str(gcode), "--sim"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    assert "printing part.gcode" in process.stderr.readline()  # streaming has begun
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == Exit.INTERRUPTED, stderr
    assert "cancelled after line" in stderr
    assert "heaters and fan turned off" in stderr
    assert "Traceback" not in stderr
