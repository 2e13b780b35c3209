"""The sans-I/O core of marlin_aio: bytes and times in, bytes and results out.

Nothing in this folder opens a port, reads a clock or imports asyncio: `Connection` takes the bytes a driver read
and the time it read them, and gives back the bytes to write and each command's result. The asyncio client
(`marlin_aio.aio`) is one driver of it; the simulator's fault campaign is another.

Exported here, for people who write their own driver and for front ends: the connection and what one step of it
gives (`Connection`, `Output`, `Command`, `Reply`), every event a line can become (the `Event` union and each of its
members), the line splitter and parsers, encoding and checking commands (checksums, line numbers, heater limits,
Marlin's own reading of G-code), the motion helpers, a print job's bookkeeping, the link's state and statistics,
the trace, and `redact` for secrets. An application needs only `marlin_aio`'s own names.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from marlin_aio._lazy import lazy_exports

if TYPE_CHECKING:
    from marlin_aio.protocol.commands import (
        DEFAULT_MAX_BED_CELSIUS,
        DEFAULT_MAX_CHAMBER_CELSIUS,
        DEFAULT_MAX_HOTEND_CELSIUS,
        MAX_COMMAND_BYTES,
        check_target,
        checksum,
        command_code,
        encode_command,
        number_command,
        strip_comment,
        validate_command,
    )
    from marlin_aio.protocol.connection import Command, Connection, Output, Reply
    from marlin_aio.protocol.events import (
        BusyKeepalive,
        Capability,
        EchoMessage,
        ErrorKind,
        ErrorMessage,
        Event,
        FirmwareInfo,
        HostAction,
        Ok,
        OverlongLine,
        PrinterLocked,
        ResendRequest,
        Start,
        TargetTemperature,
        TemperatureReport,
        UnknownCommand,
        UnrecognisedLine,
    )
    from marlin_aio.protocol.gcode import GCodeLine, parse_gcode
    from marlin_aio.protocol.heaters import DEFAULT_LIMITS, HeaterLimits, check_gcode_targets
    from marlin_aio.protocol.hostrequests import HostRequest, HostRequests, Prompt
    from marlin_aio.protocol.linkstate import LinkState
    from marlin_aio.protocol.motion import (
        LONG_COMMAND_TIMEOUT_S,
        LONG_COMMANDS,
        MAX_DISTANCE_MM,
        MAX_FEEDRATE_MM_MIN,
        command_timeout_s,
        disable_motors_command,
        extrude_commands,
        home_command,
        move_commands,
    )
    from marlin_aio.protocol.parsing import parse_endstops, parse_position
    from marlin_aio.protocol.printjob import STOPPED_BY_SERVICE, PrintJob, PrintProgress, PrintState, check_command
    from marlin_aio.protocol.secrets import redact
    from marlin_aio.protocol.stats import LinkStats
    from marlin_aio.protocol.temperatures import (
        HEATER_NAMES,
        HeaterReading,
        ReadingSource,
        TemperatureReading,
        Temperatures,
        heater_name,
        parse_temperatures,
    )
    from marlin_aio.protocol.wire import EventParser, LineSplitter, Trace, TraceEntry, classify_line

#: Where each name lives: imported on its first use (`marlin_aio._lazy`), so `marlin_aio.protocol.heaters`
#: alone does not load the connection, the parsers and the print job.
_EXPORTS: dict[str, tuple[str, ...]] = {
    "marlin_aio.protocol.commands": (
        "DEFAULT_MAX_BED_CELSIUS",
        "DEFAULT_MAX_CHAMBER_CELSIUS",
        "DEFAULT_MAX_HOTEND_CELSIUS",
        "MAX_COMMAND_BYTES",
        "check_target",
        "checksum",
        "command_code",
        "encode_command",
        "number_command",
        "strip_comment",
        "validate_command",
    ),
    "marlin_aio.protocol.connection": (
        "Command",
        "Connection",
        "Output",
        "Reply",
    ),
    "marlin_aio.protocol.events": (
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
    ),
    "marlin_aio.protocol.gcode": (
        "GCodeLine",
        "parse_gcode",
    ),
    "marlin_aio.protocol.heaters": (
        "DEFAULT_LIMITS",
        "HeaterLimits",
        "check_gcode_targets",
    ),
    "marlin_aio.protocol.hostrequests": (
        "HostRequest",
        "HostRequests",
        "Prompt",
    ),
    "marlin_aio.protocol.linkstate": ("LinkState",),
    "marlin_aio.protocol.motion": (
        "LONG_COMMAND_TIMEOUT_S",
        "LONG_COMMANDS",
        "MAX_DISTANCE_MM",
        "MAX_FEEDRATE_MM_MIN",
        "command_timeout_s",
        "disable_motors_command",
        "extrude_commands",
        "home_command",
        "move_commands",
    ),
    "marlin_aio.protocol.parsing": (
        "parse_endstops",
        "parse_position",
    ),
    "marlin_aio.protocol.printjob": (
        "STOPPED_BY_SERVICE",
        "PrintJob",
        "PrintProgress",
        "PrintState",
        "check_command",
    ),
    "marlin_aio.protocol.secrets": ("redact",),
    "marlin_aio.protocol.stats": ("LinkStats",),
    "marlin_aio.protocol.temperatures": (
        "HEATER_NAMES",
        "HeaterReading",
        "ReadingSource",
        "TemperatureReading",
        "Temperatures",
        "heater_name",
        "parse_temperatures",
    ),
    "marlin_aio.protocol.wire": (
        "EventParser",
        "LineSplitter",
        "Trace",
        "TraceEntry",
        "classify_line",
    ),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = [
    "DEFAULT_LIMITS",
    "DEFAULT_MAX_BED_CELSIUS",
    "DEFAULT_MAX_CHAMBER_CELSIUS",
    "DEFAULT_MAX_HOTEND_CELSIUS",
    "HEATER_NAMES",
    "LONG_COMMANDS",
    "LONG_COMMAND_TIMEOUT_S",
    "MAX_COMMAND_BYTES",
    "MAX_DISTANCE_MM",
    "MAX_FEEDRATE_MM_MIN",
    "STOPPED_BY_SERVICE",
    "BusyKeepalive",
    "Capability",
    "Command",
    "Connection",
    "EchoMessage",
    "ErrorKind",
    "ErrorMessage",
    "Event",
    "EventParser",
    "FirmwareInfo",
    "GCodeLine",
    "HeaterLimits",
    "HeaterReading",
    "HostAction",
    "HostRequest",
    "HostRequests",
    "LineSplitter",
    "LinkState",
    "LinkStats",
    "Ok",
    "Output",
    "OverlongLine",
    "PrintJob",
    "PrintProgress",
    "PrintState",
    "PrinterLocked",
    "Prompt",
    "ReadingSource",
    "Reply",
    "ResendRequest",
    "Start",
    "TargetTemperature",
    "TemperatureReading",
    "TemperatureReport",
    "Temperatures",
    "Trace",
    "TraceEntry",
    "UnknownCommand",
    "UnrecognisedLine",
    "check_command",
    "check_gcode_targets",
    "check_target",
    "checksum",
    "classify_line",
    "command_code",
    "command_timeout_s",
    "disable_motors_command",
    "encode_command",
    "extrude_commands",
    "heater_name",
    "home_command",
    "move_commands",
    "number_command",
    "parse_endstops",
    "parse_gcode",
    "parse_position",
    "parse_temperatures",
    "redact",
    "strip_comment",
    "validate_command",
]
