"""The simulated board's temperature commands: targets (M104/M109, M140/M190, M141/M191), M105 and M155, and
`heater_states()`, the report line that M105, the heater waits and the printer's auto-report all print.

Part of the G-code handlers (`_gcode`, whose table maps the codes to these functions), in a file of their own
because the heater wait is the longest piece of command logic. Each is `handler(board, command)` like the
others and works on the board's heaters (`Board.heaters`, `_thermal.Heaters`) directly.

M109/M190/M191 wait as `Temperature::wait_for_hotend()` / `wait_for_bed()` do in Marlin 2.1: a wait line every
second (` W:<seconds left>`, or plain with `plain_wait_lines`), 10 s residency in a 1 C window, restarted beyond
3 C; M108 ends the wait; a cooling wait (`R`) gives up when cooling stalls. With `repetier_targets` a new target
gets a line of its own before the `ok`.
"""

from __future__ import annotations

from marlin_aio.protocol.gcode import value_celsius
from marlin_aio.simulator._board import Board, Task
from marlin_aio.simulator._config import US_PER_S
from marlin_aio.simulator._intake import Command
from marlin_aio.simulator._thermal import STEP_US, Heater

__all__ = ["heater_states", "m104", "m105", "m109", "m140", "m141", "m155", "m190", "m191"]

# TEMP_RESIDENCY_TIME / TEMP_WINDOW / TEMP_HYSTERESIS (the bed and chamber use the same defaults).
_RESIDENCY_US = 10 * US_PER_S
_WINDOW_CELSIUS = 1.0
_HYSTERESIS_CELSIUS = 3.0
# MIN_COOLING_SLOPE_DEG over MIN_COOLING_SLOPE_TIME: an `R` wait that stops cooling gives up.
_COOLING_SLOPE_CELSIUS = 1.5
_COOLING_SLOPE_US = 60 * US_PER_S
_WAIT_REPORT_US = US_PER_S


def _target_extruder(board: Board, command: Command, parameters: dict[str, float | None]) -> int | None:
    """get_target_extruder_from_command(): T<n> or the active extruder; None (and a message) if invalid."""
    tool = parameters.get("T")
    if tool is None:
        return board.active_extruder
    extruder = int(tool)
    if 0 <= extruder < len(board.heaters.hotends):
        return extruder
    board.emit(f"echo:{command.code} Invalid extruder {extruder}")
    return None


def m104(board: Board, command: Command) -> None:
    """M104 S<celsius> [T<n>]: set a hotend's target and go on."""
    _set_hotend(board, command)


def m109(board: Board, command: Command) -> Task | None:
    """M109 S|R<celsius> [T<n>]: set a hotend's target and wait for it (S: only when heating)."""
    return _set_hotend(board, command, wait=True)


def _set_hotend(board: Board, command: Command, *, wait: bool = False) -> Task | None:
    parameters = command.parameters()
    extruder = _target_extruder(board, command, parameters)
    if extruder is None:
        return None
    heater = board.heaters.hotends[extruder]
    return _set_target(board, heater, command, wait, extruder)


def _set_target(board: Board, heater: Heater, command: Command, wait: bool, extruder: int) -> Task | None:
    """M104/M109, M140/M190, M141/M191: S sets and waits only for heating, R waits both ways."""
    words = command.words
    no_wait_for_cooling = words.value("S") is not None
    celsius = words.value("S") if no_wait_for_cooling else words.value("R")
    if celsius is None:
        return None
    board.sync_thermal()
    # parser.value_celsius(): strtol's long cut to a 16-bit celsius_t (`S65816` is 280), as the board reads it.
    heater.set_target(float(value_celsius(celsius)))
    if board.config.repetier_targets:
        board.emit(f"{_target_label(board, heater, extruder)}:{int(heater.target_celsius)}")
    heating = heater.target_celsius > heater.celsius
    if wait and (heating or not no_wait_for_cooling):
        return _wait_for_heater(board, heater, extruder)
    return None


def _target_label(board: Board, heater: Heater, extruder: int) -> str:
    """The Repetier name of a heater's target: `TargetExtr<n>`, `TargetBed` or `TargetChamber`."""
    if heater is board.heaters.bed:
        return "TargetBed"
    if heater is board.heaters.chamber:
        return "TargetChamber"
    return f"TargetExtr{extruder}"


def _wait_for_heater(board: Board, heater: Heater, extruder: int) -> Task:
    """Temperature::wait_for_hotend() / wait_for_bed(): a W: line every second, 10 s residency in a 1 C
    window, restarted beyond 3 C; M108 ends it at once; cooling waits give up when cooling stalls."""
    board.wait_for_heatup = True
    target = heater.target_celsius
    wants_to_cool = heater.celsius > target
    next_print = board.now_us
    residency_start: int | None = None
    first_loop = True
    old_celsius = 9999.0
    next_cool_check: int | None = None
    while True:
        board.sync_thermal()
        now = board.now_us
        if now >= next_print:
            next_print = now + _WAIT_REPORT_US
            if board.config.plain_wait_lines:
                board.emit(heater_states(board, extruder))
            else:
                left = "?" if residency_start is None else str((_RESIDENCY_US - now + residency_start) // US_PER_S)
                board.emit(f"{heater_states(board, extruder)} W:{left}")
        celsius = heater.celsius
        difference = abs(target - celsius)
        if residency_start is None:
            if difference < _WINDOW_CELSIUS:
                # Marlin starts the clock a third later when the heater is already there on the first pass.
                residency_start = now + (_RESIDENCY_US // 3 if first_loop else 0)
        elif difference > _HYSTERESIS_CELSIUS:
            residency_start = now
        first_loop = False
        if wants_to_cool and (next_cool_check is None or now >= next_cool_check):
            if old_celsius - celsius < _COOLING_SLOPE_CELSIUS:
                return
            next_cool_check = now + _COOLING_SLOPE_US
            old_celsius = celsius
        if not board.wait_for_heatup:
            return
        # Sleep until the temperature could enter the window (or, once inside, leave the hysteresis band).
        margin = difference - _WINDOW_CELSIUS if residency_start is None else _HYSTERESIS_CELSIUS - difference
        wake = min(next_print, (now // STEP_US + heater.steps_to_change(margin)) * STEP_US)
        if residency_start is not None:
            residency_end = residency_start + _RESIDENCY_US
            if now >= residency_end:
                return
            wake = min(wake, residency_end)
        if next_cool_check is not None:
            wake = min(wake, next_cool_check)
        yield wake


def m105(board: Board, command: Command) -> None:
    """M105 [T<n>]: the temperatures, on the `ok` line itself."""
    board.skip_ok = True  # M105 answers on its own `ok T:...` line, or not at all
    extruder = _target_extruder(board, command, command.parameters())
    if extruder is not None:
        board.emit("ok" + heater_states(board, extruder))


def m140(board: Board, command: Command) -> None:
    """M140 S<celsius>: set the bed's target and go on."""
    bed = board.heaters.bed
    assert bed is not None  # the table has this command only when the board has a bed
    _set_target(board, bed, command, False, board.active_extruder)


def m190(board: Board, command: Command) -> Task | None:
    """M190 S|R<celsius>: set the bed's target and wait for it (S: only when heating)."""
    bed = board.heaters.bed
    assert bed is not None  # the table has this command only when the board has a bed
    return _set_target(board, bed, command, True, board.active_extruder)


def m141(board: Board, command: Command) -> None:
    """M141 S<celsius>: set the chamber's target and go on."""
    chamber = board.heaters.chamber
    assert chamber is not None  # the table has this command only when the board has a chamber
    _set_target(board, chamber, command, False, board.active_extruder)


def m191(board: Board, command: Command) -> Task | None:
    """M191 S|R<celsius>: set the chamber's target and wait for it (S: only when heating)."""
    chamber = board.heaters.chamber
    assert chamber is not None  # the table has this command only when the board has a chamber
    return _set_target(board, chamber, command, True, board.active_extruder)


def m155(board: Board, command: Command) -> None:
    """M155 S<seconds>: report the temperatures this often (0: stop), as AUTO_REPORT_TEMPERATURES does."""
    seconds = command.parameters().get("S")
    if seconds is None:
        return
    board.report_interval_us = min(max(int(seconds), 0), 60) * US_PER_S
    board.next_report_us = board.now_us + board.report_interval_us if board.report_interval_us else None


def heater_states(board: Board, extruder: int) -> str:
    """print_heater_states(): ` T:.. /.. B:.. /.. @:.. B@:..`, starting with a space."""
    board.sync_thermal()
    heaters = board.heaters
    hotends, bed, chamber = heaters.hotends, heaters.bed, heaters.chamber
    hotend = hotends[extruder]
    # Repetier-style firmwares report targets on lines of their own, not after each reading.
    field = _reading if board.config.repetier_targets else _reading_and_target
    parts = [field("T", hotend)]
    if bed is not None:
        parts.append(field("B", bed))
    if chamber is not None:
        parts.append(field("C", chamber))
    if len(hotends) > 1:
        parts.extend(field(f"T{i}", h) for i, h in enumerate(hotends))
    parts.append(f" @:{hotend.power_127}")
    if bed is not None:
        parts.append(f" B@:{bed.power_127}")
    if chamber is not None:
        parts.append(f" C@:{chamber.power_127}")
    if len(hotends) > 1:
        parts.extend(f" @{i}:{h.power_127}" for i, h in enumerate(hotends))
    return "".join(parts)


def _celsius(value: float) -> str:
    return f"{value + 0.0:.2f}"  # + 0.0 turns -0.0 into 0.0, which Marlin would print without a sign


def _reading_and_target(letter: str, heater: Heater) -> str:
    return f" {letter}:{_celsius(heater.celsius)} /{_celsius(heater.target_celsius)}"


def _reading(letter: str, heater: Heater) -> str:
    return f" {letter}:{_celsius(heater.celsius)}"
