"""The firmware's requests to the host (HOST_ACTION_COMMANDS, HOST_PROMPT_SUPPORT), M600 and M876, on the `Board`.

Shapes as Marlin 2.1 prints them (`feature/host_actions.cpp`, `feature/pause.cpp`, `feature/runout.h`):

- A prompt: `//action:prompt_end` (any earlier one), `//action:prompt_begin <message>`, one
  `//action:prompt_button <label>` per button, `//action:prompt_show`. The host answers `M876 S<index>`, which
  the emergency parser acts on as its bytes arrive.
- A filament runout (with the default FILAMENT_RUNOUT_SCRIPT "M600"): the prompt `FilamentRunout T0` (no
  buttons), then `//action:paused filament_runout 0`, then the injected M600 runs.
- M600 (`pause_print`, `load_filament`): `//action:paused`, then the prompt `Load Filament` with the button
  `Continue` while it waits for the user (`wait_for_user`), its keepalive `echo:busy: paused for user`. M876 (any
  button) or M108 ends the wait; then `//action:resumed` and M600's ok.

Simplified: M600 moves nothing and asks once (Marlin also shows `Pause`/`Dismiss` and, after loading, `Paused`
with `PurgeMore`/`Continue`); M876 closes the prompt with `//action:prompt_end` on its own, where Marlin leaves that
to the next step of the command that asked. The board's M115 still says `Cap:PROMPT_SUPPORT:0`, as the captured
board does.
"""

from __future__ import annotations

from collections.abc import Sequence

from marlin_aio.simulator._board import Board, Handler, Task
from marlin_aio.simulator._config import US_PER_S
from marlin_aio.simulator._intake import Command

__all__ = ["answer_prompt", "check_line", "m600", "m876", "open_prompt", "runout_then"]

_CONTINUE = "Continue"


def check_line(name: str, text: str) -> None:
    """Raise ValueError unless `text` fits on one line of output.

    Raises:
        ValueError: it holds a line end.
    """
    if "\n" in text or "\r" in text:
        raise ValueError(f"{name} must be one line, got {text!r}")


def open_prompt(board: Board, message: str, buttons: Sequence[str]) -> None:
    """Show a prompt (`host_prompt_do`): the lines, and the board remembers it until it is answered or closed."""
    board.emit("//action:prompt_end")
    board.emit(f"//action:prompt_begin {message}")
    for label in buttons:
        board.emit(f"//action:prompt_button {label}")
    board.emit("//action:prompt_show")
    board.prompt = (message, tuple(buttons))


def answer_prompt(board: Board, index: int, *, by_host: bool = True) -> None:
    """M876 S<index> (`by_host`) or a click on the screen: close the open prompt and end a wait for the user (an
    answer with no prompt open, or past its buttons, is ignored, as Marlin's response handler does when no prompt
    reason is set). The host's answers are recorded in `board.answers`."""
    prompt = board.prompt
    if prompt is None or not 0 <= index < max(len(prompt[1]), 1):
        return
    if by_host:
        board.answers.append(index)
    board.prompt = None
    board.emit("//action:prompt_end")
    board.wait_for_user = False
    board.poked = True


def m876(board: Board, command: Command) -> None:
    """M876 run from the command buffer: the emergency parser has acted on it already, if the board has one."""
    if board.config.emergency_parser:
        return
    index = command.parameters().get("S")
    if index is not None:
        answer_prompt(board, int(index))


def m600(board: Board, command: Command) -> Task:
    """M600 filament change: pause, ask the user to load filament, wait for the answer, resume."""
    yield from _change_filament(board)


def runout_then(board: Board, command: Command, handler: Handler) -> Task:
    """A filament runout just before `command` runs (`event_filament_runout`): the runout's lines, the M600 it
    injects, then `command` itself (by `handler`)."""
    open_prompt(board, "FilamentRunout T0", ())
    board.emit("//action:paused filament_runout 0")
    yield from _change_filament(board)
    run = handler(board, command)
    if run is not None:
        yield from run


def _change_filament(board: Board) -> Task:
    board.emit("//action:paused")
    open_prompt(board, "Load Filament", (_CONTINUE,))
    board.wait_for_user = True
    board.busy_reason = "paused for user"
    # idle() sends the first keepalive at once: none was due while the command was not busy.
    board.emit("echo:busy: paused for user")
    try:
        while board.wait_for_user:
            yield board.now_us + US_PER_S  # M876 or M108 pokes the task awake at once
    finally:
        board.busy_reason = "processing"
        board.wait_for_user = False
    if board.prompt is not None:
        board.prompt = None
        board.emit("//action:prompt_end")
    board.emit("//action:resumed")
