"""The everyday G-code of a printer as methods, each built on `send` alone: homing, moves, extrusion, motors,
endstops, the position, fans and heater targets, with the limits those are checked against (`GcodeCommands`, a
base of `Printer`).

They are the same whatever reaches the printer (a port or `marlin-temp serve`), so they live once, here, apart
from the backends; each spells its G-code with `marlin_aio.protocol.motion` and `marlin_aio.protocol.heaters`,
which check every argument before anything is sent.
"""

from __future__ import annotations

import asyncio
from abc import ABC, abstractmethod
from dataclasses import replace

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.connection import Reply
from marlin_aio.protocol.heaters import HeaterLimits, target_commands
from marlin_aio.protocol.motion import (
    command_timeout_s,
    disable_motors_command,
    extrude_commands,
    home_command,
    move_commands,
)
from marlin_aio.protocol.parsing import parse_endstops, parse_position

__all__ = ["GcodeCommands"]


def _limit(name: str, celsius: float) -> float:
    """A heater limit as given, if it is a positive finite number of degrees.

    Raises:
        ValueError: it is not.
    """
    if isinstance(celsius, bool) or not isinstance(celsius, int | float) or not 0 < celsius < float("inf"):
        raise ValueError(f"{name} must be a positive number of degrees Celsius, got {celsius!r}")
    return float(celsius)


class GcodeCommands(ABC):
    """The everyday commands, on top of `send`, and the heater limits every target is checked against (`Printer`
    is the one to use).

    Raises:
        ValueError: a limit of `limits` is not a positive number of degrees.
    """

    def __init__(self, limits: HeaterLimits) -> None:
        self._heater_limits = HeaterLimits(
            _limit("max_hotend_celsius", limits.hotend),
            _limit("max_bed_celsius", limits.bed),
            _limit("max_chamber_celsius", limits.chamber),
        )

    @abstractmethod
    async def send(self, command: str, *, timeout_s: float | None = None, numbered: bool | None = None) -> Reply:
        """Send one command and return its reply (see `Printer.send`)."""

    @property
    @abstractmethod
    def timeout_s(self) -> float:
        """The default wait for a command's `ok`."""

    @abstractmethod
    def _limits_changed(self, limits: HeaterLimits) -> None:
        """Check every command and print line against `limits` from now on."""

    @property
    def heater_limits(self) -> HeaterLimits:
        """The three limits below as one `HeaterLimits`: what every command and print line is checked against."""
        return self._heater_limits

    @property
    def max_hotend_celsius(self) -> float:
        """The highest hotend target any command may set (checked as the firmware reads each command)."""
        return self._heater_limits.hotend

    @max_hotend_celsius.setter
    def max_hotend_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, hotend=_limit("max_hotend_celsius", celsius)))

    @property
    def max_bed_celsius(self) -> float:
        """The highest bed target any command may set."""
        return self._heater_limits.bed

    @max_bed_celsius.setter
    def max_bed_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, bed=_limit("max_bed_celsius", celsius)))

    @property
    def max_chamber_celsius(self) -> float:
        """The highest chamber target any command may set."""
        return self._heater_limits.chamber

    @max_chamber_celsius.setter
    def max_chamber_celsius(self, celsius: float) -> None:
        self._set_limits(replace(self._heater_limits, chamber=_limit("max_chamber_celsius", celsius)))

    def _set_limits(self, limits: HeaterLimits) -> None:
        self._heater_limits = limits
        self._limits_changed(limits)

    async def home(self, *axes: str, timeout_s: float | None = None) -> Reply:
        """Home the axes given (`home()` homes all, `home("x", "y")` two) with G28; return its reply.

        Homing is answered only when it is done, so unless `timeout_s` says otherwise the wait is at least
        `LONG_COMMAND_TIMEOUT_S` (3 minutes), for boards that stay silent meanwhile (see `marlin_aio.protocol.motion`).

        Raises:
            ValueError: an axis is not X, Y or Z.
            MarlinError: as `send`.
        """
        command = home_command(axes)
        if timeout_s is None:
            timeout_s = command_timeout_s(command, self.timeout_s)
        return await self.send(command, timeout_s=timeout_s)

    async def move(
        self,
        *,
        x: float | None = None,
        y: float | None = None,
        z: float | None = None,
        feedrate_mm_min: float | None = None,
        relative: bool = False,
        timeout_s: float | None = None,
    ) -> Reply:
        """Move in a straight line to (`x`, `y`, `z`) in millimetres, or by that much with `relative`; return the
        move's reply. Marlin answers once the move is planned, not when it is done (M400 waits for that).

        The mode is sent with the move (G90 or G91 before it) and the printer is left in absolute mode.
        `feedrate_mm_min` is G-code's `F`; without it the printer's current speed is used.

        Raises:
            ValueError: no axis given, a coordinate is not a finite number, the feed rate is not positive, ...
                (nothing is sent).
            MarlinError: as `send`.
        """
        commands = move_commands(x=x, y=y, z=z, feedrate_mm_min=feedrate_mm_min, relative=relative)
        return (await self._send_together(commands, timeout_s))[1]

    async def extrude(
        self, length_mm: float, *, feedrate_mm_min: float = 300.0, timeout_s: float | None = None
    ) -> Reply:
        """Push `length_mm` of filament through the hotend (negative retracts) at `feedrate_mm_min`; return the
        move's reply. Marlin refuses below its minimum extrusion temperature and says so in the reply's lines.

        Raises:
            ValueError: the length is 0 or not a finite number, the feed rate is not positive, ... (nothing is sent).
            MarlinError: as `send`.
        """
        commands = extrude_commands(length_mm, feedrate_mm_min=feedrate_mm_min)
        return (await self._send_together(commands, timeout_s))[1]

    async def disable_motors(self, *axes: str) -> Reply:
        """Turn the stepper motors of the axes given (X, Y, Z, E) off with M84, or all of them; return its reply.

        Marlin finishes the moves already planned first. The position is lost: home again before moving.

        Raises:
            ValueError: an axis is not X, Y, Z or E.
            MarlinError: as `send`.
        """
        return await self.send(disable_motors_command(axes))

    async def _send_together(self, commands: list[str], timeout_s: float | None) -> list[Reply]:
        # Each `send` queues its command before its first await, so gathering them queues these back to back: no
        # other task's command can land between a G91 and the move it is meant for.
        return await asyncio.gather(*(self.send(command, timeout_s=timeout_s) for command in commands))

    async def endstops(self) -> dict[str, bool]:
        """Read the endstops (M119): {"x_min": False, "z_min": True, ...}, True meaning triggered.

        Raises:
            MarlinError: as `send`.
        """
        return parse_endstops((await self.send("M119")).lines)

    async def position(self) -> dict[str, float]:
        """Read the current position in millimetres (M114): {"X": 10.0, "Y": 20.0, "Z": 5.0, "E": 0.0}.

        Raises:
            MarlinError: as `send`; also if the reply holds no position.
        """
        reply = await self.send("M114")
        # Some firmwares answer on the ok line itself (`ok X:10.00 Y:0.00 ...`).
        position = parse_position(reply.lines) or parse_position((reply.ok.payload,))
        if position is None:
            raise MarlinError(f"M114 was answered without a position: {reply.lines!r}")
        return position

    async def set_fan(self, fraction: float, *, fan: int = 0) -> None:
        """Set a part-cooling fan's speed, from 0.0 (off, M107) to 1.0 (full, M106 S255).

        Raises:
            ValueError: `fraction` is not between 0 and 1, or `fan` is negative.
            MarlinError: as `send`.
        """
        if not (isinstance(fraction, int | float) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"fan speed must be a fraction from 0.0 to 1.0, got {fraction!r}")
        if isinstance(fan, bool) or not isinstance(fan, int) or fan < 0:
            raise ValueError(f"fan must be a non-negative integer, got {fan!r}")
        index = f" P{fan}" if fan else ""
        await self.send(f"M107{index}" if fraction == 0 else f"M106{index} S{round(fraction * 255)}")

    async def set_temperatures(
        self,
        *,
        hotend: float | None = None,
        bed: float | None = None,
        chamber: float | None = None,
        tool: int | None = None,
    ) -> None:
        """Set heater targets (M104, M140, M141) without waiting. 0 turns a heater off.

        Every target is checked before anything is written.

        Raises:
            ValueError: a target is not a number, negative, or above the client's limit; `tool` is negative.
            MarlinError: as `send`.
        """
        for command in target_commands(self.heater_limits, hotend=hotend, bed=bed, chamber=chamber, tool=tool):
            await self.send(command)
