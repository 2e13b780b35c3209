"""Classifying lines from Marlin into events, and parsing the bodies of a few replies (M114, M119).

`classify_line` is total: every string gives exactly one event, never an exception, so garbage on the wire is
reported as `UnrecognisedLine` and never stops the client.
"""

from __future__ import annotations

import re

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
from marlin_aio.protocol.framing import DEFAULT_MAX_LINE_BYTES, LineSplitter
from marlin_aio.protocol.temperatures import Temperatures, looks_like_temperatures, parse_temperatures

__all__ = ["EventParser", "classify_line", "parse_endstops", "parse_position"]

# Digit runs are bounded: int() refuses more than 4300 digits, and classify_line must never raise.
_ADVANCED_OK = re.compile(r"([NPB])(\d{1,12})")
_RESEND = re.compile(r"(?:Resend|rs)[: ]\s*N?(\d{1,12})(?!\d)", re.IGNORECASE)
_FIRMWARE_FIELD = re.compile(r"([A-Z_]+):")
# Repetier-style targets: `TargetExtr0:200`, `TargetBed:60.5`, `TargetChamber:45`.
_TARGET = re.compile(r"Target(?:Extr(\d{1,3})|(Bed)|(Chamber))[ \t]*:[ \t]*(-?\d{1,12}(?:\.\d{0,12})?)")
_THERMAL_WORDS = ("thermal runaway", "thermal malfunction", "heating failed", "maxtemp", "mintemp")
_HALT_WORDS = ("printer halted", "kill() called")
_STOP_WORDS = ("printer stopped due to errors",)


def _classify_ok(text: str) -> Ok:
    rest = text[2:].strip()
    if rest[:2] == "T:":
        # M105's answer (the poller's, a hundred times a second): no ADVANCED_OK fields come before it.
        return Ok(payload=rest, temperatures=Temperatures.from_text(rest))
    numbers: dict[str, int] = {}
    # ADVANCED_OK fields come first as bare tokens (`N12 P15 B3`); the M105 payload starts with `T:`.
    while rest:
        word, _, after = rest.partition(" ")
        match = _ADVANCED_OK.fullmatch(word)
        if match is None or match[1] in numbers:
            break
        numbers[match[1]] = int(match[2])
        rest = after.lstrip()
    # Only M105 answers `ok T:...`; its fields are parsed when someone reads them.
    temperatures = Temperatures.from_text(rest) if looks_like_temperatures(rest) else None
    return Ok(
        line_number=numbers.get("N"),
        planner_free=numbers.get("P"),
        buffer_free=numbers.get("B"),
        payload=rest,
        temperatures=temperatures,
    )


def _error_kind(message: str, bang: bool) -> ErrorKind:
    lowered = message.lower()
    if not bang:
        if "last line" in lowered:
            return ErrorKind.LINE
        # Without `Last Line` no resend follows: a firmware refusing an unnumbered line (`Missing checksum`, or the
        # `No Checksum with line number` variant some print), not a numbered line that arrived damaged.
        if "missing checksum" in lowered or "no checksum" in lowered:
            return ErrorKind.CHECKSUM_REQUIRED
        if "checksum" in lowered or "line number" in lowered:
            return ErrorKind.LINE
    if any(word in lowered for word in _THERMAL_WORDS):
        return ErrorKind.THERMAL
    if any(word in lowered for word in _HALT_WORDS):
        return ErrorKind.HALTED
    if any(word in lowered for word in _STOP_WORDS):
        return ErrorKind.STOPPED
    # A `!!` line that is not a halt comes from a host-side bridge that did not pass the command on.
    return ErrorKind.NOT_EXECUTED if bang else ErrorKind.OTHER


def _classify_target(text: str) -> TargetTemperature | None:
    match = _TARGET.fullmatch(text)
    if match is None:
        return None
    extruder, bed, _chamber, celsius = match.groups()
    # int() normalises `TargetExtr00` to T0, the letter the temperature reports use.
    heater = f"T{int(extruder)}" if extruder is not None else "B" if bed is not None else "C"
    return TargetTemperature(heater=heater, celsius=float(celsius))


def _classify_echo(message: str) -> Event:
    if message.startswith("busy:"):
        return BusyKeepalive(reason=message[5:].strip())
    if message.startswith("Unknown command:"):
        command = message[16:].strip()
        # Marlin quotes the command; strip exactly one pair so quotes inside it survive.
        if len(command) >= 2 and command[0] == command[-1] == '"':
            command = command[1:-1]
        return UnknownCommand(command=command)
    if message.startswith("Printer locked"):
        return PrinterLocked(message=message)
    if message.startswith("Target"):
        target = _classify_target(message)
        if target is not None:
            return target
    return EchoMessage(message=message)


def _classify_firmware(text: str) -> FirmwareInfo:
    # Values contain spaces ("Marlin 2.1.2.4 (Jan  1 2024 12:00:00)"), so split at the KEY: markers instead.
    marks = [m for m in _FIRMWARE_FIELD.finditer(text) if m.start() == 0 or text[m.start() - 1] == " "]
    fields: dict[str, str] = {}
    for index, mark in enumerate(marks):
        end = marks[index + 1].start() if index + 1 < len(marks) else len(text)
        fields[mark[1]] = text[mark.end() : end].strip()
    return FirmwareInfo(name=fields.get("FIRMWARE_NAME", ""), fields=fields)


#: The plain `ok`, by far the most common line: one shared (frozen) event instead of a parse and an object each.
_PLAIN_OK = Ok()


def classify_line(text: str) -> Event:
    """Return the event one line (without its line ending) stands for."""
    if text == "ok":
        return _PLAIN_OK
    stripped = text.strip()
    head = stripped[:2]
    if head == "ok" and (len(stripped) == 2 or stripped[2] == " "):
        return _classify_ok(stripped)
    if stripped.startswith("echo:"):
        return _classify_echo(stripped[5:].strip())
    if stripped.startswith("Error:"):
        message = stripped[6:].strip()
        return ErrorMessage(message=message, kind=_error_kind(message, bang=False))
    if head == "!!":
        message = stripped[2:].strip()
        return ErrorMessage(message=message, kind=_error_kind(message, bang=True))
    if head == "bu" and stripped.startswith("busy:"):
        # Some firmwares print the keepalive without `echo:`.
        return BusyKeepalive(reason=stripped[5:].strip())
    if head == "Ta":
        target = _classify_target(stripped)
        if target is not None:
            return target
    if head in ("Re", "rs"):
        match = _RESEND.match(stripped)
        if match is not None:
            return ResendRequest(line_number=int(match[1]))
    if looks_like_temperatures(text):
        temperatures = parse_temperatures(text)
        if temperatures is not None:
            return TemperatureReport(temperatures=temperatures)
    if stripped == "start":
        return Start()
    if stripped.startswith("FIRMWARE_NAME:"):
        return _classify_firmware(stripped)
    if stripped.startswith("Cap:"):
        name, _, value = stripped[4:].rpartition(":")
        if name and value in ("0", "1"):
            return Capability(name=name, enabled=value == "1")
    if stripped.startswith("//action:"):
        action, _, argument = stripped[9:].strip().partition(" ")
        return HostAction(action=action, argument=argument.strip())
    return UnrecognisedLine(text=text)


class EventParser:
    """Bytes in, events out: a `LineSplitter` followed by `classify_line`."""

    __slots__ = ("_splitter",)

    def __init__(self, max_line_bytes: int = DEFAULT_MAX_LINE_BYTES) -> None:
        self._splitter = LineSplitter(max_line_bytes)

    def clear(self) -> None:
        """Forget any unfinished line."""
        self._splitter.clear()

    def one_line(self, data: bytes) -> str | None:
        """The text of `data` if it is exactly one whole plain line (ASCII, no NUL or carriage return, not too
        long) arriving between lines, which `receive_data` would return as it is; else None (nothing changed)."""
        if (
            not data
            or data.find(b"\n") != len(data) - 1
            or b"\r" in data
            or b"\x00" in data
            or len(data) > self._splitter.max_line_bytes
            or not data.isascii()
            or not self._splitter.idle
        ):
            return None
        return data[:-1].decode("ascii")

    def receive_data(self, data: bytes) -> list[tuple[str, Event]]:
        """Feed bytes; return each completed line's text with its event, in order."""
        out: list[tuple[str, Event]] = []
        for line in self._splitter.feed(data):
            if isinstance(line, OverlongLine):
                out.append((line.head, line))
            else:
                out.append((line, classify_line(line)))
        return out


_ENDSTOP = re.compile(r"^\s*([A-Za-z0-9_ ]+?)\s*:\s*(open|TRIGGERED)\s*$")
_POSITION = re.compile(r"([XYZE]):\s*(-?\d+(?:\.\d+)?)")


def parse_endstops(lines: list[str] | tuple[str, ...]) -> dict[str, bool]:
    """Parse M119's reply lines into {name: triggered}, e.g. {"x_min": False, "z_probe": True}."""
    states: dict[str, bool] = {}
    for line in lines:
        match = _ENDSTOP.match(line)
        if match is not None:
            states[match[1]] = match[2] == "TRIGGERED"
    return states


def parse_position(lines: list[str] | tuple[str, ...]) -> dict[str, float] | None:
    """Parse an M114 line (`X:10.00 Y:20.00 Z:5.00 E:0.00 Count X:800 ...`) into {"X": 10.0, ...}.

    Only the part before `Count` is used: those are millimetres, what follows are stepper counts.
    """
    for line in lines:
        position_part = line.split("Count", 1)[0]
        found = {axis: float(value) for axis, value in _POSITION.findall(position_part)}
        if "X" in found and "Y" in found:
            return found
    return None
