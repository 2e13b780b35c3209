"""The simulated board's serial input: the receive buffer, the emergency parser and queue.cpp's line checks.

`LineReader` holds what Marlin 2.1 keeps between the UART and the command ring (`gcode/queue.cpp`,
`feature/e_parser.h`); the printer (`_printer.SimulatedPrinter`) owns the ring and decides when lines may move.

- Bytes land in the serial receive buffer (`rx_buffer_size`); what does not fit is dropped, and the printer
  counts it. Whole lines move from there into the command ring (`command_buffer_size` slots, the running command
  included) whenever a slot is free, also while a long command blocks: Marlin's `idle()` calls
  `manage_inactivity()`, which calls `queue.get_available_commands()`. The captures show it too: the `ok` ending
  an M109 that had commands sent behind it reads `B0`, not `B3`. So line-number and checksum errors are answered
  (`Resend:` and `ok`) even while G28 or M109 runs.
- The emergency parser sees bytes as they arrive, before the receive buffer, so M108/M112/M410 act even when the
  buffer is full; the line itself is still queued and later answered with an `ok` (Marlin's no-op case).
- Line-number protection as in 2.1.2: a numbered line is run only when it is the next number, so a line is run
  once however often the host sends it. A repeat of the last line (the host retransmitted because an `ok` went
  missing) gets the line-number error and a `Resend:` of the next line; with `ignore_duplicate_lines` the two
  numbers below the next one are dropped without a word instead, as newer `queue.cpp` sources do.
- `Faults.corrupt_rx_ratio` draws from a random stream of its own (derived from the seed), so which lines are
  hit does not depend on how the host's bytes happened to be split into reads.

This is the per-byte and per-line path the benchmarks measure: each method works on whole chunks and lines,
never byte by byte in Python.
"""

from __future__ import annotations

import random
import re
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from marlin_aio.commands import checksum
from marlin_aio.simulator._config import Faults, SimulatorConfig

__all__ = ["Command", "LineReader", "parse_parameters"]

_MAX_COMMAND_CHARS = 95  # MAX_CMD_SIZE 96 including the NUL
_EOL = re.compile(rb"[\r\n]")
_LINE_NUMBER_PREFIX = re.compile(r"N-?\d+ *")
_COMMAND_WORD = re.compile(r"([GMT])(\d+)(?:\.\d+)? *")
_PARAMETER = re.compile(r"([A-Z]) *([-+]?(?:\d+\.?\d*|\.\d+))?")
_LEADING_INT = re.compile(r" *([-+]?\d+)")
# What Marlin's emergency parser (feature/e_parser.h) recognises at the start of a line.
_EMERGENCY_LINE = re.compile(rb" *(?:N[-0-9 ]*)?M *(108|112|410)")
_EMERGENCY_HINT = re.compile(rb"1[01][028]|410")
_EMERGENCY_TAIL_MAX = 64


@dataclass(slots=True)
class Command:
    """One line taken into the command ring, checked and stripped."""

    text: str  # as executed: no line number, checksum or comment
    code: str  # "G1", "M105", ... or "" when it is not a G/M/T command
    args: str  # the text after the command word
    line_label: str | None  # "N5" when the line was numbered (ADVANCED_OK echoes it)
    line_number: int | None  # 5 for that line


def parse_parameters(args: str) -> dict[str, float | None]:
    """A command's parameter words by letter: `X10 E` gives `{"X": 10.0, "E": None}`."""
    return {letter: float(value) if value else None for letter, value in _PARAMETER.findall(args)}


def _leading_int(text: str, start: int) -> int:
    match = _LEADING_INT.match(text, start)
    return int(match.group(1)) if match else 0


class LineReader:
    """The receive buffer and the line being read, checked line by line into `Command`s as queue.cpp does.

    Error replies (`Error:...`, `Resend:`, the `ok` after them) go out through `emit`, the printer's output.
    """

    def __init__(self, config: SimulatorConfig, emit: Callable[[str], None]) -> None:
        """A reader at power-on for a board built as `config`, printing its error replies with `emit`."""
        self._config = config
        self._emit = emit
        self._corrupt_rng = random.Random(f"{config.seed}:corrupt-rx")
        self.rx = bytearray()
        """The serial receive buffer; the printer appends to it, at most `rx_buffer_size` bytes in all."""
        self._partial_line = bytearray()
        self._emergency_tail = b""
        self.last_line_number = 0
        """The line counter: the number of the last numbered line taken (M110 sets it)."""

    def reset(self) -> None:
        """Power-on state: buffers empty, line counter 0. The fault stream carries on."""
        self.rx.clear()
        self._partial_line.clear()
        self._emergency_tail = b""
        self.last_line_number = 0

    def clear(self) -> None:
        """Throw away the receive buffer and the line being read (kill(), or a line error)."""
        self.rx.clear()
        self._partial_line.clear()

    def store(self, data: bytes) -> int:
        """Keep what fits of `data` in the receive buffer and nothing more; return how many bytes were dropped.

        This is all a stalled board does with its input: it reads no lines out of the buffer.
        """
        room = self._config.rx_buffer_size - len(self.rx)
        if room > 0:
            self.rx += data[:room]
        return max(len(data) - max(room, 0), 0)

    def emergency_codes(self, data: bytes) -> Sequence[bytes]:
        """What the emergency parser finds in `data` as it arrives: `b"108"`, `b"112"` or `b"410"` for each line
        that `data` completes starting with such a command, in order (e_parser.h)."""
        buffer = self._emergency_tail + data
        end = max(buffer.rfind(b"\n"), buffer.rfind(b"\r"))
        if end < 0:
            # A line this long cannot be an emergency command; remember only that it is not a line start.
            self._emergency_tail = buffer if len(buffer) <= _EMERGENCY_TAIL_MAX else b"#"
            return ()
        tail = buffer[end + 1 :]
        self._emergency_tail = tail if len(tail) <= _EMERGENCY_TAIL_MAX else b"#"
        complete = buffer[:end]
        if _EMERGENCY_HINT.search(complete) is None:
            return ()  # the common case: no candidate at all, no per-line work
        return [match.group(1) for line in complete.splitlines() if (match := _EMERGENCY_LINE.match(line))]

    def take_lines(self, ring: deque[Command], faults: Faults) -> None:
        """Move whole lines from the receive buffer into the command `ring` while it has a free slot."""
        slots = self._config.command_buffer_size
        rx = self.rx
        while rx and len(ring) < slots:
            match = _EOL.search(rx)
            if match is None:
                # Marlin keeps reading characters into its line buffer; beyond MAX_CMD_SIZE they are ignored.
                room = _MAX_COMMAND_CHARS - len(self._partial_line)
                if room > 0:
                    self._partial_line += rx[:room]
                rx.clear()
                return
            end = match.start()
            line = bytes(self._partial_line + rx[:end]) if self._partial_line else bytes(rx[:end])
            self._partial_line.clear()
            del rx[: end + 1]
            command = self._check_line(line[:_MAX_COMMAND_CHARS], faults)
            if command is not None:
                ring.append(command)

    def _check_line(self, raw: bytes, faults: Faults) -> Command | None:
        """Check one received line as queue.cpp does: the command to queue, or None (and any error reply)."""
        text = raw.decode("latin-1")
        cut = text.find(";")
        if cut >= 0:
            text = text[:cut]
        text = text.strip()
        if not text:
            return None
        ratio = faults.corrupt_rx_ratio
        if ratio > 0.0 and self._corrupt_rng.random() < ratio:
            text = self._corrupt(text)
        line_label = None
        line_number = None
        if text[0] != "N" and self._config.checksum_required:
            # Thrown away as it is read, like a line error, but with neither a resend request nor an ok.
            self._emit("Error: Missing checksum")
            return None
        if text[0] == "N":
            is_m110 = "M110" in text
            number_at = 0
            if is_m110:
                second_n = text.find("N", 4)
                if second_n >= 0:
                    number_at = second_n
            number = _leading_int(text, number_at + 1)
            if number != self.last_line_number + 1 and not is_m110:
                if self._config.ignore_duplicate_lines and 0 <= self.last_line_number - number <= 1:
                    return None  # "A request-for-resend line was already in transit so we got two"
                self._line_error("Line Number is not Last Line Number+1, Last Line: ")
                return None
            star = text.rfind("*")
            if star < 0:
                self._line_error("No Checksum with line number, Last Line: ")
                return None
            if _leading_int(text, star + 1) != checksum(text[:star].encode("latin-1")):
                self._line_error("checksum mismatch, Last Line: ")
                return None
            self.last_line_number = number
            line_number = _leading_int(text, 1)
            line_label = "N" + str(line_number)
        star = text.find("*")
        body = text if star < 0 else text[:star].rstrip()
        prefix = _LINE_NUMBER_PREFIX.match(body)
        if prefix is not None:
            body = body[prefix.end() :]
        word = _COMMAND_WORD.match(body)
        if word is None:
            return Command(body, "", "", line_label, line_number)
        code = word.group(1) + str(int(word.group(2)))
        command = Command(body, code, body[word.end() :], line_label, line_number)
        if command.code == "M110" and line_label is None:
            # Applied on reading, like the numbered form, so lines sent right behind it already match.
            new_number = parse_parameters(command.args).get("N")
            if new_number is not None:
                self.last_line_number = int(new_number)
        return command

    def _corrupt(self, text: str) -> str:
        # Never the leading N: a line that loses it is run unchecked, which no host can guard against.
        first = 1 if text[0] == "N" and len(text) > 1 else 0
        at = self._corrupt_rng.randrange(first, len(text))
        replacement = chr(self._corrupt_rng.randrange(0x21, 0x7E))
        if replacement in (text[at], ";"):
            replacement = "~"
        return text[:at] + replacement + text[at + 1 :]

    def _line_error(self, message: str) -> None:
        """gcode_line_error(): report, throw away the receive buffer, ask for the line again."""
        self._emit(f"Error:{message}{self.last_line_number}")
        self.clear()
        self._emit(f"Resend: {self.last_line_number + 1}")
        self._emit("ok")
