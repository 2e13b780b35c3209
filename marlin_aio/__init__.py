"""marlin_aio: an asyncio client for Marlin 3D-printer firmware, with a simulated printer.

    async with marlin_aio.connect("/dev/ttyUSB0") as printer:
        reading = await printer.temperatures()
        await printer.set_temperatures(hotend=200, bed=60)

This package's names are what an application needs: the `Printer` and `connect`, prints in progress, the
readings, results and link events it gives, the heater limits, the ports, and every error (all rooted at
`MarlinError`). Two more faces, for other readers:

- `marlin_aio.protocol`, the sans-I/O core, for people who write their own driver or front end: the `Connection`,
  every event a line can become, framing, parsing, encoding and checking commands, print jobs and the trace. It
  does no I/O and imports neither asyncio nor serial.
- `marlin_aio.aio`, the asyncio layer the `Printer` lives in, exports the helpers that read, check and watch
  G-code files for tools that stream files their own way.

`marlin_aio.simulator` is a Marlin look-alike served on a pseudo-terminal or TCP.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from marlin_aio._lazy import lazy_exports

if TYPE_CHECKING:
    from marlin_aio.aio._serial import PortInfo, list_ports
    from marlin_aio.aio.printer import BAUD_RATES, DEFAULT_BAUDRATE, LinkEvent, Printer, PrintHandle, connect
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
        NotSupportedError,
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
    from marlin_aio.protocol import (
        DEFAULT_MAX_BED_CELSIUS,
        DEFAULT_MAX_CHAMBER_CELSIUS,
        DEFAULT_MAX_HOTEND_CELSIUS,
        HeaterLimits,
        HeaterReading,
        HostRequest,
        LinkState,
        LinkStats,
        PrintProgress,
        PrintState,
        Reply,
        TemperatureReading,
        Temperatures,
        redact,
    )

#: Where each name of the package lives: imported on its first use (`marlin_aio._lazy`), so a program pays only for
#: what it uses (the CLI's `--help` never loads the client).
_EXPORTS: dict[str, tuple[str, ...]] = {
    "marlin_aio.aio._serial": (
        "PortInfo",
        "list_ports",
    ),
    "marlin_aio.aio.printer": (
        "BAUD_RATES",
        "DEFAULT_BAUDRATE",
        "LinkEvent",
        "Printer",
        "PrintHandle",
        "connect",
    ),
    "marlin_aio.aio.printhandle": ("COOL_DOWN",),
    "marlin_aio.errors": (
        "ChecksumRequiredError",
        "CommandNotExecutedError",
        "CommandTimeoutError",
        "ConnectError",
        "ConnectionLostError",
        "FileChangedError",
        "HandshakeError",
        "HandshakeTimeoutError",
        "LostReplyError",
        "MarlinError",
        "NotSupportedError",
        "PortBusyError",
        "PortNotFoundError",
        "PortPermissionError",
        "PrinterHaltedError",
        "PrinterLockedError",
        "PrinterResetError",
        "PrintStalledError",
        "RemoteProtocolError",
        "ResendLimitError",
        "TemperatureTimeoutError",
        "ThermalRunawayError",
    ),
    "marlin_aio.protocol": (
        "DEFAULT_MAX_BED_CELSIUS",
        "DEFAULT_MAX_CHAMBER_CELSIUS",
        "DEFAULT_MAX_HOTEND_CELSIUS",
        "HeaterLimits",
        "HeaterReading",
        "HostRequest",
        "LinkState",
        "LinkStats",
        "PrintProgress",
        "PrintState",
        "Reply",
        "TemperatureReading",
        "Temperatures",
        "redact",
    ),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__version__ = "0.1.0"

__all__ = [
    "BAUD_RATES",
    "COOL_DOWN",
    "DEFAULT_BAUDRATE",
    "DEFAULT_MAX_BED_CELSIUS",
    "DEFAULT_MAX_CHAMBER_CELSIUS",
    "DEFAULT_MAX_HOTEND_CELSIUS",
    "ChecksumRequiredError",
    "CommandNotExecutedError",
    "CommandTimeoutError",
    "ConnectError",
    "ConnectionLostError",
    "FileChangedError",
    "HandshakeError",
    "HandshakeTimeoutError",
    "HeaterLimits",
    "HeaterReading",
    "HostRequest",
    "LinkEvent",
    "LinkState",
    "LinkStats",
    "LostReplyError",
    "MarlinError",
    "NotSupportedError",
    "PortBusyError",
    "PortInfo",
    "PortNotFoundError",
    "PortPermissionError",
    "PrintHandle",
    "PrintProgress",
    "PrintStalledError",
    "PrintState",
    "Printer",
    "PrinterHaltedError",
    "PrinterLockedError",
    "PrinterResetError",
    "RemoteProtocolError",
    "Reply",
    "ResendLimitError",
    "TemperatureReading",
    "TemperatureTimeoutError",
    "Temperatures",
    "ThermalRunawayError",
    "__version__",
    "connect",
    "list_ports",
    "redact",
]

# A library logs and lets the application decide where it goes: without a handler of the application's, nothing
# is printed (not even warnings through logging's last-resort handler).
logging.getLogger("marlin_aio").addHandler(logging.NullHandler())
