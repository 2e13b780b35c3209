"""The exception hierarchy: everything marlin_aio raises on purpose derives from `MarlinError`.

Timeouts also derive from `TimeoutError` and lost links from `ConnectionError`, so code that already catches
those built-ins keeps working. Bad arguments raise plain `ValueError` before anything is written to the port.
"""

from __future__ import annotations

__all__ = [
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
    "PrintStalledError",
    "PrinterHaltedError",
    "PrinterLockedError",
    "PrinterResetError",
    "RemoteProtocolError",
    "ResendLimitError",
    "TemperatureTimeoutError",
    "ThermalRunawayError",
]


class MarlinError(Exception):
    """Base class of every error marlin_aio raises about the printer or the link."""


class RemoteProtocolError(MarlinError):
    """The printer sent something the protocol does not allow (the printer's fault, not the caller's)."""


class ConnectError(MarlinError, ConnectionError):
    """The port could not be opened."""


class PortNotFoundError(ConnectError):
    """No device exists at the given path or URL."""


class PortBusyError(ConnectError):
    """Another program holds the port open."""


class PortPermissionError(ConnectError):
    """The operating system refused access to the port (on Linux: add the user to the `dialout` group)."""


class HandshakeError(MarlinError):
    """The port opened but the printer did not complete the start-up sequence.

    `step` names the step that failed: "boot", "sync" or "identify".
    """

    def __init__(self, message: str, *, step: str) -> None:
        super().__init__(message)
        self.step = step


class HandshakeTimeoutError(HandshakeError, TimeoutError):
    """A start-up step got no answer within its timeout."""


class CommandTimeoutError(MarlinError, TimeoutError):
    """A command got no `ok` within its timeout while the printer gave no sign of being busy.

    The message says who waited for whom: the command, how long it waited, and what was last sent and received.
    `command` is the command text.
    """

    def __init__(self, message: str, *, command: str) -> None:
        super().__init__(message)
        self.command = command


class PrintStalledError(CommandTimeoutError):
    """A print got no answer within the timeout while the printer gave no sign of being busy.

    The message names the file line waited for, how long, and which side went silent; `trace` holds the last lines
    sent and received with their times, one per line.
    """

    def __init__(self, message: str, *, command: str, trace: str) -> None:
        super().__init__(message, command=command)
        self.trace = trace


class TemperatureTimeoutError(MarlinError, TimeoutError):
    """Heaters did not reach their targets within the allowed time."""


class ConnectionLostError(MarlinError, ConnectionError):
    """The link to the printer went away (port unplugged, closed, or the TCP peer left)."""


class PrinterResetError(MarlinError):
    """The printer restarted (it printed `start`); every command in flight was lost."""


class PrinterHaltedError(MarlinError):
    """The printer stopped itself (`Error:Printer halted`, M112, a kill) and answers nothing until reset.

    `message` is the printer's own explanation, as it printed it.
    """

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class ThermalRunawayError(PrinterHaltedError):
    """The printer halted because its thermal protection tripped (runaway, heating failed, MAXTEMP, MINTEMP)."""


class ResendLimitError(MarlinError):
    """The printer asked for the same line again and again; the link is too noisy to go on."""


class PrinterLockedError(MarlinError):
    """The printer is locked (Marlin's PASSWORD_FEATURE) and refuses every command until `M511 P<password>`.

    Connect with `password=` (the CLI's `--password`) or unlock it on the printer's screen.
    """


class CommandNotExecutedError(MarlinError):
    """The printer answered a command with `ok` but said it did not run it (`!! Lost communication ...`)."""


class FileChangedError(MarlinError):
    """The G-code file being printed changed on disk under the print (cut short, rewritten or appended to), so the
    rest of it is no longer the file that was checked; the print stopped feeding it.

    `path` is the file; `line` the last line of it handed to the print (0: none was).
    """

    def __init__(self, message: str, *, path: str, line: int) -> None:
        super().__init__(message)
        self.path = path
        self.line = line


class ChecksumRequiredError(MarlinError):
    """The firmware runs only lines with a line number and checksum (`Error: Missing checksum`)."""


class LostReplyError(MarlinError):
    """A command was processed but its reply cannot be proven to be its own (its `ok`, or an earlier one, was
    lost on the line), so it is not handed one.

    `command` is the command as sent.
    """

    def __init__(self, message: str, *, command: str) -> None:
        super().__init__(message)
        self.command = command


class NotSupportedError(MarlinError):
    """This printer's backend cannot serve the member asked for, and says why (a printer of `marlin-temp serve`
    has no wire of its own to trace: the service's is).

    `member` names the `Printer` member (`trace`, `sending_ahead`, ...).
    """

    def __init__(self, member: str, why: str) -> None:
        super().__init__(f"{member}: {why}")
        self.member = member
