"""The errors a user will hit, each one line on stderr with its own exit code, through real ports and processes."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import until
from rich.console import Console
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.simulator import SimulatorConfig, serve_pty, serve_tcp
from marlin_temp.common.connect import ConnectOptions, Exit
from marlin_temp.main import app
from marlin_temp.watch.command import WatchSettings, watch_printer

runner = CliRunner()


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    assert "Traceback" not in output
    return lines[0]


async def test_a_busy_port_exits_4() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim, marlin_aio.connect(sim.url):
        result = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--hotend", "200"])
    assert result.exit_code == Exit.PORT_BUSY
    assert "in use by another program" in one_line(result.output)


def test_a_silent_port_exits_6(dead_pty: tuple[int, str]) -> None:
    _, path = dead_pty
    result = runner.invoke(app, ["set", "--port", path, "--baud", "250000", "--timeout", "0.5", "--bed", "50"])
    assert result.exit_code == Exit.NO_ANSWER
    assert "nothing was received" in one_line(result.output)


@contextlib.contextmanager
def babbling(master: int) -> Iterator[None]:
    """A board talking at another rate: a steady stream of bytes, no line that makes sense. It must keep coming while
    the block runs, as pyserial throws away what arrived before the port was opened."""
    stop = threading.Event()

    def babble() -> None:
        while not stop.wait(0.02):
            os.write(master, b"\xf0\x80\x13\xfe\xff garbage \xc3\x00\n")

    noise = threading.Thread(target=babble, daemon=True)
    noise.start()
    try:
        yield
    finally:
        stop.set()
        noise.join()


def test_garbage_suggests_the_other_baud_rate(dead_pty: tuple[int, str]) -> None:
    master, path = dead_pty
    with babbling(master):
        result = runner.invoke(app, ["set", "--port", path, "--baud", "250000", "--timeout", "0.5", "--bed", "50"])
    assert result.exit_code == Exit.NO_ANSWER
    assert "wrong baud rate? 250000 is set (Marlin boards use 115200)" in one_line(result.output)


def test_after_trying_both_rates_the_hint_names_both_and_suggests_neither_again(dead_pty: tuple[int, str]) -> None:
    master, path = dead_pty
    with babbling(master):  # no --baud: 250000 is tried, then 115200
        result = runner.invoke(app, ["set", "--port", path, "--timeout", "0.5", "--bed", "50"])
    assert result.exit_code == Exit.NO_ANSWER
    # The progress note ("no answer at 250000 baud, trying 115200"), then the one error line.
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 2 and "Traceback" not in result.output, result.output
    said = lines[-1]
    assert said.startswith("error:") and "at 250000 and 115200 baud" in said
    assert "try 250000" not in said and "try 115200" not in said


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="setpriv is needed to drop root's file permissions")
def test_permission_denied_says_dialout_and_exits_5(dead_pty: tuple[int, str]) -> None:
    _, path = dead_pty
    os.chmod(path, 0)
    # Root ignores file permissions; without CAP_DAC_OVERRIDE it gets the EACCES a normal user would.
    drop = "-dac_override,-dac_read_search"
    command = ["setpriv", f"--inh-caps={drop}", f"--bounding-set={drop}"]
    command += [sys.executable, "-m", "marlin_temp", "set", "--port", path, "--hotend", "200"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode == Exit.PERMISSION, result.stderr
    assert "dialout" in one_line(result.stderr)


def test_no_port_given_and_none_found_lists_candidates_and_exits_2() -> None:
    result = runner.invoke(app, ["set", "--hotend", "200"])
    if any(port.likely_printer for port in marlin_aio.list_ports()):
        pytest.skip("this machine has a printer-like USB port plugged in")
    assert result.exit_code == Exit.USAGE
    assert "no printer port found" in one_line(result.output)


async def test_unplugged_while_watching_says_so_and_exits_8(tmp_path: Path) -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        log = tmp_path / "watch.csv"
        settings = WatchSettings(refresh_s=0.2, log_path=log)
        console = Console(file=io.StringIO(), force_terminal=False)
        watching = asyncio.create_task(watch_printer(ConnectOptions(port=sim.url), settings, console, console))
        # Unplug once readings are flowing: the log file gets its first rows within a second.
        await until(lambda: log.exists() and log.stat().st_size > 200, "rows on disk", limit_s=30)
        await sim.disconnect()
        with pytest.raises(marlin_aio.ConnectionLostError, match="unplugged\\? use --reconnect"):
            await asyncio.wait_for(watching, 10)
    assert log.read_text().count("\n") > 2  # what was logged before the unplug is on disk


def test_ctrl_c_while_waiting_says_the_heaters_stay_on() -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_temp", "set", "--sim", "--hotend", "200", "--bed", "60", "--wait"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stdout is not None
    confirmed = process.stdout.readline()  # printed before the wait starts
    assert "hotend target 200 C" in confirmed
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == Exit.INTERRUPTED
    assert "the heaters stay on" in stderr
    assert "marlin-temp set --off" in stderr
    assert "Traceback" not in stderr


async def test_watch_reconnect_keeps_retrying_and_resumes(tmp_path: Path) -> None:
    # On TCP the simulator keeps listening after a disconnect, like a board that is plugged back in.
    async with serve_tcp(SimulatorConfig(), time_scale=20) as sim:
        log = tmp_path / "watch.csv"
        settings = WatchSettings(refresh_s=0.2, log_path=log, reconnect=True, duration_s=60)
        errors = Console(file=io.StringIO(), record=True, force_terminal=False)
        watching = asyncio.create_task(watch_printer(ConnectOptions(port=sim.url), settings, errors, errors))

        async def rows_beyond(count: int) -> int:
            for _ in range(600):
                if log.exists():
                    rows = log.read_text().count("\n")
                    if rows > count:
                        return rows
                await asyncio.sleep(0.05)  # polling a condition (rows on disk), bounded
            raise AssertionError(f"the log never grew beyond {count} rows")

        before = await rows_beyond(3)
        await sim.disconnect()
        await rows_beyond(before + 20)  # readings flow again after the reconnect
        watching.cancel()
        with pytest.raises(asyncio.CancelledError):
            await watching
    assert "reconnecting in 1 s" in errors.export_text()  # the first wait of the backoff (1 s doubling to 30 s)


@pytest.mark.parametrize(
    ("args", "message"),
    [(["sim", "--drop-ok", "2"], "between 0 and 1"), (["sim", "--bogus"], "No such option: --bogus")],
)
def test_sim_takes_marlin_sims_options_and_rejects_bad_ones_in_one_line(args: list[str], message: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == Exit.USAGE
    assert message in one_line(result.output)


def test_sim_help_lists_the_options_marlin_sim_has() -> None:
    result = runner.invoke(app, ["sim", "--help"])
    assert result.exit_code == 0
    assert "marlin-temp sim" in result.output
    assert all(option in result.output for option in ("--corrupt-rx", "--checksum-required", "--tcp"))


async def test_a_locked_printer_is_one_line_naming_where_the_password_goes_and_the_password_unlocks_it() -> None:
    async with serve_pty(SimulatorConfig(password="1234"), time_scale=20) as sim:
        locked = await asyncio.to_thread(runner.invoke, app, ["set", "--port", sim.url, "--hotend", "200"])
        # From the environment: --password on the command line is refused (every user of the machine sees it).
        unlocked = await asyncio.to_thread(
            runner.invoke, app, ["set", "--port", sim.url, "--hotend", "200"], env={"MARLIN_PASSWORD": "1234"}
        )
        executed = list(sim.printer.executed)
    assert locked.exit_code != 0
    line = one_line(locked.output)
    assert "locked" in line and "MARLIN_PASSWORD" in line and "--password-file" in line
    assert unlocked.exit_code == 0, unlocked.output
    assert executed.count("M104 S200") == 1  # only the unlocked run set the target


def test_watch_piped_into_head_ends_quietly_when_head_has_read_enough() -> None:
    completed = subprocess.run(
        [
            "bash",
            "-c",
            f"{sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.1 --duration 60 | head -n 2; "
            "echo status=${PIPESTATUS[0]} >&2",
        ],
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert len(completed.stdout.splitlines()) == 2
    assert "status=0" in completed.stderr
    assert "Broken pipe" not in completed.stderr and "Traceback" not in completed.stderr, completed.stderr


@pytest.mark.parametrize("command", ["watch", "set", "log", "print", "bench"])
def test_help_shows_flags_as_flags_not_as_bool_values(command: str) -> None:
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "120"})
    assert result.exit_code == 0
    assert "<bool>" not in result.output
    assert "--sim " in result.output


def test_the_simulator_speed_has_one_name_and_the_old_ones_still_work() -> None:
    from marlin_aio.simulator._options import build_parser

    shown = runner.invoke(app, ["sim", "--help"])
    assert shown.exit_code == 0
    assert "--sim-speed" in shown.output
    assert "--time-scale" not in shown.output and "--speed " not in shown.output
    for old in ("--time-scale", "--speed", "--sim-speed"):
        assert build_parser().parse_args([old, "7"]).time_scale == 7


@pytest.mark.parametrize(
    "args",
    [
        ["watch", "--sim", "--sim-speed", "0"],
        ["watch", "--sim", "--duration", "abc"],
        ["set", "--sim", "--baud", "0", "--hotend", "20"],
        ["watch", "--bogus"],
        ["bogus"],
    ],
)
def test_usage_errors_are_one_line_and_exit_2(args: list[str]) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == Exit.USAGE, result.output
    line = one_line(result.output)
    assert line.startswith("error:") and "--help" in line


def test_every_command_calls_the_answer_timeout_timeout_and_set_calls_its_wait_limit_wait_timeout() -> None:
    for command in ("watch", "set", "log", "print", "send", "terminal", "bench"):
        shown = " ".join(runner.invoke(app, [command, "--help"], env={"COLUMNS": "200"}).output.split())
        assert "--timeout" in shown and "--answer-timeout" not in shown, command
    shown = " ".join(runner.invoke(app, ["set", "--help"], env={"COLUMNS": "200"}).output.split())
    assert "--wait-timeout" in shown


@pytest.mark.parametrize("duration", ["0", "-1"])
def test_watch_refuses_a_duration_that_is_not_positive(duration: str) -> None:
    result = runner.invoke(app, ["watch", "--sim", "--duration", duration])
    assert result.exit_code == Exit.USAGE
    assert "--duration must be a positive number" in one_line(result.output)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["set", "--sim", "--hotend", "100", "--max-hotend", "-10"], "--max-hotend"),
        (["watch", "--sim", "--tolerance", "-5"], "--tolerance"),
        (["watch", "--sim", "--sims", "2"], "give one of the two"),
    ],
)
def test_limits_and_counts_that_make_no_sense_are_refused(args: list[str], message: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == Exit.USAGE
    assert message in one_line(result.output)


def test_n_simulated_printers_is_sims_everywhere_and_polling_is_interval() -> None:
    from marlin_aio.simulator._options import build_parser

    for command in ("watch", "farm"):
        shown = " ".join(runner.invoke(app, [command, "--help"], env={"COLUMNS": "200"}).output.split())
        assert "--sims" in shown and "--interval" in shown and "--poll-interval" not in shown, command
    assert build_parser().parse_args(["--sims", "3"]).printers == 3
    shown = runner.invoke(app, ["--help"], env={"COLUMNS": "200"}).output
    assert "<bool>" not in shown  # --version and --help too


def test_an_empty_port_is_refused_not_taken_for_auto_detection() -> None:
    result = runner.invoke(app, ["set", "--port", "", "--hotend", "20"])
    assert result.exit_code == Exit.USAGE
    assert "--port is empty" in one_line(result.output)


def test_an_unknown_command_points_to_the_list_of_commands() -> None:
    result = runner.invoke(app, ["bogus"])
    assert "lists the commands" in one_line(result.output)
