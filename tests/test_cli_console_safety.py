"""Issue 20 in `marlin-temp terminal`: nothing reaches the printer that the user did not mean.

M112 is never completed, never kept in or recalled from the history, and asks before it is sent when typed; a
command the library refuses is one error line and the prompt takes the next line; firmware text is shown as it
came. The completer and the history are tested on their own; the rest in a real terminal (tmux) against the
simulated printer, which records what reached it (`executed`, `halted`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import until
from prompt_toolkit.completion import CompleteEvent
from prompt_toolkit.document import Document
from prompt_toolkit.history import FileHistory, InMemoryHistory
from test_cli_console import at_an_empty_prompt, start_terminal, typed, wait_for
from tmux_screen import Tmux, needs_tmux

from marlin_aio.simulator import SimulatorServer
from marlin_temp.common.connect import Exit
from marlin_temp.console.terminal import GcodeCompleter, HistoryWithoutStops, is_emergency_stop

# Every way of writing a line that Marlin (its parser or its emergency parser) reads as M112.
STOP_SPELLINGS = ["M112", "m112", "M0112", "M 112", "M112 ; stop", "N5 M112*27", " n12 m112", "M112.0", "!", " ! "]


# ------------------------------------------------------------------------------------------- no terminal


@pytest.mark.parametrize("text", STOP_SPELLINGS)
def test_every_spelling_of_m112_is_the_emergency_stop(text: str) -> None:
    assert is_emergency_stop(text)


@pytest.mark.parametrize("text", ["M11", "M12", "M1120", "M1112", "G112", "M117 M112", "; M112", "M105", "!!", ""])
def test_other_lines_are_not_the_emergency_stop(text: str) -> None:
    assert not is_emergency_stop(text)


def test_m112_is_never_offered_as_a_completion_from_any_prefix_in_any_case() -> None:
    completer = GcodeCompleter()
    prefixes = ["", " ", "m", "M", "m1", "M1", "m11", "M11", "m112", "M112", "M0", "M01", "M011", "M0112", "!"]
    for prefix in prefixes:
        offered = [
            completion.text
            for completion in completer.get_completions(Document(prefix), CompleteEvent(completion_requested=True))
        ]
        assert not any(is_emergency_stop(text) for text in offered), (prefix, offered)
    # M11 still completes, only not to the stop: its first completion is M114, which reports.
    first = next(iter(completer.get_completions(Document("M11"), CompleteEvent(completion_requested=True))))
    assert first.text == "M114"


def write_old_history(path: Path, lines: list[str]) -> None:
    """A history file as an older marlin-temp (a plain prompt_toolkit FileHistory) left it, oldest line first."""
    old = FileHistory(str(path))
    for line in lines:
        old.store_string(line)


def loaded(history: HistoryWithoutStops) -> list[str]:
    """What Up walks through (newest first), loaded the way a prompt loads it."""

    async def load() -> list[str]:
        return [line async for line in history.load()]

    return asyncio.run(load())


def test_a_history_file_from_an_old_session_is_loaded_without_m112(tmp_path: Path) -> None:
    path = tmp_path / "history"
    write_old_history(path, ["G28", "M112", "M114", "m0112", "N5 M112*27", "!"])
    assert "+M112" in path.read_text()  # the old file has it
    assert loaded(HistoryWithoutStops(FileHistory(str(path)))) == ["M114", "G28"]


def test_m112_is_never_written_to_the_history_nor_recalled_in_the_session(tmp_path: Path) -> None:
    path = tmp_path / "history"
    history = HistoryWithoutStops(FileHistory(str(path)))
    loaded(history)
    for line in ["M105", "M 112", "!", "m112 ; stop", "M114"]:
        history.append_string(line)
    assert history.get_strings() == ["M105", "M114"]  # Up recalls only these
    saved = path.read_text()
    assert "+M105" in saved and "+M114" in saved
    assert "112" not in saved and "+!" not in saved
    # Without a file (--no-history) the session's own history is filtered the same way.
    session_only = HistoryWithoutStops(InMemoryHistory())
    loaded(session_only)
    session_only.append_string("M112")
    session_only.append_string("G28")
    assert session_only.get_strings() == ["G28"]


def test_a_typed_password_is_never_written_to_the_history_nor_loaded_from_it(tmp_path: Path) -> None:
    path = tmp_path / "history"
    write_old_history(path, ["G28", "M511 P1234"])
    history = HistoryWithoutStops(FileHistory(str(path)))
    assert loaded(history) == ["G28"]
    history.append_string("m511 p4321")
    history.append_string("M105")
    assert history.get_strings() == ["G28", "M105"]
    assert "4321" not in path.read_text()


# ------------------------------------------------------------------------------------------- in tmux


def shows(text: str) -> Callable[[str], bool]:
    return lambda screen: text in screen


def last_prompt(screen: str) -> str:
    return [line.rstrip() for line in screen.splitlines() if line.startswith("marlin>")][-1]


@needs_tmux
async def test_m11_tab_enter_does_not_send_the_emergency_stop(
    pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s and "F12" in s, "the prompt")

    typed(tmux, "M11")
    await wait_for(tmux, lambda s: "report position" in s, "the completion menu")
    assert "EMERGENCY" not in tmux.screen()  # the stop is not even in the menu
    typed(tmux, "", "Tab")
    await wait_for(tmux, lambda s: last_prompt(s) == "marlin> M114", "the first completion")
    typed(tmux, "", "Enter")
    await wait_for(tmux, lambda s: "X:0.00 Y:0.00 Z:0.00" in s, "M114's reply")
    await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")

    # M112 would have been written ahead of M114; the printer answered M114 and never halted.
    assert not pty_sim.printer.halted
    assert not any(is_emergency_stop(command) for command in pty_sim.printer.executed)
    assert "HALTED" not in tmux.screen() and "emergency stop sent" not in tmux.screen()
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: "MARLIN-EXIT=0" in s, "the console to quit with 0")


@needs_tmux
async def test_typed_m112_asks_first_and_any_other_key_sends_nothing(
    pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s and "M112 or ! asks first" in s, "the prompt and the bar")

    for answer, spelling in [("n", "M112"), ("Enter", "m0112 ; stop"), ("C-c", "!")]:
        typed(tmux, spelling, "Enter")
        await wait_for(tmux, lambda s: s.rstrip().endswith("any other key = don't"), f"the question for {spelling}")
        typed(tmux, "", answer)
        screen = await wait_for(tmux, at_an_empty_prompt, f"the prompt after {answer}")
        assert screen.count("emergency stop not sent") == ["n", "Enter", "C-c"].index(answer) + 1
        assert not pty_sim.printer.halted

    typed(tmux, "M118 E1 still here", "Enter")  # the prompt takes the next line as usual
    await wait_for(tmux, lambda s: "echo:still here" in s, "the next command's reply")
    assert not pty_sim.printer.halted
    assert "emergency stop sent" not in tmux.screen()

    typed(tmux, "", "F12")  # the stop's own key asks nothing
    await until(lambda: pty_sim.printer.halted, "the simulated printer to halt")
    screen = await wait_for(tmux, lambda s: "emergency stop sent" in s, "the stop to show")
    assert screen.count("send the emergency stop M112?") == 3  # the three typed ones, not F12
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: f"MARLIN-EXIT={int(Exit.HALTED)}" in s, "the console to quit with 7")


@needs_tmux
async def test_a_refused_command_is_one_error_line_and_the_next_line_is_taken(
    pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    # No temperature lines: the line under each command is its answer.
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history", "--temperatures-every", "0", "--max-hotend", "290")
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")

    for number, bad in enumerate(["M104 S999", "M104 Sabc", "M140 S-5", "M104 S291"]):
        typed(tmux, bad, "Enter")
        screen = await wait_for(tmux, shows(f"marlin> {bad}\nerror: "), f"the error under {bad}")
        error = screen.split(f"marlin> {bad}\n", 1)[1].splitlines()
        assert error[0].rstrip().endswith("(not sent)"), screen  # one line, then the next prompt
        assert error[1].startswith("marlin>") or not error[1].strip(), screen
        await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")
        typed(tmux, f"M118 E1 next {number}", "Enter")  # not swallowed by a "Press ENTER to continue"
        await wait_for(tmux, shows(f"echo:next {number}"), "the next command's reply")

    typed(tmux, "M105", "Enter")
    screen = await wait_for(tmux, lambda s: "ok T:" in s, "M105's reply")
    assert "Unhandled exception" not in screen and "Traceback" not in screen and "Press ENTER" not in screen
    assert not any(command.startswith(("M104 S", "M140 S")) for command in pty_sim.printer.executed)

    typed(tmux, "M104 S280", "Enter")  # within --max-hotend 290 (above the default limit): sent
    await until(lambda: "M104 S280" in pty_sim.printer.executed, "the printer to take M104 S280")
    typed(tmux, "M104 S0", "Enter")
    await until(lambda: "M104 S0" in pty_sim.printer.executed, "the printer to take M104 S0")
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: "MARLIN-EXIT=0" in s, "the console to quit with 0")


@needs_tmux
async def test_firmware_text_is_shown_as_it_came(pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path) -> None:
    start_terminal(tmux, pty_sim.url, tmp_path, "--no-history")
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    text = "Cap:REPEAT:0 [bold]x[/] :thumbs_up: :smile:"
    typed(tmux, f"M118 E1 {text}", "Enter")
    screen = await wait_for(tmux, lambda s: "echo:Cap:" in s, "the echo")
    assert f"echo:{text}" in screen  # no markup read, no emoji codes replaced
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: "MARLIN-EXIT=0" in s, "the console to quit with 0")


@needs_tmux
async def test_m112_from_an_old_history_file_is_not_recalled_and_a_new_one_is_not_kept(
    pty_sim: SimulatorServer, tmux: Tmux, tmp_path: Path
) -> None:
    path = tmp_path / "marlin-temp" / "history"  # where start_terminal's XDG_STATE_HOME puts it
    path.parent.mkdir(parents=True)
    write_old_history(path, ["M114", "M112"])  # the old session's last line was the stop

    start_terminal(tmux, pty_sim.url, tmp_path)
    await wait_for(tmux, lambda s: "marlin>" in s, "the prompt")
    typed(tmux, "", "Up")
    await wait_for(tmux, lambda s: last_prompt(s) == "marlin> M114", "the last command that was not the stop")
    typed(tmux, "", "Up")  # nothing older: the stop is not there to reach either
    typed(tmux, "", "Enter")
    await wait_for(tmux, lambda s: "X:0.00 Y:0.00 Z:0.00" in s, "M114's reply")
    await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")
    assert not pty_sim.printer.halted
    assert "send the emergency stop" not in tmux.screen()

    typed(tmux, "m112", "Enter")  # typed again in this session, and not sent
    await wait_for(tmux, lambda s: "any other key = don't" in s, "the question")
    typed(tmux, "n")
    await wait_for(tmux, lambda s: "emergency stop not sent" in s, "the refusal")
    await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")
    typed(tmux, "", "Up")
    await wait_for(tmux, lambda s: last_prompt(s) == "marlin> M114", "M114 again, not m112")
    typed(tmux, "", "C-c")
    await wait_for(tmux, at_an_empty_prompt, "a fresh prompt")
    typed(tmux, "M118 E1 kept", "Enter")
    await wait_for(tmux, lambda s: "echo:kept" in s, "the echo")
    typed(tmux, "", "C-d")
    await wait_for(tmux, lambda s: "MARLIN-EXIT=0" in s, "the console to quit with 0")

    assert not pty_sim.printer.halted
    new_lines = path.read_text().split("+M112\n", 1)[1]  # what this session added after the old file's stop
    assert "+M118 E1 kept" in new_lines and "112" not in new_lines
