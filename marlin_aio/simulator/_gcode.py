"""The simulated board's G-code commands: one handler function per command, and the table from code to handler.

A handler is `handler(board, command)` (`_board.Handler`). It either finishes at once (and returns None) or returns
a task: a generator yielding the simulated microsecond at which it next needs to run, which the printer resumes
while keepalives, auto-reports and the line intake carry on around it, as Marlin's `idle()` does.

The handlers see the printer only through its `_board.Board`: the position and planner, the heaters, the
keepalive and report intervals, `skip_ok` for commands that answer on their own `ok` line, `emit()` for a line
and `kill()` to halt. `SimulatedPrinter` owns the board and calls them; this module does not know it.

How they follow Marlin 2.1 (`gcode/*.cpp`, `module/planner.cpp`); the temperature commands (M104/M109,
M140/M190, M141/M191, M105, M155) are in `_heating`:

- M112 without the emergency parser halts when its turn comes, as `gcode.cpp` does (`case 112: M112()`); one
  capture shows a board answering it with `ok` instead, which the source does not explain.
- Moves take distance / feedrate (no acceleration), so streamed moves finish a little sooner than on the board;
  `motion_time_scale` shortens them further, so a benchmark of the serial link is not bound by the planner.
- The dialect switches of `SimulatorConfig` that change a command's answer are honoured here (`m114_on_ok`,
  `password`) and in `_heating` (`plain_wait_lines`, `repetier_targets`).
"""

from __future__ import annotations

import math
import re

from marlin_aio.simulator._board import Board, Handler, Task
from marlin_aio.simulator._config import (
    BUILD_DATE,
    CAPABILITIES,
    SETTINGS_LINES,
    US_PER_S,
    UUID,
    SimulatorConfig,
    to_us,
)
from marlin_aio.simulator._heating import m104, m105, m109, m140, m141, m155, m190, m191
from marlin_aio.simulator._hostactions import m600, m876
from marlin_aio.simulator._intake import Command

__all__ = ["handler_table", "tool_change", "unknown"]

_STEPS_PER_MM = (80.0, 80.0, 400.0)  # X Y Z, as in the captured board's M92
_M511_PASSWORD = re.compile(r"P *(\S+)")

# Commands Marlin accepts that change nothing the simulation shows.
_NO_OPS = frozenset(
    {"G21", "M17", "M18", "M84", "M92", "M106", "M107", "M117", "M149", "M200", "M201", "M203", "M204", "M205"}
    | {"M206", "M220", "M221", "M301", "M999"}
)


def handler_table(config: SimulatorConfig) -> dict[str, Handler]:
    """The handler of each command code a board built as `config` knows (T<n> and unknown codes excepted)."""
    handlers: dict[str, Handler] = {
        "G0": _g0_g1,
        "G1": _g0_g1,
        "G4": _g4,
        "G28": _g28,
        "G90": _g90,
        "G91": _g91,
        "G92": _g92,
        "M82": _m82,
        "M83": _m83,
        "M104": m104,
        "M105": m105,
        "M108": _m108,
        "M109": m109,
        "M110": _no_op,  # replaced by the printer's own handler: M110 sets the line counter when it runs
        "M112": _m112,
        "M113": _m113,
        "M114": _m114,
        "M115": _m115,
        "M118": _m118,
        "M119": _m119,
        "M27": _m27,
        "M400": _m400,
        "M410": _m410,
        "M503": _m503,
        "M600": m600,
        "M876": m876,
    }
    for code in _NO_OPS:
        handlers[code] = _no_op
    if config.has_bed:
        handlers["M140"] = m140
        handlers["M190"] = m190
    if config.has_chamber:
        handlers["M141"] = m141
        handlers["M191"] = m191
    if config.autoreport_temp:
        handlers["M155"] = m155
    if config.password is not None:
        handlers["M511"] = _m511
    return handlers


def _no_op(board: Board, command: Command) -> None:
    return None


def unknown(board: Board, command: Command) -> None:
    """Any code the board does not know: `echo:Unknown command: "<line>"`, then the usual `ok`."""
    board.emit(f'echo:Unknown command: "{command.text}"')


def _g0_g1(board: Board, command: Command) -> Task:
    parameters = command.parameters()
    feedrate = parameters.get("F")
    if feedrate is not None and feedrate > 0:
        board.feedrate_mm_s = feedrate / 60.0
    start = list(board.position)
    target = list(start)
    for axis, letter in enumerate("XYZE"):
        value = parameters.get(letter)
        if value is None:
            continue
        relative = board.relative_e if letter == "E" else board.relative_xyz
        target[axis] = start[axis] + value if relative else value
    dx, dy, dz, de = (target[axis] - start[axis] for axis in range(4))
    length = math.sqrt(dx * dx + dy * dy + dz * dz) or abs(de)
    if length == 0.0:
        board.position = target  # Marlin plans no block for a move of no steps
        return
    # buffer_line() waits (in idle(), so lines keep coming in) until the planner has a free block.
    while board.moves_free() == 0:
        yield board.planner[0][0]
    begin = board.planner[-1][0] if board.planner else board.now_us
    duration = round(length / board.feedrate_mm_s * US_PER_S * board.config.motion_time_scale)
    board.planner.append((max(begin, board.now_us) + duration, target[0], target[1], target[2], target[3]))
    board.position = target


def _g4(board: Board, command: Command) -> Task:
    parameters = command.parameters()
    dwell_us = 0
    if (milliseconds := parameters.get("P")) is not None:
        dwell_us = round(milliseconds * 1000)
    if (seconds := parameters.get("S")) is not None:
        dwell_us = to_us(seconds)
    yield from _synchronize(board)
    end = board.now_us + dwell_us
    while board.now_us < end:
        yield end


def _g28(board: Board, command: Command) -> Task:
    parameters = command.parameters()
    axes = [axis for axis, letter in enumerate("XYZ") if letter in parameters] or [0, 1, 2]
    yield from _synchronize(board)
    end = board.now_us + to_us(board.config.homing_s)
    while board.now_us < end:
        yield end
    for axis in axes:
        board.position[axis] = 0.0
    x, y, z, e = board.position
    board.stepper_position = (x, y, z, e)
    board.emit(_position_line(board))


def _g90(board: Board, command: Command) -> None:
    board.relative_xyz = board.relative_e = False


def _g91(board: Board, command: Command) -> None:
    board.relative_xyz = board.relative_e = True


def _g92(board: Board, command: Command) -> None:
    parameters = command.parameters()
    for axis, letter in enumerate("XYZE"):
        value = parameters.get(letter)
        if value is not None:
            board.position[axis] = value


def _m82(board: Board, command: Command) -> None:
    board.relative_e = False


def _m83(board: Board, command: Command) -> None:
    board.relative_e = True


def _m27(board: Board, command: Command) -> None:
    board.emit("Not SD printing")


def _m108(board: Board, command: Command) -> None:
    if not board.config.emergency_parser:
        board.wait_for_heatup = False  # nothing waits while this runs, so it only matters for M0/M1
        board.wait_for_user = False


def _m112(board: Board, command: Command) -> None:
    if not board.config.emergency_parser:
        board.emit("echo:M112 Shutdown")
        board.kill()


def _m113(board: Board, command: Command) -> None:
    seconds = command.parameters().get("S")
    if seconds is not None:
        board.keepalive_interval_us = min(max(int(seconds), 0), 60) * US_PER_S


def _m114(board: Board, command: Command) -> None:
    if board.config.m114_on_ok:
        board.skip_ok = True  # the position rides on the ok line itself, like M105's temperatures
        board.emit(f"ok {_position_line(board)}")
    else:
        board.emit(_position_line(board))


def _m115(board: Board, command: Command) -> None:
    config = board.config
    board.emit(
        f"FIRMWARE_NAME:{config.firmware_name} ({BUILD_DATE}) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin"
        f" PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer KINEMATICS:Cartesian"
        f" EXTRUDER_COUNT:{config.extruders} UUID:{UUID}"
    )
    configured = {
        "AUTOREPORT_TEMP": config.autoreport_temp,
        "EMERGENCY_PARSER": config.emergency_parser,
        "CHAMBER_TEMPERATURE": config.has_chamber,
    }
    for name, value in CAPABILITIES:
        flag = int(configured[name]) if value is None else value
        board.emit(f"Cap:{name}:{flag}")


def _m118(board: Board, command: Command) -> None:
    text = command.args
    echo = action = False
    for _ in range(3):  # A1, E1 and Pn flags come first, in any order
        if text[:2] in ("A1", "E1") or (text[:1] == "P" and text[1:2].isdigit()):
            echo = echo or text[0] == "E"
            action = action or text[0] == "A"
            text = text[2:].lstrip(" ")
        else:
            break
    board.emit(("echo:" if echo else "") + ("//" if action else "") + text)


def _m119(board: Board, command: Command) -> None:
    board.emit("Reporting endstop status")
    for axis in ("x_min", "y_min", "z_min"):
        board.emit(f"{axis}: open")


def _m400(board: Board, command: Command) -> Task:
    yield from _synchronize(board)


def _m410(board: Board, command: Command) -> None:
    if not board.config.emergency_parser:
        board.quick_stop()


def _m511(board: Board, command: Command) -> None:
    """M511 P<password>: unlock (password.cpp compares only while locked)."""
    if not board.locked:
        return
    match = _M511_PASSWORD.search(command.args)
    if match is not None and match.group(1) == board.config.password:
        board.locked = False
    else:
        board.emit("echo:Incorrect Password")


def _m503(board: Board, command: Command) -> None:
    for line in SETTINGS_LINES:
        board.emit(line)


def tool_change(board: Board, command: Command) -> None:
    """T<n>: make hotend n the active one, or say it does not exist."""
    tool = int(command.code[1:])
    if tool < len(board.heaters.hotends):
        board.active_extruder = tool
    else:
        board.emit(f"echo:T{tool} Invalid extruder")


def _position_line(board: Board) -> str:
    x, y, z, e = (value + 0.0 for value in board.position)
    counts = [math.floor(value * steps + 0.5) for value, steps in zip((x, y, z), _STEPS_PER_MM, strict=True)]
    return f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count X:{counts[0]} Y:{counts[1]} Z:{counts[2]}"


def _synchronize(board: Board) -> Task:
    """planner.synchronize(): wait until every planned move has finished."""
    while board.moves_free() < board.config.planner_buffer_size - 1:
        yield board.planner[-1][0]
