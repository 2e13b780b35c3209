"""marlin_aio: an asyncio client for Marlin 3D-printer firmware, with a simulated printer.

    async with marlin_aio.connect("/dev/ttyUSB0") as printer:
        reading = await printer.temperatures()
        await printer.set_temperatures(hotend=200, bed=60)

The protocol core (`framing`, `parsing`, `temperatures`, `commands`, `connection`, `trace`) does no I/O and
imports neither asyncio nor serial; `client` is the asyncio layer on top; `simulator` is a Marlin look-alike
served on a pseudo-terminal or TCP.
"""

from __future__ import annotations

import logging

from marlin_aio.aio._serial import PortInfo, list_ports
from marlin_aio.aio.printer import BAUD_RATES, DEFAULT_BAUDRATE, Printer, PrintHandle, connect
from marlin_aio.aio.printhandle import COOL_DOWN
from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandNotExecutedError,
    CommandTimeoutError,
    ConnectError,
    ConnectionLostError,
    FileChangedError,
    HandshakeError,
    HandshakeTimeoutError,
    LostReplyError,
    MarlinError,
    PortBusyError,
    PortNotFoundError,
    PortPermissionError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
    PrintStalledError,
    RemoteProtocolError,
    ResendLimitError,
    TemperatureTimeoutError,
    ThermalRunawayError,
)
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
from marlin_aio.protocol.connection import Command, Connection, Reply
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
    ResendRequest,
    Start,
    TemperatureReport,
    UnrecognisedLine,
)
from marlin_aio.protocol.framing import LineSplitter
from marlin_aio.protocol.gcode import GCodeLine, parse_gcode
from marlin_aio.protocol.heaters import HeaterLimits, check_gcode_targets
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
from marlin_aio.protocol.parsing import EventParser, classify_line, parse_endstops, parse_position
from marlin_aio.protocol.printjob import PrintJob, PrintProgress, PrintState
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
from marlin_aio.protocol.trace import Trace, TraceEntry

__version__ = "0.1.0"

__all__ = [
    "BAUD_RATES",
    "COOL_DOWN",
    "DEFAULT_BAUDRATE",
    "DEFAULT_MAX_BED_CELSIUS",
    "DEFAULT_MAX_CHAMBER_CELSIUS",
    "DEFAULT_MAX_HOTEND_CELSIUS",
    "HEATER_NAMES",
    "LONG_COMMANDS",
    "LONG_COMMAND_TIMEOUT_S",
    "MAX_COMMAND_BYTES",
    "MAX_DISTANCE_MM",
    "MAX_FEEDRATE_MM_MIN",
    "BusyKeepalive",
    "Capability",
    "ChecksumRequiredError",
    "Command",
    "CommandNotExecutedError",
    "CommandTimeoutError",
    "ConnectError",
    "Connection",
    "ConnectionLostError",
    "EchoMessage",
    "ErrorKind",
    "ErrorMessage",
    "Event",
    "EventParser",
    "FileChangedError",
    "FirmwareInfo",
    "GCodeLine",
    "HandshakeError",
    "HandshakeTimeoutError",
    "HeaterLimits",
    "HeaterReading",
    "HostAction",
    "LineSplitter",
    "LinkState",
    "LinkStats",
    "LostReplyError",
    "MarlinError",
    "Ok",
    "OverlongLine",
    "PortBusyError",
    "PortInfo",
    "PortNotFoundError",
    "PortPermissionError",
    "PrintHandle",
    "PrintJob",
    "PrintProgress",
    "PrintStalledError",
    "PrintState",
    "Printer",
    "PrinterHaltedError",
    "PrinterLockedError",
    "PrinterResetError",
    "ReadingSource",
    "RemoteProtocolError",
    "Reply",
    "ResendLimitError",
    "ResendRequest",
    "Start",
    "TemperatureReading",
    "TemperatureReport",
    "TemperatureTimeoutError",
    "Temperatures",
    "ThermalRunawayError",
    "Trace",
    "TraceEntry",
    "UnrecognisedLine",
    "__version__",
    "check_gcode_targets",
    "check_target",
    "checksum",
    "classify_line",
    "command_code",
    "command_timeout_s",
    "connect",
    "disable_motors_command",
    "encode_command",
    "extrude_commands",
    "heater_name",
    "home_command",
    "list_ports",
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

# A library logs and lets the application decide where it goes: without a handler of the application's, nothing
# is printed (not even warnings through logging's last-resort handler).
logging.getLogger("marlin_aio").addHandler(logging.NullHandler())
