"""The printer's password (PASSWORD_FEATURE, M511) in the CLI: from $MARLIN_PASSWORD or --password-file, never
from the command line, where `ps` shows it to every user of the machine."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from typer.testing import CliRunner

from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.main import app

runner = CliRunner()


def test_a_password_on_the_command_line_is_refused_before_anything_is_opened() -> None:
    for command in (["send", "M105"], ["set", "--hotend", "200"], ["watch"], ["print", "x.gcode"], ["terminal"]):
        result = runner.invoke(app, [*command, "--port", "/dev/nonexistent", "--password", "1234"])
        assert result.exit_code == 2, (command, result.output)
        lines = result.output.strip().splitlines()
        assert len(lines) == 1, result.output
        assert "visible to every user" in lines[0] and "MARLIN_PASSWORD" in lines[0] and "--password-file" in lines[0]
        assert "1234" not in result.output


async def test_the_environment_and_a_file_unlock_a_locked_printer(tmp_path: Path) -> None:
    secret = tmp_path / "printer-password"
    secret.write_text("1234\n")
    async with serve_pty(SimulatorConfig(password="1234"), time_scale=20) as sim:
        by_env = await asyncio.to_thread(
            runner.invoke, app, ["send", "--port", sim.url, "M104 S201"], env={"MARLIN_PASSWORD": "1234"}
        )
        by_file = await asyncio.to_thread(
            runner.invoke, app, ["send", "--port", sim.url, "--password-file", str(secret), "M104 S202"]
        )
        executed = list(sim.printer.executed)
    assert by_env.exit_code == 0, by_env.output
    assert by_file.exit_code == 0, by_file.output
    assert "M104 S201" in executed and "M104 S202" in executed
    assert "1234" not in by_env.output + by_file.output


@pytest.mark.parametrize(
    ("content", "message"),
    [("", "is empty"), (None, "No such file")],
)
def test_a_password_file_that_cannot_be_used_is_one_line(tmp_path: Path, content: str | None, message: str) -> None:
    secret = tmp_path / "printer-password"
    if content is not None:
        secret.write_text(content)
    result = runner.invoke(app, ["send", "--sim", "--password-file", str(secret), "M105"])
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and message in result.output


def test_a_heater_limit_can_be_raised_for_an_all_metal_hotend_and_is_kept_otherwise() -> None:
    refused = runner.invoke(app, ["send", "--sim", "M104S280"])
    assert refused.exit_code == 2 and "above the limit of 260 C" in refused.output
    allowed = runner.invoke(app, ["send", "--sim", "--max-hotend", "300", "M104S280", "M105"])
    assert allowed.exit_code == 0, allowed.output
    assert "/260.00" in allowed.output  # the simulated board holds its own cap, as Marlin would
