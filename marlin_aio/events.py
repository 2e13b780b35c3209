"""Events: what one line received from Marlin means.

Every complete line the printer sends becomes exactly one of these small frozen objects (see
`marlin_aio.parsing.classify_line`). They carry facts only; what to do about them is the connection's job.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from marlin_aio.temperatures import Temperatures

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
    "ResendRequest",
    "Start",
    "TemperatureReport",
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
    """A temperature line that is not an ok: an auto-report (M155) or an M109/M190 wait line (with `W:`)."""

    temperatures: Temperatures


@dataclass(frozen=True, slots=True)
class BusyKeepalive:
    """`echo:busy: processing` (or `paused for user` / `paused for input`): a long command is still running."""

    reason: str


@dataclass(frozen=True, slots=True)
class ResendRequest:
    """`Resend: N` or `rs N`: the printer wants every line from `line_number` on again."""

    line_number: int


class ErrorKind(Enum):
    """What an `Error:` line is about."""

    LINE = "line"  # a line number or checksum problem; a resend request follows
    THERMAL = "thermal"  # thermal protection tripped; the printer halts
    HALTED = "halted"  # the printer stopped (kill() or stop()) and needs a reset or M999
    OTHER = "other"


@dataclass(frozen=True, slots=True)
class ErrorMessage:
    """An `Error:` line; `message` is the text after the prefix."""

    message: str
    kind: ErrorKind


@dataclass(frozen=True, slots=True)
class EchoMessage:
    """An `echo:` line other than a busy keepalive; `message` is the text after the prefix."""

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
    | BusyKeepalive
    | ResendRequest
    | ErrorMessage
    | EchoMessage
    | Start
    | FirmwareInfo
    | Capability
    | HostAction
    | OverlongLine
    | UnrecognisedLine
)
"""Everything `classify_line` can return."""
