"""The simulated board as its G-code commands see it: `Board`, the state they read and change, and the shape of a
command's handler (`Handler`, `Task`).

A handler is `handler(board, command)`. It works on the `Board` and on nothing else of the printer: the clock, the
heaters, the position and the planner's queue, the modes and intervals commands set, and the two things a command
asks of the firmware around it, to print a line (`emit`) and to halt (`kill`). `SimulatedPrinter` owns the board and
hands it to every handler; its core (time, intake, the command ring, output) reads the same fields, to move the
clock, run its timers and send the `ok`. So `_gcode` and `_heating` import this module, never `_printer` (which
imports their tables), and all they may touch is public here.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Generator

from marlin_aio.simulator._config import SimulatorConfig, to_us
from marlin_aio.simulator._intake import Command
from marlin_aio.simulator._thermal import Heaters

__all__ = ["Board", "Handler", "PlannerBlock", "Task"]

Task = Generator[int, None, None]
"""A blocking command: each `yield` gives the simulated microsecond at which it next needs to run."""

Handler = Callable[["Board", Command], Task | None]
"""Runs one command on the board: None when it is done at once, else the task that finishes it."""

_DEFAULT_FEEDRATE_MM_S = 1500.0 / 60.0

#: A planned move: (the simulated microsecond it ends, then X, Y, Z and E at its end). Moves run back to back.
PlannerBlock = tuple[int, float, float, float, float]


class Board:
    """The state the G-code commands work on, owned by `SimulatedPrinter`; `reset()` is its power-on state."""

    __slots__ = (
        "active_extruder",
        "answers",
        "busy_reason",
        "config",
        "emit",
        "feedrate_mm_s",
        "heaters",
        "keepalive_interval_us",
        "kill",
        "locked",
        "next_report_us",
        "now_us",
        "planner",
        "poked",
        "position",
        "prompt",
        "relative_e",
        "relative_xyz",
        "report_interval_us",
        "skip_ok",
        "stepper_position",
        "wait_for_heatup",
        "wait_for_user",
    )

    config: SimulatorConfig
    """How the board is built."""
    now_us: int
    """The simulated time, in microseconds. The printer moves it forward; handlers only read it."""
    emit: Callable[[str], None]
    """Print one line to the host (the printer's output faults act on it)."""
    kill: Callable[[], None]
    """Marlin's kill(): heaters off, the halt line, then nothing more until a reset."""
    heaters: Heaters
    """The hotends, and the bed and the chamber when the board has them."""
    active_extruder: int
    """The hotend a T<n> made the active one."""
    position: list[float]
    """The planned X, Y, Z and E, where the last move queued ends: what M114 shows."""
    stepper_position: tuple[float, float, float, float]
    """Where the last finished move left the axes (M410 goes back to it)."""
    planner: deque[PlannerBlock]
    """The moves queued and not yet finished, oldest first (`moves_free()` retires the finished ones)."""
    feedrate_mm_s: float
    """The feedrate of moves that give none (G0/G1 F sets it)."""
    relative_xyz: bool
    """G91: X, Y and Z of moves are relative (G90 makes them absolute)."""
    relative_e: bool
    """M83 or G91: E of moves is relative (M82 or G90 makes it absolute)."""
    wait_for_heatup: bool
    """True while a heater wait runs; M108 clears it to end the wait."""
    wait_for_user: bool
    """True while M600 waits for a person; M876 or M108 clears it to end the wait."""
    busy_reason: str
    """What the keepalive of a busy command says: `processing`, or `paused for user` while it waits for a person."""
    prompt: tuple[str, tuple[str, ...]] | None
    """The prompt shown to the host (its message and buttons) until M876 answers it, or None."""
    answers: list[int]
    """The button of each prompt answered with M876, in order (for tests)."""
    poked: bool
    """M108 or M410 came in: the running task resumes at once rather than when it asked to."""
    keepalive_interval_us: int
    """How often a busy command prints its keepalive (M113 S<seconds>; 0: never)."""
    report_interval_us: int
    """How often the temperatures are reported on their own (M155 S<seconds>; 0: never)."""
    next_report_us: int | None
    """When the next of those reports is due, or None while none is."""
    skip_ok: bool
    """The command answers on its own `ok` line (M105, M114 with `m114_on_ok`): the printer sends no other."""
    locked: bool
    """PASSWORD_FEATURE: every command but M511 is refused until M511 gives the password."""

    def __init__(
        self, config: SimulatorConfig, now_us: int, *, emit: Callable[[str], None], kill: Callable[[], None]
    ) -> None:
        """A board built as `config`, powered up at the simulated time `now_us`."""
        self.config = config
        self.now_us = now_us
        self.emit = emit
        self.kill = kill
        self.answers = []
        self.heaters = Heaters(
            config.extruders,
            has_bed=config.has_bed,
            has_chamber=config.has_chamber,
            ambient_celsius=config.ambient_celsius,
            now_us=now_us,
        )
        self.reset()

    def reset(self) -> None:
        """Power-on state of everything a reset loses (the temperatures themselves carry on)."""
        self.active_extruder = 0
        self.position = [0.0, 0.0, 0.0, 0.0]
        self.stepper_position = (0.0, 0.0, 0.0, 0.0)
        self.planner = deque()
        self.feedrate_mm_s = _DEFAULT_FEEDRATE_MM_S
        self.relative_xyz = False
        self.relative_e = False
        self.wait_for_heatup = False
        self.wait_for_user = False
        self.busy_reason = "processing"
        self.prompt = None
        self.poked = False
        self.keepalive_interval_us = to_us(self.config.keepalive_interval_s)
        self.report_interval_us = 0
        self.next_report_us = None
        self.skip_ok = False
        self.locked = self.config.password is not None
        self.heaters.switch_off()

    def sync_thermal(self) -> None:
        """Bring the heaters up to the present."""
        self.heaters.sync(self.now_us)

    def moves_free(self) -> int:
        """How many more moves the planner can take now, after retiring those that have finished."""
        planner = self.planner
        now = self.now_us
        while planner and planner[0][0] <= now:
            _, x, y, z, e = planner.popleft()
            self.stepper_position = (x, y, z, e)
        return self.config.planner_buffer_size - 1 - len(planner)

    def quick_stop(self) -> None:
        """M410: drop every planned move; the axes stay where the last finished move left them."""
        self.moves_free()
        self.planner.clear()
        self.position = list(self.stepper_position)
        self.poked = True
