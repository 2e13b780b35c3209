"""The sans-I/O connection: commands in, bytes out, bytes in, answers out; deadlines, halts and resets.

Marlin answers every command it processes with exactly one `ok`, in the order it received them. The connection
keeps the commands written but not yet answered in a FIFO and completes the oldest one each `ok` can answer. It is
split by ownership, as h11 keeps its state machine apart from its framing: each part owns its fields, and the
others change them only through its verbs (`python -m benchmarks.core_shape` counts the writes into another
part's fields: none), so one `ok` crosses six files of the core:

- `wire`: the byte stream, framed into lines, read into events, and recorded in the trace;
- `matching`: the FIFO of commands in flight and each command's record (`Command`): which command an `ok`
  answers, whose reply lines are whose (and why a reply handed to a caller is always its own), and the outcomes;
- `resends`: the line numbers: the history of lines sent, `Resend:` recovery, the cut lines a flush leaves (and
  why a print line runs exactly once, in order), and the link's pace with the probes it times (`Probes`);
- `linkmachine` over `states`: the link's state machine, CONNECTING to LOST, the one owner of its state and of
  the facts its moves read (a halt, the thermal message, numbers required); every move in one table;
- `streaming`: a print job fed line by line;
- `corestate`: the parts held together, with the queue and the counters;
- `receiving`: what each line from the printer means (the dispatch of every received event);
- `deadlines`: what happens when nothing comes (timeouts, probes, stalls, who waits for whom);
- this module: `Connection`, the public face: commands in, bytes out, state and counters. It holds the parts and
  composes `Receiving` and `Deadlines` over them (parts, not base classes), and keeps its own clock.

A command that gets no `ok` at all (Marlin's `M105 T9` prints an error and nothing more) times out; it keeps its
place, in doubt, until the printer settles it (its late ok, or the answer to a probe behind it), so a late ok lands
on it and not on the next caller's command. A print line unanswered for the whole timeout, with no busy keepalive,
stalls the print with a diagnosis of who waits for whom.

Time never comes from a clock here: every call takes `now` (seconds, monotonic), so tests drive it directly.
Nothing here imports asyncio or serial; `marlin_aio.aio.printer` is the thin layer that does I/O.

Over 400 lines because it is the core's whole public face: every call a driver makes (`submit`, `receive`, `tick`,
`attach`, `cancel`, `fail_all`, the emergency stop) and every counter, each with a docstring of what it does and
raises. The logic behind them is in the modules listed above.
"""

from __future__ import annotations

from dataclasses import dataclass

from marlin_aio.errors import (
    MarlinError,
    PrinterHaltedError,
    PrinterLockedError,
)
from marlin_aio.protocol.commands import MAX_COMMAND_BYTES, command_code, encode_command, validate_command
from marlin_aio.protocol.corestate import CoreState
from marlin_aio.protocol.deadlines import Deadlines
from marlin_aio.protocol.events import Event
from marlin_aio.protocol.heaters import DEFAULT_LIMITS, HeaterLimits, check_gcode_targets
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.matching import MAX_REPLY_LINES, Command, answer_stays_distinct
from marlin_aio.protocol.printjob import PrintJob
from marlin_aio.protocol.receiving import Receiving
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.resends import CALM_LINES, wanted
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.states import LineEvent, LineState, LinkEvent
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.wire import BARE_LINE_END, Trace

__all__ = ["CALM_LINES", "MAX_REPLY_LINES", "Command", "Connection", "Output", "Reply"]

#: Commands Marlin's emergency parser acts on as soon as their bytes arrive; they skip the queue here too.
EMERGENCY_COMMANDS = frozenset({"M108", "M112", "M410", "M876"})

#: How long an emergency command's `ok` may be missing once everything ahead of it was answered (Marlin answers
#: the no-op at once when its turn comes) before a probe asks whether it was thrown away or lost.
EMERGENCY_TIMEOUT_S = 2.0


@dataclass(slots=True)
class Output:
    """Everything one step of the core produced, in one place (`Connection.receive` and `Connection.tick`).

    A value to read, not to change. Not frozen, only because a frozen dataclass takes four times as long to build
    and two are built for every poll.

    The I/O layer handles it in this order: hand on `events`, write `data`, resolve `finished`, and call
    `tick()` again at `deadline` (None: nothing to wait for).
    """

    events: tuple[Event, ...]
    """The events of the lines the bytes completed (none for a tick)."""
    data: bytes
    """Bytes to write to the printer now."""
    finished: tuple[tuple[Command, Reply | MarlinError], ...]
    """Commands that ended, each with its reply or error."""
    deadline: float | None
    """When to call `tick()` next, unless bytes arrive first."""


class Connection:
    """Bookkeeping for one link to a Marlin printer, with no I/O.

    Use by an I/O layer: `submit()` commands, then `tick(now)`; feed the bytes read to `receive(data, now)`; and
    call `tick(now)` again at the `deadline` of the last `Output`. Each call returns one `Output` with everything
    it produced. (The steps it bundles, `receive_data`, `data_to_send`, `check_timeouts`, `take_results` and
    `next_deadline`, stay public for tests that drive the core step by step.)

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
        connecting: start CONNECTING, for a client that runs a handshake first (`handshake_done` ends it); else
            READY.
    """

    __slots__ = ("_after_command", "_core", "_deadlines", "_now", "_receiving", "limits")

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
        limits: HeaterLimits = DEFAULT_LIMITS,
        connecting: bool = False,
    ) -> None:
        """A connection that has sent nothing yet.

        Raises:
            ValueError: `max_in_flight` below 1 or `rx_buffer_bytes` below 16.
        """
        # One state record, and the parts that act on it: what each line from the printer means, and what happens
        # when nothing comes. (Composed, not inherited: each part is read on its own, over the same state.)
        self._core = CoreState(
            numbered=numbered,
            max_in_flight=max_in_flight,
            rx_buffer_bytes=rx_buffer_bytes,
            trace_size=trace_size,
            max_resends=max_resends,
            resend_timeout_s=resend_timeout_s,
            ok_after_resend=ok_after_resend,
            advanced_ok=advanced_ok,
            connecting=connecting,
        )
        self._receiving = Receiving(self._core)
        self._deadlines = Deadlines(self._core)
        self._now = 0.0  # the latest time any call was given (`fail_all` takes none)
        self._after_command = False  # the last command written was a user's, written for the first time
        # The one gate for heater targets: every command submitted and every line of every print passes it, read
        # as the firmware reads it (`heaters.check_gcode_targets`), whatever API or CLI command made it.
        self.limits = limits

    @property
    def trace(self) -> Trace:
        """The last lines sent and received, with their times (for diagnosing a stall)."""
        return self._core.trace

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        """Feed bytes read from the printer; return the events of the lines they complete (see `receive`)."""
        self._now = now
        return self._receiving.receive_data(data, now)

    def discard_partial_input(self) -> None:
        """Forget an unfinished line (call after flushing the port's input: its end will never arrive)."""
        self._receiving.discard_partial_input()

    def check_timeouts(self, now: float) -> None:
        """Act on the deadlines that have passed (timeouts, probes, stalls; see `deadlines`)."""
        self._now = now
        self._deadlines.check_timeouts(now)

    def next_deadline(self) -> float | None:
        """When `check_timeouts` must next be called, unless bytes arrive first; None: nothing to wait for."""
        return self._deadlines.next_deadline()

    def describe_stall(self, command: Command, now: float) -> str:
        """One line saying who waits for whom: the command, for how long, and what each side last said."""
        return self._deadlines.describe_stall(command, now)

    def probe_delay_s(self) -> float:
        """How long a streamed line may wait before a probe asks whether its `ok` was lost."""
        return self._deadlines.probe_delay_s()

    # ----------------------------------------------------------------------------------------------- state

    @property
    def state(self) -> LinkState:
        """READY, PRINTING, STOPPING (a stopped print's last lines are answered), LOCKED (refusing commands until
        unlocked), STOPPED (M999 resumes) or HALTED (needs a reset): one value, moved by `states`."""
        return self._core.link.state

    @property
    def halted(self) -> PrinterHaltedError | None:
        """Why the printer halted or stopped (the error new commands fail with), or None while it runs."""
        return self._core.link.halt

    @property
    def locked(self) -> bool:
        """True while the printer refuses commands as locked (PASSWORD_FEATURE)."""
        return self._core.link.state is LinkState.LOCKED

    @property
    def job(self) -> PrintJob | None:
        """The print job being streamed, if any."""
        return self._core.feed.job

    @property
    def numbered(self) -> bool:
        """Commands get a line number and checksum unless submitted with `numbered=False`."""
        return self._core.numbered

    @property
    def requires_numbers(self) -> bool:
        """The printer refused an unnumbered command (`Missing checksum`): every command is numbered now."""
        return self._core.link.requires_numbers

    @property
    def max_in_flight(self) -> int:
        """How many commands may be written before their `ok` (1 is ping-pong)."""
        return self._core.max_in_flight

    @property
    def rx_buffer_bytes(self) -> int:
        """The printer's receive buffer: unanswered bytes never exceed it."""
        return self._core.rx_buffer_bytes

    @property
    def window(self) -> tuple[int, int]:
        """(max_in_flight, rx_buffer_bytes): how many commands and unanswered bytes may be on the wire."""
        return self._core.max_in_flight, self._core.rx_buffer_bytes

    def set_window(self, max_in_flight: int, rx_buffer_bytes: int) -> None:
        """Change how many commands and unanswered bytes may be on the wire (a print's send-ahead, a benchmark);
        what is already in flight stays.

        Raises:
            ValueError: `max_in_flight` below 1 or `rx_buffer_bytes` below 16.
        """
        self._core.set_window(max_in_flight, rx_buffer_bytes)

    def stats(self) -> LinkStats:
        """A frozen snapshot of the counters."""
        core = self._core
        return LinkStats(
            submitted=core.submitted,
            answered=core.in_flight.answered,
            failed=core.in_flight.failed,
            cancelled=core.cancelled,
            in_flight=len(core.in_flight),
            queued=len(core.queue),
            timeouts=core.timeouts,
            resend_requests=core.resends.requests,
            resets=core.resets,
            lost_oks=core.lost_oks,
            stray_oks=core.stray_oks,
            garbage_lines=core.parser.garbage_lines,
            probes=core.probes.sent,
            fragments=core.resends.fragments,
            fragments_run=core.resends.fragments_run,
            bytes_received=core.parser.bytes_received,
        )

    @property
    def in_flight(self) -> int:
        """How many commands were written and wait for their `ok`."""
        return len(self._core.in_flight)

    @property
    def queued(self) -> int:
        """How many accepted commands wait to be written."""
        return len(self._core.queue)

    def oldest_waiting(self) -> Command | None:
        """The command the printer should answer next, if any."""
        return self._core.in_flight.head

    @property
    def probe_reserve_bytes(self) -> int:
        """Bytes of the receive buffer kept free while a job streams, so a probe or a user command always fits.

        "N<line> M105*<checksum>\\n" is 11 bytes plus the digits of the line number.
        """
        return 11 + len(str(self._core.resends.next_line))

    # ----------------------------------------------------------------------------------------------- commands

    def submit(
        self, text: str, *, timeout_s: float, now: float, numbered: bool | None = None, checked: bool = True
    ) -> Command:
        """Accept a command for sending; it goes out in order with the others.

        `checked=False` skips validation, for commands the caller built itself and knows to be valid (the client's
        own M105 polls, a hundred times a second).

        Raises:
            ValueError: the command is not valid (line break, non-ASCII, too long, empty), or it sets a heater
                target above `limits` (however it is spelt).
            PrinterHaltedError: the printer halted and answers nothing until it is reset.
        """
        core = self._core
        use_numbers = (core.numbered if numbered is None else numbered) or core.link.requires_numbers
        if checked:
            # Validate now, so a bad command never reaches the queue: as given (the clearest message), then its
            # length with a line number comfortably larger than any it can get while queued.
            text = validate_command(text)
            check_gcode_targets(text, self.limits)
            if use_numbers:
                longest_number = core.resends.next_line + len(core.queue) + len(core.in_flight) + 1000
                if len(text) + len(str(longest_number)) + 6 > MAX_COMMAND_BYTES:
                    raise ValueError(
                        f"command {redact(text)[:40]!r}... is too long: with its line number and checksum it would "
                        f"exceed Marlin's {MAX_COMMAND_BYTES}-byte limit"
                    )
            if timeout_s <= 0:
                raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        code = command_code(text)
        core.link.refuse(code)
        command = core.accept(text, code, use_numbers, timeout_s, now)
        core.queue.append(command)
        return command

    def submit_and_write(
        self, text: str, *, timeout_s: float, now: float, numbered: bool | None = None, checked: bool = True
    ) -> Command | None:
        """`submit()` and write at once, when nothing else is queued, in flight or streaming: the common case of a
        poll or a caller's command on an idle link. Return the command, its bytes to write now in `command.wire`;
        or None, having accepted nothing, when the link is not idle (then `submit()` and `tick()`).

        The same as `submit()` followed by `tick(now)` on an idle link, which writes that one command and nothing
        else (a property test holds the two to the same bytes, state and results): without the general step's
        loop, its `Output` and its empty results, which a Raspberry Pi pays for a hundred times a second.

        Raises:
            ValueError, PrinterHaltedError: as `submit()`.
        """
        core = self._core
        resends = core.resends
        if (
            core.queue
            or core.in_flight
            or core.link.state is not LinkState.READY
            or core.feed.job is not None
            or core.send_eol
            or core.in_flight.results
            or resends.drain_until is not None
            or resends.held is not None
        ):
            return None
        command = self.submit(text, timeout_s=timeout_s, now=now, numbered=numbered, checked=checked)
        # What `data_to_send` does for the one command of an idle link (no window, barrier or calm can hold back
        # the first command; its length was checked with room for a thousand more line numbers than it gets).
        core.queue.pop()
        self._now = now
        self._after_command = True
        resends.nudge(False)
        resends.assign_wire(command, max(256, 4 * core.max_in_flight))
        command.written(now)
        core.in_flight.append(command, now)
        core.trace.sent(now, command.wire.decode("ascii").rstrip("\n"))
        return command

    def emergency(self, text: str, *, now: float, timeout_s: float = EMERGENCY_TIMEOUT_S) -> bytes:
        """Return the bytes of an emergency command (M112, M108, M410, M876 S<n>) to write at once, ahead of the
        queue.

        It is never numbered: the emergency parser acts on the bare command as its bytes arrive, and it must never be
        written again (its effect already happened). But Marlin still queues the line and answers it with its own
        plain `ok` (ADVANCED_OK: `ok P.. B..`, without `N`), in order with everything else (the captured Marlin 2.1
        session shows it). So M108, M410 and M876 take their place in the FIFO now, behind everything already
        written and ahead of everything still queued, and that `ok` lands on them and on no caller's command.
        Nobody waits for the entry: if the printer threw the line away (with its receive buffer, after a line
        error) or its ok is lost, the answer to a command behind it proves it processed, or, left unanswered at the
        head of the FIFO for `timeout_s`, a probe behind it settles it (`deadlines`). M112 halts the printer: no ok
        comes, and the halt fails everything that was waiting. On a halted printer, or one that refuses unnumbered
        lines (`requires_numbers`: `Error: Missing checksum` and no ok), nothing will answer, so nothing is added.

        Raises:
            ValueError: the command is not one of M108, M112, M410, M876, or is malformed.
        """
        line = encode_command(text)
        code = command_code(text)
        if code not in EMERGENCY_COMMANDS:
            raise ValueError(f"{redact(text)!r} is not an emergency command (M108, M112, M410, M876)")
        core = self._core
        wire = line
        if core.send_eol:
            # A line whose end may have been damaged waits in the printer: end it first, or the emergency parser
            # would not see this command at the start of a line.
            core.want_line_end(False)
            wire = b"\n" + line
            core.trace.sent(now, BARE_LINE_END)
        bare = line.decode("ascii").rstrip("\n")
        if code != "M112" and core.link.state is not LinkState.HALTED and not core.link.requires_numbers:
            # No caller: its answer completes nothing.
            entry = Command(core.new_id(), bare, code, False, timeout_s, now, wire=line, orphan=True, emergency=True)
            entry.written(now)
            core.in_flight.append(entry, now)
            if (
                core.in_flight.emergencies > 1
                and now - core.probes.emergency_probed_s >= timeout_s
                and not any(c.probe for c in (*core.in_flight, *core.queue))
            ):
                # Another is still unanswered. Its ok may have been lost, or its line thrown away: then, with new
                # ones written before each is answered, the head of the FIFO never waits long enough to time out,
                # and callers wait behind entries that no ok will settle. The `ok T:` of a probe behind them all
                # settles those (at most one probe a timeout).
                core.probes.asked(now, emergency=True)
                core.queue.appendleft(core.new_probe(now))
        core.trace.sent(now, bare)
        return wire

    def emergency_stop(self, now: float) -> bytes:
        """Return M112's bytes, to write at once ahead of anything queued; from now on the printer is halted (it
        needs a reset), and every command still waiting fails with `PrinterHaltedError`."""
        core = self._core
        wire = self.emergency("M112", now=now)
        core.fail_everything(core.link.emergency_stopped(), now)
        return wire

    def attach(self, job: PrintJob, *, timeout_s: float) -> None:
        """Stream `job`'s lines from now on, interleaved with submitted commands (which go first).

        Raises:
            RuntimeError: another job is still running.
            PrinterHaltedError: the printer halted or stopped.
            PrinterLockedError: the printer is locked.
        """
        core = self._core
        core.link.refuse("")
        if core.link.state is LinkState.LOCKED:
            raise PrinterLockedError("the printer is locked: unlock it (M511 P<password>) before printing")
        job.limit_by(self.limits)  # a job made without limits gets the connection's: no line passes unchecked
        core.feed.attach(job, timeout_s)
        core.probes.restart()
        core.link.move(LinkEvent.PRINT_STARTED)

    def cancel(self, command: Command) -> bool:
        """Withdraw a command whose caller gave up; return True if it was never written (so it never will be).

        A command already written stays in the FIFO, as the printer will still answer it; only its result is dropped.
        """
        if command.sends == 0:
            try:
                self._core.queue.remove(command)
            except ValueError:
                return False
            command.move(LineEvent.WITHDRAWN)
            self._core.withdrawn()
            return True
        command.give_up()
        return False

    def handshake_done(self) -> None:
        """The client's handshake ended: CONNECTING becomes READY (see `LinkMachine.handshake_done`)."""
        self._core.link.handshake_done()

    def lose(self, error: MarlinError) -> None:
        """The port closed or went away: every command fails with `error`, and the link is LOST for good."""
        self._core.fail_everything(error, self._now)
        self._core.link.port_lost()

    def fail_all(self, error: MarlinError) -> None:
        """Fail every queued and in-flight command with `error` (the link is gone, or the client closes)."""
        self._core.fail_everything(error, self._now)

    # ----------------------------------------------------------------------------------------------- sending

    @property
    def has_data_to_send(self) -> bool:
        """True when `data_to_send()` may return something (a queued command or a print job to feed)."""
        core = self._core
        return bool(core.queue) or core.feed.job is not None or core.send_eol

    def data_to_send(self, now: float) -> bytes:
        """Return the bytes to write now: resends first, then queued commands, then print job lines, as far as the
        window allows."""
        core = self._core
        self._now = now
        resends = core.resends
        if resends.drain_over(now):
            return b""
        if core.feed.job is not None:
            core.feed.job.finish_if_idle(now)  # a cancelled print whose last lines were withdrawn while draining
        held = resends.release_held()
        if held is not None and held.state is LineState.ON_WIRE:
            # The printer has been quiet and the line it asked for again was not answered: it did not run.
            core.in_flight.remove(held, now)
            held.move(LineEvent.RESEND)
            core.queue.appendleft(held if wanted(held) else resends.placeholder_for([held], now))
        chunks: list[bytes] = []
        if core.send_eol:
            core.want_line_end(False)
            chunks.append(b"\n")
            core.trace.sent(now, BARE_LINE_END)
        feed = core.feed
        flight = core.in_flight
        # While a job streams, keep room in the printer's buffer for a probe or a user command to get in.
        limit = core.rx_buffer_bytes - (self.probe_reserve_bytes if feed.job is not None else 0)
        calm = resends.calm
        while True:
            # Commands never written go before the print's next line, but not two in a row while it streams: a
            # flood of commands must not starve the print (nor a print the commands).
            first = core.queue[0] if core.queue else None
            # (A print line in the queue goes again in its place, as a new line: never behind the print's next one.)
            fresh = first is not None and not (first.wire or first.probe or first.orphan or first.job is not None)
            if first is not None and not (fresh and self._after_command and feed.job is not None):
                command = first
            else:
                job_command = feed.next_command(core.new_id, core.numbered, now)
                if job_command is None:
                    if not core.queue:
                        break
                    command = core.queue[0]
                else:
                    command = job_command
            if _unwanted_resend(command):
                # Queued to go again, and its print was cancelled (or stopped) since: nothing of a stopped print runs
                # after the stop, so one placeholder takes the numbers of the run of such lines (client seed 1357:
                # lines 42-44 went again after the cancel and ran, while line 41, held then, got its placeholder).
                unwanted = []
                while core.queue and _unwanted_resend(core.queue[0]):
                    unwanted.append(core.queue.popleft())
                core.queue.appendleft(resends.placeholder_for(unwanted, now))
                continue
            self._after_command = command.job is None and not command.wire
            # After a probe deadline, the lines waiting to be resent and the probe behind them go out together.
            nudge = resends.nudge_pending and (bool(command.wire) or command.probe)
            if not nudge:
                resends.nudge(False)
            if flight and (
                # An M110 goes alone: Marlin sets its counter when it *runs* it, so a line taken in behind it
                # would be counted twice (and a damaged one may be dropped without a word).
                (flight.barriers and not (command.probe and resends.unanswered_m110 is not None))
                or command.code == "M110"
                or (len(flight) - flight.emergencies >= core.max_in_flight and not command.probe)
                or (calm and not (command.probe or nudge) and resends.rejectable(flight))
                or flight.bytes + resends.wire_size(command) > (core.rx_buffer_bytes if command.probe else limit)
                or not answer_stays_distinct(command, flight, exact_oks=core.exact_oks)
            ):
                break
            if command is feed.next:
                feed.took_next()
            else:
                core.queue.popleft()
            if not command.wire:
                if resends.wire_size(command) - 1 > MAX_COMMAND_BYTES:
                    # A command checked with room for its number outgrew it (the numbers grew by over a thousand
                    # while it waited, or a print line unchecked reached a long number). A print line is never
                    # skipped: the print stops at it, saying so.
                    error = MarlinError(f"{redact(command.text)!r} grew too long for Marlin once numbered")
                    if command.job is None:
                        core.in_flight.finish(command, error)
                    else:
                        command.move(LineEvent.WITHDRAWN)
                        core.stop_job(
                            MarlinError(f"print stopped at line {command.source_line} of {command.job.name}: {error}"),
                            now,
                        )
                    continue
                # Keep enough history for everything that can be in flight, with a wide margin.
                resends.assign_wire(command, max(256, 4 * core.max_in_flight))
            if command.job is not None and command.sends == 0:
                command.job.sent(command.source_line)
            command.written(now)
            flight.append(command, now)
            core.trace.sent(now, command.wire.decode("ascii").rstrip("\n"))
            chunks.append(command.wire)
        return b"".join(chunks)

    # ----------------------------------------------------------------------------------------------- results

    def take_results(self) -> list[tuple[Command, Reply | MarlinError]]:
        """Return and forget the commands finished since the last call, with their reply or error."""
        return self._core.in_flight.take_results()

    # ----------------------------------------------------------------------------------------------- one output

    def receive(self, data: bytes, now: float) -> Output:
        """Feed bytes read from the printer; return what they brought and what to do now."""
        self._now = now
        answer = self._receiving.poll_answer(data, now)
        if answer is not None:
            # An idle link's M105 answered: nothing to write, nothing left to wait for.
            return Output((answer,), b"", tuple(self.take_results()), None)
        return self._output(tuple(self._receiving.receive_data(data, now)), now)

    def tick(self, now: float) -> Output:
        """Act on deadlines that have passed and on commands waiting to go out; return what to do now."""
        self._now = now
        self._deadlines.check_timeouts(now)
        return self._output((), now)

    def _output(self, events: tuple[Event, ...], now: float) -> Output:
        # Twice per poll: the parts are called directly, and the print's state is looked at only while one runs.
        data = self.data_to_send(now) if self.has_data_to_send else b""
        state = self._core.link.state
        if state is LinkState.PRINTING or state is LinkState.STOPPING:
            self._core.sync_print_state()
        return Output(events, data, tuple(self.take_results()), self._deadlines.next_deadline())


def _unwanted_resend(command: Command) -> bool:
    """A print line queued to be written again whose print has stopped or is being cancelled since."""
    return command.state is LineState.TO_RESEND and command.job is not None and not wanted(command)
