"""The sans-I/O connection: commands in, bytes out, bytes in, answers out; deadlines, halts and resets.

Marlin answers every command it processes with exactly one `ok`, in the order it received them. The connection
keeps the commands written but not yet answered in a FIFO and completes the oldest one each `ok` can answer. Its
rooms, each in its own module:

- `marlin_aio.matching`: the FIFO, which command an `ok` answers and whose reply lines are whose (and why a reply
  handed to a caller is always its own);
- `marlin_aio.resends`: line numbers, the history of lines sent, `Resend:` recovery, and the cut lines a flush
  leaves (and why a print line runs exactly once, in order);
- `marlin_aio.streaming`: a print job fed line by line, its round trips and probes;
- `marlin_aio.linkstate`: READY, LOCKED, STOPPED, HALTED as one value;
- this module: the `Connection` that ties them together, dispatches each received line, and keeps the deadlines.

A command that gets no `ok` at all (Marlin's `M105 T9` prints an error and nothing more) times out; it keeps its
place for one more timeout, so its late ok lands on it and not on the next caller's command, and everything queued
behind it fails at once. A print line unanswered for the whole timeout, with no busy keepalive, stalls the print
with a diagnosis of who waits for whom.

Time never comes from a clock here: every call takes `now` (seconds, monotonic), so tests drive it directly.
Nothing here imports asyncio or serial; `marlin_aio.client` is the thin layer that does I/O.
"""

from __future__ import annotations

import math
from collections import deque

from marlin_aio.commands import MAX_COMMAND_BYTES, command_code, encode_command, validate_command
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
from marlin_aio.matching import InFlight, answer_stays_distinct, attribute, match_ok
from marlin_aio.parsing import EventParser
from marlin_aio.printjob import PrintJob
from marlin_aio.replies import MAX_REPLY_LINES, Command, Reply, is_noise
from marlin_aio.resends import CALM_LINES, Resends
from marlin_aio.stats import LinkStats
from marlin_aio.streaming import JobFeed
from marlin_aio.trace import Trace

__all__ = ["CALM_LINES", "MAX_REPLY_LINES", "Command", "Connection", "Reply"]

#: Commands that wait for heaters; every temperature report while they run shows the printer is alive.
_HEATER_WAITS = frozenset({"M109", "M190", "M191"})

#: Commands Marlin's emergency parser acts on as soon as their bytes arrive; they skip the queue here too.
EMERGENCY_COMMANDS = frozenset({"M108", "M112", "M410", "M876"})

#: Reply-line events a command collects while it is the oldest waiting.
_REPLY_LINES = (UnrecognisedLine, EchoMessage, FirmwareInfo, Capability)


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
        self.numbered = numbered
        self.max_in_flight = max_in_flight
        self.rx_buffer_bytes = rx_buffer_bytes
        self.set_window(max_in_flight, rx_buffer_bytes)
        self.trace = Trace(trace_size)
        self._parser = EventParser()
        self._resends = Resends(
            max_resends=max_resends, ok_after_resend=ok_after_resend, resend_timeout_s=resend_timeout_s
        )
        self._feed = JobFeed()
        self._queue: deque[Command] = deque()  # accepted, not yet written
        self._in_flight = InFlight()  # written, waiting for an ok, in the order they were written
        self._results: list[tuple[Command, Reply | MarlinError]] = []
        self._now = 0.0  # the latest time any call was given, for results that happen as a side effect
        self._next_id = 0
        self._exact_oks = advanced_ok  # the printer names lines in its oks (ADVANCED_OK): plain oks identify themselves
        self._thermal_message: str | None = None
        self._halt: PrinterHaltedError | None = None  # why the printer halted or stopped; raised to new commands
        self._stopped = False  # the halt is a stop() that M999 clears (ErrorKind.STOPPED), not a kill()
        self._locked = False  # the printer said "Printer locked!" and has not run a command since
        self.requires_numbers = False  # the printer refused an unnumbered command ("Missing checksum")
        # Counters (read them through `stats()`). Every submitted command ends up counted once: answered + failed
        # + cancelled + still queued or in flight.
        self._submitted = self._answered = self._failed = self._cancelled = 0
        self._timeouts = self._resets = self._stray_oks = self._lost_oks = self._garbage_lines = 0
        self._bytes_received = 0

    # ----------------------------------------------------------------------------------------------- state

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
    def job(self) -> PrintJob | None:
        """The print job being streamed, if any."""
        return self._feed.job

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

    def stats(self) -> LinkStats:
        """A frozen snapshot of the counters."""
        return LinkStats(
            submitted=self._submitted,
            answered=self._answered,
            failed=self._failed,
            cancelled=self._cancelled,
            in_flight=len(self._in_flight),
            queued=len(self._queue),
            timeouts=self._timeouts,
            resend_requests=self._resends.requests,
            resets=self._resets,
            lost_oks=self._lost_oks,
            stray_oks=self._stray_oks,
            garbage_lines=self._garbage_lines,
            probes=self._feed.probes,
            fragments=self._resends.fragments,
            fragments_run=self._resends.fragments_run,
            bytes_received=self._bytes_received,
        )

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
        return self._in_flight.head

    @property
    def probe_reserve_bytes(self) -> int:
        """Bytes of the receive buffer kept free while a job streams, so a probe or a user command always fits.

        "N<line> M105*<checksum>\\n" is 11 bytes plus the digits of the line number.
        """
        return 11 + len(str(self._resends.next_line))

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
        if checked:
            # Validate now, so a bad command never reaches the queue: as given (the clearest message), then its
            # length with a line number comfortably larger than any it can get while queued.
            text = validate_command(text)
            if use_numbers:
                longest_number = self._resends.next_line + len(self._queue) + len(self._in_flight) + 1000
                if len(text) + len(str(longest_number)) + 6 > MAX_COMMAND_BYTES:
                    raise ValueError(
                        f"command {text[:40]!r}... is too long: with its line number and checksum it would exceed "
                        f"Marlin's {MAX_COMMAND_BYTES}-byte limit"
                    )
            if timeout_s <= 0:
                raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        code = command_code(text)
        if self._halt is not None and code != "M999":
            raise self._halt
        self._submitted += 1
        command = Command(self._new_id(), text, code, use_numbers, timeout_s, now)
        self._queue.append(command)
        return command

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id

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

    def attach(self, job: PrintJob, *, timeout_s: float) -> None:
        """Stream `job`'s lines from now on, interleaved with submitted commands (which go first).

        Raises:
            RuntimeError: another job is still running.
        """
        self._feed.attach(job, timeout_s)

    def cancel(self, command: Command) -> bool:
        """Withdraw a command whose caller gave up; return True if it was never written (so it never will be).

        A command already written stays in the FIFO, as the printer will still answer it; only its result is dropped.
        """
        if command.sends == 0:
            try:
                self._queue.remove(command)
            except ValueError:
                return False
            self._cancelled += 1
            return True
        command.orphan = True
        return False

    def fail_all(self, error: MarlinError) -> None:
        """Fail every queued and in-flight command with `error` (the link is gone, or the client closes)."""
        self._fail_everything(error)

    # ----------------------------------------------------------------------------------------------- sending

    @property
    def has_data_to_send(self) -> bool:
        """True when `data_to_send()` may return something (a queued command or a print job to feed)."""
        return bool(self._queue) or self._feed.job is not None

    def data_to_send(self, now: float) -> bytes:
        """Return the bytes to write now: resends first, then queued commands, then print job lines, as far as the
        window allows."""
        self._now = now
        resends = self._resends
        if resends.drain_over(now):
            return b""
        chunks: list[bytes] = []
        feed = self._feed
        flight = self._in_flight
        # While a job streams, keep room in the printer's buffer for a probe or a user command to get in.
        limit = self.rx_buffer_bytes - (self.probe_reserve_bytes if feed.job is not None else 0)
        calm = resends.calm
        while True:
            if self._queue:
                command = self._queue[0]
            else:
                job_command = feed.next_command(self._new_id, self.numbered, now)
                if job_command is None:
                    break
                command = job_command
            # After a probe deadline, the lines waiting to be resent and the probe behind them go out together.
            nudge = resends.nudge_pending and (bool(command.wire) or command.probe)
            if not nudge:
                resends.nudge_pending = False
            if flight and (
                (len(flight) >= self.max_in_flight and not command.probe)
                or (calm and not (command.probe or nudge) and resends.rejectable(flight))
                or flight.bytes + resends.wire_size(command) > (self.rx_buffer_bytes if command.probe else limit)
                or not answer_stays_distinct(command, flight, exact_oks=self._exact_oks)
            ):
                break
            if command is feed.next:
                feed.next = None
            else:
                self._queue.popleft()
            if not command.wire:
                if resends.wire_size(command) - 1 > MAX_COMMAND_BYTES:
                    # Only possible if the line numbers grew by over a thousand while it waited in the queue.
                    self._finish(command, MarlinError(f"{command.text!r} grew too long for Marlin once numbered"))
                    continue
                # Keep enough history for everything that can be in flight, with a wide margin.
                resends.assign_wire(command, max(256, 4 * self.max_in_flight))
            if command.job is not None and command.sends == 0:
                command.job.sent()
            command.sends += 1
            if command.sent_s is None:
                command.sent_s = now
            command.written_s = now
            flight.append(command, now)
            self.trace.sent(now, command.wire.decode("ascii").rstrip("\n"))
            chunks.append(command.wire)
        return b"".join(chunks)

    # ----------------------------------------------------------------------------------------------- receiving

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        """Feed bytes read from the printer; return the events of the lines they complete.

        Results (answered and failed commands) collect in `take_results()`; call `data_to_send()` afterwards,
        as an answer may open the window for more.
        """
        self._now = now
        self._bytes_received += len(data)
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
        # An ok leaves the "last line was a line error" mark alone: only other lines are between an error and
        # its `Resend:`.
        is_line_error = None if type(event) is Ok else isinstance(event, ErrorMessage) and event.kind is ErrorKind.LINE
        after_line_error = self._resends.note_line(is_line_error, now, self._feed.quiet_s())
        head = self._in_flight.head
        match event:
            case Ok():
                self._on_ok(event, now)
            case BusyKeepalive():
                if head is not None:
                    head.alive_s = now  # the printer is alive and working on the oldest command
            case TemperatureReport() if event.temperatures.waiting or (head is not None and head.code in _HEATER_WAITS):
                # Marlin marks its wait lines with W:; other firmwares send plain reports while M109/M190 wait.
                if head is not None:
                    head.alive_s = now
            case ResendRequest():
                self._check(
                    self._resends.on_request(
                        event.line_number,
                        self._in_flight,
                        self._queue,
                        now,
                        rejected=after_line_error,
                        quiet_s=self._feed.quiet_s(),
                    )
                )
            case ErrorMessage():
                self._on_error(event, now)
            case Start():
                self._on_start()
            case OverlongLine():
                self._garbage_lines += 1  # noise from the link (a baud glitch, a reset) is nobody's reply
            case UnrecognisedLine() if is_noise(text):
                self._garbage_lines += 1
            case UnknownCommand() if self._resends.is_fragment(event.command):
                # The tail of a line cut in two by a flush, which the firmware read as a command of its own and
                # refused: its ok answers nothing.
                self._resends.fragment_refused()
            case PrinterLocked() | UnknownCommand():
                if head is not None:
                    head.add_line(text)
                    if isinstance(event, PrinterLocked):
                        # The ok that follows answers a command that was refused, not run.
                        head.refusal = text
                        self._locked = True
                    elif head.job is not None:
                        head.refusal = text  # a print line the firmware did not understand was not printed
            case _ if head is not None and isinstance(event, _REPLY_LINES):
                head.add_line(text)

    def _on_ok(self, ok: Ok, now: float) -> None:
        if self._resends.take_ok():
            return
        # Which in-flight command does this ok answer? The oldest one whose answer can look like it; every command
        # ahead of that one was processed (Marlin answers in order) but its own ok was lost.
        index = match_ok(self._in_flight, ok, exact_oks=self._exact_oks) if self._in_flight else None
        if index is None:
            self._stray_oks += 1
            if self._resends.draining and ok.temperatures is None:
                self._fragment_ran(now)
            return
        if ok.line_number is not None:
            self._exact_oks = True
        skipped = [self._in_flight.popleft(now) for _ in range(index)]
        command = self._in_flight.popleft(now)
        lines = attribute(skipped, command)
        for lost in skipped:
            self._lost_oks += 1
            self._settle(lost, None, None, now)
        self._settle(command, ok, lines, now)

    def _settle(self, command: Command, ok: Ok | None, lines: tuple[str, ...] | None, now: float) -> None:
        """Finish one command taken off the FIFO: answered by `ok`, or (ok None) processed with its ok lost."""
        refused = command.refusal is not None and not command.orphan and not command.probe
        self._resends.settled(command, answered_line=ok is not None and command.job is not None and not refused)
        if command.code == "M999" and self._stopped:
            # stop() (unlike kill()) leaves Marlin running; M999 resumes it.
            self._halt = None
            self._stopped = False
        if command.refusal is None and self._locked and not command.orphan and command.code != "M511":
            self._locked = False  # a command ran normally: the printer was unlocked (M511 or its screen)
        if refused:
            self._refused(command, now)
        elif command.job is not None:
            # A print line needs no reply: a later answer proves it ran, whether its own ok came or not.
            if ok is not None:
                self._feed.answered(command, now)
            command.job.acked(len(command.wire), command.source_bytes, command.source_line, now)
        elif command.probe:
            self._feed.probe = None
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
            self._stop_job(type(error)(f"print stopped at {where}: {error}"), now)
            return
        self._finish(command, error)

    def _fragment_ran(self, now: float) -> None:
        """An ok that no command earned arrived after a flush: the tail of a cut line ran as a command of its own."""
        self._resends.fragments_run += 1
        job = self._feed.job
        if job is None or not job.active:
            return
        pieces = ", ".join(repr(text) for _, text in self._resends.fragment_wires[:3])
        message = (
            f"print stopped after line {job.last_source_line} of {job.name}: after a line error the printer threw "
            "away its receive buffer in the middle of a line and ran the rest of it as a command of its own (an ok "
            f"that no command earned; the line was one of {pieces}), so a line ran out of place; "
            "send-ahead cannot rule this out on this link: print with send_ahead=False (ping-pong)"
        )
        self._stop_job(RemoteProtocolError(message), now)

    def _stop_job(self, error: MarlinError, now: float) -> None:
        """End the print with `error`; lines already written stay in the FIFO as orphans (their oks are still
        due), unwritten ones go."""
        job = self._feed.job
        if job is not None:
            job.fail(error, now)
        self._feed.job = None
        self._feed.next = None
        for command in self._in_flight:
            if command.job is not None:
                command.orphan = True
        kept = [c for c in self._queue if c.job is None]
        self._queue.clear()
        self._queue.extend(kept)

    def _on_error(self, event: ErrorMessage, now: float) -> None:
        head = self._in_flight.head
        match event.kind:
            case ErrorKind.THERMAL:
                self._thermal_message = event.message
                self._halt_with(ThermalRunawayError(f"thermal protection tripped: {event.message}"), stopped=False)
            case ErrorKind.HALTED | ErrorKind.STOPPED if self._thermal_message is not None:
                message = f"thermal protection tripped: {self._thermal_message} ({event.message})"
                self._halt_with(ThermalRunawayError(message), stopped=False)
            case ErrorKind.HALTED | ErrorKind.STOPPED:
                halted = PrinterHaltedError(f"the printer halted: {event.message}")
                self._halt_with(halted, stopped=event.kind is ErrorKind.STOPPED)
            case ErrorKind.NOT_EXECUTED if head is not None:
                head.add_line(f"!! {event.message}")
                head.refusal = f"!! {event.message}"
            case ErrorKind.CHECKSUM_REQUIRED:
                self._on_checksum_required(event.message, now)
            case ErrorKind.OTHER if head is not None:
                head.add_line(f"Error:{event.message}")

    def _on_checksum_required(self, message: str, now: float) -> None:
        # The firmware ran nothing and will send no ok for the oldest unnumbered command: fail it now, and number
        # every command from here on.
        self.requires_numbers = True
        command = next((c for c in self._in_flight if c.line_number is None), None)
        if command is None:
            return
        self._in_flight.remove(command, now)
        if not command.orphan and command.job is None and not command.probe:
            error = ChecksumRequiredError(
                f"the printer refused {command.text!r} without a line number and checksum "
                f"('Error:{message}'); it needs numbered commands"
            )
            self._finish(command, error)

    def _halt_with(self, error: PrinterHaltedError, *, stopped: bool) -> None:
        """The printer halted (`stopped`: a stop() that M999 clears; otherwise it needs a reset)."""
        if self._halt is None or isinstance(error, ThermalRunawayError):
            self._halt = error
        # A second line about the same halt: a kill() after a stop() is final, and a stop() never softens a kill().
        self._stopped = stopped if self._halt is error else self._stopped and stopped
        self._fail_everything(self._halt)

    def _on_start(self) -> None:
        self._resets += 1
        # The board rebooted: it forgot every command and its line counter. Nothing is replayed into it.
        self._fail_everything(PrinterResetError("the printer reset (it printed 'start'); commands in flight were lost"))
        self._halt = None
        self._stopped = False
        self._locked = False
        self._thermal_message = None
        self._resends.restart_numbering()

    def _fail_everything(self, error: MarlinError) -> None:
        feed = self._feed
        if feed.job is not None:
            # Nothing is replayed into a board that reset or halted: the print ends here, at the line it reached.
            feed.job.fail(feed.job_error(error), self._now)
        feed.detach()
        for command in (*self._in_flight, *self._queue):
            if not command.orphan and command.job is None and not command.probe:
                self._finish(command, error)
        self._in_flight.clear()
        self._queue.clear()
        self._resends.clear()

    def _check(self, error: MarlinError | None) -> None:
        if error is not None:
            self._fail_everything(error)

    # ----------------------------------------------------------------------------------------------- time

    def next_deadline(self) -> float | None:
        """When the oldest command in flight times out (or a stalled stream is probed) unless the printer shows a
        sign of life first."""
        drain_until = self._resends.drain_until
        head = self._in_flight.head
        if head is None:
            return drain_until
        due = min(self._deadlines(head))
        return due if drain_until is None else min(due, drain_until)

    def _deadlines(self, head: Command) -> tuple[float, float, float]:
        """(time out, write again, probe) for the oldest command; inf where that step does not apply."""
        start = max(head.head_since_s or 0.0, head.alive_s or 0.0)
        resends = self._resends
        resend_at = start + min(head.timeout_s, resends.resend_timeout_s) if resends.resending(head) else math.inf
        feed = self._feed
        # Only while a job streams: outside prints a probe M105 could answer a user's own M105 (say M105 T9).
        may_probe = feed.active and feed.probe is None and self.numbered and not resends.draining
        probe_at = max(start, feed.probed_s) + feed.probe_delay_s() if may_probe else math.inf
        return start + head.timeout_s, resend_at, probe_at

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost (see `JobFeed`)."""
        return self._feed.probe_delay_s()

    def check_timeouts(self, now: float) -> None:
        """Time out the oldest command if its deadline has passed; the commands behind it go on.

        While a job streams, a line that waits too long first gets a probe (a numbered M105: its `ok T:` proves
        every older line was processed, so a lost `ok` costs a moment, not the print). A line that still gets no
        answer within the timeout, with no busy keepalive, stalls the print: the job fails with a diagnosis.
        """
        self._now = now
        resends = self._resends
        resends.drain_over(now)
        while (head := self._in_flight.head) is not None:
            deadline = self.next_deadline()
            if deadline is None or now < deadline:
                return
            timeout_at, resend_at, probe_at = self._deadlines(head)
            last_in = self.trace.last_received
            talking = last_in is not None and last_in.time_s > (head.head_since_s or 0.0)
            if now >= resend_at and head.line_number is not None and talking:
                # A resent line went unanswered while the printer talked: its rejection was probably taken for a
                # stale one. (A silent printer is not helped by resends: it times out below.)
                self._check(resends.resend_overdue(head, self._in_flight, self._queue, now, self._feed.quiet_s()))
                continue
            if now < timeout_at:
                if now >= probe_at:
                    self._probe(now)
                return
            # No stale rejection can still be on its way after this much silence.
            resends.forget_stale()
            self._timeouts += 1
            if head.job is not None or head.probe:
                self._stall_job(head, now)
                continue
            if head.orphan:
                # Its caller was told already (it timed out behind another command, or gave up): drop it quietly.
                self._in_flight.popleft(now)
                continue
            summary = self.describe_stall(head, now)
            # Its caller is told now, but the command keeps its place for one more timeout (quarantine): Marlin may
            # still answer it (a long G28), and that late ok must land on it, not on the next caller's command,
            # which waits (see `answer_stays_distinct`). Only then is its place given up.
            head.orphan = True
            head.head_since_s = now
            head.alive_s = None
            self._finish(head, CommandTimeoutError(summary, command=head.text))
            self._give_up_behind(head, summary)
            return

    def _probe(self, now: float) -> None:
        self._feed.probed_s = now
        if self._queue and self._queue[0].wire:
            # Lines wait to be written again, one at a time, behind this one, whose ok may be lost. With plain oks
            # only an M105's `ok T:` can prove that, so the probe goes behind those lines (its number comes after
            # theirs) and they all go out now. One at a time (ping-pong) the next of them is the probe.
            if self.max_in_flight > 1:
                at = 0
                while at < len(self._queue) and self._queue[at].wire:
                    at += 1
                self._resends.forget_stale()
                self._queue.insert(at, self._feed.new_probe(self._new_id(), now))
            self._resends.nudge_pending = True
            return
        # A probe follows several round trips of silence: no rejection of a line written before the last resend
        # can still be on its way, so whatever the printer asks for next is a fresh request, acted on at once.
        self._resends.forget_stale()
        self._queue.appendleft(self._feed.new_probe(self._new_id(), now))

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
        kept: list[Command] = []
        for command in self._queue:
            if command.job is None and not command.probe:
                error = CommandTimeoutError(
                    f"not sent: the printer stopped answering ({summary})", command=command.text
                )
                self._finish(command, error)
            else:
                kept.append(command)
        self._queue.clear()
        self._queue.extend(kept)

    def _stall_job(self, head: Command, now: float) -> None:
        """The stream got no answer within the timeout: end the print with a diagnosis, drop its lines."""
        feed = self._feed
        job = feed.job or head.job
        summary = self.describe_stall(head, now)
        where = f"line {head.source_line} of {job.name}" if head.job is not None and job else "a probe"
        error = PrintStalledError(
            f"print stalled at {where}: {summary}", command=head.text, trace=self.trace.format(now)
        )
        if job is not None:
            job.fail(error, now)
        feed.detach()
        # The stream's lines will not be answered (the printer is silent): take them out so the FIFO stays true
        # for whatever the user sends next.
        self._in_flight.keep_only((c for c in self._in_flight if c.job is None and not c.probe), now, restart_head=True)
        kept = [c for c in self._queue if c.job is None and not c.probe]
        self._queue.clear()
        self._queue.extend(kept)

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
            self._answered += 1
        else:
            self._failed += 1
        self._results.append((command, outcome))

    def take_results(self) -> list[tuple[Command, Reply | MarlinError]]:
        """Return and forget the commands finished since the last call, with their reply or error."""
        results, self._results = self._results, []
        return results
