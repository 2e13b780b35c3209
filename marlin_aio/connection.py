"""The sans-I/O connection: which command each `ok` answers, resends, deadlines, halts and resets.

Marlin answers every command it processes with exactly one `ok`, in the order it received them. So the connection
keeps the commands written but not yet answered in a FIFO (`in flight`) and each plain `ok` completes the oldest.
Three exceptions are handled here, all from Marlin's sources (`gcode/queue.cpp`):

- After a line-number or checksum error the printer prints `Resend: N` then an `ok` that answers nothing; the
  command is written again. The firmware also throws away what sat in its receive buffer, so every line from N on
  is written again, and rejections of lines that were already on the wire ("stale") do not trigger more resends.
- With ADVANCED_OK the `ok` names its line (`ok N12 ...`), and M105's `ok` is recognisable by its temperatures;
  either one proves that every older command was processed, so a lost `ok` does not shift every later answer.
- A command that gets no `ok` at all (Marlin's `M105 T9` prints an error and nothing more) times out and is
  dropped, so the commands behind it go on.

Why a reply handed to a caller is its own (the invariant of issue 8). An `ok` can name its command only by its
shape: `ok N<line>` (ADVANCED_OK) names a numbered line, `ok T:...` names "an M105", a plain `ok` names nothing.
So an ok answers the oldest command in flight whose answer it can be (`_match`), and every command ahead of that
one was processed (Marlin answers in order) but lost its ok: such a command is never handed the later answer; it
fails with `LostReplyError`, or, for a print line, counts as run. That is sound only if no two commands in flight
could take each other's ok, so `_answer_stays_distinct` lets a command out only when a lost ok cannot make its
answer ambiguous: at most one M105 at a time, and, unless the printer names lines in its oks, a command someone
waits for is never in flight beside another plainly answered one (print lines may share the wire with each other,
as a later answer proves that they ran). Reply lines go to the oldest command waiting when they arrive; after a lost
ok they may belong to a later command, so `_attribute` hands them on only when the skipped commands print nothing
(a bare M105), and otherwise to nobody. A command that times out keeps its place for one more timeout, so its late
ok lands on it and not on the next caller's command. Noise (non-ASCII, control characters) is nobody's reply line.

Why a print line runs exactly once, in order. Every line is numbered, and Marlin runs a numbered line only if it
follows the last one it ran, so a line written twice is never run twice. The exception is a firmware fact: when
Marlin rejects a line it throws away its receive buffer, and a line that was half received is cut in two; its tail
arrives later as an unnumbered line of its own. Marlin refuses most tails (`Unknown command`, recognised by
`_is_fragment`, whose ok then answers nothing), but a tail that begins at the command word runs, out of place. Only
a line written behind an unanswered one can be cut, so ping-pong (one line in flight) is exact on any link. With
send-ahead, after a line error nothing is written until the printer has been quiet (`_drain_until`: every stale
line and tail has arrived), then one line at a time for `CALM_LINES` lines; a tail that ran shows as an ok that no
command earned while draining, and the print stops saying so (`_fragment_ran`).

A print job (`marlin_aio.printjob.PrintJob`) is fed through the same FIFO, after any submitted commands, as far as
the window allows. While it streams, a line left unanswered for a few round trips gets a probe (a numbered M105)
so that a lost `ok` costs a moment; a line unanswered for the whole timeout, with no busy keepalive, stalls the
print with a diagnosis.

Time never comes from a clock here: every call takes `now` (seconds, monotonic), so tests drive it directly.
Nothing here imports asyncio or serial; `marlin_aio.client` is the thin layer that does I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from marlin_aio.commands import MAX_COMMAND_BYTES, command_code, encode_command, number_command, validate_command
from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandNotExecutedError,
    CommandTimeoutError,
    LostReplyError,
    MarlinError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
    PrintStalledError,
    RemoteProtocolError,
    ResendLimitError,
    ThermalRunawayError,
)
from marlin_aio.events import (
    BusyKeepalive,
    Capability,
    EchoMessage,
    ErrorKind,
    ErrorMessage,
    Event,
    FirmwareInfo,
    Ok,
    OverlongLine,
    PrinterLocked,
    ResendRequest,
    Start,
    TemperatureReport,
    UnknownCommand,
    UnrecognisedLine,
)
from marlin_aio.linkstate import LinkState
from marlin_aio.parsing import EventParser
from marlin_aio.printjob import PrintJob, PrintState
from marlin_aio.stats import LinkStats
from marlin_aio.temperatures import Temperatures
from marlin_aio.trace import Trace

__all__ = ["Command", "Connection", "Reply"]

#: Errors whose only argument is the message, so the print's position can be added to it.
_PLAIN_ERRORS = (PrinterHaltedError, ThermalRunawayError, PrinterResetError, ResendLimitError, RemoteProtocolError)

#: Commands that wait for heaters; every temperature report while they run shows the printer is alive.
_HEATER_WAITS = frozenset({"M109", "M190", "M191"})

#: How many reply lines one command keeps (M115 prints about 40, M503 about 25); older ones are counted only.
MAX_REPLY_LINES = 256

#: After a line error, how many print lines must be answered without another before send-ahead writes more than
#: one line at a time again. One line at a time never leaves a line on the wire behind one the firmware may reject.
CALM_LINES = 100

#: Commands Marlin's emergency parser acts on as soon as their bytes arrive; they skip the queue here too.
EMERGENCY_COMMANDS = frozenset({"M108", "M112", "M410", "M876"})


@dataclass(frozen=True, slots=True)
class Reply:
    """What the printer answered to one command: the lines that came with it, and its `ok`.

    `sent_s` and `answered_s` are on the connection's clock, so `latency_s` is the round trip.
    """

    command: str
    lines: tuple[str, ...]
    ok: Ok
    sent_s: float
    answered_s: float
    lines_dropped: int = 0
    """Lines that came before `lines` and were not kept (over `MAX_REPLY_LINES`)."""

    @property
    def latency_s(self) -> float:
        """Seconds from writing the command to its `ok`."""
        return self.answered_s - self.sent_s

    @property
    def temperatures(self) -> Temperatures | None:
        """The temperatures an M105 `ok` carried, if any."""
        return self.ok.temperatures


@dataclass(slots=True, eq=False)
class Command:
    """A command the connection has accepted: queued, in flight, or finished.

    `id` is unique per connection, for matching results to waiters.
    """

    id: int
    text: str
    code: str
    numbered: bool
    timeout_s: float
    submitted_s: float
    line_number: int | None = None
    wire: bytes = b""
    sent_s: float | None = None
    head_since_s: float | None = None  # when it became the oldest command waiting for an ok
    alive_s: float | None = None  # last busy keepalive / wait line while it was the oldest
    lines: list[str] = field(default_factory=list)
    lines_dropped: int = 0  # reply lines beyond MAX_REPLY_LINES, counted, not kept
    sends: int = 0
    orphan: bool = False  # its caller already gave up (timed out); an answer completes nothing
    job: PrintJob | None = None  # set for the lines of a print job: their answers go to the job, not to a waiter
    source_line: int = 0
    source_bytes: int = 0
    probe: bool = False  # an M105 written to find out whether a stalled stream lost an ok
    refusal: str | None = None  # the printer's line saying it did not run this command (locked, not executed)

    def add_line(self, text: str) -> None:
        """Collect one reply line, keeping only the last `MAX_REPLY_LINES` (a chatty or noisy printer must not
        grow one command's reply without bound)."""
        self.lines.append(text)
        if len(self.lines) > MAX_REPLY_LINES:
            del self.lines[0]
            self.lines_dropped += 1


def _is_garbage(text: str) -> bool:
    """True for a line no firmware prints: Marlin writes ASCII only, so anything else is noise from the link."""
    return not text.isascii() or any(ch < " " or ch == "\x7f" for ch in text)


class Connection:
    """Bookkeeping for one link to a Marlin printer, with no I/O.

    Typical use by an I/O layer: `submit()` commands, write `data_to_send()`, feed bytes read to
    `receive_data()`, call `check_timeouts()` at `next_deadline()`, and deliver `take_results()`.

    Args:
        numbered: give every command a line number and checksum so the printer can ask for it again.
        max_in_flight: how many commands may be written before their `ok` (1 is ping-pong).
        rx_buffer_bytes: the printer's serial receive buffer; unanswered bytes never exceed it.
        trace_size: how many lines sent and received the trace keeps.
        max_resends: how often one line may be requested again before the link is declared too noisy.
        resend_timeout_s: while lines are being resent, how long a resent line may go unanswered before it is
            written again (its rejection may have been taken for a stale one).
        ok_after_resend: the firmware follows every `Resend:` with an `ok` that answers nothing (Marlin 2.1);
            False for the 2.0.x builds that omit it.
        advanced_ok: the printer is known to name the line in each ok (ADVANCED_OK), so numbered commands may
            share the line from the start; otherwise this is learnt from the first `ok N<line>`.
    """

    def __init__(
        self,
        *,
        numbered: bool = True,
        max_in_flight: int = 1,
        rx_buffer_bytes: int = 128,
        trace_size: int = 64,
        max_resends: int = 10,
        resend_timeout_s: float = 3.0,
        ok_after_resend: bool = True,
        advanced_ok: bool = False,
    ) -> None:
        if max_in_flight < 1:
            raise ValueError(f"max_in_flight must be at least 1, got {max_in_flight}")
        if rx_buffer_bytes < 16:
            raise ValueError(f"rx_buffer_bytes must be at least 16, got {rx_buffer_bytes}")
        self.numbered = numbered
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes
        self.max_resends = max_resends
        self.ok_after_resend = ok_after_resend
        self._now = 0.0  # the latest time any call was given, for results that happen as a side effect
        self.job: PrintJob | None = None
        self._job_next: Command | None = None
        self.stream_timeout_s = 10.0
        self._probe: Command | None = None
        self._rtts: deque[float] = deque(maxlen=32)
        self.probes = 0
        self.resend_timeout_s = resend_timeout_s
        self.trace = Trace(trace_size)
        self._parser = EventParser()
        self._next_id = 0
        self._next_line = 1  # after reset (or M110 N0) Marlin expects line 1
        self._queue: deque[Command] = deque()  # accepted, not yet written
        self._in_flight: deque[Command] = deque()  # written, waiting for an ok, in the order they were written
        self._in_flight_bytes = 0
        self._history: dict[int, Command] = {}  # numbered lines by number, for resends
        self._history_order: deque[int] = deque()
        self._resend_from: int | None = None  # the resend being carried out
        self._stale = 0  # answers still due for lines written before the last resend request
        self._swallow_ok = False  # the ok right after a resend request answers nothing
        self._after_line_error = False  # the last line was `Error:...Last Line` (a rejection, not an M999 request)
        # After a line error with more lines on the wire behind the rejected one: write nothing until the printer has
        # been quiet this long (every stale line and fragment has arrived and been answered), then resend.
        self._drain_until: float | None = None
        self._calm_left = 0  # print lines still to be answered one at a time after the last line error
        self._accepted_through = 0  # the printer has taken every numbered line up to this one (it cannot reject it)
        self._fragment_wires: list[tuple[str, str]] = []  # (wire, text) of lines a flush may have cut in two
        self._probed_s = 0.0  # when the last probe (an M105, or a resend let out early) was written
        self._nudge_pending = False  # let the next resend out past the window, as a probe
        self._fragment_oks = 0  # oks still due for fragments the firmware reported as unknown commands
        self.fragments = 0  # pieces of lines the printer received on their own after a flush (and refused)
        self.fragments_run = 0  # pieces of lines the printer ran on their own: a line ran out of place
        self._results: list[tuple[Command, Reply | MarlinError]] = []
        self._thermal_message: str | None = None
        self._halt: PrinterHaltedError | None = None  # why the printer halted or stopped; raised to new commands
        self._stopped = False  # the halt is a stop() that M999 clears (ErrorKind.STOPPED), not a kill()
        self.resets = 0
        self.resend_requests = 0
        self.stray_oks = 0
        self.lost_oks = 0  # oks proven lost: a later answer showed that their command had been processed
        self._exact_oks = advanced_ok  # the printer names lines in its oks (ADVANCED_OK): plain oks identify themselves
        self._locked = False  # the printer said "Printer locked!" and has not run a command since
        self.requires_numbers = False  # the printer refused an unnumbered command ("Missing checksum")
        self.garbage_lines = 0  # lines of noise received (not given to any command)
        self.bytes_received = 0
        self._submitted = 0  # commands accepted by submit() (print lines and probes are not commands of anyone's)
        self.timeouts = 0
        # Every submitted command ends up counted once: answered + failed + cancelled + still queued or in flight.
        self.answered = 0
        self.failed = 0
        self.cancelled = 0

    # ----------------------------------------------------------------------------------------------- commands

    def submit(
        self, text: str, *, timeout_s: float, now: float, numbered: bool | None = None, checked: bool = True
    ) -> Command:
        """Accept a command for sending; it goes out in order with the others.

        `checked=False` skips validation, for commands the caller built itself and knows to be valid (the client's
        own M105 polls, a hundred times a second).

        Raises:
            ValueError: the command is not valid (line break, non-ASCII, too long, empty).
            PrinterHaltedError: the printer halted and answers nothing until it is reset.
        """
        use_numbers = (self.numbered if numbered is None else numbered) or self.requires_numbers
        if not checked:
            if self._halt is not None:
                raise self._halt
            self._submitted += 1
            self._next_id += 1
            command = Command(self._next_id, text, command_code(text), use_numbers, timeout_s, now)
            self._queue.append(command)
            return command
        # Validate now, so a bad command never reaches the queue: as given (the clearest message), then its length
        # with a line number comfortably larger than any it can get while queued ("N<n> " and "*<checksum>").
        stripped = validate_command(text)
        if use_numbers:
            longest_number = self._next_line + len(self._queue) + len(self._in_flight) + 1000
            if len(stripped) + len(str(longest_number)) + 6 > MAX_COMMAND_BYTES:
                raise ValueError(
                    f"command {text[:40]!r}... is too long: with its line number and checksum it would exceed "
                    f"Marlin's {MAX_COMMAND_BYTES}-byte limit"
                )
        code = command_code(stripped)
        if self._halt is not None and code != "M999":
            raise self._halt
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self._submitted += 1
        self._next_id += 1
        command = Command(self._next_id, stripped, code, use_numbers, timeout_s, now)
        self._queue.append(command)
        return command

    def emergency(self, text: str, *, now: float) -> bytes:
        """Return the bytes of an emergency command (M112, M108, M410) to write at once, ahead of the queue.

        It is never numbered (the emergency parser wants the bare command) and gets no entry in the FIFO: M112 halts
        the printer, and the halt fails everything that was waiting.

        Raises:
            ValueError: the command is not one of M108, M112, M410, M876, or is malformed.
        """
        wire = encode_command(text)
        if command_code(text) not in EMERGENCY_COMMANDS:
            raise ValueError(f"{text!r} is not an emergency command (M108, M112, M410, M876)")
        self.trace.sent(now, wire.decode("ascii").rstrip("\n"))
        return wire

    def emergency_stop(self, now: float) -> bytes:
        """Return M112's bytes, to write at once ahead of anything queued; from now on the printer is halted (it
        needs a reset), and every command still waiting fails with `PrinterHaltedError`."""
        wire = self.emergency("M112", now=now)
        self._halt = PrinterHaltedError("emergency stop (M112) sent; reset the printer to go on")
        self._stopped = False
        self._fail_everything(self._halt)
        return wire

    @property
    def state(self) -> LinkState:
        """READY, LOCKED (refusing commands until unlocked), STOPPED (M999 resumes) or HALTED (needs a reset)."""
        if self._halt is not None:
            return LinkState.STOPPED if self._stopped else LinkState.HALTED
        return LinkState.LOCKED if self._locked else LinkState.READY

    @property
    def halted(self) -> PrinterHaltedError | None:
        """Why the printer halted or stopped (the error new commands fail with), or None while it runs."""
        return self._halt

    @property
    def locked(self) -> bool:
        """True while the printer refuses commands as locked (PASSWORD_FEATURE)."""
        return self._locked

    @property
    def window(self) -> tuple[int, int]:
        """(max_in_flight, rx_buffer_bytes): how many commands and unanswered bytes may be on the wire."""
        return self.max_in_flight, self.rx_buffer_bytes

    def set_window(self, max_in_flight: int, rx_buffer_bytes: int) -> None:
        """Change how many commands and unanswered bytes may be on the wire (a print's send-ahead, a benchmark);
        what is already in flight stays.

        Raises:
            ValueError: `max_in_flight` below 1 or `rx_buffer_bytes` below 16.
        """
        if max_in_flight < 1:
            raise ValueError(f"max_in_flight must be at least 1, got {max_in_flight}")
        if rx_buffer_bytes < 16:
            raise ValueError(f"rx_buffer_bytes must be at least 16, got {rx_buffer_bytes}")
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes

    def data_to_send(self, now: float) -> bytes:
        """Return the bytes to write now: resends first, then queued commands, then print job lines, as far as the
        window allows."""
        self._now = now
        if self._drain_until is not None:
            if now < self._drain_until:
                return b""
            self._end_drain()
        chunks: list[bytes] = []
        # While a job streams, keep room in the printer's buffer for a probe or a user command to get in.
        limit = self.rx_buffer_bytes - (self.probe_reserve_bytes if self.job is not None else 0)
        calm = self._calm_left > 0
        while True:
            if self._queue:
                command = self._queue[0]
            else:
                job_command = self._next_job_command(now)
                if job_command is None:
                    break
                command = job_command
            nudge = self._nudge_pending and bool(command.wire)
            self._nudge_pending = False
            if self._in_flight and (
                (len(self._in_flight) >= self.max_in_flight and not command.probe)
                or (calm and not (command.probe or nudge) and self._rejectable_in_flight())
                or self._in_flight_bytes + self._wire_size(command) > (self.rx_buffer_bytes if command.probe else limit)
                or not self._answer_stays_distinct(command)
            ):
                break
            if command is self._job_next:
                self._job_next = None
            else:
                self._queue.popleft()
            if not command.wire:
                if self._wire_size(command) - 1 > MAX_COMMAND_BYTES:
                    # Only possible if the line numbers grew by over a thousand while it waited in the queue.
                    self._finish(command, MarlinError(f"{command.text!r} grew too long for Marlin once numbered"))
                    continue
                self._assign_wire(command)
            if command.job is not None and command.sends == 0:
                command.job.sent()
            chunks.append(self._write(command, now))
        return b"".join(chunks)

    def _rejectable_in_flight(self) -> bool:
        """Is a numbered line on the wire that the printer may still reject (and so flush what follows it)?"""
        through = self._accepted_through
        return any(c.line_number is not None and c.line_number > through for c in self._in_flight)

    def _answer_stays_distinct(self, command: Command) -> bool:
        """May `command` go out now without its answer becoming confusable with another's if an ok is lost?

        An ok names its command only by line number (ADVANCED_OK) or by its shape (M105's `ok T:`). So, unless
        the printer numbers its oks, a command whose reply someone waits for is never in flight together with
        another whose ok looks the same: at most one M105 at a time, and a user's command that is answered by
        a plain ok only while no other plainly answered command is in flight. Print lines may share the line
        with each other (a print line needs only to be known to have run, and a later answer proves that).
        """
        if command.code == "M105":
            return not any(c.code == "M105" for c in self._in_flight)
        if self._exact_oks and command.numbered:
            return True
        waits_for_reply = command.job is None and not command.probe
        for other in self._in_flight:
            if other.code == "M105":
                continue
            if waits_for_reply or (other.job is None and not other.probe and not other.orphan):
                return False
        return True

    def _next_job_command(self, now: float) -> Command | None:
        """The job's next line as a command (kept until it fits the window), or None."""
        job = self.job
        if job is None:
            return None
        if self._job_next is not None:
            if job.cancelling:
                self._job_next = None  # read from the source but never written: it is simply not sent
            elif job.state is PrintState.RUNNING:
                return self._job_next
            else:
                return None
        if job.finished:
            self.job = None
            return None
        item = job.next_command()
        if item is None:
            job.finish_if_idle(now)
            if job.finished:
                self.job = None
            return None
        text, source_line, source_bytes = item
        self._next_id += 1
        command = Command(self._next_id, text, command_code(text), self.numbered, self.stream_timeout_s, now)
        command.job, command.source_line, command.source_bytes = job, source_line, source_bytes
        self._job_next = command
        return command

    def attach(self, job: PrintJob, *, timeout_s: float) -> None:
        """Stream `job`'s lines from now on, interleaved with submitted commands (which go first).

        Raises:
            RuntimeError: another job is still running.
        """
        if self.job is not None and self.job.active:
            raise RuntimeError(f"a print is already running ({self.job.name})")
        self.job = job
        self.stream_timeout_s = timeout_s
        self._rtts.clear()

    def _wire_size(self, command: Command) -> int:
        if command.wire:
            return len(command.wire)
        if not command.numbered:
            return len(command.text) + 1
        # "N<n> <text>*<checksum>\n": the checksum has at most 3 digits, so this is never too small.
        return len(command.text) + len(str(self._line_number_for(command))) + 7

    def _line_number_for(self, command: Command) -> int:
        if command.code == "M110":
            # M110 sets the counter: number the line with the value it sets, as Marlin's own hosts do.
            words = command.text.split()
            return next((int(w[1:]) for w in words[1:] if w[:1] in "Nn" and w[1:].isdigit()), 0)
        return self._next_line

    def _assign_wire(self, command: Command) -> None:
        if not command.numbered:
            command.wire = command.text.encode("ascii") + b"\n"
            return
        command.line_number = self._line_number_for(command)
        if command.code == "M110":
            self._forget_history()
            self._accepted_through = command.line_number - 1
        self._next_line = command.line_number + 1
        command.wire = number_command(command.text, command.line_number).encode("ascii") + b"\n"
        self._history[command.line_number] = command
        self._history_order.append(command.line_number)
        # Keep enough history for everything that can be in flight, with a wide margin.
        while len(self._history_order) > max(256, 4 * self.max_in_flight):
            self._history.pop(self._history_order.popleft(), None)

    def _forget_history(self) -> None:
        self._history.clear()
        self._history_order.clear()

    def _write(self, command: Command, now: float) -> bytes:
        command.sends += 1
        if command.sent_s is None:
            command.sent_s = now
        if not self._in_flight:
            command.head_since_s = now
        self._in_flight.append(command)
        self._in_flight_bytes += len(command.wire)
        self.trace.sent(now, command.wire.decode("ascii").rstrip("\n"))
        return command.wire

    # ----------------------------------------------------------------------------------------------- receiving

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        """Feed bytes read from the printer; return the events of the lines they complete.

        Results (answered and failed commands) collect in `take_results()`; call `data_to_send()` afterwards,
        as an answer may open the window for more.
        """
        self._now = now
        self.bytes_received += len(data)
        events: list[Event] = []
        for text, event in self._parser.receive_data(data):
            self.trace.received(now, text)
            self._handle(text, event, now)
            events.append(event)
        return events

    def discard_partial_input(self) -> None:
        """Forget an unfinished line (call after flushing the port's input: its end will never arrive)."""
        self._parser.clear()

    def _handle(self, text: str, event: Event, now: float) -> None:
        if self._drain_until is not None:
            # The printer is still answering what was on the wire when it threw its buffer away.
            self._drain_until = max(self._drain_until, now + self._quiet_s())
        kind = type(event)
        if kind is Ok:
            assert isinstance(event, Ok)
            self._on_ok(event, now)
            return
        # A noise line between `Resend:` and its `ok` does not end the wait for that ok: both are printed by one
        # call in Marlin's queue.cpp, so any line between them came from the link, not from the firmware.
        after_line_error = self._after_line_error
        self._after_line_error = (
            kind is ErrorMessage and isinstance(event, ErrorMessage) and event.kind is ErrorKind.LINE
        )
        head = self._in_flight[0] if self._in_flight else None
        if kind is BusyKeepalive or (
            kind is TemperatureReport
            and isinstance(event, TemperatureReport)
            # Marlin marks its wait lines with W:; other firmwares send plain reports while M109/M190 wait.
            and (event.temperatures.waiting or (head is not None and head.code in _HEATER_WAITS))
        ):
            # Proof that the printer is alive and working on the oldest command: push its deadline out.
            if head is not None:
                head.alive_s = now
        elif kind is ResendRequest:
            assert isinstance(event, ResendRequest)
            self._on_resend(event.line_number, now, rejected=after_line_error)
        elif kind is ErrorMessage:
            assert isinstance(event, ErrorMessage)
            self._on_error(event, now)
        elif kind is Start:
            self._on_start()
        elif kind is OverlongLine or (kind is UnrecognisedLine and _is_garbage(text)):
            # Noise from the link (a baud glitch, a reset) is nobody's reply.
            self.garbage_lines += 1
        elif kind is UnknownCommand and self._is_fragment(event):
            # The tail of a line cut in two by a flush, which the firmware read as a command of its own and
            # refused: its ok answers nothing.
            self.fragments += 1
            self._fragment_oks += 1
        elif kind is PrinterLocked or kind is UnknownCommand:
            if head is not None:
                head.add_line(text)
                if kind is PrinterLocked:
                    # The ok that follows answers a command that was refused, not run.
                    head.refusal = text
                    self._locked = True
                elif head.job is not None:
                    head.refusal = text  # a print line the firmware did not understand was not printed
        elif head is not None and kind in (UnrecognisedLine, EchoMessage, FirmwareInfo, Capability):
            head.add_line(text)

    def _is_fragment(self, event: Event) -> bool:
        """Is this "Unknown command" about a piece of a line that a flush cut in two?

        Its text is then part of a line written behind a rejected one, but not that line's whole command (a line
        whose command the firmware does not know is refused with its own text, and that refusal stops a print).
        """
        assert isinstance(event, UnknownCommand)
        piece = event.command
        return any(piece != text and piece in wire for wire, text in self._fragment_wires)

    def _on_ok(self, ok: Ok, now: float) -> None:
        if self._swallow_ok:
            self._swallow_ok = False
            return
        if self._fragment_oks:
            self._fragment_oks -= 1
            return
        # Which in-flight command does this ok answer? The oldest one whose answer can look like it; every command
        # ahead of that one was processed (Marlin answers in order) but its own ok was lost.
        index = self._match(ok) if self._in_flight else None
        if index is None:
            self.stray_oks += 1
            if self._drain_until is not None and ok.temperatures is None:
                self._fragment_ran(now)
            return
        if ok.line_number is not None:
            self._exact_oks = True
        skipped = [self._pop_in_flight(now) for _ in range(index)]
        command = self._pop_in_flight(now)
        lines = self._attribute(skipped, command)
        for lost in skipped:
            self.lost_oks += 1
            self._settle(lost, None, None, now)
        self._settle(command, ok, lines, now)

    def _match(self, ok: Ok) -> int | None:
        """The index in the FIFO of the command `ok` answers, or None when it answers none of them."""
        flight = self._in_flight
        if ok.line_number is not None:
            for index, command in enumerate(flight):
                if command.line_number == ok.line_number:
                    return index
            # It names a line no longer in flight: completing another command with it would hand that command
            # someone else's answer. (An unnumbered command's ok carries no N, so only numbered heads rule it out.)
            return 0 if flight[0].line_number is None else None
        if ok.temperatures is not None:
            # Only M105 answers `ok T:...`.
            return next((i for i, c in enumerate(flight) if c.code == "M105"), None)
        if self._exact_oks:
            # This printer names the line in the ok of every numbered command: a plain ok is an unnumbered one's.
            return next(
                (i for i, c in enumerate(flight) if c.line_number is None and (c.code != "M105" or c.refusal)), None
            )
        # A plain ok: the oldest command that answers with a plain ok (not M105, whose answer carries temperatures;
        # a refused one is answered plainly whatever it was).
        return next((i for i, c in enumerate(flight) if c.code != "M105" or c.refusal is not None), None)

    def _attribute(self, skipped: list[Command], command: Command) -> tuple[str, ...] | None:
        """The reply lines of `command`, or None when they cannot be told apart from a skipped command's.

        Lines go to the oldest command waiting when they arrive; when its ok was lost, the lines of the commands
        behind it landed in its slot too. They are `command`'s for certain only if every skipped command prints
        nothing but its ok line (a bare M105).
        """
        if not skipped:
            return tuple(command.lines)
        if all(lost.text == "M105" or lost.probe for lost in skipped):
            return tuple(line for lost in skipped for line in lost.lines) + tuple(command.lines)
        if not any(lost.lines for lost in skipped):
            return tuple(command.lines)
        return None

    def _settle(self, command: Command, ok: Ok | None, lines: tuple[str, ...] | None, now: float) -> None:
        """Finish one command taken off the FIFO: answered by `ok`, or (ok None) processed with its ok lost."""
        if command.line_number is not None and command.line_number > self._accepted_through:
            self._accepted_through = command.line_number
        if self._stale == 0 or (self._resend_from is not None and (command.line_number or 0) >= self._resend_from):
            # The firmware has reached the lines written again: nothing older can still answer.
            self._stale = 0
            self._resend_from = None
        if command.code == "M999" and self._stopped:
            # stop() (unlike kill()) leaves Marlin running; M999 resumes it.
            self._halt = None
            self._stopped = False
        if command.refusal is None and self._locked and not command.orphan and command.code != "M511":
            self._locked = False  # a command ran normally: the printer was unlocked (M511 or its screen)
        if command.refusal is not None and not command.orphan and not command.probe:
            self._refused(command, now)
        elif command.job is not None:
            # A print line needs no reply: a later answer proves it ran, whether its own ok came or not.
            if ok is not None and command.sends == 1 and command.sent_s is not None:
                self._rtts.append(now - command.sent_s)
            if ok is not None and self._calm_left and self._resend_from is None and self._drain_until is None:
                self._calm_left -= 1
            command.job.acked(len(command.wire), command.source_bytes, command.source_line, now)
        elif command.probe:
            self._probe = None
        elif command.orphan:
            return
        elif ok is None or lines is None:
            what = "its ok was lost" if ok is None else "the ok of a command before it was lost"
            self._finish(
                command,
                LostReplyError(
                    f"{command.text!r} was processed but {what}, so which reply lines are its own cannot be "
                    "proven; it was not handed another command's answer",
                    command=command.text,
                ),
            )
        else:
            sent = now if command.sent_s is None else command.sent_s
            self._finish(command, Reply(command.text, lines, ok, sent, now, command.lines_dropped))

    def _refused(self, command: Command, now: float) -> None:
        """The printer answered `command` with an ok but said it did not run it."""
        said = command.refusal or ""
        error: MarlinError
        if "locked" in said.lower():
            error = PrinterLockedError(
                f"the printer is locked and refused {command.text!r} ({said.removeprefix('echo:')}): "
                "unlock it with M511 P<password> (connect with password=..., or --password) or on its screen"
            )
        else:
            error = CommandNotExecutedError(f"the printer did not run {command.text!r}: it said {said!r}")
        if command.job is not None:
            job = command.job
            job.in_flight -= 1
            where = f"line {command.source_line} of {job.name}"
            # Nothing after the refused line may run in its place: the print stops here, with the printer's words.
            self._fail_everything_of_job(type(error)(f"print stopped at {where}: {error}"), now)
            return
        self._finish(command, error)

    def _fail_everything_of_job(self, error: MarlinError, now: float) -> None:
        job = self.job
        if job is not None:
            job.fail(error, now)
        self.job = None
        self._job_next = None
        # Lines of the job already written stay in the FIFO as orphans (their oks are still due); unwritten ones go.
        for queued in self._in_flight:
            if queued.job is not None:
                queued.orphan = True
        self._queue = deque(c for c in self._queue if c.job is None)

    def _pop_in_flight(self, now: float) -> Command:
        command = self._in_flight.popleft()
        self._in_flight_bytes -= len(command.wire)
        if self._in_flight:
            self._in_flight[0].head_since_s = now
        return command

    def _on_resend(self, line_number: int, now: float, *, rejected: bool = False) -> None:
        self.resend_requests += 1
        # The printer took every line before the one it asks for.
        self._accepted_through = max(self._accepted_through, line_number - 1)
        # The ok right after a resend request answers nothing. (M999 prints `Resend:` and `ok` too, then its own ok.)
        self._swallow_ok = self.ok_after_resend
        if line_number != self._resend_from:
            # A request for another line means the firmware has got past every stale line.
            self._stale = 0
        elif self._stale > 0:
            # The rejection of a line that was already on the wire when this resend began: expected, no action.
            # (If it was in fact the resent line failing again, the shorter resend deadline recovers.)
            self._stale -= 1
            return
        head = self._in_flight[0] if self._in_flight else None
        if line_number == self._next_line:
            if rejected and head is not None and head.code == "M110":
                # The M110 itself was damaged: the firmware's counter is not reset, and it asks for the line after
                # its old one, which happens to be our next. Write the M110 again; it sets the counter whatever
                # its own number.
                self._pop_in_flight(now)
                self._queue.appendleft(head)
                self._check_resend_limit(head, line_number)
            # Otherwise the printer has every line we sent (M999 asks this way): nothing to write again.
            return
        self._resend(line_number, now)

    def _check_resend_limit(self, command: Command, line_number: int) -> bool:
        """Fail everything if `command` was written more often than allowed; return True if so."""
        if command.sends <= self.max_resends:
            return False
        self._fail_everything(
            ResendLimitError(
                f"the printer asked for line {line_number} ({command.text!r}) {command.sends} times; "
                "the link is too noisy (check the cable, baud rate and grounding)"
            )
        )
        return True

    def _resend(self, line_number: int, now: float) -> None:
        first = self._history.get(line_number)
        if first is not None and first.job is not None:
            first.job.resends += 1
        if first is None:
            self._fail_everything(
                RemoteProtocolError(
                    f"the printer asked for line {line_number}, which was never sent or is too old to resend "
                    f"(next line is {self._next_line})"
                )
            )
            return
        if self._check_resend_limit(first, line_number):
            return
        # Marlin rejected one line and threw away its receive buffer: every numbered line from N on that is on
        # the wire will be rejected or lost. Take them out of the in-flight FIFO (all but the one this rejection
        # answers will each send a stale rejection, or nothing) and write every line from N on again, in order,
        # ahead of new commands.
        owed = {id(c) for c in self._in_flight}
        keep: deque[Command] = deque()
        removed = 0
        behind: list[Command] = []  # written after the rejected line: on the wire when the firmware flushed
        for command in self._in_flight:
            if removed:
                behind.append(command)
            if command.line_number is not None and command.line_number >= line_number:
                removed += 1
            else:
                keep.append(command)
        self._stale = max(removed - 1, 0)
        self._calm_left = CALM_LINES
        if behind:
            # One of those lines may have been cut in two by the flush; its tail arrives as a line of its own. Hold
            # every write until the printer has answered all of them, so nothing new is cut, and recognise the
            # pieces (`_is_fragment`).
            self._drain_until = now + self._quiet_s()
            self._fragment_wires = [(c.wire.decode("ascii").rstrip("\n"), c.text) for c in behind]
        queued = {id(c) for c in self._queue}
        again: list[Command] = []
        for number in range(line_number, self._next_line):
            resend = self._history.get(number)
            if resend is None:
                continue
            if id(resend) not in owed and id(resend) not in queued:
                # Not in flight and not queued: its caller already had a result (a timeout). Resend it so the
                # numbering goes on, but its answer completes nothing.
                resend.orphan = True
            again.append(resend)
        self._in_flight = keep
        self._in_flight_bytes = sum(len(c.wire) for c in keep)
        if keep and keep[0].head_since_s is None:
            keep[0].head_since_s = now
        self._resend_from = line_number
        # Every line from N on goes out again in order, ahead of everything else, including the lines an earlier
        # request had already queued for resending.
        again_ids = {id(c) for c in again}
        self._queue = deque(c for c in self._queue if id(c) not in again_ids)
        self._queue.extendleft(reversed(again))

    def _quiet_s(self) -> float:
        """How long the printer must say nothing before what was on the wire at a flush is taken as all answered:
        four median round trips, within 20 ms to 0.5 s."""
        if not self._rtts:
            return 0.1
        ordered = sorted(self._rtts)
        return min(max(4 * ordered[len(ordered) // 2], 0.02), 0.5)

    def _end_drain(self) -> None:
        # The printer has been quiet: every line that was on the wire at the flush was rejected or answered, so a
        # rejection from now on is a fresh one.
        self._drain_until = None
        self._stale = 0

    def _fragment_ran(self, now: float) -> None:
        """An ok that no command earned arrived after a flush: the tail of a cut line ran as a command of its own."""
        self.fragments_run += 1
        job = self.job
        if job is None or not job.active:
            return
        pieces = ", ".join(repr(text) for _, text in self._fragment_wires[:3])
        message = (
            f"print stopped after line {job.last_source_line} of {job.name}: after a line error the printer threw "
            "away its receive buffer in the middle of a line and ran the rest of it as a command of its own (an ok "
            f"that no command earned; the line was one of {pieces}), so a line ran out of place; "
            "send-ahead cannot rule this out on this link: print with send_ahead=False (ping-pong)"
        )
        self._fail_everything_of_job(RemoteProtocolError(message), now)

    def _on_error(self, event: ErrorMessage, now: float) -> None:
        if event.kind is ErrorKind.THERMAL:
            self._thermal_message = event.message
            self._halt_with(ThermalRunawayError(f"thermal protection tripped: {event.message}"), stopped=False)
        elif event.kind is ErrorKind.HALTED or event.kind is ErrorKind.STOPPED:
            if self._thermal_message is not None:
                message = f"thermal protection tripped: {self._thermal_message} ({event.message})"
                self._halt_with(ThermalRunawayError(message), stopped=False)
            else:
                error = PrinterHaltedError(f"the printer halted: {event.message}")
                self._halt_with(error, stopped=event.kind is ErrorKind.STOPPED)
        elif event.kind is ErrorKind.NOT_EXECUTED and self._in_flight:
            head = self._in_flight[0]
            head.add_line(f"!! {event.message}")
            head.refusal = f"!! {event.message}"
        elif event.kind is ErrorKind.CHECKSUM_REQUIRED:
            self._on_checksum_required(event.message, now)
        elif event.kind is ErrorKind.OTHER and self._in_flight:
            self._in_flight[0].add_line(f"Error:{event.message}")

    def _on_checksum_required(self, message: str, now: float) -> None:
        # The firmware ran nothing and will send no ok for the oldest unnumbered command: fail it now, and number
        # every command from here on.
        self.requires_numbers = True
        for index, command in enumerate(self._in_flight):
            if command.line_number is None:
                del self._in_flight[index]
                self._in_flight_bytes -= len(command.wire)
                if index == 0 and self._in_flight:
                    self._in_flight[0].head_since_s = now
                if not command.orphan and command.job is None and not command.probe:
                    error = ChecksumRequiredError(
                        f"the printer refused {command.text!r} without a line number and checksum "
                        f"('Error:{message}'); it needs numbered commands"
                    )
                    self._finish(command, error)
                return

    def _halt_with(self, error: PrinterHaltedError, *, stopped: bool) -> None:
        """The printer halted (`stopped`: a stop() that M999 clears; otherwise it needs a reset)."""
        if self._halt is None or isinstance(error, ThermalRunawayError):
            self._halt = error
        # A second line about the same halt: a kill() after a stop() is final, and a stop() never softens a kill().
        self._stopped = stopped if self._halt is error else self._stopped and stopped
        self._fail_everything(self._halt)

    def _on_start(self) -> None:
        self.resets += 1
        # The board rebooted: it forgot every command and its line counter. Nothing is replayed into it.
        self._fail_everything(PrinterResetError("the printer reset (it printed 'start'); commands in flight were lost"))
        self._halt = None
        self._stopped = False
        self._locked = False
        self._thermal_message = None
        self._next_line = 1
        self._accepted_through = 0

    def _fail_everything(self, error: MarlinError) -> None:
        if self.job is not None:
            # Nothing is replayed into a board that reset or halted: the print ends here, at the line it reached.
            self.job.fail(self._job_error(error), self._now)
            self.job = None
        self._job_next = None
        self._probe = None
        for command in (*self._in_flight, *self._queue):
            if not command.orphan and command.job is None and not command.probe:
                self._finish(command, error)
        self._in_flight.clear()
        self._queue.clear()
        self._in_flight_bytes = 0
        self._forget_history()
        self._stale = 0
        self._resend_from = None
        self._swallow_ok = False
        self._drain_until = None
        self._fragment_oks = 0
        self._fragment_wires = []

    def cancel(self, command: Command) -> bool:
        """Withdraw a command whose caller gave up; return True if it was never written (so it never will be).

        A command already written stays in the FIFO, as the printer will still answer it; only its result is dropped.
        """
        if command.sends == 0:
            try:
                self._queue.remove(command)
            except ValueError:
                return False
            self.cancelled += 1
            return True
        command.orphan = True
        return False

    def fail_all(self, error: MarlinError) -> None:
        """Fail every queued and in-flight command with `error` (the link is gone, or the client closes)."""
        self._fail_everything(error)

    # ----------------------------------------------------------------------------------------------- time

    def next_deadline(self) -> float | None:
        """When the oldest command in flight times out (or a stalled stream is probed) unless the printer shows a
        sign of life first."""
        if not self._in_flight:
            return self._drain_until
        due = min(self._deadlines(self._in_flight[0]))
        return due if self._drain_until is None else min(due, self._drain_until)

    def _deadlines(self, head: Command) -> tuple[float, float, float]:
        """(time out, write again, probe) for the oldest command; inf where that step does not apply."""
        start = max(head.head_since_s or 0.0, head.alive_s or 0.0)
        resend_at = start + min(head.timeout_s, self.resend_timeout_s) if self._resending(head) else math.inf
        probe_at = max(start, self._probed_s) + self.probe_delay_s() if self._may_probe() else math.inf
        return start + head.timeout_s, resend_at, probe_at

    def _resending(self, head: Command) -> bool:
        return (
            self._resend_from is not None
            and head.line_number is not None
            and head.line_number >= self._resend_from
            and head.sends <= self.max_resends
        )

    def _may_probe(self) -> bool:
        # Only while a job streams: outside prints a probe M105 could answer a user's own M105 (say M105 T9).
        return (
            self.job is not None
            and self.job.active
            and self._probe is None
            and self.numbered
            and self._drain_until is None
        )

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost.

        Eight times the median round trip of recent lines, within 50 ms to 1 s: quick on a fast link, patient
        with a slow one. A probe is a numbered M105, harmless if nothing was lost.
        """
        if not self._rtts:
            return 1.0
        ordered = sorted(self._rtts)
        return min(max(8 * ordered[len(ordered) // 2], 0.05), 1.0)

    def check_timeouts(self, now: float) -> None:
        """Time out the oldest command if its deadline has passed; the commands behind it go on.

        While a job streams, a line that waits too long first gets a probe (a numbered M105: its `ok T:` proves
        every older line was processed, so a lost `ok` costs a moment, not the print). A line that still gets no
        answer within the timeout, with no busy keepalive, stalls the print: the job fails with a diagnosis.
        """
        self._now = now
        if self._drain_until is not None and now >= self._drain_until:
            self._end_drain()
        while self._in_flight:
            deadline = self.next_deadline()
            if deadline is None or now < deadline:
                return
            head = self._in_flight[0]
            timeout_at, resend_at, probe_at = self._deadlines(head)
            last_in = self.trace.last_received
            talking = last_in is not None and last_in.time_s > (head.head_since_s or 0.0)
            if now >= resend_at and head.line_number is not None and talking:
                # A resent line went unanswered while the printer talked: its rejection was probably taken for a
                # stale one. Resend again. (A silent printer is not helped by resends: it times out below.)
                self._stale = 0
                self._resend(head.line_number, now)
                continue
            if now < timeout_at:
                if now >= probe_at:
                    self._probed_s = now
                    if self._queue and self._queue[0].wire:
                        # Lines wait to be written again (one at a time, behind this one): the next of them is as
                        # good a probe as an M105, and a new M105 would take a line number ahead of theirs.
                        self._nudge_pending = True
                    else:
                        self._send_probe(now)
                return
            # No stale rejection can still be on its way after this much silence.
            self._stale = 0
            self.timeouts += 1
            if head.job is not None or head.probe:
                self._stall_job(head, now)
                continue
            if head.orphan:
                # Its caller was told already (it timed out behind another command, or gave up): drop it quietly.
                self._pop_in_flight(now)
                continue
            summary = self.describe_stall(head, now)
            error = CommandTimeoutError(summary, command=head.text)
            # Its caller is told now, but the command keeps its place for one more timeout (quarantine): Marlin may
            # still answer it (a long G28), and that late ok must land on it, not on the next caller's command,
            # which waits (see `_answer_stays_distinct`). Only then is its place given up.
            head.orphan = True
            head.head_since_s = now
            head.alive_s = None
            self._finish(head, error)
            self._give_up_behind(head, summary)
            return

    def _give_up_behind(self, dead: Command, summary: str) -> None:
        """The oldest command got no answer for its whole timeout: fail everything behind it at once.

        Commands never written are dropped, so a printer that wakes up later does not run a backlog nobody waits
        for. If the printer has been silent all that time, commands already written fail too: they stay in the
        FIFO (their late `ok`s must land on them, not on a newer command), but their callers are told now instead
        of one timeout after another.
        """
        last_in = self.trace.last_received
        silent = last_in is None or self._now - last_in.time_s >= dead.timeout_s
        for command in self._in_flight if silent else ():
            if not command.orphan and command.job is None and not command.probe:
                command.orphan = True
                self._finish(
                    command, CommandTimeoutError(f"gave up behind {dead.text!r}: {summary}", command=command.text)
                )
        keep: deque[Command] = deque()
        for command in self._queue:
            if command.job is None and not command.probe:
                self._finish(
                    command,
                    CommandTimeoutError(f"not sent: the printer stopped answering ({summary})", command=command.text),
                )
            else:
                keep.append(command)
        self._queue = keep

    def _send_probe(self, now: float) -> None:
        # A probe follows several round trips of silence: no rejection of a line written before the last resend
        # can still be on its way, so whatever the printer asks for next is a fresh request, acted on at once
        # (otherwise a resent line damaged again would be taken for stale, and so would the probe after it).
        self._stale = 0
        self.probes += 1
        self._next_id += 1
        probe = Command(self._next_id, "M105", "M105", True, self.stream_timeout_s, now, probe=True)
        self._probe = probe
        # Behind any lines waiting to be written again (their numbers come first), ahead of everything new.
        at = 0
        while at < len(self._queue) and self._queue[at].wire:
            at += 1
        self._queue.insert(at, probe)

    def _stall_job(self, head: Command, now: float) -> None:
        """The stream got no answer within the timeout: end the print with a diagnosis, drop its lines."""
        job = self.job or head.job
        summary = self.describe_stall(head, now)
        where = f"line {head.source_line} of {job.name}" if head.job is not None and job else "a probe"
        message = f"print stalled at {where}: {summary}"
        error = PrintStalledError(message, command=head.text, trace=self.trace.format(now))
        if job is not None:
            job.fail(error, now)
        self.job = None
        self._job_next = None
        self._probe = None
        # The stream's lines will not be answered (the printer is silent): take them out so the FIFO stays true
        # for whatever the user sends next.
        keep = deque(c for c in self._in_flight if c.job is None and not c.probe)
        self._in_flight = keep
        self._in_flight_bytes = sum(len(c.wire) for c in keep)
        self._queue = deque(c for c in self._queue if c.job is None and not c.probe)
        if keep:
            keep[0].head_since_s = now

    def _job_error(self, error: MarlinError) -> MarlinError:
        job = self.job
        if job is None:
            return error
        where = f"{job.name}, after line {job.last_source_line} ({job.lines_acked} commands acknowledged)"
        return type(error)(f"{error} [print stopped: {where}]") if type(error) in _PLAIN_ERRORS else error

    def describe_stall(self, command: Command, now: float) -> str:
        """One line saying who waits for whom: the command, for how long, and what each side last said."""
        waited = now - (command.submitted_s if command.head_since_s is None else command.head_since_s)
        parts = [f"no 'ok' for {command.text!r} after {waited:.1f} s"]
        if command.line_number is not None:
            parts[0] += f" (line {command.line_number})"
        behind = len(self._in_flight) - 1 + len(self._queue)
        if behind:
            parts.append(f"{behind} more command{'s' if behind != 1 else ''} waiting behind it")
        last_in = self.trace.last_received
        last_out = self.trace.last_sent
        if last_out is not None:
            parts.append(f"last sent {last_out.text!r} {now - last_out.time_s:.1f} s ago")
        if last_in is None:
            parts.append("nothing ever received: the printer is silent (wrong port or baud rate?)")
        else:
            silent = now - last_in.time_s
            parts.append(f"last received {last_in.text!r} {silent:.1f} s ago")
            if silent >= command.timeout_s:
                parts.append("the printer has been silent since")
            else:
                parts.append("the printer is talking but did not answer this command")
        return "; ".join(parts)

    # ----------------------------------------------------------------------------------------------- results

    def _finish(self, command: Command, outcome: Reply | MarlinError) -> None:
        if isinstance(outcome, Reply):
            self.answered += 1
        else:
            self.failed += 1
        self._results.append((command, outcome))

    def stats(self) -> LinkStats:
        """A frozen snapshot of the counters."""
        return LinkStats(
            submitted=self._submitted,
            answered=self.answered,
            failed=self.failed,
            cancelled=self.cancelled,
            in_flight=len(self._in_flight),
            queued=len(self._queue),
            timeouts=self.timeouts,
            resend_requests=self.resend_requests,
            resets=self.resets,
            lost_oks=self.lost_oks,
            stray_oks=self.stray_oks,
            garbage_lines=self.garbage_lines,
            probes=self.probes,
            fragments=self.fragments,
            fragments_run=self.fragments_run,
            bytes_received=self.bytes_received,
        )

    @property
    def submitted(self) -> int:
        """How many commands were accepted by `submit()` in all."""
        return self._submitted

    def take_results(self) -> list[tuple[Command, Reply | MarlinError]]:
        """Return and forget the commands finished since the last call, with their reply or error."""
        results, self._results = self._results, []
        return results

    @property
    def has_data_to_send(self) -> bool:
        """True when `data_to_send()` may return something (a queued command or a print job to feed)."""
        return bool(self._queue) or self.job is not None

    @property
    def probe_reserve_bytes(self) -> int:
        """Bytes of the receive buffer kept free while a job streams, so a probe or a user command always fits.

        "N<line> M105*<checksum>\\n" is 11 bytes plus the digits of the line number.
        """
        return 11 + len(str(self._next_line))

    @property
    def in_flight(self) -> int:
        """How many commands were written and wait for their `ok`."""
        return len(self._in_flight)

    @property
    def queued(self) -> int:
        """How many accepted commands wait to be written."""
        return len(self._queue)

    def oldest_waiting(self) -> Command | None:
        """The command the printer should answer next, if any."""
        return self._in_flight[0] if self._in_flight else None
