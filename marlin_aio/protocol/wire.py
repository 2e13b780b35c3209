"""The wire: the bytes from the printer split into lines, each line read as one event, and the trace of the last
lines both ways.

One part owns the byte stream in both directions, so one ok's bytes are framed, read and recorded here and nowhere
else:

- **framing** (`LineSplitter`): Marlin ends lines with `\\n`; some boards send `\\r\\n`, and noise can hold a lone
  `\\r`. All three end a line, and a chunk may be cut anywhere (even between `\\r` and `\\n`): feeding the same bytes
  in any chunks gives the same lines. Bytes that are not UTF-8, and NUL bytes, become U+FFFD so nothing downstream
  ever has to deal with a decode error.
- **events** (`classify_line`, `EventParser`): `classify_line` is total: every string gives exactly one event,
  never an exception, so garbage on the wire is reported as `UnrecognisedLine` and never stops the client.
- **the trace** (`Trace`): a ring buffer of the last lines sent and received, for saying who was waiting for whom
  when a link stalls. Lines are kept as they went over the wire and redacted (`secrets.redact`) whenever they
  leave the trace (`entries`, `format`, `last_sent`, the tap): the trace ends up in error messages and logs, and an
  `M511 P<password>` line must not carry the password there. Redacting on the way out, not on the way in, keeps
  the two lines of every poll free of that work.

Over 400 lines because the three are one part: the bytes of a line are framed, read and recorded in one pass
(`EventParser.receive_data`, `Trace.received`), and the fast lane of a poll's answer (`EventParser.one_line`)
must agree with the framing it skips.
"""

from __future__ import annotations

import logging
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

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
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.temperatures import Temperatures, looks_like_temperatures, parse_temperatures

__all__ = [
    "BARE_LINE_END",
    "DEFAULT_MAX_LINE_BYTES",
    "EventParser",
    "LineSplitter",
    "Tap",
    "Trace",
    "TraceEntry",
    "classify_line",
    "is_noise",
]

# ------------------------------------------------------------------------------------------------------ framing

#: Marlin's longest lines (M115, M503 settings) are a few hundred bytes; 4 KiB leaves room and bounds memory.
DEFAULT_MAX_LINE_BYTES = 4096


def _decode(raw: bytes) -> str:
    text = raw.decode("utf-8", errors="replace")
    return text.replace("\x00", "\ufffd") if "\x00" in text else text


class LineSplitter:
    """Turn chunks of bytes into complete lines (without their line ending). Empty lines are skipped.

    A line longer than `max_line_bytes` is not kept whole: it yields one `OverlongLine` holding its first
    `max_line_bytes` bytes, and the rest of it is discarded as it arrives.
    """

    __slots__ = ("_buffer", "_discarding", "_max", "_overlong_head", "_skip_lf")

    def __init__(self, max_line_bytes: int = DEFAULT_MAX_LINE_BYTES) -> None:
        if max_line_bytes < 1:
            raise ValueError(f"max_line_bytes must be at least 1, got {max_line_bytes}")
        self._max = max_line_bytes
        self._buffer = b""
        self._skip_lf = False  # the last chunk ended in \r: a \n starting the next one belongs to it
        self._discarding = 0  # >0 while skipping the rest of an overlong line: bytes seen so far
        self._overlong_head = b""

    def feed(self, data: bytes) -> list[str | OverlongLine]:
        """Add bytes; return the lines they complete, in order."""
        if self._skip_lf:
            self._skip_lf = False
            if data[:1] == b"\n":
                data = data[1:]
        if not data:
            return []
        if b"\r" in data:
            self._skip_lf = data.endswith(b"\r")
            data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        buffer = self._buffer + data if self._buffer else data
        parts = buffer.split(b"\n")
        tail = parts.pop()
        out: list[str | OverlongLine] = []
        for raw in parts:
            if self._discarding:
                out.append(self._finish_overlong(len(raw)))
            elif len(raw) > self._max:
                out.append(OverlongLine(head=_decode(raw[: self._max]), length=len(raw)))
            elif raw:
                out.append(_decode(raw))
        if self._discarding:
            self._discarding += len(tail)
            tail = b""
        elif len(tail) > self._max:
            # Keep only the head; count the rest without storing it.
            self._discarding = len(tail)
            self._overlong_head = tail[: self._max]
            tail = b""
        self._buffer = tail
        return out

    def _finish_overlong(self, extra: int) -> OverlongLine:
        line = OverlongLine(head=_decode(self._overlong_head), length=self._discarding + extra)
        self._discarding = 0
        self._overlong_head = b""
        return line

    def clear(self) -> None:
        """Forget any unfinished line (after the input was flushed, its rest will never come)."""
        self._buffer = b""
        self._skip_lf = False
        self._discarding = 0
        self._overlong_head = b""

    @property
    def idle(self) -> bool:
        """True between lines: nothing of an unfinished line is held, skipped or discarded."""
        return not self._buffer and not self._skip_lf and not self._discarding

    @property
    def max_line_bytes(self) -> int:
        """The longest line kept whole."""
        return self._max

    @property
    def pending_bytes(self) -> int:
        """How many bytes of an unfinished line are held (for diagnostics)."""
        return len(self._buffer)


# ------------------------------------------------------------------------------------------------------ events

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
    """Bytes in, events out: a `LineSplitter` followed by `classify_line`; it counts the bytes it was fed and the
    lines that are noise from the link (overlong, or holding bytes no firmware prints: `is_noise`)."""

    __slots__ = ("_splitter", "bytes_received", "garbage_lines")

    def __init__(self, max_line_bytes: int = DEFAULT_MAX_LINE_BYTES) -> None:
        self._splitter = LineSplitter(max_line_bytes)
        self.bytes_received = 0
        self.garbage_lines = 0

    def count_bytes(self, size: int) -> None:
        """`size` bytes arrived that were read without `receive_data` (the fast lane, `one_line`)."""
        self.bytes_received += size

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
        self.bytes_received += len(data)
        out: list[tuple[str, Event]] = []
        for line in self._splitter.feed(data):
            if isinstance(line, OverlongLine):
                self.garbage_lines += 1
                out.append((line.head, line))
            else:
                event = classify_line(line)
                if type(event) is UnrecognisedLine and is_noise(line):
                    self.garbage_lines += 1
                out.append((line, event))
        return out


def is_noise(text: str) -> bool:
    """True for a line no firmware prints: Marlin writes ASCII only, so anything else is noise from the link."""
    return not text.isascii() or any(ch < " " or ch == "\x7f" for ch in text)


# ------------------------------------------------------------------------------------------------------ the trace

#: How a bare line end (written to complete a line whose own end was damaged) reads in the trace.
BARE_LINE_END = "(a bare line end)"

#: Every line on the wire, at DEBUG (`logging.getLogger("marlin_aio.wire").setLevel(logging.DEBUG)` to see them).
_wire_log = logging.getLogger("marlin_aio.wire")


@dataclass(frozen=True, slots=True)
class TraceEntry:
    """One line on the wire: `direction` is "sent" or "received"; `time_s` is on the connection's clock."""

    time_s: float
    direction: Literal["sent", "received"]
    text: str


_Line = tuple[float, Literal["sent", "received"], str]

#: What `Trace.tap` is called with: each line's time (the connection's clock), its direction and its redacted text.
Tap = Callable[[float, Literal["sent", "received"], str], None]


class Trace:
    """The last `size` lines sent and received, oldest first, plus when each direction last saw traffic.

    Lines are kept as plain tuples and turned into `TraceEntry` values only when read: two lines are recorded for
    every poll, a hundred times a second, and read only when something went wrong.

    Attributes:
        tap: called with every line as it is recorded (a wire log: `marlin_aio.aio.WireLog`), or None. It runs
            inside the link's read handler, so it must not raise.
    """

    __slots__ = ("_entries", "_last_received", "_last_sent", "tap")

    def __init__(self, size: int = 64) -> None:
        self._entries: deque[_Line] = deque(maxlen=size)
        self._last_sent: _Line | None = None
        self._last_received: _Line | None = None
        self.tap: Tap | None = None

    def sent(self, time_s: float, text: str) -> None:
        """Record a line written to the printer (redacted when read: see the module's docstring)."""
        entry: _Line = (time_s, "sent", text)
        self._entries.append(entry)
        self._last_sent = entry
        self._tell(entry, ">>")

    def received(self, time_s: float, text: str) -> None:
        """Record a line read from the printer (redacted when read: firmware without PASSWORD_FEATURE echoes an
        M511 back in its `Unknown command`)."""
        entry: _Line = (time_s, "received", text)
        self._entries.append(entry)
        self._last_received = entry
        self._tell(entry, "<<")

    def _tell(self, entry: _Line, arrow: str) -> None:
        time_s, direction, text = entry
        if self.tap is not None:
            self.tap(time_s, direction, redact(text))
        if _wire_log.isEnabledFor(logging.DEBUG):
            _wire_log.debug("%s %s", arrow, redact(text))

    @property
    def last_sent(self) -> TraceEntry | None:
        """The last line written, or None."""
        return None if self._last_sent is None else _entry(self._last_sent)

    @property
    def last_received(self) -> TraceEntry | None:
        """The last line read, or None."""
        return None if self._last_received is None else _entry(self._last_received)

    @property
    def last_received_s(self) -> float | None:
        """When the last line was read, or None (the deadlines ask on every check; no entry is built)."""
        return None if self._last_received is None else self._last_received[0]

    def entries(self) -> list[TraceEntry]:
        """The recorded lines, oldest first."""
        return [_entry(entry) for entry in self._entries]

    def format(self, now: float) -> str:
        """The recorded lines as text, one per line, each with its age: `  -0.512 s >> N12 G1 X10*93`."""
        return "\n".join(
            f"{time_s - now:+9.3f} s {'>>' if direction == 'sent' else '<<'} {redact(text)}"
            for time_s, direction, text in self._entries
        )


def _entry(line: _Line) -> TraceEntry:
    time_s, direction, text = line
    return TraceEntry(time_s, direction, redact(text))
