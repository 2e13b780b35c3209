"""`--on-done CMD` on `set --wait` and `print` (issue 25): the command runs once through the shell with the outcome in
its environment. Through CliRunner against the simulated printer (`--sim`); the hook writes its environment to a
file the test reads."""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console
from typer.testing import CliRunner

from marlin_temp.common.hooks import Done, run_on_done
from marlin_temp.main import app

runner = CliRunner()


def hook_env(tmp_path: Path) -> tuple[str, Path]:
    """An --on-done command writing its environment to a file, and the file."""
    out = tmp_path / "env.txt"
    return f"env > '{out}'", out


def read_env(path: Path) -> dict[str, str]:
    pairs = (line.partition("=") for line in path.read_text(encoding="utf-8").splitlines())
    return {name: value for name, _, value in pairs if name.startswith("MARLIN_TEMP_")}


def test_set_wait_tells_the_hook_the_target_was_reached(tmp_path: Path) -> None:
    hook, out = hook_env(tmp_path)
    args = ["set", "--sim", "--sim-speed", "50", "--hotend", "50", "--wait", "--on-done", hook]
    result = runner.invoke(app, args, env={"COLUMNS": "100"})
    assert result.exit_code == 0, result.output
    env = read_env(out)
    assert env["MARLIN_TEMP_EVENT"] == "set"
    assert env["MARLIN_TEMP_OUTCOME"] == "reached"
    assert env["MARLIN_TEMP_EXIT"] == "0"
    assert env["MARLIN_TEMP_PORT"].startswith("/dev/")
    assert env["MARLIN_TEMP_MESSAGE"].startswith("hotend 50 C reached on /dev/")
    assert env["MARLIN_TEMP_ELAPSED_S"].isdigit()
    assert "MARLIN_TEMP_FILE" not in env


def test_set_wait_that_times_out_tells_the_hook_and_keeps_its_exit_code(tmp_path: Path) -> None:
    hook, out = hook_env(tmp_path)
    args = ["set", "--sim", "--hotend", "250", "--wait", "--wait-timeout", "0.5", "--on-done", hook]
    result = runner.invoke(app, args, env={"COLUMNS": "100"})
    assert result.exit_code == 9, result.output
    env = read_env(out)
    assert env["MARLIN_TEMP_OUTCOME"] == "timeout"
    assert env["MARLIN_TEMP_EXIT"] == "9"
    assert "did not reach the target" in env["MARLIN_TEMP_MESSAGE"]


def test_a_failing_hook_is_one_warning_and_leaves_the_exit_code(tmp_path: Path) -> None:
    args = ["set", "--sim", "--sim-speed", "50", "--hotend", "40", "--wait", "--on-done", "exit 5"]
    result = runner.invoke(app, args, env={"COLUMNS": "100"})
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if "--on-done" in line]
    assert warnings == ["warning: --on-done exited with code 5"]


def test_set_on_done_without_wait_exits_2_and_runs_nothing(tmp_path: Path) -> None:
    hook, out = hook_env(tmp_path)
    result = runner.invoke(app, ["set", "--sim", "--hotend", "50", "--on-done", hook])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "--on-done" in lines[0] and "--wait" in lines[0]
    assert not out.exists()


def test_print_tells_the_hook_it_is_done_with_the_file(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\n" + "".join(f"G1 X{i} Y{i}\n" for i in range(20)))
    hook, out = hook_env(tmp_path)
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50", "--on-done", hook])
    assert result.exit_code == 0, result.output
    env = read_env(out)
    assert env["MARLIN_TEMP_EVENT"] == "print"
    assert env["MARLIN_TEMP_OUTCOME"] == "done"
    assert env["MARLIN_TEMP_EXIT"] == "0"
    assert env["MARLIN_TEMP_FILE"] == str(gcode.resolve())
    assert env["MARLIN_TEMP_MESSAGE"].startswith("print of part.gcode on /dev/")


def test_a_print_that_cannot_connect_tells_the_hook_it_failed(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\n")
    hook, out = hook_env(tmp_path)
    result = runner.invoke(app, ["print", str(gcode), "--port", "/dev/no-such-port", "--on-done", hook])
    assert result.exit_code == 3, result.output
    env = read_env(out)
    assert env["MARLIN_TEMP_OUTCOME"] == "failed" and env["MARLIN_TEMP_EXIT"] == "3"


async def test_a_hook_that_hangs_is_stopped_with_a_warning(tmp_path: Path) -> None:
    errors = Console(record=True, width=200)
    started = time.monotonic()
    await run_on_done("sleep 60", Done("set", "reached", 0, "hi"), errors, timeout_s=0.5)
    # Bounded by the timeout, not by the command: far below its 60 s even on a loaded machine.
    assert time.monotonic() - started < 30
    assert "--on-done was still running after 0.5 s: stopped" in errors.export_text()


async def test_the_message_is_one_line(tmp_path: Path) -> None:
    out = tmp_path / "message.txt"
    errors = Console(record=True, width=200)
    done = Done("print", "failed", 1, "the print stopped:\nline two", port="/dev/ttyUSB0")
    await run_on_done(f"printf %s \"$MARLIN_TEMP_MESSAGE\" > '{out}'", done, errors)
    assert out.read_text(encoding="utf-8") == "the print stopped: line two"
    assert not errors.export_text()
