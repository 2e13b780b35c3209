"""The simulated board's serial input: the wire's bit flips, the receive buffer, the emergency parser, and
`queue.cpp`'s and `parser.cpp`'s reading of each line (Marlin bugfix-2.1.x).

`WireFlips` is the cable: the faults that flip bits of the host's bytes before the board sees them. `LineReader`
holds what Marlin keeps between the UART and the command ring (`gcode/queue.cpp`, `feature/e_parser.h`); the
printer (`_printer.SimulatedPrinter`) owns the ring and decides when lines may move.

- Bytes land in the serial receive buffer (`rx_buffer_size`); what does not fit is dropped, and the printer
  counts it. Lines move from there into the command ring (`command_buffer_size` slots, the running command
  included) whenever a slot is free, also while a long command blocks: Marlin's `idle()` calls
  `manage_inactivity()`, which calls `queue.get_available_commands()`. The captures show it too: the `ok` ending
  an M109 that had commands sent behind it reads `B0`, not `B3`. So line-number and checksum errors are answered
  (`Resend:` and `ok`) even while G28 or M109 runs.
- Each byte goes through `process_stream_char()` as it is read: `;` starts a comment to the end of the line (a
  `*checksum` after it is lost), 0x08 erases the byte before, `\\` makes the next byte plain, and from the 95th
  byte on (MAX_CMD_SIZE - 1) the rest of the line is skipped. `\\n` or `\\r` ends a line; empty lines are
  ignored, but a line of spaces is a command (an unknown one, `""`). A NUL ends the line's text where it stands,
  as it ends a C string.
- `queue.cpp`: after leading spaces, a line is numbered only if its first byte is `N`. A numbered line with
  `M110` anywhere in it takes its number from the `N` after it and skips the sequence check; otherwise `last+1`
  is taken, `last` and `last-1` are dropped without a word ("a request-for-resend line was already in transit";
  `ignore_duplicate_lines`, 2.1.2 answered them with the line error), and anything else is the line-number
  error. Then the checksum (XOR of every byte before the last `*`, against the decimal number after it).
  Every error is `Error:...Last Line: <last>`, `Resend: <last+1>`, `ok`, and the rest of the receive buffer
  thrown away. Anything else, `n15 ...` or a damaged `N` included, is unnumbered: no check, counter unchanged.
- `parser.cpp`: spaces and an `N<digits>` word are skipped (with `case_insensitive`, an `n` too), the text is cut
  at the first `*`, and the command letter must be G, M or T followed by digits; otherwise the command is unknown
  and the echo shows the text as cut (`echo:Unknown command: "?15 G1 X0.1"`).
- M110 sets the counter when it runs (`gcode/host/M110.cpp`), unnumbered or numbered alike; a numbered one set it
  on reading too. Here every line of a burst arrives at the same instant, where on the wire the next line takes
  longer to come in than an idle board needs to run an M110 (and the quick commands before it); so while no
  command is running, the lines behind an M110 are read after it has run, as on the board. An M110 that waits
  behind a running command (G28, M109, a dwell) lets the lines behind it in first, and resets the counter under
  them when its turn comes, as Marlin does.
- The emergency parser sees bytes as they arrive, before the receive buffer, so M108/M112/M410 act even when the
  buffer is full; the line itself is still queued and later answered with an `ok` (Marlin's no-op case).
- `Faults.corrupt_rx_ratio` draws from a random stream of its own (derived from the seed), so which lines are
  hit does not depend on how the host's bytes happened to be split into reads; `WireFlips` likewise.

Not modelled: without the emergency parser, queue.cpp acts on an unnumbered `M108`/`M112`/`M410` as soon as its
line is read; here it waits its turn (see `_gcode`).

This is the per-byte and per-line path the benchmarks measure: each method works on whole chunks and lines; only
a line with a `;`, `\\` or 0x08 in it is walked byte by byte.

Over 400 lines because it follows `queue.cpp` and `parser.cpp` step by step, each quirk next to the code that
copies it and the source it comes from; split, a quirk would sit apart from the reading that depends on it.
"""

from __future__ import annotations

import math
import random
import re
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from marlin_aio.protocol import gcode
from marlin_aio.protocol.gcode import GCodeLine
from marlin_aio.simulator._config import Faults, SimulatorConfig

__all__ = ["Command", "LineReader", "WireFlips"]

_MAX_COMMAND_BYTES = 95  # MAX_CMD_SIZE 96 including the NUL
_EOL = re.compile(rb"[\r\n]")
# process_stream_char()'s input states (PS_NORMAL, PS_EOL, PS_ESC; no quoted strings or paren comments).
_NORMAL, _SKIP, _ESCAPED = 0, 1, 2
_STREAM_SPECIAL = re.compile(rb"[;\\\x08]")
_LONG_MIN, _LONG_MAX = -(2**31), 2**31 - 1  # a long on AVR and 32-bit ARM
_LEADING_LONG = re.compile(rb"[ \t\n\v\f\r]*([-+]?[0-9]+)")  # strtol skips what isspace() says
# What the ADVANCED_OK `ok` echoes of a command that starts with N: the N and every signed digit after it.
_OK_LABEL = re.compile(rb"N[-+0-9]*")
_TO_UPPER = str.maketrans("abcdefghijklmnopqrstuvwxyz", "ABCDEFGHIJKLMNOPQRSTUVWXYZ")
# Commands whose argument is a string, not parameters (parser.cpp hands them the raw text); M511's password is a
# number on Marlin, a word here, so it keeps its case too.
_STRING_ARGUMENT_CODES = gcode.STRING_ARGUMENT_CODES | {"M511"}
# What Marlin's emergency parser (feature/e_parser.h) recognises at the start of a line.
_EMERGENCY_LINE = re.compile(rb" *(?:N[-0-9 ]*)?M *(108|112|410|876 *S *[0-9]+)")
_EMERGENCY_HINT = re.compile(rb"1[01][028]|410|876")
_EMERGENCY_TAIL_MAX = 64


@dataclass(slots=True)
class Command:
    """One line taken into the command ring, checked and parsed."""

    text: str
    """The command as parser.cpp sees it: no leading spaces or line number, cut at the first `*` (and the spaces
    before it); what `echo:Unknown command: "..."` shows."""
    code: str
    """`"G1"`, `"M105"`, `"T0"` (letter uppercased, number without leading zeros), or `""` when the line is not
    a G, M or T command."""
    args: str
    """The text after the command's number; uppercased with `case_insensitive`, except for string arguments."""
    line_label: str | None
    """`"N5"` when the stored line starts with `N` (ADVANCED_OK echoes it in the `ok`)."""
    line_number: int | None
    """5 for a numbered line (its own number, also for an M110 line), None for an unnumbered one."""
    words: GCodeLine
    """The line as parser.cpp reads it (`marlin_aio.protocol.gcode`, the library's own reading): its parameters, with
    Marlin's rules for values (`value_celsius`), are what the handlers act on."""

    def parameters(self) -> dict[str, float | None]:
        """The parameter words by letter, as Marlin's `floatval` reads them (the last of a letter wins): `X10 E`
        gives `{"X": 10.0, "E": None}`."""
        return {letter: None if value is None else gcode.value_float(value) for letter, value in self.words.words}


def _strtol(data: bytes, start: int) -> int:
    """C's `strtol(data + start, nullptr, 10)` for a 32-bit long: white space, a sign, digits; 0 if none."""
    match = _LEADING_LONG.match(data, start)
    if match is None:
        return 0
    value = int(match.group(1))
    return value if _LONG_MIN <= value <= _LONG_MAX else min(max(value, _LONG_MIN), _LONG_MAX)


def _xor(data: bytes) -> int:
    value = 0
    for byte in data:
        value ^= byte
    return value


def _stream_chars(line: bytearray, state: int, chunk: bytes | bytearray) -> int:
    """queue.cpp's `process_stream_char()` over `chunk` (no line end in it): add to `line`, return the new state."""
    if state == _SKIP:
        return state
    if state == _NORMAL and _STREAM_SPECIAL.search(chunk) is None:
        line += chunk[: _MAX_COMMAND_BYTES - len(line)]
        return _SKIP if len(line) >= _MAX_COMMAND_BYTES else _NORMAL
    for byte in chunk:
        if state == _ESCAPED:
            state = _NORMAL  # the escaped byte is kept as it is (a 0x08 still erases: Marlin checks it after)
        elif byte == 0x5C:  # backslash
            state = _ESCAPED
            continue
        elif byte == 0x3B:  # ;
            return _SKIP
        if byte == 0x08:
            if line:
                del line[-1]
        else:
            line.append(byte)
            if len(line) >= _MAX_COMMAND_BYTES:
                return _SKIP
    return state


class WireFlips:
    """Bit flips on the host-to-printer wire (`Faults.flip_bit_ratio` and `Faults.flip_once`).

    Random flips are decided byte by byte in the order the bytes come: the gap to the next flipped byte is drawn
    geometrically from a random stream of its own, so the common case costs one comparison a chunk and which bytes
    are hit does not depend on how the stream was split into chunks.
    """

    def __init__(self, seed: int) -> None:
        """Flips drawn from a stream derived from `seed`."""
        self._rng = random.Random(f"{seed}:flip-bit")
        self._gap_ratio = 0.0  # the ratio `_gap` was drawn for
        self._gap = 0  # bytes still to pass unflipped before the next flipped one
        self._line_start = True  # the last byte passed on (as sent) ended a line
        self._held_sent = bytearray()  # with flip_once: the unfinished line as sent ...
        self._held = bytearray()  # ... and as it will arrive (random flips applied)
        self.count = 0
        """How many bits were flipped so far, random and targeted."""
        self.unseen = 0
        """Lines damaged in a way Marlin's checks cannot see (counted at the line's end, random flips only): two
        or more flips whose masks cancel in the 8-bit XOR before the `*`, or a leading `N` turned into `n` (an
        unnumbered line, run unchecked) with more damage behind it."""
        self._line_sent = bytearray()  # the unfinished line as sent (random flips only)
        self._line_flips: list[tuple[int, int]] = []  # (offset in that line, mask) of its random flips

    def carry(self, data: bytes, faults: Faults) -> bytes:
        """What arrives at the board of `data` as the host sent it, by the `faults` in force now."""
        sent = data
        if faults.flip_bit_ratio != self._gap_ratio:
            self._redraw(faults.flip_bit_ratio)
        if self._gap_ratio > 0.0:
            if self._gap >= len(data):
                self._gap -= len(data)
                self._account(sent, [])
            else:
                data = self._flip_random(data)
        if faults.flip_once or self._held_sent:
            return self._flip_targeted(sent, data, faults)
        if sent:
            self._line_start = sent[-1] in b"\r\n"
        return data

    def _redraw(self, ratio: float) -> None:
        self._gap_ratio = ratio
        if ratio > 0.0:
            self._gap = self._draw_gap()

    def _draw_gap(self) -> int:
        ratio = self._gap_ratio
        if ratio >= 1.0:
            return 0
        # Geometric: the number of unflipped bytes before the next flipped one.
        return int(math.log(1.0 - self._rng.random()) / math.log1p(-ratio))

    def _flip_random(self, data: bytes) -> bytes:
        flipped = bytearray(data)
        at = self._gap
        rng = self._rng
        flips: list[tuple[int, int]] = []
        while at < len(flipped):
            mask = 1 << rng.randrange(8)
            flipped[at] ^= mask
            flips.append((at, mask))
            self.count += 1
            at += 1 + self._draw_gap()
        self._gap = at - len(flipped)
        self._account(data, flips)
        return bytes(flipped)

    def _account(self, sent: bytes, flips: list[tuple[int, int]]) -> None:
        """Follow the lines (as sent) that random flips hit, and count those damaged unseen (`unseen`)."""
        if not flips and not self._line_flips:
            # The common case: keep only the unfinished line as sent, in case a flip hits it later.
            end = max(sent.rfind(b"\n"), sent.rfind(b"\r"))
            if end < 0:
                self._line_sent += sent
            else:
                self._line_sent[:] = sent[end + 1 :]
            return
        start = 0
        index = 0
        while True:
            match = _EOL.search(sent, start)
            end = len(sent) if match is None else match.start()
            base = len(self._line_sent)
            while index < len(flips) and flips[index][0] < end + (match is not None):
                offset, mask = flips[index]
                self._line_flips.append((base + offset - start, mask))
                index += 1
            self._line_sent += sent[start:end]
            if match is None:
                return
            if self._line_flips:
                self._judge(bytes(self._line_sent), self._line_flips)
                self._line_flips = []
            self._line_sent.clear()
            start = match.end()

    def _judge(self, line: bytes, flips: list[tuple[int, int]]) -> None:
        """Count `line` (as sent) in `unseen` if its `flips` leave a numbered line that still passes its checksum,
        or a line made unnumbered by `N` -> `n` (run unchecked) with more damage behind it."""
        if len(flips) < 2 or line[:1] != b"N":
            return
        damaged = bytearray(line)
        for offset, mask in flips:
            if offset < len(damaged):
                damaged[offset] ^= mask
        if damaged == line or b"\n" in damaged or b"\r" in damaged:
            return  # a flip on the line end, or one that made a new one: the pieces meet the checks on their own
        # As the firmware reads it: a backslash made by a flip escapes the byte after it and is dropped, a `;` cuts
        # the rest (`process_stream_char`), so the checks below see the line the board checks.
        read = bytearray()
        _stream_chars(read, _NORMAL, bytes(damaged))
        damaged = read
        if damaged[:1] == b"n":
            self.unseen += 1
            return
        star = damaged.rfind(b"*")
        if damaged[:1] == b"N" and star >= 0 and _strtol(bytes(damaged), star + 1) == _xor(bytes(damaged[:star])):
            self.unseen += 1

    def _flip_targeted(self, sent: bytes, data: bytes, faults: Faults) -> bytes:
        """Hold back the unfinished line; at each line end, apply the `flip_once` entries that match it."""
        self._held_sent += sent
        self._held += data
        out = bytearray()
        start = 0
        if not self._line_start:
            # A line already partly passed on when the entries were set: they start with the next line.
            match = _EOL.search(self._held_sent)
            if match is None:
                out += self._held
                self._held_sent.clear()
                self._held.clear()
                return bytes(out)
            start = match.end()
            out += self._held[:start]
            self._line_start = True
        while faults.flip_once:
            match = _EOL.search(self._held_sent, start)
            if match is None:
                break
            end = match.start()
            line = bytes(self._held_sent[start:end])
            for entry in list(faults.flip_once):
                substring, offset, bit = entry
                if substring.encode("latin-1") not in line:
                    continue
                faults.flip_once.remove(entry)
                if offset <= end - start:  # the line's bytes and its line end
                    self._held[start + offset] ^= 1 << bit
                    self.count += 1
            out += self._held[start : end + 1]
            start = end + 1
        if faults.flip_once:
            rest_sent, rest = self._held_sent[start:], self._held[start:]
        else:
            out += self._held[start:]
            rest_sent, rest = bytearray(), bytearray()
            if self._held_sent:
                self._line_start = self._held_sent[-1] in b"\r\n"
        self._held_sent, self._held = rest_sent, rest
        return bytes(out)


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
        self._line = bytearray()  # the line being read, as process_stream_char() stored it
        self._state = _NORMAL
        self._emergency_tail = b""
        self._m110_queued = False  # an M110 went into the ring (and may not have run yet)
        self.last_line_number = 0
        """The line counter: the number of the last numbered line taken (M110 sets it)."""
        self.dropped_since_counted = 0
        """Numbered lines dropped without a word (as repeats of the last two) since the last one counted."""
        self.unseen = 0
        """Numbered lines that `Faults.corrupt_rx_ratio` damaged and that still passed the checksum: one replaced
        byte alone never does, so a flip on the wire (`WireFlips`) cancelled it in the 8-bit XOR."""

    def reset(self) -> None:
        """Power-on state: buffers empty, line counter 0. The fault stream carries on."""
        self.clear()
        self._emergency_tail = b""
        self.last_line_number = 0
        self.dropped_since_counted = 0

    def clear(self) -> None:
        """Throw away the receive buffer and the line being read (kill(), or a line error)."""
        self.rx.clear()
        self._line.clear()
        self._state = _NORMAL

    def store(self, data: bytes) -> int:
        """Keep what fits of `data` in the receive buffer and nothing more; return how many bytes were dropped.

        This is all a stalled board does with its input: it reads no lines out of the buffer.
        """
        room = self._config.rx_buffer_size - len(self.rx)
        if room > 0:
            self.rx += data[:room]
        return max(len(data) - max(room, 0), 0)

    def emergency_codes(self, data: bytes) -> Sequence[bytes]:
        """What the emergency parser finds in `data` as it arrives: `b"108"`, `b"112"`, `b"410"` or `b"876 S1"` for
        each line that `data` completes starting with such a command, in order (e_parser.h)."""
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

    def take_lines(self, ring: deque[Command], faults: Faults, *, busy: bool) -> None:
        """Move lines from the receive buffer into the command `ring` while it has a free slot; `busy` says a
        command is running (so the ring's first command is not waiting to start)."""
        if self._m110_queued and not busy:
            if any(command.code == "M110" for command in ring):
                return  # it runs before the next line is read (see the module's docstring)
            self._m110_queued = False
        slots = self._config.command_buffer_size
        rx = self.rx
        while rx and len(ring) < slots:
            match = _EOL.search(rx)
            if match is None:
                # Marlin reads what has come into its line buffer and waits for the rest.
                self._state = _stream_chars(self._line, self._state, rx)
                rx.clear()
                return
            end = match.start()
            if not self._line and self._state == _NORMAL and _STREAM_SPECIAL.search(rx, 0, end) is None:
                raw = bytes(rx[: min(end, _MAX_COMMAND_BYTES)])  # the common case: a plain line, whole
            else:
                self._state = _stream_chars(self._line, self._state, rx[:end])
                raw = bytes(self._line)
                self._line.clear()
            self._state = _NORMAL
            del rx[: end + 1]
            if not raw:
                continue  # an empty line (or a comment alone)
            command = self._check_line(raw, faults)
            if command is None:
                continue
            ring.append(command)
            if command.code == "M110":
                self._m110_queued = True
                if not busy:
                    return  # it runs before the next line is read (see the module's docstring)

    def run_m110(self, command: Command) -> None:
        """M110 as it runs (`gcode/host/M110.cpp`): `N<n>` sets the line counter, for any M110 line."""
        number = command.parameters().get("N")
        if number is not None:
            self.last_line_number = min(max(int(number), _LONG_MIN), _LONG_MAX)

    def _check_line(self, raw: bytes, faults: Faults) -> Command | None:
        """Check one received line as queue.cpp does: the command to queue, or None (and any error reply)."""
        nul = raw.find(0)
        if nul >= 0:
            raw = raw[:nul]  # the rest is beyond the C string's end
        command = raw.lstrip(b" ")
        ratio = faults.corrupt_rx_ratio
        corrupted = False
        if command and ratio > 0.0 and self._corrupt_rng.random() < ratio:
            damaged = self._corrupt(command)
            corrupted = damaged != command  # a `~` replaced by `~` changes nothing
            command = damaged
            raw = raw[: len(raw) - len(command)] + command
        line_number = None
        if command[:1] == b"N":
            is_m110 = b"M110" in command
            number_at = 0
            if is_m110:
                second_n = command.find(b"N", 4)
                if second_n >= 0:
                    number_at = second_n
            number = _strtol(command, number_at + 1)
            last = self.last_line_number
            if number != last + 1 and not is_m110:
                if self._config.ignore_duplicate_lines and last - 1 <= number <= last:
                    self.dropped_since_counted += 1
                    return None  # "A request-for-resend line was already in transit so we got two"
                self._line_error("Line Number is not Last Line Number+1, Last Line: ")
                return None
            star = command.rfind(b"*")
            if star < 0:
                self._line_error("No Checksum with line number, Last Line: ")
                return None
            if _strtol(command, star + 1) != _xor(command[:star]):
                self._line_error("checksum mismatch, Last Line: ")
                return None
            if corrupted:
                self.unseen += 1  # a byte replaced and the checksum still right: a wire flip cancelled it
            self.last_line_number = number
            self.dropped_since_counted = 0
            line_number = number if not is_m110 else _strtol(command, 1)
            label = _OK_LABEL.match(raw)  # None after leading spaces
            if label is not None:
                return self._parse(command.decode("latin-1"), label.group().decode("latin-1"), line_number)
        elif self._config.checksum_required:
            # Thrown away as it is read, like a line error, but with neither a resend request nor an ok.
            self._emit("Error: Missing checksum")
            return None
        return self._parse(command.decode("latin-1"), None, line_number)

    def _parse(self, text: str, line_label: str | None, line_number: int | None) -> Command:
        """parser.cpp's `parse()` of a line without its leading spaces: the library's own reading of it
        (`marlin_aio.protocol.gcode.parse_gcode`), so what the host checks is what the board runs."""
        case_insensitive = self._config.case_insensitive
        words = gcode.parse_gcode(text, case_insensitive=case_insensitive)
        code, args = words.code, words.args
        if code and case_insensitive and code not in _STRING_ARGUMENT_CODES and not args.isupper():
            # Only a-z: str.upper() would also change latin-1 letters, which Marlin leaves alone.
            args = args.upper() if args.isascii() else args.translate(_TO_UPPER)
        return Command(words.text, code, args, line_label, line_number, words)

    def _corrupt(self, command: bytes) -> bytes:
        # Never the leading N: a line that loses it is run unchecked (flip_bit_ratio is the fault that can).
        first = 1 if command[:1] == b"N" and len(command) > 1 else 0
        at = self._corrupt_rng.randrange(first, len(command))
        replacement = self._corrupt_rng.randrange(0x21, 0x7E)
        if replacement in (command[at], 0x3B):
            replacement = 0x7E  # ~
        return command[:at] + bytes((replacement,)) + command[at + 1 :]

    def _line_error(self, message: str) -> None:
        """gcode_line_error(): report, throw away the receive buffer, ask for the line again."""
        self._emit(f"Error:{message}{self.last_line_number}")
        self.clear()
        self._emit(f"Resend: {self.last_line_number + 1}")
        self._emit("ok")
