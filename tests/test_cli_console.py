"""The G-code console: `marlin-temp send` through CliRunner against the simulated printer, and `marlin-temp
terminal` in a real terminal under tmux (typing, replies, history, completion, the emergency stop key).

The simulated printer runs in the test's event loop; the command runs in a worker thread (CliRunner) or in tmux,
so the test can read the printer's own record (`executed`, `halted`) of what reached it.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from conftest import TIME_SCALE, until
from prompt_toolkit.completion import CompleteEvent
from prompt_toolkit.document import Document
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner, Result

from marlin_aio import TemperatureReading
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.console.terminal import GcodeCompleter, default_history_path, temperature_line
from marlin_temp.main import app

runner = CliRunner()


async def invoke(*args: str) -> Result:
    """Run marlin-temp in a worker thread, so the simulated printer keeps running in this loop."""
    return await asyncio.to_thread(runner.invoke, app, list(args))


def one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


# ------------------------------------------------------------------------------------------- send


async def test_send_prints_each_reply_under_its_command_and_exits_0(pty_sim: SimulatorServer) -> None:
    start = len(pty_sim.printer.executed)
    result = await invoke("send", "M115", "G28 X ; home x", "G1 X12.5 F3000", "M114", "--port", pty_sim.url)
    assert result.exit_code == Exit.OK, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == "> M115"
    assert lines[1].startswith("FIRMWARE_NAME:Marlin")
    assert "> G28 X" in lines  # the comment is not sent
    m114 = lines.index("> M114")
    assert lines[m114 + 1].startswith("X:12.50 Y:0.00 Z:0.00 E:0.00")
    assert lines[m114 + 2] == "ok"
    assert lines.count("ok") == 4
    assert result.stderr == ""
    # (An M105 may run behind G28 X: the probe that asks, while it homes, whether its ok was lost.)
    ran = [text for text in list(pty_sim.printer.executed)[start:] if text != "M105"]
    assert ran[-4:] == ["M115", "G28 X", "G1 X12.5 F3000", "M114"]


def test_send_with_the_built_in_simulator_prints_the_reply_alone() -> None:
    result = runner.invoke(app, ["send", "--sim", "--sim-speed", "50", "M105"])
    assert result.exit_code == Exit.OK, result.output
    assert one_line(result.stdout).startswith("ok T:")  # one command: no title, M105's temperatures on its ok


@pytest.mark.parametrize(
    ("command", "message"),
    [
        ("G28\nM503", "line break"),
        ("M117 h\u00e9llo", "non-ASCII"),
        ("", "empty"),
        ("   ; only a comment", "empty"),
        ("G1 X1*12", "'*'"),
        ("M117 " + "x" * 85, "too long"),
    ],
)
async def test_send_refuses_a_bad_command_in_one_line_and_sends_nothing(
    pty_sim: SimulatorServer, command: str, message: str
) -> None:
    executed = pty_sim.printer.executed_count
    result = await invoke("send", "M114", command, "--port", pty_sim.url)
    assert result.exit_code == Exit.USAGE
    error = one_line(result.stderr)
    assert message in error and "command 2 of 2" in error and "nothing was sent" in error
    assert result.stdout == ""
    # Not even the handshake: the port was never opened, so the good command before the bad one never ran.
    assert pty_sim.printer.executed_count == executed


def test_send_without_commands_says_how() -> None:
    result = runner.invoke(app, ["send", "--sim"])
    assert result.exit_code == Exit.USAGE
    assert "no command given" in one_line(result.stderr)


async def test_send_an_unknown_code_exits_1_after_running_the_rest(pty_sim: SimulatorServer) -> None:
    result = await invoke("send", "M9999", "M114", "--port", pty_sim.url)
    assert result.exit_code == Exit.ERROR
    assert 'echo:Unknown command: "M9999"' in result.stdout
    assert "X:0.00" in result.stdout  # M114 still ran
    assert "does not know M9999" in one_line(result.stderr)


async def test_send_a_timeout_exits_9_and_sends_no_more(pty_sim: SimulatorServer) -> None:
    result = await invoke("send", "M105 T9", "M118 E1 after", "--port", pty_sim.url, "--timeout", "2")
    assert result.exit_code == Exit.TIMEOUT
    assert "M105 T9" in one_line(result.stderr)
    assert "M118 E1 after" not in pty_sim.printer.executed


async def test_send_m112_is_the_emergency_stop_and_what_follows_exits_7(pty_sim: SimulatorServer) -> None:
    result = await invoke("send", "M112", "G28", "--port", pty_sim.url)
    assert result.exit_code == Exit.HALTED
    assert "emergency stop sent" in result.stdout
    assert "EMERGENCY_PARSER" not in result.stdout  # this board acts on M112 as it arrives: no warning
    assert "M112" in one_line(result.stderr)  # G28 was refused: the printer is halted
    await until(lambda: pty_sim.printer.halted, "the simulated printer to halt")
    assert "G28" not in pty_sim.printer.executed


async def test_send_m112_warns_when_the_firmware_has_no_emergency_parser() -> None:
    async with serve_pty(SimulatorConfig(emergency_parser=False), time_scale=TIME_SCALE) as sim:
        result = await invoke("send", "M112", "--port", sim.url)
        assert result.exit_code == Exit.OK, result.output
        assert "no EMERGENCY_PARSER" in result.stdout and "cut its power" in result.stdout
        await until(lambda: sim.printer.halted, "the simulated printer to halt")  # its turn came at once


def test_send_help_explains_checks_and_exit_codes() -> None:
    result = runner.invoke(app, ["send", "--help"])
    assert result.exit_code == 0
    text = " ".join(result.stdout.split())
    assert "nothing is sent" in text and "M112" in text and "Exit codes" in text


# ------------------------------------------------------------------------------------------- terminal, no terminal


def test_terminal_without_a_terminal_says_to_use_send() -> None:
    result = runner.invoke(app, ["terminal", "--sim"])
    assert result.exit_code == Exit.USAGE
    assert "marlin-temp send" in one_line(result.stderr)


def test_completion_offers_codes_with_what_they_do_only_for_the_first_word() -> None:
    completer = GcodeCompleter()

    def complete(text: str) -> dict[str, str]:
        found = completer.get_completions(Document(text), CompleteEvent(completion_requested=True))
        return {c.text: c.display_meta_text for c in found}

    offered = complete("m11")
    assert offered["M114"] == "report position"
    assert "M104" not in offered
    assert "M112" not in offered  # never: Tab, Enter would be the emergency stop (see test_cli_console_safety)
    assert complete("G2") == {"G28": "home (all, or X Y Z)", "G29": "bed levelling probe"}
    assert complete("G28 X") == {}
    assert "temps" in complete("te")


def test_history_lives_in_the_xdg_state_dir() -> None:
    assert default_history_path({"XDG_STATE_HOME": "/var/state"}) == Path("/var/state/marlin-temp/history")
    home_default = Path.home() / ".local/state/marlin-temp/history"
    assert default_history_path({}) == home_default
    assert default_history_path({"XDG_STATE_HOME": "relative/dir"}) == home_default  # ignored, as XDG says


def test_the_temperature_line_is_compact() -> None:
    temperatures = parse_temperatures("T:199.84 /200.00 B:60.02 /60.00 T0:199.84 /200.00 T1:25.00 /0.00 @:64")
    assert temperatures is not None
    reading = TemperatureReading(temperatures, 0.0, 0.0, ReadingSource.POLL)
    assert temperature_line(reading) == "hotend 0 199.8/200 C  hotend 1 25.0 C off  bed 60.0/60 C"


# ------------------------------------------------------------------------------------------- terminal, in tmux


@pytest.fixture
def tmux_server() -> Iterator[Tmux]:
    server = Tmux()
    yield server
    subprocess.run(["tmux", "-L", server.socket, "kill-server"], capture_output=True, check=False)


def start_terminal(tmux: Tmux, port: str, state_dir: Path, *options: str) -> None:
    command = (
        f"XDG_STATE_HOME={state_dir} {sys.executable} -m marlin_temp terminal --port {port} {' '.join(options)}; "
        "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit code
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "110", "-y", "30", command)


async def wait_for(tmux: Tmux, condition: Callable[[str], bool], what: str) -> str:
    """Poll the screen from a worker thread, so the simulated printer in this loop keeps answering."""
    return await asyncio.to_thread(tmux.wait_for, condition, what)


def at_an_empty_prompt(screen: str) -> bool:
    """The last prompt on the screen is empty: a new line editor is up (keys typed while the last one was closing
    can go to the closing one, so a test waits for this before typing on)."""
    prompts = [line.rstrip() for line in screen.splitlines() if line.startswith("marlin>")]
    return bool(prompts) and prompts[-1] == "marlin>"


def typed(tmux: Tmux, text: str, *keys: str) -> None:
    if text:
        tmux.run("send-keys", "-t", "w", "-l", text)  # literally: no key names inside G-code
    if keys:
        tmux.run("send-keys", "-t", "w", *keys)


@needs_tmux
async def test_terminal_runs_commands_shows_replies_hides_polls_and_keeps_history(
    pty_sim: SimulatorServer, tmux_server: Tmux, tmp_path: Path
) -> None:
    tmux = tmux_server
    start_terminal(tmux, pty_sim.url, tmp_path, "--interval", "0.2", "--temperatures-every", "0.5")
    await wait_for(tmux, lambda s: "marlin>" in s and "F12" in s, "the prompt and the bottom bar")

    typed(tmux, "M118 E1 hello console", "Enter")
    screen = await wait_for(tmux, lambda s: "echo:hello console" in s, "the reply")
    assert screen.index("marlin> M118 E1 hello console") < screen.index("echo:hello console")

    typed(tmux, "M104 S50", "Enter")  # a new target: a temperature line joins the scrollback
    screen = await wait_for(
        tmux, lambda s: any(line.startswith("hotend ") and "/50 C" in line for line in s.splitlines()), "a line"
    )
    assert "ok T:" not in screen  # hundreds of polls were answered meanwhile; none is printed

    typed(tmux, "M11")  # completion while typing: the codes with what they do
    await wait_for(tmux, lambda s: "report position" in s and "endstop states" in s, "the completion menu")
    typed(tmux, "", "C-c")  # Ctrl-C drops the line: M11 is never sent
    await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")
    typed(tmux, "M114", "Enter")
    await wait_for(tmux, lambda s: "X:0.00 Y:0.00 Z:0.00" in s, "the position")
    assert not any(command.startswith("M11 ") or command == "M11" for command in pty_sim.printer.executed)

    typed(tmux, "", "C-d")
    screen = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "the console to quit")
    assert "MARLIN-EXIT=0" in screen
    history = (tmp_path / "marlin-temp" / "history").read_text()
    assert "M118 E1 hello console" in history and "M114" in history

    # The next session starts with that history: Up brings back the last command. (A terminal of its own: a
    # tmux server that was just killed may still hold its socket.)
    second = Tmux()
    try:
        start_terminal(second, pty_sim.url, tmp_path)
        await wait_for(second, lambda s: "marlin>" in s, "the second session's prompt")
        typed(second, "", "Up")
        await wait_for(second, lambda s: "marlin> M114" in s, "the last command from the history")
        typed(second, "", "C-c")
        await wait_for(second, at_an_empty_prompt, "a fresh prompt")
        typed(second, "", "C-d")
        await wait_for(second, lambda s: "MARLIN-EXIT=0" in s, "the second session to quit")
    finally:
        kill = ["tmux", "-L", second.socket, "kill-server"]
        await asyncio.to_thread(subprocess.run, kill, capture_output=True, check=False)


@needs_tmux
async def test_f12_halts_the_printer_at_once_even_while_a_long_command_runs(
    pty_sim: SimulatorServer, tmux_server: Tmux, tmp_path: Path
) -> None:
    tmux = tmux_server
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s and "F12" in s, "the prompt")

    typed(tmux, "G4 S3600", "Enter")  # an hour's dwell: the prompt is back at once, the command keeps running
    await wait_for(tmux, lambda s: "running: 1" in s, "the dwell to be under way")
    await until(lambda: "G4 S3600" in pty_sim.printer.executed, "the printer to start the dwell")
    assert not pty_sim.printer.halted

    typed(tmux, "", "F12")
    await until(lambda: pty_sim.printer.halted, "the simulated printer to halt")
    screen = await wait_for(tmux, lambda s: "emergency stop sent" in s and "HALTED" in s, "the stop to show")
    await wait_for(tmux, lambda s: "error: G4 S3600" in s, "the dwell to fail")  # it failed, it did not finish
    assert "G4 S3600" in screen

    typed(tmux, "", "C-d")
    screen = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "the console to quit")
    assert f"MARLIN-EXIT={int(Exit.HALTED)}" in screen


@needs_tmux
@pytest.mark.parametrize("typed_stop", ["!", "m112 ; stop", "M 112", "M0112"])
async def test_typing_the_stop_asks_and_y_halts_the_printer(
    pty_sim: SimulatorServer, tmux_server: Tmux, tmp_path: Path, typed_stop: str
) -> None:
    tmux = tmux_server
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    typed(tmux, typed_stop, "Enter")
    await wait_for(tmux, lambda s: "send the emergency stop M112?" in s, "the question")
    assert not pty_sim.printer.halted  # asked, not sent
    typed(tmux, "y")
    await until(lambda: pty_sim.printer.halted, "the simulated printer to halt")
    await wait_for(tmux, lambda s: "emergency stop sent" in s and "HALTED" in s, "the stop to show")
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: f"MARLIN-EXIT={int(Exit.HALTED)}" in s, "the console to quit with 7")


@needs_tmux
async def test_ctrl_d_leaves_at_once_while_a_long_command_runs(
    pty_sim: SimulatorServer, tmux_server: Tmux, tmp_path: Path
) -> None:
    tmux = tmux_server
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    typed(tmux, "G4 S3600", "Enter")  # 3 minutes at this simulator's speed, longer than any wait below
    await wait_for(tmux, lambda s: "running: 1" in s, "the dwell to be under way")
    typed(tmux, "", "C-d")
    screen = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "the console to quit")
    assert "MARLIN-EXIT=0" in screen
    assert "left without waiting for: G4 S3600" in screen
    assert not pty_sim.printer.halted  # leaving is not a stop: the printer finishes what it was given


@needs_tmux
async def test_the_console_ends_with_exit_8_when_the_printer_goes_away(
    pty_sim: SimulatorServer, tmux_server: Tmux, tmp_path: Path
) -> None:
    tmux = tmux_server
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history", "--interval", "0.2")
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    await pty_sim.disconnect()
    screen = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "the console to end")
    assert f"MARLIN-EXIT={int(Exit.LOST)}" in screen
    assert "Traceback" not in screen
