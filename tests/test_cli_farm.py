"""`marlin-temp farm`'s arguments and its TOML file: every mistake is one line and exit 2, before anything opens."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from marlin_aio.farm.config import load_config, specs_from_options
from marlin_temp.common.connect import Exit
from marlin_temp.main import app

runner = CliRunner()


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


def test_a_toml_file_lists_printers_with_defaults(tmp_path: Path) -> None:
    config = tmp_path / "farm.toml"
    config.write_text(
        "[defaults]\nbaud = 115200\npoll_interval_s = 0.5\n\n"
        '[[printer]]\nname = "prusa-1"\nport = "/dev/ttyUSB0"\nmax_hotend_celsius = 280\n\n'
        '[[printer]]\nname = "ender"\nport = "socket://10.0.0.5:23"\nbaud = 250000\n'
    )
    first, second = load_config(config)
    assert (first.name, first.port, first.baud, first.poll_interval_s, first.max_hotend_celsius) == (
        "prusa-1",
        "/dev/ttyUSB0",
        115200,
        0.5,
        280.0,
    )
    assert (second.name, second.baud) == ("ender", 250000)


def test_ports_and_sims_from_options_get_names() -> None:
    specs = specs_from_options(["left=/dev/ttyUSB0", "/dev/ttyUSB1"], 2, baud=250000, poll_interval_s=0.1, sim_speed=1)
    assert [(s.name, s.port, s.sim) for s in specs] == [
        ("left", "/dev/ttyUSB0", False),
        ("printer2", "/dev/ttyUSB1", False),
        ("sim1", None, True),
        ("sim2", None, True),
    ]


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ('[[printer]]\nname = "a/b"\nport = "/dev/x"\n', "must be letters, digits"),
        ('[[printer]]\nname = "a"\nport = "/dev/x"\n[[printer]]\nname = "a"\nport = "/dev/y"\n', "given twice"),
        ('[[printer]]\nname = "a"\nport = "/dev/x"\n[[printer]]\nname = "b"\nport = "/dev/x"\n', "given twice"),
        ('[[printer]]\nname = "a"\nport = "/dev/x"\nbaud = "fast"\n', "baud must be a whole number"),
        ('[[printer]]\nname = "a"\nport = "/dev/x"\npoll_interval_s = 0\n', "must be a positive number"),
        ('[[printer]]\nname = "a"\nport = "/dev/x"\nspeed = 3\n', "unknown setting 'speed'"),
        ('[[printer]]\nname = "a"\n', "needs a name and a port"),
        ("[printer\n", "not valid TOML"),
        ("[other]\n", "unknown section"),
    ],
)
def test_a_bad_toml_file_is_one_line_and_exit_2(tmp_path: Path, toml: str, message: str) -> None:
    config = tmp_path / "farm.toml"
    config.write_text(toml)
    result = runner.invoke(app, ["farm", "--config", str(config)])
    assert result.exit_code == Exit.USAGE, result.output
    assert message in one_line(result.output)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "no printers"),
        (["--port", "a b=/dev/x"], "must be letters, digits"),
        (["--sims", "1", "--rate", "0"], "--rate must be above 0"),
        (["--sims", "1", "--interval", "1", "--rate", "5"], "at most the poll rate"),
        (["--sims", "1", "--broker", "host:99999"], "port must be a number from 1 to 65535"),
        (["--sims", "1", "--prefix", "a/#"], "topic prefix"),
        (["--sims", "1", "--tls-key", "k.pem"], "--tls-key needs --tls-cert"),
        (["--sims", "1", "--allowed-dir", "."], "give --allow-commands too"),
        (["--sims", "1", "--duration", "0"], "--duration must be a positive"),
        (["--config", "/nonexistent/farm.toml"], "No such file"),
    ],
)
def test_bad_farm_options_are_one_line_and_exit_2(args: list[str], message: str) -> None:
    result = runner.invoke(app, ["farm", *args])
    assert result.exit_code == Exit.USAGE, result.output
    assert message in one_line(result.output)


def test_a_password_is_never_on_the_command_line_and_needs_a_user(tmp_path: Path) -> None:
    secret = tmp_path / "password"
    secret.write_text("hunter2\n")
    result = runner.invoke(app, ["farm", "--sims", "1", "--password-file", str(secret)])
    assert result.exit_code == Exit.USAGE
    assert "no --username" in one_line(result.output) and "hunter2" not in result.output
    result = runner.invoke(app, ["farm", "--password", "x"])
    assert result.exit_code == Exit.USAGE  # no such option: secrets do not go in argv


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--port", "a="], "no port after the name"),
        (["--sims", "1", "--allowed-dir", "/nonexistent", "--allow-commands"], "no such folder"),
    ],
)
def test_more_bad_farm_options(args: list[str], message: str) -> None:
    result = runner.invoke(app, ["farm", *args])
    assert result.exit_code == Exit.USAGE, result.output
    assert message in one_line(result.output)


def test_a_farm_that_never_reached_its_broker_does_not_exit_0() -> None:
    result = runner.invoke(app, ["farm", "--sims", "1", "--broker", "127.0.0.1:9", "--duration", "1.5"])
    assert result.exit_code == Exit.ERROR
    assert "never reached the MQTT broker at 127.0.0.1:9" in result.output
