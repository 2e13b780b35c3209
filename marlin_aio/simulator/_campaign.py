"""A seeded, model-based fault campaign in simulated time: the protocol core against the simulated firmware.

One `run_print()` is one print of a generated file over a simulated serial line, driven by a discrete-event loop:
the host side is a `marlin_aio.protocol.connection.Connection` fed by the same calls the asyncio client makes (a poller
sending M105 every 10 ms, any number of users sending commands whose answers identify themselves, some of whom
give up waiting, the print job, paused or cancelled on the way), the printer is a `SimulatedPrinter` whose line
intake is Marlin's, with its faults switched on (bit flips anywhere in what the host sends, damaged lines, lost
oks, noise, a reset, a silent board), and the line between them carries bytes at a UART's speed in each
direction. No clock, no thread and no I/O, so a run of thousands of lines takes a fraction of a second and every
run with the same seed is the same run.

What each run checks, on the simulator's own record of what it executed:

- at most once, in order: the file lines the firmware executed are the file's first lines, each once, in order;
  exactly all of them when the print reports done (and then `M114` shows the exact position the file's relative
  moves add up to);
- never one more: when the print stops, the firmware ran exactly the lines the print says ran, give or take the
  lines it names as possibly run (those on the wire at a reset); nothing of it ran after that;
- each reply to its own caller: a user command is `M118 U<k>`, which the firmware answers with the line `U<k>`,
  so a reply that carries another command's line (or none) is caught; every poll reply carries temperatures;
  a caller who gave up gets nothing;
- every wait bounded: every command submitted gets its result within its bound, and the run ends.

The one fault no host can see is left out of the invariants and named in the result: a line damaged twice in the
same bit (the 8-bit XOR checksum cannot see it), and a line whose leading `N` turned into `n` while its `ok`
was lost too (it ran unnumbered, and nothing the printer says tells).

Over 400 lines because the discrete-event loop and the checks of what it recorded belong together: each check
reads the loop's own record of that run, and a third of the module is the `Scenario` and `CampaignResult` records,
each field said.
"""

from __future__ import annotations

import heapq
import random
import re
from collections import Counter
from dataclasses import dataclass, field, replace

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.commands import number_command
from marlin_aio.protocol.connection import Command, Connection, Output, Reply
from marlin_aio.protocol.hostrequests import HostRequests
from marlin_aio.protocol.printjob import PrintJob, PrintState
from marlin_aio.simulator._printer import Faults, SimulatedPrinter, SimulatorConfig

__all__ = ["CampaignResult", "Scenario", "mixed_scenario", "print_lines", "run_print"]

_BYTE_S = 10 / 250_000  # one byte on a 250000-baud UART (start bit, 8 data bits, stop bit)
_M114_X = re.compile(r"X:(-?\d+\.\d+)")
_FILE_CODES = ("G1 ", "G91")  # how the campaign's file lines begin (`print_lines`), as the board ran them


@dataclass(frozen=True)
class Scenario:
    """One run's settings: the fault mix, the host's mode and what else happens during the print."""

    seed: int
    lines: int = 400
    send_ahead: bool = True
    advanced_ok: bool = False
    corrupt: float = 0.0  # share of host lines the firmware receives with one character replaced
    flip_bits: float = 0.0  # share of host bytes that get one bit flipped on the wire (any byte: N, M110, '*', EOL)
    drop_ok: float = 0.0  # share of oks the firmware never sends
    noise: float = 0.0  # share of firmware lines preceded by a line of garbage
    poll_interval_s: float | None = 0.01  # the poller's M105; None: no polling
    user_interval_s: float | None = 0.05  # each user's `M118 U<k>` about this often (random); None: no users
    users: int = 1  # callers sending at the same time, each awaiting its own command
    give_up: float = 0.0  # share of user commands whose caller gives up (cancels) before the answer
    relative: bool = False  # the file is G91 and relative moves; done, M114 must show the exact sum
    pause_at_line: int | None = None  # pause the print once this many lines were answered, resume 0.2 s later
    cancel_at_line: int | None = None  # cancel the print once this many lines were answered
    reset_at_line: int | None = None  # the board resets once this many print lines ran
    silent_at_line: int | None = None  # the board falls silent (and stays so) once this many print lines ran
    timeout_s: float = 2.0
    time_limit_s: float = 600.0
    chunk_bytes: int | None = None  # deliver the host's bytes in pieces this size (16: a USB bridge's FIFO)
    flip_once: tuple[tuple[str, int, int], ...] = ()  # targeted flips (`Faults.flip_once`): (substring, byte, bit)
    previous_lines: int = 0  # numbered lines an earlier session left the firmware's counter at
    emergency_interval_s: float | None = None  # M108 or M876 S0 written at once (`Connection.emergency`) this often
    runout_at_line: int | None = None  # the filament runs out before this line: M600 waits for the host to answer
    # (M876 S0 or M108, through the emergency path, as `Printer.answer_prompt` and `interrupt_wait` write them)


@dataclass
class CampaignResult:
    """What one run did, and each broken invariant in words (empty when all held)."""

    scenario: Scenario
    state: PrintState
    error: str | None
    executed_in_order: bool
    lines_executed: int
    lines_said_run: int = 0  # the file lines the print says ran (its last acknowledged line)
    user_replies: int = 0
    user_failures: int = 0
    damaged_replies: int = 0  # replies to a user command that arrived damaged past the checksum (its own, damaged)
    users_gave_up: int = 0
    poll_replies: int = 0
    wrong_replies: int = 0
    emergency_writes: int = 0  # M108 and M876 written at once, unasked or answering the printer's wait
    answers: int = 0  # of those, the ones answering a wait for the user or a prompt (a runout's M600)
    unfinished_commands: int = 0
    end_s: float = 0.0
    position_checked: bool = False  # M114 was read after a print that reported done
    bits_flipped: int = 0
    fragments: int = 0  # tails of cut lines the firmware refused, recognised by the host
    fragments_run: int = 0  # tails of cut lines the firmware ran: the print stopped with that diagnosis
    tail_ran_after_reset: bool = False  # the board reset mid-line and ran the rest of that line afterwards
    blind_spot: bool = False  # a fault no host can see struck (see the module's docstring)
    problems: list[str] = field(default_factory=list)
    failures_by_kind: Counter[str] = field(default_factory=Counter)
    # (command, reply lines) of user replies that are not their own: judged at the end (`_judge_foreign_replies`),
    # once the board's record shows whether the command ran as a damaged copy of itself
    foreign_replies: list[tuple[str, tuple[str, ...]]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when every invariant held."""
        return not self.problems


def mixed_scenario(seed: int, *, actions: bool = True) -> Scenario:
    """A run drawn from `seed`: the mode, the fault mix (bit flips, damaged lines, lost oks, noise), concurrent
    users of whom some give up, polling, mishaps (a pause, a cancel, a reset, a silent board) and, with `actions`,
    emergency writes (M108, M876) and a filament runout. The same seed always gives the same scenario, so a
    failing seed is a reproducible run; without `actions` it is the scenario the seed drew before those joined the
    draw (their draws come last, so every other field is the same either way)."""
    rng = random.Random(f"{seed}:scenario")
    scenario = Scenario(
        seed=seed,
        lines=rng.choice([60, 150, 300]),
        send_ahead=rng.random() < 0.5,
        advanced_ok=rng.random() < 0.5,
        flip_bits=rng.choice([0.0, 0.001, 0.005, 0.01]),
        corrupt=rng.choice([0.0, 0.0, 0.01, 0.03]),
        drop_ok=rng.choice([0.0, 0.0, 0.005, 0.02]),
        noise=rng.choice([0.0, 0.0, 0.01, 0.03]),
        poll_interval_s=rng.choice([None, 0.01, 0.05]),
        user_interval_s=rng.choice([None, 0.003, 0.02, 0.05]),
        users=rng.choice([1, 2, 4, 8]),
        give_up=rng.choice([0.0, 0.0, 0.2]),
        relative=rng.random() < 0.5,
        pause_at_line=rng.choice([None, None, 30]),
        cancel_at_line=rng.choice([None, None, None, 40]),
        reset_at_line=rng.choice([None] * 9 + [45]),
        silent_at_line=rng.choice([None] * 9 + [50]),
        chunk_bytes=rng.choice([None, 16]),
    )
    if not actions:
        return scenario
    return replace(
        scenario,
        emergency_interval_s=rng.choice([None, None, 0.1, 0.5]),
        runout_at_line=rng.choice([None, None, None, 20]),
    )


def print_lines(count: int, *, relative: bool = False) -> list[str]:
    """The campaign's file: distinct absolute moves, or G91 and relative moves of 0.1 mm (whose sum M114 shows)."""
    if relative:
        return ["G91", *(f"G1 X0.1 F{6000 + 60 * (index % 7)}" for index in range(count - 1))]
    return [f"G1 X{index % 200}.{index % 10} Y{(index * 7) % 200} F6000" for index in range(count)]


def run_print(scenario: Scenario) -> CampaignResult:
    """Run one print under `scenario` and check the invariants."""
    # Marlin's command loop takes its time over each command (the defaults of `command_time_s` and `report_time_s`),
    # so lines wait in its ring, and a line error read behind them is answered before their oks, as on a board.
    config = SimulatorConfig(
        advanced_ok=scenario.advanced_ok,
        seed=scenario.seed,
        motion_time_scale=0.0,
        record_limit=None,
    )
    faults = Faults(corrupt_rx_ratio=scenario.corrupt, drop_ok_ratio=scenario.drop_ok, noise_ratio=scenario.noise)
    if scenario.flip_bits:
        faults.flip_bit_ratio = scenario.flip_bits
    faults.flip_once = list(scenario.flip_once)
    faults.runout_at_line = scenario.runout_at_line
    printer = SimulatedPrinter(config, faults, now=-1.0, boot=False)
    if scenario.previous_lines:
        # An earlier session's lines: the firmware's counter stands where they left it. They are run, and their
        # oks thrown away, before this session begins (its commands cost the loop's time, `command_time_s`).
        earlier = "".join(f"{number_command('M400', n)}\n" for n in range(1, scenario.previous_lines + 1))
        printer.receive(earlier.encode("ascii"), -1.0)
    printer.advance(0.0)
    printer.take_output()
    conn = Connection(numbered=True, max_in_flight=64 if scenario.send_ahead else 1)
    lines = print_lines(scenario.lines, relative=scenario.relative)
    rng = random.Random(f"{scenario.seed}:campaign")
    emergency_rng = random.Random(f"{scenario.seed}:emergency")  # its own stream: the users' draws stay as they were

    now = 0.0
    to_printer: list[tuple[float, int, bytes]] = []  # (arrival, sequence, bytes) on the wire, host to printer
    to_host: list[tuple[float, int, bytes]] = []
    wire_free = {"out": 0.0, "in": 0.0}
    sequence = 0
    pending: dict[int, tuple[Command, float, str]] = {}  # command id -> (command, bound, kind)
    gave_up: set[int] = set()  # ids of commands whose caller stopped waiting
    give_up_at: list[tuple[float, int]] = []  # (when, command id)
    result = CampaignResult(scenario, PrintState.RUNNING, None, False, 0)
    poll: Command | None = None
    next_poll = 0.0 if scenario.poll_interval_s is not None else None
    user_due: list[float | None] = [
        0.01 + rng.random() * 0.01 if scenario.user_interval_s is not None else None for _ in range(scenario.users)
    ]
    user_command: list[int | None] = [None] * scenario.users
    user_count = 0
    reset_done = paused = cancelled = False
    requests = HostRequests()  # the firmware's prompts and waits for the user, as the client follows them
    answer_at: float | None = None  # when the host answers the printer's wait for the user
    answered_s = -1.0
    next_emergency = scenario.emergency_interval_s
    resume_at: float | None = None
    position: list[str] = []  # M114's reply lines once the print is done

    def transmit(data: bytes, direction: str, queue: list[tuple[float, int, bytes]]) -> None:
        nonlocal sequence
        # With `chunk_bytes`, in pieces of that size, each arriving when its last byte has crossed the wire: the
        # firmware sees its receive buffer fill as fast as the line allows, not a whole write at once.
        size = scenario.chunk_bytes or len(data)
        for at in range(0, len(data), size):
            piece = data[at : at + size]
            start = max(now, wire_free[direction])
            wire_free[direction] = start + len(piece) * _BYTE_S
            sequence += 1
            heapq.heappush(queue, (wire_free[direction], sequence, piece))

    def submit(text: str, kind: str) -> Command | None:
        try:
            command = conn.submit(text, timeout_s=scenario.timeout_s, now=now)
        except MarlinError as error:  # the printer halted (a line damaged into M112, say): refused at once
            result.failures_by_kind[type(error).__name__] += 1
            return None
        # The bound: its own timeout after every command ahead of it had theirs, with room for resends.
        ahead = conn.in_flight + conn.queued
        pending[command.id] = (command, now + scenario.timeout_s * (ahead + 3) + 5.0, kind)
        return command

    def act(output: Output) -> None:
        """Carry out one step of the core, as the client's link does: bytes on the wire, results to their
        waiters."""
        nonlocal poll
        for event in output.events:
            requests.receive(event)
        if output.data:
            transmit(output.data, "out", to_printer)
        for command, outcome in output.finished:
            entry = pending.pop(command.id, None)
            if entry is None:
                who = "a caller who gave up on it" if command.id in gave_up else "nobody"
                result.problems.append(f"a result for {command.text!r}, for {who}")
                continue
            _, bound, kind = entry
            if now > bound:
                result.problems.append(f"{command.text!r} finished at {now:.2f} s, past its bound {bound:.2f} s")
            if kind == "poll":
                poll = None
            if isinstance(outcome, MarlinError):
                if kind == "user":
                    result.user_failures += 1
                result.failures_by_kind[type(outcome).__name__] += 1
                continue
            if kind == "position":
                position.extend(outcome.lines)
                continue
            _check_reply(command, outcome, kind, result)

    def flush() -> None:
        act(conn.tick(now))

    def pump_printer() -> None:
        out = printer.take_output()
        if out:
            transmit(out, "in", to_host)

    job = PrintJob(lines, name="campaign.gcode", lines_total=len(lines))
    start = submit("M110 N0", "internal")
    assert start is not None
    flush()
    started = False
    position_asks = 0

    while now < scenario.time_limit_s:
        if not started and start.id not in pending:
            started = True
            try:
                conn.attach(job, timeout_s=scenario.timeout_s)
            except MarlinError as error:  # halted before the print began
                job.fail(error, now)
            flush()
        if (
            started
            and job.state is PrintState.DONE
            and scenario.relative
            and not position
            and position_asks < 3  # its ok may be lost on a faulty link: asked again
            and conn.halted is None
            # Last: a walk over the pending commands, on every turn of the loop otherwise.
            and not any(kind == "position" for _, _, kind in pending.values())
        ):
            position_asks += 1
            submit("M114", "position")
            flush()
        if started and job.finished and not pending and not to_printer and not to_host:
            break
        candidates = [scenario.time_limit_s]
        for queue in (to_printer, to_host):
            if queue:
                candidates.append(queue[0][0])
        for due in (conn.next_deadline(), printer.next_wakeup(), next_poll, resume_at, answer_at, next_emergency):
            if due is not None:
                candidates.append(max(due, now))
        for due in user_due:
            if due is not None:
                candidates.append(max(due, now))
        if give_up_at:
            candidates.append(max(give_up_at[0][0], now))
        now = max(now, min(candidates))

        if to_printer and to_printer[0][0] <= now:
            _, _, data = heapq.heappop(to_printer)
            printer.receive(data, now)
            pump_printer()
            continue
        if to_host and to_host[0][0] <= now:
            _, _, data = heapq.heappop(to_host)
            act(conn.receive(data, now))
            continue
        printer.advance(now)
        pump_printer()
        ran = printer.executed_line_count
        if scenario.reset_at_line is not None and not reset_done and ran >= scenario.reset_at_line:
            reset_done = True
            printer.reset(now)
            pump_printer()
        if scenario.silent_at_line is not None and ran >= scenario.silent_at_line:
            faults.silent = True
        if scenario.pause_at_line is not None and not paused and job.lines_acked >= scenario.pause_at_line:
            paused = True
            if job.active:
                job.pause()
                resume_at = now + 0.2
        if resume_at is not None and now >= resume_at:
            resume_at = None
            if job.state is PrintState.PAUSED:
                job.resume(now)
                flush()
        if scenario.cancel_at_line is not None and not cancelled and job.lines_acked >= scenario.cancel_at_line:
            cancelled = True
            if job.active:
                job.cancel(now)
                flush()
        # The printer waits for the user (M600, a runout): the host answers through the emergency path, as
        # `Printer.answer_prompt` and `interrupt_wait` do, and again if the wait goes on (its bytes may be damaged).
        asked = requests.waiting_for_user or (requests.prompt is not None and bool(requests.prompt.buttons))
        if asked and answer_at is None and now >= answered_s + 0.8:
            answer_at = now + 0.05 + emergency_rng.random() * 0.35
        if answer_at is not None and now >= answer_at:
            answer_at = None
            if asked and not job.finished:
                answered_s = now
                result.answers += 1
                result.emergency_writes += 1
                if requests.prompt is not None and requests.prompt.buttons and emergency_rng.random() < 0.7:
                    transmit(conn.emergency("M876 S0", now=now), "out", to_printer)
                    requests.answered()
                else:
                    transmit(conn.emergency("M108", now=now), "out", to_printer)
                flush()  # the core's next deadline may be this command's now
        if next_emergency is not None and now >= next_emergency and scenario.emergency_interval_s is not None:
            # Unasked: M108 ends no wait, M876 answers no prompt; each is still queued and answered in its turn.
            if not job.finished:
                result.emergency_writes += 1
                transmit(
                    conn.emergency("M108" if emergency_rng.random() < 0.5 else "M876 S0", now=now), "out", to_printer
                )
                flush()
            next_emergency = now + emergency_rng.expovariate(1.0 / scenario.emergency_interval_s)
        while give_up_at and give_up_at[0][0] <= now:
            _, command_id = heapq.heappop(give_up_at)
            entry = pending.pop(command_id, None)
            if entry is not None:
                # As `asyncio.wait_for` does when it runs out: the caller withdraws and waits no more.
                gave_up.add(command_id)
                result.users_gave_up += 1
                conn.cancel(entry[0])
        deadline = conn.next_deadline()
        if deadline is not None and now >= deadline:
            flush()  # the core acts on the deadline that passed
        if next_poll is not None and now >= next_poll and scenario.poll_interval_s is not None:
            if poll is None and not job.finished and conn.halted is None:
                poll = submit("M105", "poll")
                flush()
            next_poll = now + scenario.poll_interval_s
        for user, due in enumerate(user_due):
            if due is None or now < due or scenario.user_interval_s is None:
                continue
            # Each user awaits its command before sending the next, as a task calling `send()` does.
            waiting = user_command[user]
            if not job.finished and conn.halted is None and (waiting is None or waiting not in pending):
                user_count += 1
                command = submit(f"M118 U{user_count}", "user")
                if command is None:
                    continue
                user_command[user] = command.id
                if scenario.give_up and rng.random() < scenario.give_up:
                    heapq.heappush(give_up_at, (now + rng.random() * 2 * scenario.timeout_s, command.id))
                flush()
            user_due[user] = now + rng.expovariate(1.0 / scenario.user_interval_s)

    result.end_s = now
    stats = conn.stats()
    result.fragments, result.fragments_run = stats.fragments, stats.fragments_run
    result.bits_flipped = printer.bits_flipped
    # What no host can see: a line damaged past Marlin's checks; a line run without its number (its N hit, or
    # the tail of a line cut by a flush) whose answer cannot show it: an M105 (its `ok T:` looks the same either
    # way) or one whose ok may have been lost on the way back.
    ran_texts = list(printer.executed)
    result.blind_spot = (
        printer.unseen_damage > 0
        or printer.unnumbered_m105_runs > 0
        or (printer.unnumbered_runs > 0 and scenario.drop_ok > 0)
        # A line whose `N` was hit (a flip) and whose body was damaged too (another flip, or `corrupt`): unnumbered,
        # it has no checksum, and it runs as it arrived. The simulator counts two flips so (`unseen_damage`), not a
        # flip and a replaced byte; the client campaign's judge already excused it (core seed 2911: `n32 G1 X0.1
        # F60l0` ran as file line 24 and the print ended done, as no host can tell).
        or (printer.unnumbered_runs > 0 and _damaged_in_place(ran_texts, lines))
    )
    _judge_foreign_replies(ran_texts, result)
    result.state = job.state
    result.error = None if job.error is None else str(job.error)
    result.lines_said_run = job.last_source_line
    if job.active:
        result.problems.append(f"the print was still {job.state.value} at the time limit ({now:.0f} s)")
    for command, bound, kind in pending.values():
        if kind != "internal" or now > bound:
            result.unfinished_commands += 1
            result.problems.append(f"{kind} command {command.text!r} never finished")
    _check_record(printer, lines, job, result)
    if result.damaged_replies and not result.blind_spot:
        result.problems.append(f"{result.damaged_replies} replies were damaged copies, but no line was damaged unseen")
    if job.state is PrintState.DONE and scenario.relative and not result.blind_spot:
        _check_position(position, lines, result)
    return result


def _damaged_copy(ran: str, text: str) -> bool:
    """`ran` is `text` with one or two characters changed (what the simulator's faults do to a line)."""
    return ran != text and len(ran) == len(text) and sum(a != b for a, b in zip(ran, text, strict=True)) <= 2


def _damaged_in_place(ran: list[str], lines: list[str]) -> bool:
    """Print lines ran in their place as damaged copies: texts that are no line of the file, each a line's own
    text with a character or two changed (lines of the file differ from each other in a character or two too)."""
    printed = [upper for text in ran if (upper := text.upper()).startswith(_FILE_CODES)]
    known = set(lines)
    mismatched = [(a, b) for a, b in zip(printed, lines, strict=False) if a != b]
    return bool(mismatched) and all(a not in known and _damaged_copy(a, b) for a, b in mismatched)


def _judge_foreign_replies(ran: list[str], result: CampaignResult) -> None:
    """Judge the user replies that were not their own (`CampaignResult.foreign_replies`), on what the board ran.

    A command the board ran as a damaged copy of itself (`M115 U30` for `M118 U30`: its `N` hit, so unchecked,
    and its body damaged) gets that copy's reply, which is its own as far as any host can tell: counted in
    `damaged_replies`, allowed only in a run with a blind spot (core seed 2452 was judged wrong for it). Any other
    is another command's reply: a broken invariant.
    """
    for text, reply_lines in result.foreign_replies:
        if any(_damaged_copy(command, text) for command in ran):
            result.damaged_replies += 1
        else:
            result.wrong_replies += 1
            result.problems.append(f"{text!r} was handed the reply lines {reply_lines!r}")


def _check_record(printer: SimulatedPrinter, lines: list[str], job: PrintJob, result: CampaignResult) -> None:
    """The invariants on what the firmware executed: at most once, in order; all when done; never one more.

    A run in which the wire damaged a line in a way no check can see (`blind_spot`) is exempt from the exactness
    of what ran, as no host can tell; a print that stops because it noticed such damage after all is expected.
    """
    scenario = result.scenario
    if result.blind_spot:
        return
    # Marlin reads G-code case-insensitively, so a flip of bit 5 turns `F` into `f` and changes nothing it runs.
    executed = [upper for text in printer.executed if (upper := text.upper()).startswith(_FILE_CODES)]
    result.lines_executed = len(executed)
    result.executed_in_order = executed == lines[: len(executed)]
    # With send-ahead, a flush can cut a line in two and the firmware run its tail: the one fault no host can
    # prevent with lines on the wire. The print must then stop at once, saying so, with that one line out of place.
    one_extra = not result.executed_in_order and _one_line_out_of_place(executed, lines)
    failed_with = result.error if job.state is PrintState.FAILED and result.error is not None else ""
    diagnosed_fragment = (
        (result.executed_in_order or one_extra) and result.fragments_run > 0 and "ran out of place" in failed_with
    )
    # A board that resets mid-line forgets the line numbering; the tail of the line then on the wire reaches the
    # fresh board as a command of its own (the host cannot stop bytes already sent). The print has stopped with
    # the reset's diagnosis.
    result.tail_ran_after_reset = one_extra and scenario.reset_at_line is not None and "reset" in failed_with
    if not result.executed_in_order and not (diagnosed_fragment or result.tail_ran_after_reset):
        result.problems.append(
            f"the firmware executed print lines out of order, twice or not at all (first difference at file line "
            f"{_first_difference(executed, lines)}; {len(executed)} executed)"
        )
    if job.state is PrintState.DONE and len(executed) != len(lines):
        result.problems.append(f"the print ended DONE with {len(executed)} of {len(lines)} lines executed")
    if job.state is PrintState.DONE and result.fragments_run:
        result.problems.append("a cut line ran on its own and the print still ended DONE")
    if job.state in (PrintState.FAILED, PrintState.CANCELLED) and result.executed_in_order:
        # Never one more: the lines it says ran, plus at most those it names as possibly run.
        said = job.last_source_line
        maybe = job.in_flight  # written and never answered: the lines it names as possibly run
        if not said <= len(executed) <= said + maybe:
            result.problems.append(
                f"the print says {said} lines ran (and {maybe} may have), but the firmware ran {len(executed)}"
            )
    # Marlin's emergency parser acts on `M112` before any checksum: one flipped bit turns `M110` into it.
    killed_by_damage = "halted" in failed_with and (scenario.flip_bits > 0 or scenario.corrupt > 0)
    expected_failure = scenario.reset_at_line is not None or scenario.silent_at_line is not None or killed_by_damage
    # The host noticed, after the fact, a line damaged past the checksum: stopping, saying so, is right.
    noticed = "checksum could not show" in failed_with
    if job.state is PrintState.FAILED and not expected_failure and not diagnosed_fragment and not noticed:
        result.problems.append(f"the print failed on a link that should carry it: {result.error}")
    if job.state is PrintState.CANCELLED and scenario.cancel_at_line is None:
        result.problems.append("the print ended CANCELLED, but nobody cancelled it")


def _check_position(position: list[str], lines: list[str], result: CampaignResult) -> None:
    expected = 0.1 * (len(lines) - 1)
    found = next((m for line in position if (m := _M114_X.search(line))), None)
    if found is None:
        result.problems.append(f"M114 after the print answered {position!r}, without a position")
        return
    result.position_checked = True
    if abs(float(found.group(1)) - expected) > 0.005:
        result.problems.append(f"M114 shows X:{found.group(1)} after the print; its moves add up to {expected:.2f}")


def _changed_bytes(a: str, b: str) -> int:
    if len(a) != len(b):
        return 99
    return sum(x != y for x, y in zip(a, b, strict=True))


def _first_difference(executed: list[str], lines: list[str]) -> int:
    for index, (ran, line) in enumerate(zip(executed, lines, strict=False)):
        if ran != line:
            return index + 1
    return min(len(executed), len(lines)) + 1


def _one_line_out_of_place(executed: list[str], lines: list[str]) -> bool:
    """True if `executed` is the start of `lines` with one extra line somewhere in it (the tail of a cut line, which
    the link may have damaged too)."""
    for at in range(len(executed)):
        rest = executed[:at] + executed[at + 1 :]
        if rest == lines[: len(rest)]:
            return True
    return False


def _check_reply(command: Command, reply: Reply, kind: str, result: CampaignResult) -> None:
    if kind == "user":
        result.user_replies += 1
        token = command.text.split()[1]
        if reply.lines != (token,) and not (reply.ok_lost and reply.lines == ()):
            # Its own answer to a copy damaged past the checksum: a damaged echo, or none (the copy became another
            # command); or its own answer twice: it ran unnumbered (its `N` damaged) with its ok lost, so the printer
            # asked for it again and it ran again. Judged at the end: only a run with a blind spot may have these.
            damaged = (
                not reply.lines
                or (
                    len(reply.lines) == 1
                    and min(_changed_bytes(reply.lines[0], token), _changed_bytes(reply.lines[0], f" {token}")) <= 2
                )
                or reply.lines == (token, token)
            )
            if damaged:
                result.damaged_replies += 1
                return
            result.foreign_replies.append((command.text, reply.lines))
    elif kind == "poll":
        result.poll_replies += 1
        if reply.temperatures is None and not reply.ok_lost:
            result.wrong_replies += 1
            result.problems.append(f"a poll was handed an ok without temperatures: {reply.ok!r}")
