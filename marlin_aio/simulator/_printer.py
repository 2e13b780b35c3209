"""The simulated Marlin firmware, sans-I/O: bytes in, bytes out, time passed in by the caller.

`SimulatedPrinter` never reads a clock, sleeps or touches a port. The caller hands it the host's bytes with
`receive(data, now)`, lets time pass with `advance(now)`, collects the reply bytes with `take_output()` and asks
`next_wakeup()` when it must call again. Every run with the same inputs, times and seed gives the same bytes, so
the tests drive it through minutes of simulated heating in microseconds.

This module is the core: time, the command ring, execution and output, one state machine in one class. It is
over 400 lines, over half of them this docstring, the public face and the documented counters; the core proper
is some 210 lines whose steps share the ring, the running task and the output, and parting it further would put
calls on the per-line path. It composes the parts that live in files of their own:

- `_config`: how the board is built (`SimulatorConfig`) and the faults it shows (`Faults`).
- `_intake`: the wire's bit flips (`WireFlips`), the receive buffer, the emergency parser and the line checks
  (`LineReader`), which hand it `Command`s.
- `_board`: the state the commands work on (`Board`: the clock, the heaters, the position and the planner's
  queue, the modes and intervals commands set). The printer owns it and hands it to each command's handler.
- `_gcode` (and `_heating` for the temperature commands): what each command does, by code, written against the
  `Board` alone.
- `_thermal`: the heaters, integrated lazily on a fixed grid, so temperatures do not depend on call frequency.

How it follows Marlin 2.1 (`MarlinCore.cpp`, `gcode/gcode.cpp`):

- Execution is an event simulation on integer microseconds. A command either finishes at once or becomes a task
  (a generator yielding the simulated time at which it next needs to run) while keepalives and auto-reports keep
  their own timers, as `idle()` does. Integer time keeps ties exact: a keepalive due at the same moment as an M109
  wait line comes first, as in the captures.
- Each kind of random fault draws from a stream of its own (derived from the seed), so which `ok`s are dropped
  does not depend on how the host's bytes happened to be split into reads.
- After power-up or `reset()` the board sits in its bootloader for `SimulatorConfig.boot_delay_s`: it reads
  nothing (the host's bytes are dropped) and says nothing until its `start` line.
- What was run is recorded in `executed` and `executed_line_numbers`, bounded to the last
  `SimulatorConfig.record_limit` entries so a simulator served for hours does not grow without end;
  `executed_count` and `executed_line_count` keep the totals.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Sequence

from marlin_aio.simulator._board import Board, Task
from marlin_aio.simulator._config import BUILD_DATE, SETTINGS_LINES, US_PER_S, Faults, SimulatorConfig, to_us
from marlin_aio.simulator._gcode import handler_table, tool_change, unknown
from marlin_aio.simulator._heating import heater_states
from marlin_aio.simulator._hostactions import answer_prompt, check_line, open_prompt, runout_then
from marlin_aio.simulator._intake import Command, LineReader, WireFlips
from marlin_aio.simulator._record import BoundedRecord

# Faults and SimulatorConfig are re-exported: they were defined here, and code imports them from here.
__all__ = ["Faults", "SimulatedPrinter", "SimulatorConfig"]

_LOCKED = "echo:Printer locked! (Unlock with M511 or LCD)"  # STR_PRINTER_LOCKED, as SERIAL_ECHO_MSG prints it
_LOST_MCU = "!! Lost communication with MCU 'mcu'"
#: Numbered lines a host sends beside a print's own (polls, renumbering): a runout waits for a print line.
_NOT_PRINTING = frozenset({"M105", "M110"})
# What a host writes without a line number on purpose, for the emergency parser (`Connection.emergency`).
_BARE_BY_DESIGN = frozenset({"M108", "M410", "M876"})


class SimulatedPrinter:
    """A Marlin 2.1 board behind a serial line, driven without I/O.

    All times are simulated seconds (`now`); they must not go backwards (an earlier `now` counts as the latest one).
    """

    def __init__(
        self,
        config: SimulatorConfig | None = None,
        faults: Faults | None = None,
        *,
        now: float = 0.0,
        boot: bool = True,
    ) -> None:
        """Power the board up at `now`; with `boot` its banner is the first output."""
        self.config = config if config is not None else SimulatorConfig()
        self.faults = faults if faults is not None else Faults()
        limit = self.config.record_limit
        self.executed: BoundedRecord[str] = BoundedRecord(limit)
        """The commands executed, in order, as received minus line number, checksum, comment and trailing
        spaces: the last `SimulatorConfig.record_limit` of them (`executed_count` counts all)."""
        self.executed_line_numbers: BoundedRecord[int] = BoundedRecord(limit)
        """The number of each numbered line executed, in order (unnumbered commands add nothing): the last
        `SimulatorConfig.record_limit` of them (`executed_line_count` counts all)."""
        self.unnumbered_runs = 0
        """How many commands ran that came without a line number (`M110 N0`-style hosts number every line, so
        for them each is a line whose `N` the wire damaged, or the tail of a line cut by a line error's flush). The
        commands a host writes bare for the emergency parser (M108, M410, M876) are not counted."""
        self.unnumbered_m105_runs = 0
        """Of those, how many were an M105 (whose `ok T:` cannot show whether it was counted) run while a line
        before it had been dropped without a word: its answer then seems to prove that line ran."""
        self.rx_overflows = 0
        """How many arrivals of bytes found the receive buffer too full to hold them all."""
        self.rx_dropped_bytes = 0
        """How many received bytes were dropped because the receive buffer was full."""
        self.halted = False
        """True after kill() (M112, thermal runaway) until `reset()`: nothing is answered."""
        self.stalled = False
        """True once `Faults.silent_after_lines` struck, until `reset()`: bytes are buffered, nothing else."""
        seed = self.config.seed
        self._drop_ok_rng = random.Random(f"{seed}:drop-ok")
        self._noise_rng = random.Random(f"{seed}:noise")
        self._not_executed_rng = random.Random(f"{seed}:not-executed")
        self._out = bytearray()
        self._board = Board(self.config, to_us(now), emit=self._emit, kill=self._kill)
        self._wire = WireFlips(seed)
        self._booting_until: int | None = None
        self._boot_cause = "PowerUp"
        self._reader = LineReader(self.config, self._emit)
        self._handlers = handler_table(self.config)
        # M110 sets the counter when it runs (M110.cpp), not only as its line is read.
        self._handlers["M110"] = self._m110
        self._clear_state()
        if boot:
            self._boot("PowerUp", self.config.boot_delay_s)

    # ----------------------------------------------------------------------------------------------- public API

    @property
    def executed_count(self) -> int:
        """How many commands were executed since power-up, also those `executed` no longer keeps."""
        return self.executed.total

    @property
    def executed_line_count(self) -> int:
        """How many numbered lines were executed since power-up, also those `executed_line_numbers` no longer
        keeps."""
        return self.executed_line_numbers.total

    @property
    def bits_flipped(self) -> int:
        """How many bits of the host's bytes the wire flipped so far (`Faults.flip_bit_ratio`, `Faults.flip_once`)."""
        return self._wire.count

    @property
    def unseen_damage(self) -> int:
        """How many lines the wire damaged in a way no check of Marlin's can see (`WireFlips.unseen`), or a flip
        and a replaced byte together (`LineReader.unseen`): the 8-bit XOR's blind spot. No host can keep such a
        line from running as it arrived."""
        return self._wire.unseen + self._reader.unseen

    @property
    def booting(self) -> bool:
        """True while the board is in its bootloader after power-up or `reset()` (`boot_delay_s`): deaf and mute."""
        return self._booting_until is not None

    def receive(self, data: bytes, now: float) -> None:
        """Bytes from the host arriving at `now`.

        The wire's faults (`Faults.flip_bit_ratio`, `Faults.flip_once`) act on them first. Lines move on into the
        command buffer while the bytes come in, as the board's main loop keeps reading, so only bytes that find
        the receive buffer full while the command buffer is full too are lost (counted in `rx_overflows` and
        `rx_dropped_bytes`). A board in its bootloader drops them all.
        """
        self._run_until(to_us(now))
        if not data:
            return
        data = self._wire.carry(data, self.faults)
        if self.halted or not data or self._booting_until is not None:
            return
        if self.stalled:
            self._count_overflow(self._reader.store(data))
            return
        if self.config.emergency_parser:
            self._emergency_parse(data)
            if self.halted:
                return
        size = self.config.rx_buffer_size
        rx = self._reader.rx
        taken = 0
        while taken < len(data):
            room = size - len(rx)
            if room <= 0:
                self._count_overflow(len(data) - taken)
                return
            rx += data[taken : taken + room]
            taken += room
            self._settle()
            if self.halted:
                return
            if self.stalled:
                self._count_overflow(self._reader.store(data[taken:]))
                return

    def advance(self, now: float) -> None:
        """Let simulated time pass up to `now`."""
        self._run_until(to_us(now))

    def take_output(self) -> bytes:
        """Return the bytes written to the host since the last call."""
        data = bytes(self._out)
        self._out.clear()
        return data

    def next_wakeup(self) -> float | None:
        """Simulated time at which `advance()` must next be called, or None while nothing is scheduled."""
        if self._booting_until is not None:
            return self._booting_until / US_PER_S
        if self.halted or self.stalled:
            return None
        due = self._next_event_us()
        return None if due is None else due / US_PER_S

    def reset(self, now: float, *, boot_delay_s: float | None = None) -> None:
        """Reset the board at `now`: everything in flight is lost, line counter 0, targets 0, and the banner
        again once the bootloader is done, `boot_delay_s` later (None: `SimulatorConfig.boot_delay_s`).

        Raises:
            ValueError: if `boot_delay_s` is negative.
        """
        delay_s = self.config.boot_delay_s if boot_delay_s is None else boot_delay_s
        if not delay_s >= 0.0:
            raise ValueError(f"boot_delay_s must not be negative, got {boot_delay_s!r}")
        self._run_until(to_us(now))
        self._board.sync_thermal()
        self.halted = False
        self.stalled = False
        self._board.reset()
        self._clear_state()
        self._boot("External Reset", delay_s)

    def thermal_runaway(self, now: float, heater: str = "E0") -> None:
        """Trip thermal protection at `now`: the error, the kill() line, then silence until `reset()`.

        Raises:
            ValueError: if `heater` is empty or not one line.
        """
        if not heater or "\n" in heater or "\r" in heater:
            raise ValueError(f"heater must be a one-line name such as 'E0' or 'bed', got {heater!r}")
        self._run_until(to_us(now))
        if self.halted or self.stalled or self._booting_until is not None:
            return
        self._emit(f"Error:Thermal Runaway, system stopped! Heater_ID: {heater}")
        self._kill()

    def open_prompt(self, now: float, message: str, buttons: Sequence[str] = ("Continue",)) -> None:
        """Show a prompt at `now` as HOST_PROMPT_SUPPORT does (`prompt_end`, `prompt_begin`, a `prompt_button` per
        button, `prompt_show`); the host's `M876 S<index>` answers it (`prompt`, `prompt_answers`).

        Raises:
            ValueError: the message or a button is not one line, or a button is empty.
        """
        check_line("message", message)
        for label in buttons:
            check_line("a button", label)
            if not label.strip():
                raise ValueError("a button needs a label")
        self._run_until(to_us(now))
        if self.halted or self.stalled or self._booting_until is not None:
            return
        open_prompt(self._board, message, buttons)

    def host_action(self, now: float, action: str, argument: str = "") -> None:
        """Send `//action:<action> <argument>` at `now`: `pause`, `paused`, `resume`, `resumed`, `cancel`,
        `disconnect`, `notification <text>`, ...

        Raises:
            ValueError: `action` is not one word, or `argument` is not one line.
        """
        if not action or not action.isascii() or any(c.isspace() for c in action):
            raise ValueError(f"action must be one word such as 'cancel', got {action!r}")
        check_line("argument", argument)
        self._run_until(to_us(now))
        if self.halted or self.stalled or self._booting_until is not None:
            return
        self._emit(f"//action:{action} {argument}" if argument else f"//action:{action}")

    def answer_on_screen(self, now: float, index: int = 0) -> None:
        """A person at the printer picks button `index` of the open prompt on its screen at `now` (a click that
        ends M600's wait), as M876 S<index> would; with no prompt open, the click ends a wait for the user."""
        self._run_until(to_us(now))
        board = self._board
        if board.prompt is not None:
            answer_prompt(board, index, by_host=False)
        elif board.wait_for_user:
            board.wait_for_user = False
            board.poked = True

    @property
    def prompt(self) -> tuple[str, tuple[str, ...]] | None:
        """The prompt shown to the host and not yet answered (its message and buttons), or None."""
        return self._board.prompt

    @property
    def prompt_answers(self) -> list[int]:
        """The button of each prompt the host answered (`M876 S<index>`), in order, since power-up."""
        return self._board.answers

    @property
    def waiting_for_user(self) -> bool:
        """True while M600 (or a runout's M600) waits for the host's answer or M108."""
        return self._board.wait_for_user

    @property
    def thermal_steps(self) -> int:
        """Grid steps the thermal model has integrated one by one, over all heaters (its work, for tests)."""
        self._board.sync_thermal()
        return self._board.heaters.integrated_steps

    def heater_celsius(self, name: str) -> float:
        """Current simulated temperature of heater `name`: "T0", "T1", ... "B" (bed) or "C" (chamber).

        Raises:
            ValueError: if the printer has no such heater.
        """
        heaters = self._board.heaters.by_name
        heater = heaters.get(name)
        if heater is None:
            raise ValueError(f"no heater {name!r}; this printer has {', '.join(heaters)}")
        self._board.sync_thermal()
        return heater.celsius

    # ------------------------------------------------------------------------------------------ state and time

    def _clear_state(self) -> None:
        """Power-on state of the core's part of what a reset loses (the board's is `Board.reset()`)."""
        self._reader.reset()
        self._ring: deque[Command] = deque()
        self._task: Task | None = None
        self._task_due = 0
        self._next_keepalive: int | None = None
        # The command the loop is working through before it runs it (`command_time_s`), and when it is done.
        self._loop_command: Command | None = None
        self._loop_due = 0

    def _loop_time_us(self, command: Command) -> int:
        config = self.config
        return to_us(config.report_time_s if command.code == "M105" else config.command_time_s)

    def _next_event_us(self) -> int | None:
        due: int | None = self._board.next_report_us
        if self._loop_command is not None and (due is None or self._loop_due < due):
            due = self._loop_due
        if self._task is not None:
            if due is None or self._task_due < due:
                due = self._task_due
            if self._next_keepalive is not None and self._next_keepalive < due:
                due = self._next_keepalive
        return due

    def _boot(self, cause: str, delay_s: float) -> None:
        """Start the firmware, after `delay_s` in the bootloader (a banner saying `cause` when it starts)."""
        if delay_s > 0.0:
            self._booting_until = self._board.now_us + to_us(delay_s)
            self._boot_cause = cause
        else:
            self._booting_until = None
            self._print_banner(cause)

    def _run_until(self, now_us: int) -> None:
        """Process every event up to `now_us` in time order."""
        board = self._board
        if self._booting_until is not None:
            if now_us < self._booting_until:
                board.now_us = max(board.now_us, now_us)
                return
            board.now_us = max(board.now_us, self._booting_until)
            self._booting_until = None
            self._print_banner(self._boot_cause)
        if not (self.halted or self.stalled):
            while True:
                self._settle()
                due = self._next_event_us()
                if self.halted or self.stalled or due is None or due > now_us:
                    break
                board.now_us = max(board.now_us, due)
                self._fire_timers()
        board.now_us = max(board.now_us, now_us)

    def _fire_timers(self) -> None:
        """What idle() prints at this moment; the task itself resumes in `_settle()`."""
        board = self._board
        now = board.now_us
        if self._task is not None and self._next_keepalive is not None and self._next_keepalive <= now:
            reason = board.busy_reason
            self._emit(f"busy:{reason}" if self.config.bare_busy else f"echo:busy: {reason}")
            interval = board.keepalive_interval_us
            self._next_keepalive = now + interval if interval > 0 else None
        if board.next_report_us is not None and board.next_report_us <= now:
            self._emit(heater_states(board, board.active_extruder))
            board.next_report_us = now + board.report_interval_us

    def _settle(self) -> None:
        """Run everything that can happen at this instant: resume a due task, take in lines, run commands."""
        board = self._board
        while not (self.halted or self.stalled):
            if self._task is not None:
                if self._task_due > board.now_us and not board.poked:
                    self._intake()
                    return
                board.poked = False
                try:
                    self._task_due = next(self._task)
                except StopIteration:
                    self._task = None
                    self._finish_command()
                    continue
                self._intake()
                return
            self._intake()
            if not self._ring:
                return
            command = self._ring[0]
            if self._loop_command is not command:
                cost = self._loop_time_us(command)
                if cost > 0:
                    # The loop's own time over this command (`command_time_s`) comes before it runs.
                    self._loop_command = command
                    self._loop_due = board.now_us + cost
            if self._loop_command is command:
                if self._loop_due > board.now_us:
                    return
                self._loop_command = None
            self._start_command(command)

    # ------------------------------------------------------------------------------------------------- intake

    def _intake(self) -> None:
        """Move whole lines from the receive buffer into the command ring while it has room."""
        if not (self.halted or self.stalled):
            self._reader.take_lines(self._ring, self.faults, busy=self._task is not None)

    def _count_overflow(self, dropped: int) -> None:
        if dropped > 0:
            self.rx_overflows += 1
            self.rx_dropped_bytes += dropped

    def _emergency_parse(self, data: bytes) -> None:
        """Act on M108/M112/M410 lines as their bytes arrive, before the receive buffer (e_parser.h)."""
        for code in self._reader.emergency_codes(data):
            if code == b"108":
                self._board.wait_for_heatup = False
                self._board.wait_for_user = False
                self._board.poked = True
            elif code.startswith(b"876"):
                answer_prompt(self._board, int(code.rpartition(b"S")[2]))
            elif code == b"112":
                self._emit("echo:M112 Shutdown")
                self._kill()
                return
            else:
                self._board.quick_stop()

    # ---------------------------------------------------------------------------------------------- execution

    def _start_command(self, command: Command) -> None:
        board = self._board
        board.skip_ok = False
        ratio = self.faults.not_executed_ratio
        if ratio > 0.0 and self._not_executed_rng.random() < ratio:
            self._emit(_LOST_MCU)
            self._finish_command()
            return
        if board.locked and command.code != "M511":
            # gcode.cpp refuses everything but M511 before looking at the command.
            self._emit(_LOCKED)
            self._finish_command()
            return
        self.executed.append(command.text.rstrip(" "))  # a comment cut after a space leaves the space behind
        if (
            command.line_number is None
            and (command.code in self._handlers or command.code[:1] == "T")
            and not (command.code in _BARE_BY_DESIGN and self.config.emergency_parser)
        ):
            self.unnumbered_runs += 1
            if command.code == "M105" and self._reader.dropped_since_counted:
                self.unnumbered_m105_runs += 1
        if command.line_number is not None:
            self.executed_line_numbers.append(command.line_number)
        handler = self._handlers.get(command.code)
        if handler is None:
            handler = tool_change if command.code[:1] == "T" else unknown
        runout = self.faults.runout_at_line
        if (
            runout is not None
            and command.line_number is not None
            and command.line_number >= runout
            and command.code not in _NOT_PRINTING
        ):
            self.faults.runout_at_line = None  # it strikes once
            task: Task | None = runout_then(board, command, handler)
        else:
            task = handler(board, command)
        if self.halted:
            return
        if task is None:
            self._finish_command()
            return
        try:
            self._task_due = next(task)
        except StopIteration:
            self._finish_command()
            return
        self._task = task
        interval = board.keepalive_interval_us
        self._next_keepalive = board.now_us + interval if interval > 0 else None

    def _finish_command(self) -> None:
        command = self._ring[0]
        if not self._board.skip_ok and not self.halted:
            self._send_ok(command)
        self._ring.popleft()
        self._next_keepalive = None
        limit = self.faults.silent_after_lines
        if limit is not None and command.line_number is not None and self.executed_line_count >= limit:
            self.stalled = True

    def _send_ok(self, command: Command) -> None:
        ratio = self.faults.drop_ok_ratio
        if ratio > 0.0 and self._drop_ok_rng.random() < ratio:
            return
        if command.code in self.faults.drop_ok_codes:
            return
        self._emit(self._ok_line(command))

    def _ok_line(self, command: Command) -> str:
        """`ok`, with ADVANCED_OK `ok N<line> P<free blocks> B<free slots>`."""
        if not self.config.advanced_ok:
            return "ok"
        free_blocks = self._board.moves_free()
        free_slots = self.config.command_buffer_size - len(self._ring)
        label = "" if command.line_label is None else f" {command.line_label}"
        return f"ok{label} P{free_blocks} B{free_slots}"

    def _kill(self) -> None:
        """kill(): heaters off, the halt line, then nothing more until reset."""
        self._emit("Error:Printer halted. kill() called!")
        self._board.sync_thermal()
        self._board.heaters.switch_off()
        self.halted = True
        self._task = None
        self._ring.clear()
        self._reader.clear()
        self._board.planner.clear()

    # ---------------------------------------------------------------------------------------------- output

    def _emit(self, line: str) -> None:
        faults = self.faults
        if faults.silent or self.stalled:
            return
        ratio = faults.noise_ratio
        if ratio > 0.0 and self._noise_rng.random() < ratio:
            garbage = bytearray(self._noise_rng.randbytes(self._noise_rng.randint(1, 16)))
            if 0x20 <= garbage[0] <= 0x7E:
                garbage[0] |= 0x80  # never a printable start, so noise never looks like "ok" or "echo:"
            self._out += garbage.replace(b"\n", b"\x00").replace(b"\r", b"\xff")
            self._out += b"\n"
        self._out += line.encode("latin-1")
        self._out += b"\n"

    def _print_banner(self, cause: str) -> None:
        self._emit("start")
        self._emit(cause)
        self._emit(self.config.firmware_name)
        self._emit("echo: Last Updated: 2024-01-01 | Author: (none, default config)")
        self._emit(f"echo: Compiled: {BUILD_DATE[:11]}")
        self._emit(f"echo: Free Memory: 0  PlannerBufferBytes: {92 * self.config.planner_buffer_size}")
        self._emit("echo:Hardcoded Default Settings Loaded")
        for line in SETTINGS_LINES:
            self._emit(line)

    # ------------------------------------------------------------------------------------------------ handler

    def _m110(self, board: Board, command: Command) -> None:
        """M110 N<n>: set the line counter as the command runs (numbered lines set it as they were read, too)."""
        self._reader.run_m110(command)
