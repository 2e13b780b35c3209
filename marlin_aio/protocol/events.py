"""Events: what one line received from Marlin means.

Every complete line the printer sends becomes exactly one of these small frozen objects (see
`parsing.classify_line`). They carry facts only; what to do about them is the connection's job.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from marlin_aio.protocol.temperatures import Temperatures

__all__ = [
    "BusyKeepalive",
    "Capability",
    "EchoMessage",
    "ErrorKind",
    "ErrorMessage",
    "Event",
    "FirmwareInfo",
    "HostAction",
    "Ok",
    "OverlongLine",
    "PrinterLocked",
    "ResendRequest",
    "Start",
    "TargetTemperature",
    "TemperatureReport",
    "UnknownCommand",
    "UnrecognisedLine",
]


@dataclass(frozen=True, slots=True)
class Ok:
    """`ok`: the oldest command still waiting has finished.

    With ADVANCED_OK the printer adds `N<line>` (only for numbered commands), `P<free planner blocks>` and
    `B<free command buffer slots>`. `payload` is whatever follows (for M105, the temperatures, also parsed into
    `temperatures`).
    """

    line_number: int | None = None
    planner_free: int | None = None
    buffer_free: int | None = None
    payload: str = ""
    temperatures: Temperatures | None = None


@dataclass(frozen=True, slots=True)
class TemperatureReport:
    """A temperature line that is not an ok: an auto-report (M155) or an M109/M190 wait line.

    Marlin ends wait lines with `W:`; some firmwares print them as plain reports, which look like auto-reports.
    """

    temperatures: Temperatures


@dataclass(frozen=True, slots=True)
class TargetTemperature:
    """A Repetier-style target line (`TargetExtr0:200`, `TargetBed:60`, `TargetChamber:45`): a heater's new target.

    `heater` uses the report letters: "T0", "T1", ... for `TargetExtrN`, "B" for the bed, "C" for the chamber.
    """

    heater: str
    celsius: float


@dataclass(frozen=True, slots=True)
class BusyKeepalive:
    """`echo:busy: processing` (or `paused for user` / `paused for input`; some firmwares drop the `echo:`).

    A long command is still running.
    """

    reason: str


@dataclass(frozen=True, slots=True)
class ResendRequest:
    """`Resend: N` or `rs N`: the printer wants every line from `line_number` on again."""

    line_number: int


class ErrorKind(Enum):
    """What an `Error:` line is about."""

    LINE = "line"  # a line number or checksum problem; a resend request follows
    # The firmware takes only numbered lines with a checksum: the unnumbered command was thrown away, and neither a
    # resend request nor an ok follows.
    CHECKSUM_REQUIRED = "checksum_required"
    THERMAL = "thermal"  # thermal protection tripped; the printer halts
    HALTED = "halted"  # the printer halted (kill()): only a reset brings it back
    STOPPED = "stopped"  # the printer stopped (stop(): "Printer stopped due to errors"): M999 resumes it
    # A `!!` line that is not a halt (`!! Lost communication with MCU 'mcu'` from a host-side bridge): the command
    # that the next ok answers was not run.
    NOT_EXECUTED = "not_executed"
    OTHER = "other"


@dataclass(frozen=True, slots=True)
class ErrorMessage:
    """An `Error:` or `!!` line; `message` is the text after the prefix."""

    message: str
    kind: ErrorKind


@dataclass(frozen=True, slots=True)
class EchoMessage:
    """An `echo:` line no other event stands for; `message` is the text after the prefix."""

    message: str


@dataclass(frozen=True, slots=True)
class UnknownCommand:
    """`echo:Unknown command: "G999"`: the firmware does not know the command; its ok still follows.

    `command` is the quoted text without the quotes.
    """

    command: str


@dataclass(frozen=True, slots=True)
class PrinterLocked:
    """`echo:Printer locked! (Unlock with M511 or LCD)` (PASSWORD_FEATURE): the command was not run; an ok follows.

    `message` is the text after `echo:`. `M511 P<password>` unlocks the printer.
    """

    message: str


@dataclass(frozen=True, slots=True)
class Start:
    """`start`: the board has (re)booted; everything that was in flight is gone."""


@dataclass(frozen=True, slots=True)
class FirmwareInfo:
    """The M115 `FIRMWARE_NAME:` line, split into its `KEY:value` fields."""

    name: str
    fields: dict[str, str]


@dataclass(frozen=True, slots=True)
class Capability:
    """One M115 `Cap:NAME:0|1` line."""

    name: str
    enabled: bool


@dataclass(frozen=True, slots=True)
class HostAction:
    """A `//action:` line (pause, resume, cancel, prompt_...); `action` is the first word, `argument` the rest."""

    action: str
    argument: str


@dataclass(frozen=True, slots=True)
class OverlongLine:
    """A line longer than the cap; only its beginning is kept, the rest was discarded unread."""

    head: str
    length: int


@dataclass(frozen=True, slots=True)
class UnrecognisedLine:
    """Any other line (M114 positions, M119 endstops, banner lines, noise), with its text."""

    text: str


Event = (
    Ok
    | TemperatureReport
    | TargetTemperature
    | BusyKeepalive
    | ResendRequest
    | ErrorMessage
    | EchoMessage
    | UnknownCommand
    | PrinterLocked
    | Start
    | FirmwareInfo
    | Capability
    | HostAction
    | OverlongLine
    | UnrecognisedLine
)
"""Everything `classify_line` can return."""
