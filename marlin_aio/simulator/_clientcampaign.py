"""The fault campaign of the whole asyncio client: `marlin_aio.connect()` on the in-memory link to the simulated
Marlin, each run on a `SimulatedTimeLoop`, so a print of hundreds of lines with its timeouts, stalls and pauses
costs a few tens of milliseconds of CPU, and a seed is the same run every time.

`_campaign.run_print` checks the sans-I/O core: it drives `Connection` from a discrete-event loop of its own, a
copy of what the link does, thousands of runs in seconds; the asyncio layer is never under it. Here nothing is
copied: the real `Printer`, `Link`, handshake, `Poller`, temperature feed and `PrintHandle` talk to `serve_memory()`
at 250000 baud, and the campaign does only what an application does:

- a print (`start_print(print_lines(...), send_ahead=...)`), paused through its `PrintHandle` at the scenario's
  line and resumed 0.2 s later, or cancelled (`PrintHandle.cancel()`);
- polls by the printer's own poller (`poll_temperatures`, kept at the scenario's interval during the print with
  `print_poll_interval_s`), counted as the poll readings `on_reading` gets;
- `users` tasks, each sending `M118 U<k>` with `printer.send` and checking that the reply is its own (the
  simulator answers `U<k>`; `_campaign._check_reply` judges it), some giving up with `asyncio.wait_for` within
  10 ms, while the command is on its way (the core campaign's callers wait up to two timeouts, which on this
  link would give up only on a silent or reset board);
- emergency writes (`emergency_interval_s`): `interrupt_wait()` (M108) unasked, or `answer_prompt(0)` (M876 S0)
  when a prompt is open, both written at once ahead of the queue; an unasked M876 is what no application can
  write through the client (`answer_prompt` refuses it with no prompt open), so it is the core campaign's alone;
- a filament runout (`runout_at_line`): the board's M600 waits for a person, and the campaign answers as one
  would, with `answer_prompt(0)` or `interrupt_wait()`, again if the wait goes on;
- mishaps from outside, as a hand on the board would cause them: a reset (`server.printer.reset()`) once the
  scenario's number of numbered lines ran since the print began, or a board that falls silent (`faults.silent`),
  each followed by `server.poke()`.

Then the core campaign's invariants are checked on the simulator's record (`_campaign._check_record`): each file
line at most once and in order, all of them when the print says done (and `M114` at the exact sum of the relative
moves), never one more than the print says ran; each reply to its own caller; every wait bounded: each `send`
ends within the core campaign's bound for it, and the whole run within the scenario's time limit (an
`asyncio.timeout` in simulated time; a run that hits it "never finished", naming who still waited).

The scenarios are `mixed_scenario(seed)`'s but for what the real client cannot reproduce: `chunk_bytes` (how the
host's bytes are split is the memory link's and the simulated UART's business) and `previous_lines` (each connect
resets the board, so no earlier session's counter survives). The faults are switched on once the handshake is
done (a handshake through bit flips is another test's business), so the print's own `M110 N0` meets them first.
Also left out: a reconnect after the reset or the silence, auto-reports (M155), heater waits (M109/M190), the
emergency stop (M112), and the serial stack below the transport (pyserial, a pty): the tests of those run in
real time.

Two faults no host can see are excused beyond the core campaign's blind spot (`CampaignResult.blind_spot`), as
`_check` says: a line whose `N` and body were both damaged (an unnumbered line has no checksum), and a user's
command damaged past the checksum into another command (`M118 U17` into `M119 U07`: its reply is M119's).

The one module of the simulator that imports the library's face (`marlin_aio`): it is a client of the library, as
an application is, run against the simulator (tests/test_architecture.py names it). The simulator's `__init__`
never imports it. Over 400 lines because one run (`_Session`) and the checks of what it recorded (`_check`) read
best together, as in `_campaign`.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
from collections import Counter
from dataclasses import dataclass, field

import marlin_aio
from marlin_aio.errors import MarlinError
from marlin_aio.protocol.connection import Command
from marlin_aio.protocol.hostrequests import HostRequest
from marlin_aio.protocol.printjob import PrintJob, PrintState
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.temperatures import ReadingSource, TemperatureReading
from marlin_aio.simulator._campaign import (
    CampaignResult,
    Scenario,
    _check_position,
    _check_record,
    _check_reply,
    _damaged_in_place,
    _judge_foreign_replies,
    print_lines,
)
from marlin_aio.simulator._config import Faults, SimulatorConfig
from marlin_aio.simulator._serve import SimulatorServer, serve_memory
from marlin_aio.simulator._virtual import run_in_simulated_time

__all__ = ["ClientRun", "run_client_print"]

BAUD_RATE = 250_000
# How often the mishap watcher looks at the board: about a line's time on the wire at 250000 baud.
WATCH_INTERVAL_S = 0.001
GIVE_UP_WITHIN_S = 0.01


@dataclass
class ClientRun:
    """One run of the client: the campaign's result, and the link's last lines (for a run that failed)."""

    result: CampaignResult
    trace: str = ""
    # What happened, by kind: reset, silent, pause, cancel, emergency (an unasked write), answer (to a wait or prompt)
    mishaps: Counter[str] = field(default_factory=Counter)


def run_client_print(scenario: Scenario) -> ClientRun:
    """Run one print of the real client under `scenario`, in simulated time, and check the invariants."""
    return run_in_simulated_time(_run(scenario))


async def _run(scenario: Scenario) -> ClientRun:
    loop = asyncio.get_running_loop()
    # Marlin's command loop takes its time over each command, as in the core's campaign (`_campaign.run_print`).
    config = SimulatorConfig(
        advanced_ok=scenario.advanced_ok,
        seed=scenario.seed,
        motion_time_scale=0.0,
        record_limit=None,
    )
    faults = Faults()
    lines = print_lines(scenario.lines, relative=scenario.relative)
    result = CampaignResult(scenario, PrintState.RUNNING, None, False, 0)
    session = _Session(scenario, lines, result)
    async with serve_memory(config, faults, baud_rate=BAUD_RATE) as server:
        try:
            async with asyncio.timeout(scenario.time_limit_s):
                await session.run(server, faults)
        except TimeoutError:
            waiting = "; ".join(f"{who}: {what}" for who, what in session.waiting.items()) or "nothing"
            result.problems.append(f"never finished within {scenario.time_limit_s:g} s; still waiting: {waiting}")
        result.end_s = loop.time()
        _check(server, session, result)
    return ClientRun(result, session.trace if result.problems else "", session.mishaps)


class _Session:
    """What one run does on its printer: the print, the poller, the users and the mishaps."""

    def __init__(self, scenario: Scenario, lines: list[str], result: CampaignResult) -> None:
        self.scenario = scenario
        self.lines = lines
        self.result = result
        self.rng = random.Random(f"{scenario.seed}:client-campaign")
        self.job = PrintJob(lines, name="campaign.gcode", lines_total=len(lines))  # replaced by the print's own
        self.over = asyncio.Event()  # the print ended (or never began): the users stop
        self.waiting: dict[str, str] = {}  # who -> what it awaits now, for a run that never finishes
        self.position: list[str] = []  # M114's reply lines once a relative print is done
        self.mishaps: Counter[str] = Counter()
        self.unnumbered_before = (0, 0)  # the board's (unnumbered_runs, unnumbered_m105_runs) as the faults began
        self.trace = ""
        self._tokens = itertools.count(1)
        self._asked = asyncio.Event()  # the printer asked for a person (a prompt, a wait for the user)
        self._helpers: list[asyncio.Task[None]] = []  # the emergency writers: cancelled when the print ends

    async def run(self, server: SimulatorServer, faults: Faults) -> None:
        loop = asyncio.get_running_loop()
        self.waiting["connect"] = "the handshake"
        async with marlin_aio.connect(server.url, timeout_s=self.scenario.timeout_s) as printer:
            del self.waiting["connect"]
            try:
                await self._session(printer, server, faults)
            finally:
                self.trace = printer.trace.format(loop.time())
                stats = printer.stats
                self.result.fragments, self.result.fragments_run = stats.fragments, stats.fragments_run

    async def _session(self, printer: marlin_aio.Printer, server: SimulatorServer, faults: Faults) -> None:
        scenario = self.scenario
        result = self.result
        # The handshake's unnumbered M105 ran before any fault: only what runs unnumbered from here on counts.
        self.unnumbered_before = server.printer.unnumbered_runs, server.printer.unnumbered_m105_runs
        faults.corrupt_rx_ratio = scenario.corrupt
        faults.drop_ok_ratio = scenario.drop_ok
        faults.noise_ratio = scenario.noise
        faults.flip_bit_ratio = scenario.flip_bits
        faults.flip_once = list(scenario.flip_once)
        faults.runout_at_line = scenario.runout_at_line

        def count_poll(reading: TemperatureReading) -> None:
            if reading.source is ReadingSource.POLL:
                result.poll_replies += 1

        printer.on_reading(count_poll)
        async with contextlib.AsyncExitStack() as stack:
            if scenario.poll_interval_s is not None:
                printer.print_poll_interval_s = scenario.poll_interval_s  # no slower while the print streams
                await stack.enter_async_context(printer.poll_temperatures(scenario.poll_interval_s, auto_report=False))
            async with asyncio.TaskGroup() as group:
                if scenario.user_interval_s is not None:
                    for user in range(scenario.users):
                        group.create_task(self._user(printer, user, scenario.user_interval_s), name=f"user {user}")
                # Its own stream, as in the core campaign: the users' draws stay what they were without it.
                emergency_rng = random.Random(f"{scenario.seed}:emergency")
                if scenario.runout_at_line is not None:
                    stop = printer.on_host_request(self._host_request)
                    stack.callback(stop)
                    self._helpers.append(group.create_task(self._answer(printer, emergency_rng), name="answer"))
                if scenario.emergency_interval_s is not None:
                    writer = self._emergencies(printer, emergency_rng, scenario.emergency_interval_s)
                    self._helpers.append(group.create_task(writer, name="emergencies"))
                await self._print(printer, server, faults, group)
        if self.job.state is PrintState.DONE and scenario.relative:
            await self._ask_position(printer)

    async def _print(
        self, printer: marlin_aio.Printer, server: SimulatorServer, faults: Faults, group: asyncio.TaskGroup
    ) -> None:
        scenario = self.scenario
        ran_before = server.printer.executed_line_count
        self.waiting["print"] = "start_print (its M110 N0)"
        try:
            handle = await printer.start_print(self.lines, send_ahead=scenario.send_ahead)
        except MarlinError as error:  # the printer halted (a line damaged into M112, say) before the print began
            self.job.fail(error, asyncio.get_running_loop().time())
            self.result.failures_by_kind[type(error).__name__] += 1
            del self.waiting["print"]
            self.over.set()
            for helper in self._helpers:
                helper.cancel()
            return
        self.job = handle.job
        mishaps = (scenario.reset_at_line, scenario.silent_at_line, scenario.pause_at_line, scenario.cancel_at_line)
        if any(at is not None for at in mishaps):
            group.create_task(self._mishaps(handle, server, faults, ran_before, group), name="mishaps")
        self.waiting["print"] = "the print's end"
        try:
            await handle
        except MarlinError as error:
            self.result.failures_by_kind[type(error).__name__] += 1
        finally:
            del self.waiting["print"]
            self.over.set()
            for helper in self._helpers:
                helper.cancel()

    async def _mishaps(
        self,
        handle: marlin_aio.PrintHandle,
        server: SimulatorServer,
        faults: Faults,
        ran_before: int,
        group: asyncio.TaskGroup,
    ) -> None:
        """What a hand on the board or the application does, each once, at its line: a reset, a silent board, a
        pause of 0.2 s, a cancel. Watched every `WATCH_INTERVAL_S`, as no event says that a line ran."""
        scenario = self.scenario
        board = server.printer
        reset_at, silent_at = scenario.reset_at_line, scenario.silent_at_line
        pause_at, cancel_at = scenario.pause_at_line, scenario.cancel_at_line
        while not handle.finished and any(at is not None for at in (reset_at, silent_at, pause_at, cancel_at)):
            ran = board.executed_line_count - ran_before
            if reset_at is not None and ran >= reset_at:
                reset_at = None
                self.mishaps["reset"] += 1
                board.reset(server.now())
                server.poke()
            if silent_at is not None and ran >= silent_at:
                silent_at = None
                self.mishaps["silent"] += 1
                faults.silent = True
                server.poke()
            if cancel_at is not None and handle.job.lines_acked >= cancel_at:
                cancel_at = None
                self.mishaps["cancel"] += 1
                group.create_task(self._cancel(handle), name="cancel")
            if pause_at is not None and handle.job.lines_acked >= pause_at:
                pause_at = None
                if handle.job.active:
                    self.mishaps["pause"] += 1
                    handle.pause()
                    self.waiting["pause"] = "0.2 s of pause"
                    await asyncio.sleep(0.2)
                    del self.waiting["pause"]
                    handle.resume()
                continue
            await asyncio.sleep(WATCH_INTERVAL_S)

    async def _cancel(self, handle: marlin_aio.PrintHandle) -> None:
        self.waiting["cancel"] = "the cancelled print's end"
        with contextlib.suppress(MarlinError):  # the print failed first: counted where it is awaited
            await handle.cancel()
        del self.waiting["cancel"]

    def _host_request(self, request: HostRequest) -> None:
        self._asked.set()

    async def _answer(self, printer: marlin_aio.Printer, rng: random.Random) -> None:
        """A person at the printer: a wait for the user (the runout's M600) or a prompt with buttons is answered
        within 0.05-0.4 s, with `answer_prompt(0)` (M876 S0) or `interrupt_wait()` (M108), and again after 0.8 s
        if the wait goes on (the answer's bytes may have been damaged on the way)."""
        while True:
            await self._asked.wait()
            self._asked.clear()
            while _asked(printer) and not self.over.is_set():
                await asyncio.sleep(0.05 + rng.random() * 0.35)
                if not _asked(printer) or self.over.is_set():
                    break
                prompt = printer.prompt
                self.mishaps["answer"] += 1
                with contextlib.suppress(MarlinError, ValueError):  # the prompt closed, or the link ended
                    if prompt is not None and prompt.buttons and rng.random() < 0.7:
                        await printer.answer_prompt(0)
                    else:
                        printer.interrupt_wait()
                await asyncio.sleep(0.8)

    async def _emergencies(self, printer: marlin_aio.Printer, rng: random.Random, interval_s: float) -> None:
        """Emergency writes nobody asked for, about every `interval_s`: M108 ends no wait, and an M876 answers a
        prompt only when one is open; each is still queued by the board and answered by its own ok in its turn."""
        while True:
            await asyncio.sleep(rng.expovariate(1.0 / interval_s))
            prompt = printer.prompt
            self.mishaps["emergency"] += 1
            with contextlib.suppress(MarlinError, ValueError):  # the prompt closed, or the link ended
                if rng.random() < 0.5 and prompt is not None and prompt.buttons:
                    await printer.answer_prompt(0)
                else:
                    printer.interrupt_wait()

    async def _user(self, printer: marlin_aio.Printer, user: int, interval_s: float) -> None:
        """A caller sending `M118 U<k>`, each awaited before the next, as a task calling `send()` does."""
        loop = asyncio.get_running_loop()
        scenario = self.scenario
        result = self.result
        rng = self.rng
        who = f"user {user}"
        await asyncio.sleep(0.01 + rng.random() * 0.01)
        while not self.over.is_set():
            text = f"M118 U{next(self._tokens)}"
            stats = printer.stats
            started = loop.time()
            # The core campaign's bound: its own timeout after every command ahead of it (itself included) had
            # theirs, with room for resends.
            bound = started + scenario.timeout_s * (stats.in_flight + stats.queued + 4) + 5.0
            # Within 10 ms, while the command is on its way (an answer takes 2-5 ms here): its late answer must reach
            # nobody, and never the next caller.
            give_up_s = rng.random() * GIVE_UP_WITHIN_S if rng.random() < scenario.give_up else None
            self.waiting[who] = f"{text!r} since {started:.3f} s"
            reply: Reply | None = None
            try:
                if give_up_s is None:
                    reply = await printer.send(text)
                else:
                    reply = await asyncio.wait_for(printer.send(text), give_up_s)
            except MarlinError as error:  # first: a command's own timeout is a TimeoutError too
                result.user_failures += 1
                result.failures_by_kind[type(error).__name__] += 1
            except TimeoutError:
                result.users_gave_up += 1
            finally:
                del self.waiting[who]
            if loop.time() > bound:
                result.problems.append(f"{text!r} finished at {loop.time():.2f} s, past its bound {bound:.2f} s")
            if reply is not None:
                _check_reply(_as_command(text), reply, "user", result)
            await asyncio.sleep(rng.expovariate(1.0 / interval_s))

    async def _ask_position(self, printer: marlin_aio.Printer) -> None:
        """M114 after a relative print that reported done; asked again if its ok was lost on a faulty link."""
        for _ in range(3):
            self.waiting["position"] = "M114"
            try:
                reply = await printer.send("M114")
            except MarlinError:
                continue
            finally:
                del self.waiting["position"]
            self.position = list(reply.lines)  # checked at the end, unless the run hit the blind spot
            return


def _asked(printer: marlin_aio.Printer) -> bool:
    """The printer waits for a person: a command waits for the user, or a prompt with buttons is open."""
    prompt = printer.prompt
    return printer.waiting_for_user or (prompt is not None and bool(prompt.buttons))


def _as_command(text: str) -> Command:
    """A stand-in for the core's record of a command, which is all `_check_reply` reads of it (its text)."""
    return Command(id=0, text=text, code=text.split()[0], numbered=True, timeout_s=0.0, submitted_s=0.0)


def _check(server: SimulatorServer, session: _Session, result: CampaignResult) -> None:
    """The invariants on the simulator's record, as `_campaign.run_print` checks them after its own loop.

    Beyond the simulator's count of lines damaged unseen (`unseen_damage`: two flips that cancel in the checksum,
    or an `N` turned into `n` with more flips behind it), two faults no host can see make the blind spot here:
    a print line that ran in its place as a damaged copy (a text that is no line of the file) while the board ran
    lines unnumbered (its `N` was hit, and its body by a flip or by `corrupt`: an unnumbered line has no
    checksum), and a user's command that the board ran as a damaged copy (`M119 U07` for `M118 U17`), whose reply
    is then the other command's.
    """
    board = server.printer
    scenario = result.scenario
    lines = session.lines
    job = session.job
    ran = list(board.executed)
    result.bits_flipped = board.bits_flipped
    unnumbered = board.unnumbered_runs - session.unnumbered_before[0]
    result.blind_spot = (
        board.unseen_damage > 0
        or board.unnumbered_m105_runs > session.unnumbered_before[1]
        or (unnumbered > 0 and scenario.drop_ok > 0)
        or (unnumbered > 0 and _damaged_in_place(ran, lines))
    )
    _judge_foreign_replies(ran, result)
    result.state = job.state
    result.error = None if job.error is None else str(job.error)
    result.lines_said_run = job.last_source_line
    if job.active:
        result.problems.append(f"the print was still {job.state.value} at the end ({result.end_s:.0f} s)")
    _check_record(board, lines, job, result)
    if result.damaged_replies and not result.blind_spot:
        result.problems.append(f"{result.damaged_replies} replies were damaged copies, but no line was damaged unseen")
    if job.state is PrintState.DONE and scenario.relative and not result.blind_spot:
        _check_position(session.position, lines, result)
