"""What each line from the printer means: answers matched to commands, resend requests, errors, halts, resets.

Every received line is parsed into an event and dispatched here (`_handle`). An `ok` completes the oldest command
it can answer (`matching`); `Resend:` goes to `resends`; busy keepalives and wait lines push
the oldest command's deadline out; `Error:` lines halt, stop or refuse; `start` means the board reset.

Over 400 lines because what an `ok` answers is one decision (`_on_ok`): matched in order, a line taken unnumbered,
the held line's own or a cut line's tail's (`_held_in_doubt`, `_fragment_ran`), or lost; split, the cases that
share one ok would be judged apart, and one could take another's ok.
"""

from __future__ import annotations

import logging

from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandNotExecutedError,
    LostReplyError,
    MarlinError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
    RemoteProtocolError,
    ThermalRunawayError,
)
from marlin_aio.protocol.corestate import CoreState
from marlin_aio.protocol.events import (
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
from marlin_aio.protocol.matching import Command, attribute, match_ok
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.resends import answers_plainly, wanted
from marlin_aio.protocol.secrets import redact
from marlin_aio.protocol.states import LineEvent, LineState, LinkEvent, LinkState
from marlin_aio.protocol.wire import classify_line, is_noise

__all__ = ["Receiving"]

#: Recoveries at INFO, oddities and failures at WARNING (lines on the wire: "marlin_aio.wire" at DEBUG).
_log = logging.getLogger("marlin_aio")

#: Commands that wait for heaters; every temperature report while they run shows the printer is alive.
_HEATER_WAITS = frozenset({"M109", "M190", "M191"})

#: Reply-line events a command collects while it is the oldest waiting.
_REPLY_LINES = (UnrecognisedLine, EchoMessage, FirmwareInfo, Capability)


def _changed(sent: str, echoed: str) -> int:
    """How many bytes of `sent` differ in `echoed`, if one or two (else 3 or more). The printer drops trailing
    spaces from what it echoes, so a byte damaged into a space at the end shows as a shorter echo."""
    if len(echoed) == len(sent) + 1:
        echoed = echoed[1:]  # a damaged byte before the line (a bare line end sent ahead of it)
    if sent == echoed or not 0 <= len(sent) - len(echoed) <= 2:
        return 3
    padded = echoed.ljust(len(sent))
    return sum(a != b for a, b in zip(sent, padded, strict=True))


class Receiving:
    """The receiving side of `Connection`: a part composed over the core's one state record (`CoreState`)."""

    __slots__ = ("_core",)

    def __init__(self, core: CoreState) -> None:
        self._core = core

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        """Feed bytes read from the printer; return the events of the lines they complete.

        Results (answered and failed commands) collect in `take_results()`; call `data_to_send()` afterwards,
        as an answer may open the window for more.
        """
        core = self._core
        events: list[Event] = []
        for text, event in core.parser.receive_data(data):
            core.trace.received(now, text)
            self._handle(text, event, now)
            events.append(event)
        return events

    def poll_answer(self, data: bytes, now: float) -> Ok | None:
        """The fast lane of `receive_data` for its most common input, a hundred times a second while polling: one
        whole `ok T:` line answering the only command in flight, an M105 a caller waits for, while nothing else is
        under way (nothing queued, no print, no resend, flush or lock). Return its event, the M105 finished with
        its reply into the results; or None, having changed nothing, for anything else (`receive_data` reads it).

        It does what `receive_data` does for that input (a property test holds the two to the same outcome, by
        feeding the same bytes whole and split), without the general dispatch of each line.
        """
        core = self._core
        flight = core.in_flight
        if len(flight) != 1 or data[:5] != b"ok T:":
            return None
        head = flight[0]
        if (
            head.code != "M105"
            or head.state is not LineState.ON_WIRE
            or head.job is not None
            or head.probe
            or head.orphan
            or head.refusal is not None
            or core.link.state is not LinkState.READY
            or core.queue
            or core.in_flight.results
            or core.send_eol
            or core.feed.job is not None
            or not core.resends.idle
        ):
            return None
        text = core.parser.one_line(data)
        if text is None:
            return None
        ok = classify_line(text)
        if type(ok) is not Ok or ok.temperatures is None or ok.line_number is not None:
            return None
        core.parser.count_bytes(len(data))
        core.trace.received(now, text)
        flight.popleft(now)
        # `_settle` for an M105 answered by its own ok, on a READY link with no resend under way.
        head.move(LineEvent.OK)
        core.resends.settled(head, answered_line=False)
        if head.sends == 1:
            core.probes.answered(head, now)
        sent = now if head.sent_s is None else head.sent_s
        core.in_flight.finish(head, Reply(head.text, tuple(head.lines), ok, sent, now, head.lines_dropped))
        return ok

    def discard_partial_input(self) -> None:
        """Forget an unfinished line (call after flushing the port's input: its end will never arrive)."""
        self._core.parser.clear()

    def _handle(self, text: str, event: Event, now: float) -> None:
        core = self._core
        # An ok leaves the "last line was a line error" mark alone: only other lines are between an error and
        # its `Resend:`.
        is_line_error = None if type(event) is Ok else isinstance(event, ErrorMessage) and event.kind is ErrorKind.LINE
        if is_line_error:
            assert isinstance(event, ErrorMessage)
            core.resends.line_error(sequence=event.message.startswith("Line Number"))
        after_line_error = core.resends.note_line(is_line_error, now, core.probes.quiet_s)
        head = core.in_flight.head
        match event:
            case Ok():
                self._on_ok(event, now)
            case BusyKeepalive():
                if head is not None:
                    head.alive(now)  # the printer is alive and working on the oldest command
            case TemperatureReport() if event.temperatures.waiting or (head is not None and head.code in _HEATER_WAITS):
                # Marlin marks its wait lines with W:; other firmwares send plain reports while M109/M190 wait.
                if head is not None:
                    head.alive(now)
            case ResendRequest():
                core.check(
                    core.resends.on_request(
                        event.line_number,
                        core.in_flight,
                        core.queue,
                        now,
                        rejected=after_line_error,
                        quiet_s=core.probes.quiet_s(),
                    ),
                    now,
                )
            case ErrorMessage():
                self._on_error(event, now)
            case Start():
                self._on_start(now)
            case OverlongLine():
                pass  # noise from the link (a baud glitch, a reset) is nobody's reply (the wire counts it)
            case UnrecognisedLine() if is_noise(text):
                pass
            case UnknownCommand() if not any(c.text == event.command for c in core.in_flight):
                # Not the text of any command of ours: something damaged on the way (a line whose `N` was hit, which
                # the printer took as unnumbered and did not count, or the tail of a line cut in two by a flush).
                # The firmware refused it, and its ok answers nothing.
                self._damaged_input(event.command, now)
            case PrinterLocked() | UnknownCommand():
                if head is not None:
                    head.add_line(text)
                    if isinstance(event, PrinterLocked):
                        # The ok that follows answers a command that was refused, not run.
                        head.refuse(text)
                        if core.link.state is not LinkState.LOCKED:
                            _log.warning("the printer is locked: %s", redact(text))
                        core.link.move(LinkEvent.LOCKED, remote=True)
                    elif head.job is not None:
                        self._lacked(head, text)
            case _ if head is not None and isinstance(event, _REPLY_LINES):
                head.add_line(text)

    def _on_ok(self, ok: Ok, now: float) -> None:
        core = self._core
        if core.resends.take_ok(ok.temperatures is None):
            return
        # Which in-flight command does this ok answer? The oldest one whose answer can look like it; every command
        # ahead of that one was processed (Marlin answers in order) but its own ok was lost.
        index = match_ok(core.in_flight, ok, exact_oks=core.exact_oks) if core.in_flight else None
        if index is None and core.exact_oks and ok.line_number is None and ok.temperatures is None:
            index = self._taken_unnumbered(ok)
        if index is None:
            core.stray_ok()
            _log.warning("an ok that answers no command waiting: %r", ok)
            if core.resends.draining and ok.temperatures is None:
                self._fragment_ran(now)
            return
        held = core.resends.held
        if held is not None and ok.line_number is None and core.in_flight[index].emergency:
            # A plain ok, and an emergency command written behind the held line: the ok is the held line's if it
            # ran unnumbered, else the emergency command's. It proves nothing about the held line: judged as its.
            ahead = [c for c in core.in_flight][:index]
            if held in ahead:
                index = ahead.index(held)
        entry = core.in_flight[index]
        if (
            ok.line_number is None
            and ok.temperatures is None
            and entry.line_number is not None
            and not entry.emergency
            and index + 1 < len(core.in_flight)
        ):
            behind = core.in_flight[index + 1]
            if behind.emergency:
                # A plain ok, and an emergency command written right behind the numbered line it would answer: it
                # is that line's, or, if the line never arrived, the emergency command's (core seed 1643: `N75`
                # was lost, the M876's ok settled it, and the printer's `Resend: 75` then found it "run"). Taken
                # as the emergency command's, it costs nothing either way: if the line ran, the emergency
                # command's own ok follows and answers it; if its ok was lost, a probe proves it ran; if it never
                # arrived, the printer asks for it again and it goes again. (So for a line held after a `Resend:`
                # too, core seed 1535: the M108's ok was judged the held line's unnumbered run, a placeholder took
                # its number, and the line never ran.)
                core.in_flight.remove(behind, now)
                self._settle(behind, ok, (), now)
                return
        if (
            entry.emergency
            and core.exact_oks
            and any(core.in_flight[at].line_number is not None for at in range(index))
        ):
            # Its own ok, with numbered lines ahead of it unanswered: it proves nothing about them (unnumbered, it
            # met no sequence check, and the printer may have dropped one of them without a word). They stay, for
            # an answer that can prove it (an `ok N`, a probe's `ok T:`) or a resend.
            core.in_flight.remove(entry, now)
            self._settle(entry, ok, (), now)
            return
        if held is not None and core.in_flight[index] is held and ok.line_number is None:
            plain = ok.temperatures is None
            if plain != answers_plainly(held):
                self._fragment_ran(now)  # not the held line's answer: a tail's; the held line goes again
                return
            if not core.resends.held_answer_proven(held, plain=plain):
                self._held_in_doubt(held, now)
                return
        if ok.line_number is not None:
            core.oks_name_lines()
        skipped = [core.in_flight.popleft(now) for _ in range(index)]
        command = core.in_flight.popleft(now)
        lines = attribute(skipped, command)
        for at, lost in enumerate(skipped):
            core.lost_ok()
            _log.info("the ok of %r was lost; %r was answered after it", redact(lost.text), redact(command.text))
            # Its lines are its own if every command after it printed nothing but its ok (a bare M105).
            quiet = all(c.text == "M105" or c.probe or c.emergency for c in (*skipped[at + 1 :], command))
            self._settle(lost, None, tuple(lost.lines) if quiet else None, now, proof=ok)
        self._settle(command, ok, lines, now)

    def _damaged_copy(self, echoed: str, *, body: bool = False) -> Command | None:
        """The numbered command in flight of which `echoed` (an `Unknown command`'s text) is a damaged copy.

        The printer echoes what it received up to the `*`; a line it took as unnumbered because its leading `N`
        was damaged reads as that line's wire with one or two bytes changed (an undecodable byte is one U+FFFD).
        With `body`, the echo is compared with the command's text instead: a line counted under its number whose
        command arrived damaged.
        """
        best: Command | None = None
        fewest = 3
        for command in self._core.in_flight:
            wire = command.wire
            if command.line_number is None:
                continue
            star = wire.rfind(b"*")
            sent = wire[:star].decode("ascii")
            if body:
                # What follows the number: the separator (a damaged one shows in the echo) and the command.
                after = len(str(command.line_number)) + 1
                changed = min(_changed(sent[after:], echoed), _changed(command.text, echoed))
            else:
                changed = _changed(sent, echoed)
            if changed < fewest:
                best, fewest = command, changed
        return best

    def _taken_unnumbered(self, ok: Ok) -> int | None:
        """With ADVANCED_OK, a plain ok that no unnumbered command earned: the FIFO index of the numbered line the
        printer took as unnumbered (its `N` damaged), or None for the tail of a line cut by a flush.

        Tails arrive only after a flush, while nothing is written (`draining`); a line held after a flush was in
        the printer before it, so the first such ok may be its own (`_on_ok` decides whether it is surely so).
        Otherwise it is the oldest plainly answered line.
        """
        core = self._core
        held = core.resends.held
        if core.resends.draining:
            commands = list(core.in_flight)
            return commands.index(held) if held is not None and held in commands else None
        return match_ok(core.in_flight, ok, exact_oks=False)

    def _damaged_input(self, echoed: str, now: float) -> None:
        """The printer refused something we never sent as such: its ok answers nothing.

        If it is a damaged copy of a numbered line in flight, that line was not counted. Lines written behind it
        meet the sequence check and bring a `Resend:` for it; with none behind it (one line at a time), it goes
        again at once, in its place.
        """
        core = self._core
        if any(c.emergency and _changed(c.text, echoed) < 3 for c in core.in_flight):
            # An emergency command damaged on the way (unnumbered, nothing checks it): the printer queued it like
            # any line and answers it in its turn, this refusal and then its ok, which lands on its entry.
            return
        damaged_body = self._damaged_copy(echoed, body=True)
        if damaged_body is not None:
            # The line was counted with a damaged body (two flips of one bit, which the 8-bit checksum cannot
            # see): the printer did not run what was sent.
            said = f"echo:Unknown command: {redact(echoed)!r} (it arrived damaged in a way its checksum could not show)"
            ran_behind = any(c.line_number is not None and not c.probe for c in core.in_flight.after(damaged_body))
            if damaged_body.job is not None and not ran_behind:
                # One line at a time, nothing of the print is behind it: written again under the next number, it
                # runs exactly in its place.
                self._write_anew(damaged_body, said, now)
            else:
                # Lines behind it ran (or will) before it could go again: the print stops there, naming them.
                damaged_body.refuse(said)
            return
        core.resends.fragment_refused()
        command = self._damaged_copy(echoed)
        if command is None:
            return
        behind = any(c.line_number is not None for c in core.in_flight.after(command))
        core.in_flight.remove(command, now)
        command.move(LineEvent.MANGLED)
        _log.info("the printer received a damaged copy of %r and did not count it; it goes again", redact(command.text))
        if not behind:
            core.queue.appendleft(command if wanted(command) else core.resends.placeholder_for([command], now))

    def _lacked(self, line: Command, said: str) -> None:
        """The firmware does not know print line `line`'s command (it echoed it as sent): Marlin skipped it. The
        print goes on, warned once per command, unless its job stops on such a line."""
        job = line.job
        assert job is not None
        if job.stop_on_unknown:
            line.refuse(said)  # the ok that follows answers a line that was not printed: the print stops there
        elif job.lacked(line.code, line.source_line):
            _log.warning(
                "the printer does not know %s (line %d of %s): it skipped the line and the print goes on; "
                "told once per command",
                line.code,
                line.source_line,
                job.name,
            )

    def _write_anew(self, line: Command, said: str, now: float) -> None:
        """`line`, a print line the printer counted but did not run, goes again as a new line (the next number);
        its entry stays in flight, with nobody waiting, for the ok the printer still owes its number."""
        core = self._core
        job = line.job
        assert job is not None
        job.not_run()
        line.replaced(said)
        if job.cancelling or not job.active:
            job.finish_if_idle(now)  # nothing of a cancelled print goes out again
            return
        _log.info("line %d of %s arrived damaged and did not run; it goes again", line.source_line, job.name)
        again = Command(
            core.new_id(),
            line.text,
            line.code,
            line.numbered,
            line.timeout_s,
            now,
            job=job,
            source_line=line.source_line,
            source_bytes=line.source_bytes,
        )
        core.queue.appendleft(again)

    def _settle(
        self, command: Command, ok: Ok | None, lines: tuple[str, ...] | None, now: float, proof: Ok | None = None
    ) -> None:
        """Finish one command taken off the FIFO: answered by `ok`, or (ok None) processed with its ok lost, as
        `proof` (the answer of a command behind it) shows."""
        core = self._core
        if command.state in (LineState.ON_WIRE, LineState.IN_DOUBT):
            command.move(LineEvent.REFUSED if command.refusal is not None else LineEvent.OK)
        if command is core.resends.held:
            core.resends.release_held()
            if ok is not None and command.refusal is None:
                # The line the printer asked for again had run, unnumbered: a placeholder takes its number.
                core.queue.appendleft(core.resends.placeholder_for([command], now))
        if command.code == "M110" and (ok is not None or proof is not None) and command.refusal is None:
            core.resends.m110_answered(command)
            if command.sends > 1:
                core.resends.m110_repeated(command, now, core.probes.quiet_s())
        refused = command.refusal is not None and not command.orphan and not command.probe
        core.resends.settled(command, answered_line=ok is not None and command.job is not None and not refused)
        state = core.link.state
        if command.code == "M999" and state is LinkState.STOPPED:
            # stop() (unlike kill()) leaves Marlin running; M999 resumes it.
            core.link.resumed()
        elif state is LinkState.LOCKED and command.refusal is None and not command.orphan and command.code != "M511":
            core.link.move(LinkEvent.UNLOCKED)  # a command ran normally: the printer was unlocked (M511 or its screen)
        if ok is not None and not refused and (command.job is not None or command.sends == 1) and not command.emergency:
            # The link's pace, for how soon a probe asks whether an ok was lost, in a print or not.
            core.probes.answered(command, now)
        if refused:
            self._refused(command, now)
        elif command.job is not None:
            # A print line needs no reply: a later answer proves it ran, whether its own ok came or not.
            command.job.acked(len(command.wire), command.source_bytes, command.source_line, now)
        elif command.probe or command.orphan:
            return  # nobody waits for its answer
        elif ok is None:
            # It ran (a later answer proves it), but its own ok was lost: its caller gets that, marked as such,
            # never an error that would invite running it twice.
            sent = now if command.sent_s is None else command.sent_s
            answer = proof if proof is not None else Ok()
            own = lines or ()
            core.in_flight.finish(
                command, Reply(command.text, own, answer, sent, now, command.lines_dropped, ok_lost=True)
            )
        elif lines is None:
            core.in_flight.finish(
                command,
                LostReplyError(
                    f"{redact(command.text)!r} was processed but the ok of a command before it was lost, so which "
                    "reply lines are its own cannot be proven; it was not handed another command's answer",
                    command=redact(command.text),
                ),
            )
        else:
            sent = now if command.sent_s is None else command.sent_s
            core.in_flight.finish(command, Reply(command.text, lines, ok, sent, now, command.lines_dropped))

    def _refused(self, command: Command, now: float) -> None:
        """The printer answered `command` with an ok but said it did not run it."""
        said = redact(command.refusal or "")
        error: MarlinError
        if "locked" in said.lower():
            error = PrinterLockedError(
                f"the printer is locked and refused {redact(command.text)!r} ({said.removeprefix('echo:')}): "
                "unlock it with M511 P<password> (connect with password=..., or $MARLIN_PASSWORD) or on its screen"
            )
        else:
            error = CommandNotExecutedError(f"the printer did not run {redact(command.text)!r}: it said {said!r}")
        if command.job is not None:
            job = command.job
            job.withdrew_line()
            where = f"line {command.source_line} of {job.name}"
            # Nothing after the refused line may run in its place: the print stops here, with the printer's words.
            # Lines written behind it (send-ahead) are in the printer already and run: a resume starts after them.
            behind = [c.source_line for c in self._core.in_flight if c.job is job]
            ran = ""
            if behind:
                lines = f"line {behind[0]}" if len(behind) == 1 else f"lines {behind[0]}-{behind[-1]}"
                ran = f"; {lines} had been sent behind it and may have run: resume from line {behind[-1] + 1}"
            self._core.stop_job(type(error)(f"print stopped at {where}: {error}{ran}"), now)
            return
        self._core.in_flight.finish(command, error)

    def _held_in_doubt(self, held: Command, now: float) -> None:
        """An ok that no command earned came while `held` waits, and it cannot be proven `held`'s own: either
        `held` ran unnumbered, or it did not run and the tail of a line cut behind it did. Neither may be guessed:
        the print stops (`_fragment_ran`) and `held` is never written again (a placeholder takes its number once
        the printer is quiet); a caller waiting for it is told that it may or may not have run."""
        _log.warning("an ok that either %r (run unnumbered) or a cut line's tail earned", redact(held.text))
        self._fragment_ran(now, held=held)
        if held.job is None and not held.probe and not held.placeholder and not held.orphan:
            held.give_up()
            error = RemoteProtocolError(
                f"{redact(held.text)!r} may or may not have run: after a line error the printer sent an ok that it "
                "earned if it ran without its line number, or the tail of a line cut in two by the flush earned",
            )
            core = self._core
            core.in_flight.finish(held, error)

    def _fragment_ran(self, now: float, held: Command | None = None) -> None:
        """An ok that no command earned arrived after a flush: the tail of a cut line ran as a command of its own
        (or, with `held`, that line ran unnumbered: which of the two cannot be told)."""
        core = self._core
        core.resends.fragment_ran()
        _log.warning("after a line error the tail of a cut line ran as a command of its own")
        job = core.feed.job
        if job is None or not job.active:
            return
        pieces = ", ".join(repr(redact(text)) for text in core.resends.fragment_texts[:3])
        if held is None:
            what = "ran the rest of it as a command of its own (an ok that no command earned"
            ran = "a line ran out of place"
        else:
            what = "may have run the rest of it as a command of its own (an ok that no command surely earned"
            ran = (
                f"either a line ran out of place, or {redact(held.text)!r}, asked for again, had run without its "
                "line number: which of the two cannot be told"
            )
        message = (
            f"print stopped after line {job.last_source_line} of {job.name}: after a line error the printer threw "
            f"away its receive buffer in the middle of a line and {what}; the line was one of {pieces}), so {ran}; "
            "send-ahead cannot rule this out on this link: print with send_ahead=False (ping-pong)"
        )
        core.stop_job(RemoteProtocolError(message), now)

    def _on_error(self, event: ErrorMessage, now: float) -> None:
        core = self._core
        head = core.in_flight.head
        match event.kind:
            case ErrorKind.THERMAL:
                core.link.thermal_error(event.message)
                self._halt_with(ThermalRunawayError(f"thermal protection tripped: {event.message}"), now, stopped=False)
            case ErrorKind.HALTED | ErrorKind.STOPPED if core.link.thermal_message is not None:
                message = f"thermal protection tripped: {core.link.thermal_message} ({event.message})"
                self._halt_with(ThermalRunawayError(message), now, stopped=False)
            case ErrorKind.HALTED | ErrorKind.STOPPED:
                halted = PrinterHaltedError(f"the printer halted: {event.message}")
                self._halt_with(halted, now, stopped=event.kind is ErrorKind.STOPPED)
            case ErrorKind.NOT_EXECUTED if head is not None:
                head.add_line(f"!! {event.message}")
                head.refuse(f"!! {event.message}")
            case ErrorKind.CHECKSUM_REQUIRED:
                self._on_checksum_required(event.message, now)
            case ErrorKind.OTHER if head is not None:
                head.add_line(f"Error:{event.message}")

    def _on_checksum_required(self, message: str, now: float) -> None:
        core = self._core
        # The firmware ran nothing and will send no ok for the oldest unnumbered command: fail it now, and number
        # every command from here on.
        core.link.checksums_required()
        command = next((c for c in core.in_flight if c.line_number is None), None)
        if command is None:
            return
        core.in_flight.remove(command, now)
        if command.state in (LineState.ON_WIRE, LineState.IN_DOUBT):
            command.move(LineEvent.REFUSED)  # thrown away as it was read (an emergency command acted on even so)
        if not command.orphan and command.job is None and not command.probe:
            error = ChecksumRequiredError(
                f"the printer refused {redact(command.text)!r} without a line number and checksum "
                f"('Error:{message}'); it needs numbered commands"
            )
            core.in_flight.finish(command, error)

    def _halt_with(self, error: PrinterHaltedError, now: float, *, stopped: bool) -> None:
        """The printer halted (`stopped`: a stop() that M999 clears; otherwise it needs a reset)."""
        core = self._core
        _log.warning("%s", error)
        core.fail_everything(core.link.halted(error, stopped=stopped), now)

    def _on_start(self, now: float) -> None:
        core = self._core
        core.was_reset()
        _log.warning("the printer reset (it printed 'start')")
        # The board rebooted: it forgot every command and its line counter. Nothing is replayed into it.
        core.fail_everything(
            PrinterResetError("the printer reset (it printed 'start'); commands in flight were lost"), now
        )
        core.link.reset()
        core.resends.restart_numbering()
