"""The printer's own requests in the CLI (issue 25): `print`, `watch` and `terminal` show its prompts with their
buttons and answer them by a key (or `answer N`), and a print says why the printer paused it.

The wording and the keys' meaning are pure (`common.prompts`, `WatchControls`) and tested without I/O; the rest
runs against the simulated printer, which raises a filament runout at a print line or opens a prompt, through
a pipe (plain output) and in a real terminal under tmux (keys). The simulator runs in the test's loop and the
command in a worker thread or in tmux; waits poll a condition with a deadline, never a fixed sleep.
"""

from __future__ import annotations

import asyncio
import signal
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest
from conftest import until
from rich.console import Console
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.protocol import Prompt
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.common.model import AnswerPrompt, SetTargets, WatchControls, WatchModel
from marlin_temp.common.prompts import answer_index, prompt_text
from marlin_temp.common.render import controls_view
from marlin_temp.main import app
from marlin_temp.printing.view import PrintStatus, plain_status, print_view
from marlin_temp.watch.command import _outcome

LOAD = Prompt("Load Filament", ("Continue",), shown=True)
TWO = Prompt("Paused", ("Continue", "PurgeMore"), shown=True)
FILAMENT_CHANGE = "filament change: load filament, then press 1 Continue"


# ------------------------------------------------------------------------------------------- pure


def test_the_words_for_a_prompt_a_filament_change_and_a_bare_wait() -> None:
    assert prompt_text(LOAD, waiting_for_user=True) == FILAMENT_CHANGE
    assert prompt_text(TWO, waiting_for_user=False) == "printer asks: Paused  press 1 Continue  2 PurgeMore"
    assert prompt_text(Prompt("FilamentRunout T0", (), shown=True), False) == "printer: FilamentRunout T0"
    assert prompt_text(None, waiting_for_user=True) == "the printer waits for the user (on its screen, or M108)"
    assert prompt_text(None, waiting_for_user=False) is None
    assert prompt_text(LOAD, True, press="type answer") == "filament change: load filament, then type answer 1 Continue"


def test_only_the_digits_of_its_buttons_answer_a_prompt() -> None:
    assert answer_index("1", TWO) == 0
    assert answer_index("2", TWO) == 1
    assert answer_index("3", TWO) is None
    assert answer_index("0", TWO) is None
    assert answer_index("1", None) is None
    assert answer_index("\x1b[1", TWO) is None


def test_while_a_prompt_is_open_its_digits_answer_it_before_the_presets() -> None:
    controls = WatchControls()
    model = WatchModel()
    assert isinstance(controls.press("1", model), SetTargets)  # no prompt: 1 is a preset
    controls.printer_prompt = TWO
    assert controls.press("1", model) == AnswerPrompt(0, "Continue")
    assert controls.press("2", model) == AnswerPrompt(1, "PurgeMore")
    assert controls.press("3", model) is None  # not one of its buttons, and no preset either
    controls.press("h", model)  # an input line open: digits are typed into it
    assert controls.press("1", model) is None
    assert controls.buffer == "1"


def test_watch_shows_the_prompt_under_the_chart() -> None:
    controls = WatchControls()
    controls.printer_prompt = LOAD
    controls.printer_prompt_text = prompt_text(LOAD, waiting_for_user=True)
    console = Console(record=True, width=60)
    console.print(controls_view(controls, 60))
    assert FILAMENT_CHANGE in " ".join(console.export_text().split())


@pytest.mark.parametrize("width", [40, 80, 120])
def test_the_print_view_says_why_it_is_paused_and_what_the_printer_asks(width: int) -> None:
    status = PrintStatus(
        "part.gcode", 9, 40, state="paused", paused_by="printer asked: filament_runout 0", prompt=FILAMENT_CHANGE
    )
    console = Console(record=True, width=width)
    console.print(print_view(status))
    text = " ".join(console.export_text().split())
    assert "paused: printer asked: filament_runout 0" in text
    assert FILAMENT_CHANGE in text
    assert "paused" in plain_status(status)


# ------------------------------------------------------------------------------------------- against the simulator


@pytest.fixture
async def runout_sim() -> AsyncIterator[SimulatorServer]:
    """A printer whose filament runs out at print line 15 (its moves take no time)."""
    async with serve_pty(SimulatorConfig(motion_time_scale=0), Faults(runout_at_line=15), time_scale=20) as server:
        yield server


def write_gcode(path: Path, lines: int = 40) -> Path:
    path.write_text("; part\n" + "".join(f"G1 X{index} Y{index % 9}\n" for index in range(lines)))
    return path


def moves(sim: SimulatorServer) -> list[str]:
    return [command for command in sim.printer.executed if command.startswith("G1 ")]


async def test_print_says_why_the_printer_paused_it_and_what_it_asks(
    runout_sim: SimulatorServer, tmp_path: Path
) -> None:
    gcode = write_gcode(tmp_path / "part.gcode")
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "marlin_temp", "print", str(gcode), "--port", runout_sim.url),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdout is not None
    said: list[str] = []
    try:
        async with asyncio.timeout(60):
            while FILAMENT_CHANGE not in said:
                said.append((await process.stdout.readline()).decode().strip())
                assert said[-1] or not process.stdout.at_eof(), said
        # Not a terminal, so no keys: a person at the printer answers on its screen.
        runout_sim.printer.answer_on_screen(runout_sim.now())
        runout_sim.poke()
        _, errors = await asyncio.wait_for(process.communicate(), 60)
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
    assert process.returncode == Exit.OK, errors.decode()
    assert "paused: printer asked: filament_runout 0" in said
    assert "done: 40 commands" in errors.decode()
    assert moves(runout_sim) == [f"G1 X{index} Y{index % 9}" for index in range(40)]
    assert runout_sim.printer.prompt_answers == []  # answered on the printer, not by the host


async def test_ctrl_c_during_a_filament_change_ends_the_wait_and_cancels(
    runout_sim: SimulatorServer, tmp_path: Path
) -> None:
    gcode = write_gcode(tmp_path / "part.gcode")
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "marlin_temp", "print", str(gcode), "--port", runout_sim.url),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdout is not None
    try:
        async with asyncio.timeout(60):
            while FILAMENT_CHANGE not in (await process.stdout.readline()).decode():
                assert not process.stdout.at_eof()
        process.send_signal(signal.SIGINT)  # no terminal to ask on: Ctrl-C cancels at once
        _, errors = await asyncio.wait_for(process.communicate(), 60)
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
    text = errors.decode()
    assert process.returncode == Exit.INTERRUPTED, text
    assert "M108 sent: the printer's wait for the user ended" in text
    assert "cancelled after line" in text
    assert not runout_sim.printer.waiting_for_user
    executed = moves(runout_sim)
    assert executed == [f"G1 X{index} Y{index % 9}" for index in range(len(executed))] and len(executed) < 40


async def test_print_cancelled_by_the_printer_says_so_and_turns_the_heaters_off(
    runout_sim: SimulatorServer, tmp_path: Path
) -> None:
    gcode = write_gcode(tmp_path / "part.gcode")
    args = ["print", str(gcode), "--port", runout_sim.url]
    printing = asyncio.ensure_future(asyncio.to_thread(CliRunner().invoke, app, args))
    await until(lambda: runout_sim.printer.waiting_for_user or printing.done(), "the runout's filament change")
    # Someone at the printer cancels on its screen, then the filament change ends.
    runout_sim.printer.host_action(runout_sim.now(), "cancel")
    runout_sim.printer.answer_on_screen(runout_sim.now())
    runout_sim.poke()
    result = await asyncio.wait_for(printing, 60)
    assert result.exit_code == Exit.INTERRUPTED, result.output
    text = " ".join(result.output.split())
    assert "the printer cancelled the print after line" in text
    assert "printer asked: cancel); heaters and fan turned off" in text
    executed = list(runout_sim.printer.executed)
    last_move = max(index for index, command in enumerate(executed) if command.startswith("G1 "))
    after = [command for command in executed[last_move:] if command in ("M104 S0", "M140 S0", "M107")]
    assert after == ["M104 S0", "M140 S0", "M107"]
    assert len(moves(runout_sim)) < 40


async def test_watch_answers_the_prompt_it_shows(runout_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(runout_sim.url, timeout_s=5.0) as printer:
        runout_sim.printer.open_prompt(runout_sim.now(), "Door open", ["Continue", "Cancel"])
        runout_sim.poke()
        await until(lambda: printer.prompt is not None, "the prompt")
        controls = WatchControls()
        controls.printer_prompt = printer.prompt
        action = controls.press("2", WatchModel())
        assert action == AnswerPrompt(1, "Cancel")
        notice = await _outcome(printer, action, WatchModel())
        assert notice.title == "answered the printer: Cancel (M876 S1)" and not notice.error
        await until(lambda: runout_sim.printer.prompt_answers == [1], "the answer at the printer")
        # Answered already: a second press is refused by the library, as one error line, and nothing is sent.
        again = await _outcome(printer, AnswerPrompt(0, "Continue"), WatchModel())
        assert again.error and "no prompt is open" in again.title
        assert runout_sim.printer.prompt_answers == [1]


# ------------------------------------------------------------------------------------------- keys, in a terminal


async def wait_for(tmux: Tmux, condition: Callable[[str], bool], what: str) -> str:
    """Poll the screen from a worker thread, so the simulated printer in this loop keeps answering."""
    return await asyncio.to_thread(tmux.wait_for, condition, what)


def flat(screen: str) -> str:
    return " ".join(screen.split())


@needs_tmux
async def test_print_key_1_answers_the_runout_and_the_print_completes(
    runout_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    gcode = write_gcode(tmp_path / "part.gcode")
    command = f"{sys.executable} -m marlin_temp print {gcode} --port {runout_sim.url}; echo MARLIN-EXIT=$?; sleep 600"
    tmux.run("new-session", "-d", "-s", "w", "-x", "120", "-y", "30", command)
    screen = await wait_for(tmux, lambda s: FILAMENT_CHANGE in flat(s), "the filament change prompt")
    assert "paused: printer asked: filament_runout 0" in flat(screen)
    assert runout_sim.printer.prompt_answers == []
    tmux.run("send-keys", "-t", "w", "1")
    screen = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "the print to end")
    assert "MARLIN-EXIT=0" in screen, screen
    assert runout_sim.printer.prompt_answers == [0]
    assert moves(runout_sim) == [f"G1 X{index} Y{index % 9}" for index in range(40)]


@needs_tmux
async def test_terminal_prints_the_prompt_and_answer_n_answers_it(
    pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    command = (
        f"XDG_STATE_HOME={tmp_path} {sys.executable} -m marlin_temp terminal --port {pty_sim.url}; "
        "echo MARLIN-EXIT=$?; sleep 600"
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "110", "-y", "30", command)
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    tmux.run("send-keys", "-t", "w", "-l", "answer 1")
    tmux.run("send-keys", "-t", "w", "Enter")
    await wait_for(tmux, lambda s: "shows no prompt to answer (not sent)" in s, "the refusal")

    pty_sim.printer.open_prompt(pty_sim.now(), "Door open", ["Continue", "Cancel"])
    pty_sim.poke()
    await wait_for(tmux, lambda s: "printer asks: Door open  type answer 1 Continue  2 Cancel" in s, "the prompt")
    tmux.run("send-keys", "-t", "w", "-l", "answer 3")
    tmux.run("send-keys", "-t", "w", "Enter")
    await wait_for(tmux, lambda s: "answer takes one of 1 Continue  2 Cancel (not sent)" in s, "the bad answer")
    assert pty_sim.printer.prompt_answers == []
    tmux.run("send-keys", "-t", "w", "-l", "answer 2")
    tmux.run("send-keys", "-t", "w", "Enter")
    await wait_for(tmux, lambda s: "answered the printer: Cancel (M876 S1)" in s, "the answer")
    await until(lambda: pty_sim.printer.prompt_answers == [1], "the answer at the printer")
    tmux.run("send-keys", "-t", "w", "C-d")
    await wait_for(tmux, lambda s: "MARLIN-EXIT=0" in s, "the console to quit")


@needs_tmux
async def test_watch_shows_the_prompt_and_its_digit_answers_it_not_the_preset(tmux: Tmux) -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        command = f"{sys.executable} -m marlin_temp watch --port {sim.url} --refresh 0.3; echo MARLIN-EXIT=$?"
        command += "; sleep 600"  # keep the pane alive to read the exit code
        tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", command)
        await wait_for(tmux, lambda s: "h hotend" in s and "°C" in s, "the live view")
        sim.printer.open_prompt(sim.now(), "Door open", ["Continue", "Cancel"])
        sim.poke()
        await wait_for(tmux, lambda s: "printer asks: Door open  press 1 Continue  2 Cancel" in s, "the prompt")
        tmux.run("send-keys", "-t", "w", "2")  # PETG's preset otherwise
        await wait_for(tmux, lambda s: "answered the printer: Cancel (M876 S1)" in s, "the answer")
        await until(lambda: sim.printer.prompt_answers == [1], "the answer at the printer")
        await wait_for(tmux, lambda s: "printer asks" not in s, "the prompt to close")
        tmux.run("send-keys", "-t", "w", "q")
        after = await wait_for(tmux, lambda s: "MARLIN-EXIT=" in s, "watch to exit")
        assert "MARLIN-EXIT=0" in after
        executed = list(sim.printer.executed)
    assert not [c for c in executed if c.startswith(("M104", "M140"))]  # no preset was set


async def test_watch_piped_prints_the_printers_question_once(pty_sim: SimulatorServer) -> None:
    args = ["watch", "--port", pty_sim.url, "--refresh", "0.2", "--duration", "4"]
    watching = asyncio.ensure_future(asyncio.to_thread(CliRunner().invoke, app, args))
    await until(lambda: pty_sim.printer.executed_count > 20 or watching.done(), "watch to poll")
    pty_sim.printer.open_prompt(pty_sim.now(), "Door open", ["Continue"])
    pty_sim.poke()
    result = await asyncio.wait_for(watching, 60)
    assert result.exit_code == Exit.OK, result.output
    assert result.output.count("printer asks: Door open  press 1 Continue") == 1, result.output
