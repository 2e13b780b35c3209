"""Turning G-code text into the bytes Marlin expects: validation, comments, line numbers, checksums.

Pure functions, no I/O. Everything that can be wrong with a command is found here and raised as `ValueError`
before a byte reaches the port, so a caller's mistake never turns into a half-written line on the printer.
"""

from __future__ import annotations

import functools

from marlin_aio.protocol.gcode import command_code
from marlin_aio.protocol.secrets import redact

__all__ = [
    "DEFAULT_MAX_BED_CELSIUS",
    "DEFAULT_MAX_CHAMBER_CELSIUS",
    "DEFAULT_MAX_HOTEND_CELSIUS",
    "MAX_COMMAND_BYTES",
    "NUMBERING_BYTES",
    "check_numbered_length",
    "check_target",
    "checksum",
    "command_code",
    "encode_command",
    "format_celsius",
    "number_command",
    "strip_comment",
    "validate_command",
]

#: Marlin's `MAX_CMD_SIZE` is 96 bytes including the terminating NUL, so 95 bytes of text fit.
MAX_COMMAND_BYTES = 95

#: What numbering adds to a command checked before it is queued (`N<number> ` and `*<checksum>`): room for line
#: numbers of up to seven digits, past what a print of millions of lines reaches.
NUMBERING_BYTES = len("N9999999 *255")


def check_numbered_length(command: str) -> None:
    """Refuse a command that would not fit Marlin's buffer once numbered and checksummed (`NUMBERING_BYTES`).

    Raises:
        ValueError: it is too long; the message says why.
    """
    if len(command) + NUMBERING_BYTES > MAX_COMMAND_BYTES:
        raise ValueError(
            f"command is too long: {redact(command)[:40]!r}... with a line number and checksum it would exceed "
            f"Marlin's {MAX_COMMAND_BYTES}-byte limit (at most {MAX_COMMAND_BYTES - NUMBERING_BYTES} characters)"
        )


def checksum(data: bytes) -> int:
    """Return Marlin's checksum of `data`: the XOR of every byte (the bytes before the `*`)."""
    value = 0
    for byte in data:
        value ^= byte
    return value


def strip_comment(text: str) -> str:
    """Return `text` without its `;` comment and surrounding white space.

    Marlin treats everything after `;` as a comment, including a `*checksum` placed after it, so comments must go
    before a line is numbered.
    """
    cut = text.find(";")
    if cut >= 0:
        text = text[:cut]
    return text.strip()


@functools.lru_cache(maxsize=256)
def validate_command(text: str) -> str:
    """Return the command as it will be sent (comment and surrounding space removed), or raise.

    (Cached, as `gcode.command_code` is: the same few commands come back many times a second. A command that raises is
    not cached, so it raises every time.)

    Raises:
        ValueError: a line break, NUL, non-ASCII or `*` in it, or nothing left once the comment is removed.
    """
    if "\n" in text or "\r" in text:
        raise ValueError(f"command contains a line break: {redact(text)!r}; send one command per call")
    if not text.isascii():
        raise ValueError(f"command contains non-ASCII characters: {redact(text)!r}")
    if "\x00" in text:
        raise ValueError(f"command contains a NUL byte: {redact(text)!r}")
    command = strip_comment(text)
    if not command:
        raise ValueError(f"command is empty (after removing comments): {redact(text)!r}")
    if "*" in command:
        # Marlin reads the first `*` as the start of the checksum: the line could never be accepted.
        raise ValueError(f"command contains '*', which Marlin reserves for the checksum: {redact(text)!r}")
    return command


def number_command(command: str, line_number: int) -> str:
    """Return `N<line_number> <command>*<checksum>`: Marlin's reliable form of a command.

    Raises:
        ValueError: if `line_number` is negative.
    """
    if line_number < 0:
        raise ValueError(f"line number must not be negative, got {line_number}")
    prefix = f"N{line_number} "
    # XOR is associative: the command's part is computed once per distinct command (the poller's M105 repeats).
    return f"{prefix}{command}*{checksum(prefix.encode('ascii')) ^ _command_checksum(command)}"


@functools.lru_cache(maxsize=256)
def _command_checksum(command: str) -> int:
    return checksum(command.encode("ascii"))


def encode_command(text: str, line_number: int | None = None) -> bytes:
    """Validate a command and return the exact bytes to write, newline included.

    Comments are stripped; with `line_number` the line is numbered and checksummed.

    Raises:
        ValueError: if the command holds a line break, NUL or a non-ASCII character, is empty once its comment
            is removed, or is longer than Marlin's 95-byte command buffer once numbered.
    """
    command = validate_command(text)
    line = command if line_number is None else number_command(command, line_number)
    if len(line) > MAX_COMMAND_BYTES:
        raise ValueError(
            f"command is {len(line)} bytes, longer than Marlin's {MAX_COMMAND_BYTES}-byte limit: {line[:40]!r}..."
        )
    return line.encode("ascii") + b"\n"


#: Marlin's default clamps: HEATER_0_MAXTEMP 275 - HOTEND_OVERSHOOT 15, BED_MAXTEMP 150 - BED_OVERSHOOT 10.
DEFAULT_MAX_HOTEND_CELSIUS = 260.0
DEFAULT_MAX_BED_CELSIUS = 140.0
DEFAULT_MAX_CHAMBER_CELSIUS = 60.0


def check_target(name: str, celsius: object, max_celsius: float) -> float:
    """Return `celsius` as a float if it is a usable heater target for `name`, else raise.

    Raises:
        ValueError: not a number, NaN or infinite, negative, or above `max_celsius`.
    """
    if isinstance(celsius, bool) or not isinstance(celsius, int | float | str):
        raise ValueError(f"{name} target must be a number of degrees Celsius, got {celsius!r}")
    try:
        value = float(celsius)
    except (ValueError, OverflowError):
        raise ValueError(f"{name} target must be a number of degrees Celsius, got {celsius!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise ValueError(f"{name} target must be a finite number, got {celsius!r}")
    if value < 0:
        raise ValueError(f"{name} target must not be negative, got {value:g} C")
    if value > max_celsius:
        raise ValueError(f"{name} target {value:g} C is above the limit of {max_celsius:g} C")
    return value


def format_celsius(value: float) -> str:
    """Format a target the way G-code wants it: `200`, `60.5` (no exponent, no trailing zeros)."""
    return f"{value:.2f}".rstrip("0").rstrip(".")
