"""The simulated board's G-code commands: one handler function per command, and the table from code to handler.

A handler is `handler(printer, command)`. It either finishes at once (and returns None) or returns a task: a
generator yielding the simulated microsecond at which it next needs to run, which the printer resumes while
keepalives, auto-reports and the line intake carry on around it, as Marlin's `idle()` does.

The handlers are the printer's own code, kept in a file of their own so that `_printer` reads as the core (time,
intake, execution, output). They read and change its state directly, as its methods would: the position and
planner, the heaters, the keepalive and report intervals, `_skip_ok` for commands that answer on their own
`ok` line. Only `SimulatedPrinter` calls them.

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
from collections.abc import Callable, Generator
from typing import TYPE_CHECKING

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
from marlin_aio.simulator._intake import Command

if TYPE_CHECKING:
    from marlin_aio.simulator._printer import SimulatedPrinter

__all__ = ["Handler", "Task", "handler_table", "tool_change", "unknown"]

Task = Generator[int, None, None]
"""A blocking command: each `yield` gives the simulated microsecond at which it next needs to run."""

Handler = Callable[["SimulatedPrinter", Command], Task | None]
"""Runs one command on the printer: None when it is done at once, else the task that finishes it."""

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


def _no_op(printer: SimulatedPrinter, command: Command) -> None:
    return None


def unknown(printer: SimulatedPrinter, command: Command) -> None:
    """Any code the board does not know: `echo:Unknown command: "<line>"`, then the usual `ok`."""
    printer._emit(f'echo:Unknown command: "{command.text}"')


def _g0_g1(printer: SimulatedPrinter, command: Command) -> Task:
    parameters = command.parameters()
    feedrate = parameters.get("F")
    if feedrate is not None and feedrate > 0:
        printer._feedrate_mm_s = feedrate / 60.0
    start = list(printer._position)
    target = list(start)
    for axis, letter in enumerate("XYZE"):
        value = parameters.get(letter)
        if value is None:
            continue
        relative = printer._relative_e if letter == "E" else printer._relative_xyz
        target[axis] = start[axis] + value if relative else value
    dx, dy, dz, de = (target[axis] - start[axis] for axis in range(4))
    length = math.sqrt(dx * dx + dy * dy + dz * dz) or abs(de)
    if length == 0.0:
        printer._position = target  # Marlin plans no block for a move of no steps
        return
    # buffer_line() waits (in idle(), so lines keep coming in) until the planner has a free block.
    while printer._moves_free() == 0:
        yield printer._planner[0][0]
    begin = printer._planner[-1][0] if printer._planner else printer._t
    duration = round(length / printer._feedrate_mm_s * US_PER_S * printer.config.motion_time_scale)
    printer._planner.append((max(begin, printer._t) + duration, target[0], target[1], target[2], target[3]))
    printer._position = target


def _g4(printer: SimulatedPrinter, command: Command) -> Task:
    parameters = command.parameters()
    dwell_us = 0
    if (milliseconds := parameters.get("P")) is not None:
        dwell_us = round(milliseconds * 1000)
    if (seconds := parameters.get("S")) is not None:
        dwell_us = to_us(seconds)
    yield from _synchronize(printer)
    end = printer._t + dwell_us
    while printer._t < end:
        yield end


def _g28(printer: SimulatedPrinter, command: Command) -> Task:
    parameters = command.parameters()
    axes = [axis for axis, letter in enumerate("XYZ") if letter in parameters] or [0, 1, 2]
    yield from _synchronize(printer)
    end = printer._t + to_us(printer.config.homing_s)
    while printer._t < end:
        yield end
    for axis in axes:
        printer._position[axis] = 0.0
    x, y, z, e = printer._position
    printer._stepper_position = (x, y, z, e)
    printer._emit(_position_line(printer))


def _g90(printer: SimulatedPrinter, command: Command) -> None:
    printer._relative_xyz = printer._relative_e = False


def _g91(printer: SimulatedPrinter, command: Command) -> None:
    printer._relative_xyz = printer._relative_e = True


def _g92(printer: SimulatedPrinter, command: Command) -> None:
    parameters = command.parameters()
    for axis, letter in enumerate("XYZE"):
        value = parameters.get(letter)
        if value is not None:
            printer._position[axis] = value


def _m82(printer: SimulatedPrinter, command: Command) -> None:
    printer._relative_e = False


def _m83(printer: SimulatedPrinter, command: Command) -> None:
    printer._relative_e = True


def _m27(printer: SimulatedPrinter, command: Command) -> None:
    printer._emit("Not SD printing")


def _m108(printer: SimulatedPrinter, command: Command) -> None:
    if not printer.config.emergency_parser:
        printer._wait_for_heatup = False  # nothing waits while this runs, so it only matters for M0/M1


def _m112(printer: SimulatedPrinter, command: Command) -> None:
    if not printer.config.emergency_parser:
        printer._emit("echo:M112 Shutdown")
        printer._kill()


def _m113(printer: SimulatedPrinter, command: Command) -> None:
    seconds = command.parameters().get("S")
    if seconds is not None:
        printer._keepalive_us = min(max(int(seconds), 0), 60) * US_PER_S


def _m114(printer: SimulatedPrinter, command: Command) -> None:
    if printer.config.m114_on_ok:
        printer._skip_ok = True  # the position rides on the ok line itself, like M105's temperatures
        printer._emit(f"ok {_position_line(printer)}")
    else:
        printer._emit(_position_line(printer))


def _m115(printer: SimulatedPrinter, command: Command) -> None:
    config = printer.config
    printer._emit(
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
        printer._emit(f"Cap:{name}:{flag}")


def _m118(printer: SimulatedPrinter, command: Command) -> None:
    text = command.args
    echo = action = False
    for _ in range(3):  # A1, E1 and Pn flags come first, in any order
        if text[:2] in ("A1", "E1") or (text[:1] == "P" and text[1:2].isdigit()):
            echo = echo or text[0] == "E"
            action = action or text[0] == "A"
            text = text[2:].lstrip(" ")
        else:
            break
    printer._emit(("echo:" if echo else "") + ("//" if action else "") + text)


def _m119(printer: SimulatedPrinter, command: Command) -> None:
    printer._emit("Reporting endstop status")
    for axis in ("x_min", "y_min", "z_min"):
        printer._emit(f"{axis}: open")


def _m400(printer: SimulatedPrinter, command: Command) -> Task:
    yield from _synchronize(printer)


def _m410(printer: SimulatedPrinter, command: Command) -> None:
    if not printer.config.emergency_parser:
        printer._quick_stop()


def _m511(printer: SimulatedPrinter, command: Command) -> None:
    """M511 P<password>: unlock (password.cpp compares only while locked)."""
    if not printer._locked:
        return
    match = _M511_PASSWORD.search(command.args)
    if match is not None and match.group(1) == printer.config.password:
        printer._locked = False
    else:
        printer._emit("echo:Incorrect Password")


def _m503(printer: SimulatedPrinter, command: Command) -> None:
    for line in SETTINGS_LINES:
        printer._emit(line)


def tool_change(printer: SimulatedPrinter, command: Command) -> None:
    """T<n>: make hotend n the active one, or say it does not exist."""
    tool = int(command.code[1:])
    if tool < len(printer._hotends):
        printer._active_extruder = tool
    else:
        printer._emit(f"echo:T{tool} Invalid extruder")


def _position_line(printer: SimulatedPrinter) -> str:
    x, y, z, e = (value + 0.0 for value in printer._position)
    counts = [math.floor(value * steps + 0.5) for value, steps in zip((x, y, z), _STEPS_PER_MM, strict=True)]
    return f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count X:{counts[0]} Y:{counts[1]} Z:{counts[2]}"


def _synchronize(printer: SimulatedPrinter) -> Task:
    """planner.synchronize(): wait until every planned move has finished."""
    while printer._moves_free() < printer.config.planner_buffer_size - 1:
        yield printer._planner[-1][0]
