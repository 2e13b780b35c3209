"""The simulated Marlin firmware, sans-I/O: bytes in, bytes out, time passed in by the caller.

`SimulatedPrinter` never reads a clock, sleeps or touches a port. The caller hands it the host's bytes with
`receive(data, now)`, lets time pass with `advance(now)`, collects the reply bytes with `take_output()` and asks
`next_wakeup()` when it must call again. Every run with the same inputs, times and seed gives the same bytes, so
the tests drive it through minutes of simulated heating in microseconds.

How it follows Marlin 2.1 (`gcode/queue.cpp`, `MarlinCore.cpp`, `module/temperature.cpp`):

- Intake: bytes land in the serial receive buffer (`rx_buffer_size`, overflow dropped). Whole lines move from there
  into the command ring (`command_buffer_size` slots, the running command included) whenever a slot is free, also
  while a long command blocks: Marlin's `idle()` calls `manage_inactivity()`, which calls
  `queue.get_available_commands()`. The captures show it too: the `ok` ending an M109 that had commands sent
  behind it reads `B0`, not `B3`. So line-number and checksum errors are answered (`Resend:` and `ok`) even while
  G28 or M109 runs.
- The emergency parser sees bytes as they arrive, before the receive buffer, so M108/M112/M410 act even when the
  buffer is full; the line itself is still queued and later answered with an `ok` (Marlin's no-op case).
- Execution is an event simulation on integer microseconds. A command either finishes at once or becomes a task
  (a generator yielding the simulated time at which it next needs to run) while keepalives and auto-reports keep
  their own timers, as `idle()` does. Integer time keeps ties exact: a keepalive due at the same moment as an M109
  wait line comes first, as in the captures.
- Temperatures come from `_thermal`, integrated lazily on a fixed grid, so they do not depend on call frequency.
- M112 without the emergency parser halts when its turn comes, as `gcode.cpp` does (`case 112: M112()`); one
  capture shows a board answering it with `ok` instead, which the source does not explain.
- Moves take distance / feedrate (no acceleration), so streamed moves finish a little sooner than on the board;
  `motion_time_scale` shortens them further, so a benchmark of the serial link is not bound by the planner.
- Line-number protection as in 2.1.2: a numbered line is run only when it is the next number, so a line is run
  once however often the host sends it. A repeat of the last line (the host retransmitted because an `ok` went
  missing) gets the line-number error and a `Resend:` of the next line; with `ignore_duplicate_lines` the two
  numbers below the next one are dropped without a word instead, as newer `queue.cpp` sources do.
- Each kind of random fault draws from a stream of its own (derived from the seed), so which `ok`s are dropped
  does not depend on how the host's bytes happened to be split into reads.
- Dialects a host meets in the field (Marlin forks, Repetier-compatible boards, options) are switches of
  `SimulatorConfig`, each off by default: `checksum_required`, `plain_wait_lines`, `bare_busy`,
  `repetier_targets`, `m114_on_ok` and `password` (PASSWORD_FEATURE). A host-side bridge that drops commands is
  the fault `Faults.not_executed_ratio`.
- What was run is recorded in `executed` and `executed_line_numbers`, bounded to the last
  `SimulatorConfig.record_limit` entries so a simulator served for hours does not grow without end;
  `executed_count` and `executed_line_count` keep the totals.
"""

from __future__ import annotations

import math
import random
import re
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass

from marlin_aio.commands import checksum
from marlin_aio.simulator._record import BoundedRecord
from marlin_aio.simulator._thermal import BED, CHAMBER, HOTEND, STEP_US, Heater

__all__ = ["Faults", "SimulatedPrinter", "SimulatorConfig"]

_US_PER_S = 1_000_000
_STEPS_PER_MM = (80.0, 80.0, 400.0)  # X Y Z, as in the captured board's M92
_MAX_COMMAND_CHARS = 95  # MAX_CMD_SIZE 96 including the NUL
_DEFAULT_FEEDRATE_MM_S = 1500.0 / 60.0
# TEMP_RESIDENCY_TIME / TEMP_WINDOW / TEMP_HYSTERESIS (the bed and chamber use the same defaults).
_RESIDENCY_US = 10 * _US_PER_S
_WINDOW_CELSIUS = 1.0
_HYSTERESIS_CELSIUS = 3.0
# MIN_COOLING_SLOPE_DEG over MIN_COOLING_SLOPE_TIME: an `R` wait that stops cooling gives up.
_COOLING_SLOPE_CELSIUS = 1.5
_COOLING_SLOPE_US = 60 * _US_PER_S
_WAIT_REPORT_US = _US_PER_S

_LOCKED = "echo:Printer locked! (Unlock with M511 or LCD)"  # STR_PRINTER_LOCKED, as SERIAL_ECHO_MSG prints it
_LOST_MCU = "!! Lost communication with MCU 'mcu'"
_M511_PASSWORD = re.compile(r"P *(\S+)")

_BUILD_DATE = "Jan  1 2024 12:00:00"
_UUID = "cede2a2f-41a2-4748-9b12-c55c62f367ff"

#: What M503 prints, and the boot banner after "Hardcoded Default Settings Loaded" (from boot-banner.txt).
_SETTINGS_LINES = (
    "echo:; Linear Units:",
    "echo:  G21 ; (mm)",
    "echo:; Temperature Units:",
    "echo:  M149 C ; Units in Celsius",
    "echo:; Filament settings (Disabled):",
    "echo:  M200 S0 D1.75",
    "echo:; Steps per unit:",
    "echo:  M92 X80.00 Y80.00 Z400.00 E500.00",
    "echo:; Max feedrates (units/s):",
    "echo:  M203 X300.00 Y300.00 Z5.00 E25.00",
    "echo:; Max Acceleration (units/s2):",
    "echo:  M201 X3000.00 Y3000.00 Z100.00 E10000.00",
    "echo:; Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):",
    "echo:  M204 P3000.00 R3000.00 T3000.00",
    "echo:; Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>):",
    "echo:  M205 B20000.00 S0.00 T0.00 J0.01",
    "echo:; Home offset:",
    "echo:  M206 X0.00 Y0.00 Z0.00",
    "echo:; Hotend PID:",
    "echo:  M301 P22.20 I1.08 D114.00",
)

#: M115 capability lines in the captured order; None marks the ones that follow the configuration.
_CAPABILITIES: tuple[tuple[str, int | None], ...] = (
    ("SERIAL_XON_XOFF", 0),
    ("BINARY_FILE_TRANSFER", 0),
    ("EEPROM", 0),
    ("VOLUMETRIC", 1),
    ("AUTOREPORT_POS", 0),
    ("AUTOREPORT_TEMP", None),
    ("PROGRESS", 0),
    ("PRINT_JOB", 1),
    ("AUTOLEVEL", 0),
    ("RUNOUT", 0),
    ("Z_PROBE", 0),
    ("LEVELING_DATA", 0),
    ("BUILD_PERCENT", 0),
    ("SOFTWARE_POWER", 0),
    ("TOGGLE_LIGHTS", 0),
    ("CASE_LIGHT_BRIGHTNESS", 0),
    ("EMERGENCY_PARSER", None),
    ("HOST_ACTION_COMMANDS", 0),
    ("PROMPT_SUPPORT", 0),
    ("SDCARD", 0),
    ("REPEAT", 0),
    ("SD_WRITE", 0),
    ("AUTOREPORT_SD_STATUS", 0),
    ("LONG_FILENAME", 0),
    ("LFN_WRITE", 0),
    ("CUSTOM_FIRMWARE_UPLOAD", 0),
    ("EXTENDED_M20", 0),
    ("THERMAL_PROTECTION", 1),
    ("MOTION_MODES", 0),
    ("ARCS", 1),
    ("BABYSTEPPING", 0),
    ("EP_BABYSTEP", 0),
    ("CHAMBER_TEMPERATURE", None),
    ("COOLER_TEMPERATURE", 0),
    ("MEATPACK", 0),
    ("CONFIG_EXPORT", 0),
)

# Commands Marlin accepts that change nothing the simulation shows.
_NO_OPS = frozenset(
    {"G21", "M17", "M18", "M84", "M92", "M106", "M107", "M117", "M149", "M200", "M201", "M203", "M204", "M205"}
    | {"M206", "M220", "M221", "M301", "M999"}
)

_EOL = re.compile(rb"[\r\n]")
_LINE_NUMBER_PREFIX = re.compile(r"N-?\d+ *")
_COMMAND_WORD = re.compile(r"([GMT])(\d+)(?:\.\d+)? *")
_PARAMETER = re.compile(r"([A-Z]) *([-+]?(?:\d+\.?\d*|\.\d+))?")
_LEADING_INT = re.compile(r" *([-+]?\d+)")
# What Marlin's emergency parser (feature/e_parser.h) recognises at the start of a line.
_EMERGENCY_LINE = re.compile(rb" *(?:N[-0-9 ]*)?M *(108|112|410)")
_EMERGENCY_HINT = re.compile(rb"1[01][028]|410")
_EMERGENCY_TAIL_MAX = 64

_Task = Generator[int, None, None]
"""A blocking command: each `yield` gives the simulated microsecond at which it next needs to run."""


@dataclass
class SimulatorConfig:
    """How the simulated board is built (Marlin's compile-time configuration)."""

    advanced_ok: bool = False
    """ADVANCED_OK: `ok N<line> P<planner free> B<buffer free>`; N only when the command had a line number."""
    command_buffer_size: int = 4
    """BUFSIZE: command ring slots, the running command included."""
    rx_buffer_size: int = 128
    """Serial receive buffer in bytes; bytes arriving when it is full are dropped silently."""
    planner_buffer_size: int = 16
    """BLOCK_BUFFER_SIZE; `P` counts free blocks, one fewer than this when idle (P15)."""
    extruders: int = 1
    has_bed: bool = True
    has_chamber: bool = False
    autoreport_temp: bool = True
    """AUTO_REPORT_TEMPERATURES: M155 and `Cap:AUTOREPORT_TEMP:1`."""
    emergency_parser: bool = True
    """EMERGENCY_PARSER: M108/M112/M410 acted on as their bytes arrive."""
    ambient_celsius: float = 25.0
    firmware_name: str = "Marlin 2.1.2.4"
    keepalive_interval_s: float = 2.0
    """DEFAULT_KEEPALIVE_INTERVAL: `echo:busy: processing` this often while a command blocks (M113 changes it)."""
    homing_s: float = 6.0
    """How long G28 takes once the planner is empty."""
    motion_time_scale: float = 1.0
    """Factor on the time each move takes (distance / feedrate): 0.1 runs moves ten times faster, 0 makes them
    instant, so a link benchmark measures the link rather than the planner."""
    ignore_duplicate_lines: bool = False
    """Drop a numbered line repeating one of the last two numbers without any answer (no error, no `ok`), as
    newer Marlin `queue.cpp` does; off, such a line gets the line-number error and `Resend:` like 2.1.2."""
    checksum_required: bool = False
    """Take only numbered lines with a checksum: an unnumbered command is answered with `Error: Missing checksum`
    and nothing else (no `ok`) and is not run. Numbered lines, `N0 M110` included, work as usual."""
    plain_wait_lines: bool = False
    """M109/M190/M191 print their once-a-second wait lines as plain reports, without ` W:<seconds left>`."""
    bare_busy: bool = False
    """Keepalives read `busy:processing`, without the `echo:` prefix."""
    repetier_targets: bool = False
    """Repetier style: a heater's new target gets a line of its own before the `ok` (`TargetExtr0:200`,
    `TargetBed:60`, `TargetChamber:45`, from M104/M109, M140/M190, M141/M191), and temperature reports show each
    sensor without its ` /target` (`ok T:21.50 B:21.30 @:0 B@:0`)."""
    m114_on_ok: bool = False
    """M114 answers on its `ok` line (`ok X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0`), no separate line."""
    password: str | None = None
    """PASSWORD_FEATURE: locked at power-up and after every reset, the board answers each command other than
    `M511 P<password>` with `echo:Printer locked! (Unlock with M511 or LCD)` and `ok` and does not run it.
    The right password unlocks it; a wrong one prints `echo:Incorrect Password`. None: no such feature (M511 is
    then an unknown command)."""
    record_limit: int | None = 100_000
    """How many of the latest commands `executed` and `executed_line_numbers` keep (None: all, which grows
    without end on a simulator served for hours). `executed_count` and `executed_line_count` count them all.
    The default holds a whole test print of tens of thousands of lines, and at 100 commands a second the last
    quarter of an hour: some 12 MB at most, where keeping everything grew by about 40 MB an hour."""
    seed: int = 0
    """Seed of the `random.Random` behind every fault decision, so runs are reproducible."""

    def __post_init__(self) -> None:
        if self.command_buffer_size < 1:
            raise ValueError(f"command_buffer_size must be at least 1, got {self.command_buffer_size}")
        if self.rx_buffer_size < 1:
            raise ValueError(f"rx_buffer_size must be at least 1, got {self.rx_buffer_size}")
        if self.planner_buffer_size < 2:
            raise ValueError(f"planner_buffer_size must be at least 2, got {self.planner_buffer_size}")
        if not 1 <= self.extruders <= 8:
            raise ValueError(f"extruders must be 1 to 8, got {self.extruders}")
        if self.keepalive_interval_s < 0 or self.homing_s < 0:
            raise ValueError("keepalive_interval_s and homing_s must not be negative")
        if not self.motion_time_scale >= 0 or math.isinf(self.motion_time_scale):
            raise ValueError(f"motion_time_scale must be a finite number >= 0, got {self.motion_time_scale}")
        if "\n" in self.firmware_name or "\r" in self.firmware_name:
            raise ValueError("firmware_name must be one line")
        if self.password is not None and (
            not self.password or any(c.isspace() or c in ";*" for c in self.password) or not self.password.isascii()
        ):
            # It has to survive the trip as one `M511 P<password>` word: no blanks, no comment or checksum mark.
            raise ValueError(f"password must be one word of ASCII without ';' or '*', got {self.password!r}")
        if self.record_limit is not None and self.record_limit < 0:
            raise ValueError(f"record_limit must be None or at least 0, got {self.record_limit}")


@dataclass
class Faults:
    """Faults the printer shows from now on; change the fields at any time, also while it is served."""

    corrupt_rx_ratio: float = 0.0
    """Share of received lines that get one character changed before parsing (numbered ones then fail their
    line-number or checksum check; the leading `N` itself is never hit)."""
    drop_ok_ratio: float = 0.0
    """Share of normal command `ok`s not sent at all (not M105's `ok T:...`, nor M114's `ok X:...` with
    `m114_on_ok`, nor the `ok` after `Resend:`)."""
    silent: bool = False
    """Keep reading and executing, but write nothing."""
    noise_ratio: float = 0.0
    """Share of output lines preceded by a line of 1-16 random bytes (never `\\n` or `\\r`; the first byte is
    never printable ASCII, so noise cannot pose as a reply) ending in `\\n`."""
    silent_after_lines: int | None = None
    """Stall once this many numbered lines have been run (counting every numbered line run since power-up,
    `executed_line_numbers`): the `ok` of the last one still goes out, then the board runs and writes nothing
    more, while its receive buffer keeps filling (and overflowing) as on a hung board. `reset()` revives it,
    but with the fault still set the next numbered line stalls it again."""
    not_executed_ratio: float = 0.0
    """Share of commands a host-side bridge does not pass on: each is answered with
    `!! Lost communication with MCU 'mcu'` and `ok`, and is not run (not in `executed`)."""
    drop_ok_codes: frozenset[str] = frozenset()
    """Commands (by code: `"M110"`, `"M115"`) that run, print their reply lines, and never get their `ok`."""


@dataclass(slots=True)
class _Command:
    text: str  # as executed: no line number, checksum or comment
    code: str  # "G1", "M105", ... or "" when it is not a G/M/T command
    args: str  # the text after the command word
    line_label: str | None  # "N5" when the line was numbered (ADVANCED_OK echoes it)
    line_number: int | None  # 5 for that line


def _to_us(seconds: float) -> int:
    return round(seconds * _US_PER_S)


def _celsius(value: float) -> str:
    return f"{value + 0.0:.2f}"  # + 0.0 turns -0.0 into 0.0, which Marlin would print without a sign


def _reading_and_target(letter: str, heater: Heater) -> str:
    return f" {letter}:{_celsius(heater.celsius)} /{_celsius(heater.target_celsius)}"


def _reading(letter: str, heater: Heater) -> str:
    return f" {letter}:{_celsius(heater.celsius)}"


def _leading_int(text: str, start: int) -> int:
    match = _LEADING_INT.match(text, start)
    return int(match.group(1)) if match else 0


def _parameters(args: str) -> dict[str, float | None]:
    return {letter: float(value) if value else None for letter, value in _PARAMETER.findall(args)}


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
        """The commands executed, in order, as received minus line number, checksum and comment: the last
        `SimulatorConfig.record_limit` of them (`executed_count` counts all)."""
        self.executed_line_numbers: BoundedRecord[int] = BoundedRecord(limit)
        """The number of each numbered line executed, in order (unnumbered commands add nothing): the last
        `SimulatorConfig.record_limit` of them (`executed_line_count` counts all)."""
        self.rx_overflows = 0
        """How many arrivals of bytes found the receive buffer too full to hold them all."""
        self.rx_dropped_bytes = 0
        """How many received bytes were dropped because the receive buffer was full."""
        self.halted = False
        """True after kill() (M112, thermal runaway) until `reset()`: nothing is answered."""
        self.stalled = False
        """True once `Faults.silent_after_lines` struck, until `reset()`: bytes are buffered, nothing else."""
        seed = self.config.seed
        self._corrupt_rng = random.Random(f"{seed}:corrupt-rx")
        self._drop_ok_rng = random.Random(f"{seed}:drop-ok")
        self._noise_rng = random.Random(f"{seed}:noise")
        self._not_executed_rng = random.Random(f"{seed}:not-executed")
        self._out = bytearray()
        self._t = _to_us(now)
        self._thermal_step = self._t // STEP_US
        ambient = self.config.ambient_celsius
        self._hotends = [Heater(HOTEND, ambient) for _ in range(self.config.extruders)]
        self._bed = Heater(BED, ambient) if self.config.has_bed else None
        self._chamber = Heater(CHAMBER, ambient) if self.config.has_chamber else None
        self._heaters_by_name: dict[str, Heater] = {f"T{i}": h for i, h in enumerate(self._hotends)}
        if self._bed is not None:
            self._heaters_by_name["B"] = self._bed
        if self._chamber is not None:
            self._heaters_by_name["C"] = self._chamber
        self._handlers = self._build_handlers()
        self._clear_state()
        if boot:
            self._print_banner("PowerUp")

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

    def receive(self, data: bytes, now: float) -> None:
        """Bytes from the host arriving at `now`.

        Whole lines move on into the command buffer while the bytes come in, as the board's main loop keeps
        reading, so only bytes that find the receive buffer full while the command buffer is full too are lost
        (counted in `rx_overflows` and `rx_dropped_bytes`).
        """
        self._run_until(_to_us(now))
        if self.halted or not data:
            return
        if self.stalled:
            self._buffer(data)
            return
        if self.config.emergency_parser:
            self._emergency_parse(data)
            if self.halted:
                return
        size = self.config.rx_buffer_size
        taken = 0
        while taken < len(data):
            room = size - len(self._rx)
            if room <= 0:
                self._count_overflow(len(data) - taken)
                return
            self._rx += data[taken : taken + room]
            taken += room
            self._settle()
            if self.halted:
                return
            if self.stalled:
                self._buffer(data[taken:])
                return

    def advance(self, now: float) -> None:
        """Let simulated time pass up to `now`."""
        self._run_until(_to_us(now))

    def take_output(self) -> bytes:
        """Return the bytes written to the host since the last call."""
        data = bytes(self._out)
        self._out.clear()
        return data

    def next_wakeup(self) -> float | None:
        """Simulated time at which `advance()` must next be called, or None while nothing is scheduled."""
        if self.halted or self.stalled:
            return None
        due = self._next_event_us()
        return None if due is None else due / _US_PER_S

    def reset(self, now: float) -> None:
        """Reset the board at `now`: everything in flight is lost, line counter 0, targets 0, banner again."""
        self._run_until(_to_us(now))
        self._sync_thermal()
        self.halted = False
        self.stalled = False
        self._clear_state()
        self._print_banner("External Reset")

    def thermal_runaway(self, now: float, heater: str = "E0") -> None:
        """Trip thermal protection at `now`: the error, the kill() line, then silence until `reset()`.

        Raises:
            ValueError: if `heater` is empty or not one line.
        """
        if not heater or "\n" in heater or "\r" in heater:
            raise ValueError(f"heater must be a one-line name such as 'E0' or 'bed', got {heater!r}")
        self._run_until(_to_us(now))
        if self.halted or self.stalled:
            return
        self._emit(f"Error:Thermal Runaway, system stopped! Heater_ID: {heater}")
        self._kill()

    @property
    def thermal_steps(self) -> int:
        """Grid steps the thermal model has integrated one by one, over all heaters (its work, for tests)."""
        self._sync_thermal()
        return sum(heater.integrated_steps for heater in self._heaters_by_name.values())

    def heater_celsius(self, name: str) -> float:
        """Current simulated temperature of heater `name`: "T0", "T1", ... "B" (bed) or "C" (chamber).

        Raises:
            ValueError: if the printer has no such heater.
        """
        heater = self._heaters_by_name.get(name)
        if heater is None:
            raise ValueError(f"no heater {name!r}; this printer has {', '.join(self._heaters_by_name)}")
        self._sync_thermal()
        return heater.celsius

    # ------------------------------------------------------------------------------------------ state and time

    def _clear_state(self) -> None:
        """Power-on state of everything a reset loses (temperatures themselves carry on)."""
        self._rx = bytearray()
        self._partial_line = bytearray()
        self._emergency_tail = b""
        self._ring: deque[_Command] = deque()
        self._task: _Task | None = None
        self._task_due = 0
        self._poked = False
        self._last_line_number = 0
        # Planner blocks as (end time, X, Y, Z, E at the end); they run back to back.
        self._planner: deque[tuple[int, float, float, float, float]] = deque()
        self._position = [0.0, 0.0, 0.0, 0.0]  # planned X Y Z E, what M114 shows
        self._stepper_position = (0.0, 0.0, 0.0, 0.0)  # where the last finished block left the axes
        self._feedrate_mm_s = _DEFAULT_FEEDRATE_MM_S
        self._relative_xyz = False
        self._relative_e = False
        self._active_extruder = 0
        self._wait_for_heatup = False
        self._keepalive_us = _to_us(self.config.keepalive_interval_s)
        self._next_keepalive: int | None = None
        self._report_us = 0
        self._next_report: int | None = None
        self._skip_ok = False
        self._locked = self.config.password is not None
        for heater in self._heaters_by_name.values():
            heater.set_target(0.0)

    def _sync_thermal(self) -> None:
        step = self._t // STEP_US
        steps = step - self._thermal_step
        if steps > 0:
            self._thermal_step = step
            for heater in self._heaters_by_name.values():
                heater.advance(steps)

    def _next_event_us(self) -> int | None:
        due: int | None = self._next_report
        if self._task is not None:
            if due is None or self._task_due < due:
                due = self._task_due
            if self._next_keepalive is not None and self._next_keepalive < due:
                due = self._next_keepalive
        return due

    def _run_until(self, now_us: int) -> None:
        """Process every event up to `now_us` in time order."""
        if not (self.halted or self.stalled):
            while True:
                self._settle()
                due = self._next_event_us()
                if self.halted or self.stalled or due is None or due > now_us:
                    break
                self._t = max(self._t, due)
                self._fire_timers()
        self._t = max(self._t, now_us)

    def _fire_timers(self) -> None:
        """What idle() prints at this moment; the task itself resumes in `_settle()`."""
        now = self._t
        if self._task is not None and self._next_keepalive is not None and self._next_keepalive <= now:
            self._emit("busy:processing" if self.config.bare_busy else "echo:busy: processing")
            self._next_keepalive = now + self._keepalive_us if self._keepalive_us > 0 else None
        if self._next_report is not None and self._next_report <= now:
            self._emit(self._heater_states(self._active_extruder))
            self._next_report = now + self._report_us

    def _settle(self) -> None:
        """Run everything that can happen at this instant: resume a due task, take in lines, run commands."""
        while not (self.halted or self.stalled):
            if self._task is not None:
                if self._task_due > self._t and not self._poked:
                    self._intake()
                    return
                self._poked = False
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
            self._start_command(self._ring[0])

    # ------------------------------------------------------------------------------------------------- intake

    def _buffer(self, data: bytes) -> None:
        """Store what fits in the receive buffer and nothing more (a stalled board reads no lines out of it)."""
        room = self.config.rx_buffer_size - len(self._rx)
        if len(data) > room:
            self._count_overflow(len(data) - max(room, 0))
        if room > 0:
            self._rx += data[:room]

    def _count_overflow(self, dropped: int) -> None:
        if dropped > 0:
            self.rx_overflows += 1
            self.rx_dropped_bytes += dropped

    def _emergency_parse(self, data: bytes) -> None:
        """Act on M108/M112/M410 lines as their bytes arrive, before the receive buffer (e_parser.h)."""
        buffer = self._emergency_tail + data
        end = max(buffer.rfind(b"\n"), buffer.rfind(b"\r"))
        if end < 0:
            # A line this long cannot be an emergency command; remember only that it is not a line start.
            self._emergency_tail = buffer if len(buffer) <= _EMERGENCY_TAIL_MAX else b"#"
            return
        tail = buffer[end + 1 :]
        self._emergency_tail = tail if len(tail) <= _EMERGENCY_TAIL_MAX else b"#"
        complete = buffer[:end]
        if _EMERGENCY_HINT.search(complete) is None:
            return  # the common case: no candidate at all, no per-line work
        for line in complete.splitlines():
            match = _EMERGENCY_LINE.match(line)
            if match is None:
                continue
            code = match.group(1)
            if code == b"108":
                self._wait_for_heatup = False
                self._poked = True
            elif code == b"112":
                self._emit("echo:M112 Shutdown")
                self._kill()
                return
            else:
                self._quick_stop()

    def _intake(self) -> None:
        """Move whole lines from the receive buffer into the command ring while it has room."""
        slots = self.config.command_buffer_size
        rx = self._rx
        while rx and len(self._ring) < slots and not (self.halted or self.stalled):
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
            self._take_line(line[:_MAX_COMMAND_CHARS])

    def _take_line(self, raw: bytes) -> None:
        """Check one received line as queue.cpp does and append it to the ring."""
        text = raw.decode("latin-1")
        cut = text.find(";")
        if cut >= 0:
            text = text[:cut]
        text = text.strip()
        if not text:
            return
        ratio = self.faults.corrupt_rx_ratio
        if ratio > 0.0 and self._corrupt_rng.random() < ratio:
            text = self._corrupt(text)
        line_label = None
        line_number = None
        if text[0] != "N" and self.config.checksum_required:
            # Thrown away as it is read, like a line error, but with neither a resend request nor an ok.
            self._emit("Error: Missing checksum")
            return
        if text[0] == "N":
            is_m110 = "M110" in text
            number_at = 0
            if is_m110:
                second_n = text.find("N", 4)
                if second_n >= 0:
                    number_at = second_n
            number = _leading_int(text, number_at + 1)
            if number != self._last_line_number + 1 and not is_m110:
                if self.config.ignore_duplicate_lines and 0 <= self._last_line_number - number <= 1:
                    return  # "A request-for-resend line was already in transit so we got two"
                self._line_error("Line Number is not Last Line Number+1, Last Line: ")
                return
            star = text.rfind("*")
            if star < 0:
                self._line_error("No Checksum with line number, Last Line: ")
                return
            if _leading_int(text, star + 1) != checksum(text[:star].encode("latin-1")):
                self._line_error("checksum mismatch, Last Line: ")
                return
            self._last_line_number = number
            line_number = _leading_int(text, 1)
            line_label = "N" + str(line_number)
        star = text.find("*")
        body = text if star < 0 else text[:star].rstrip()
        prefix = _LINE_NUMBER_PREFIX.match(body)
        if prefix is not None:
            body = body[prefix.end() :]
        word = _COMMAND_WORD.match(body)
        if word is None:
            command = _Command(body, "", "", line_label, line_number)
        else:
            code = word.group(1) + str(int(word.group(2)))
            command = _Command(body, code, body[word.end() :], line_label, line_number)
            if command.code == "M110" and line_label is None:
                # Applied on reading, like the numbered form, so lines sent right behind it already match.
                new_number = _parameters(command.args).get("N")
                if new_number is not None:
                    self._last_line_number = int(new_number)
        self._ring.append(command)

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
        self._emit(f"Error:{message}{self._last_line_number}")
        self._rx.clear()
        self._partial_line.clear()
        self._emit(f"Resend: {self._last_line_number + 1}")
        self._emit("ok")

    # ---------------------------------------------------------------------------------------------- execution

    def _start_command(self, command: _Command) -> None:
        self._skip_ok = False
        ratio = self.faults.not_executed_ratio
        if ratio > 0.0 and self._not_executed_rng.random() < ratio:
            self._emit(_LOST_MCU)
            self._finish_command()
            return
        if self._locked and command.code != "M511":
            # gcode.cpp refuses everything but M511 before looking at the command.
            self._emit(_LOCKED)
            self._finish_command()
            return
        self.executed.append(command.text)
        if command.line_number is not None:
            self.executed_line_numbers.append(command.line_number)
        handler = self._handlers.get(command.code)
        if handler is None:
            handler = self._tool_change if command.code[:1] == "T" else self._unknown
        task = handler(command)
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
        self._next_keepalive = self._t + self._keepalive_us if self._keepalive_us > 0 else None

    def _finish_command(self) -> None:
        command = self._ring[0]
        if not self._skip_ok and not self.halted:
            self._send_ok(command)
        self._ring.popleft()
        self._next_keepalive = None
        limit = self.faults.silent_after_lines
        if limit is not None and command.line_number is not None and self.executed_line_count >= limit:
            self.stalled = True

    def _send_ok(self, command: _Command) -> None:
        ratio = self.faults.drop_ok_ratio
        if ratio > 0.0 and self._drop_ok_rng.random() < ratio:
            return
        if command.code in self.faults.drop_ok_codes:
            return
        self._emit(self._ok_line(command))

    def _ok_line(self, command: _Command) -> str:
        """`ok`, with ADVANCED_OK `ok N<line> P<free blocks> B<free slots>`."""
        if not self.config.advanced_ok:
            return "ok"
        free_blocks = self._moves_free()
        free_slots = self.config.command_buffer_size - len(self._ring)
        label = "" if command.line_label is None else f" {command.line_label}"
        return f"ok{label} P{free_blocks} B{free_slots}"

    def _kill(self) -> None:
        """kill(): heaters off, the halt line, then nothing more until reset."""
        self._emit("Error:Printer halted. kill() called!")
        self._sync_thermal()
        for heater in self._heaters_by_name.values():
            heater.set_target(0.0)
        self.halted = True
        self._task = None
        self._ring.clear()
        self._rx.clear()
        self._partial_line.clear()
        self._planner.clear()

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
        self._emit(f"echo: Compiled: {_BUILD_DATE[:11]}")
        self._emit(f"echo: Free Memory: 0  PlannerBufferBytes: {92 * self.config.planner_buffer_size}")
        self._emit("echo:Hardcoded Default Settings Loaded")
        for line in _SETTINGS_LINES:
            self._emit(line)

    def _heater_states(self, extruder: int) -> str:
        """print_heater_states(): ` T:.. /.. B:.. /.. @:.. B@:..`, starting with a space."""
        self._sync_thermal()
        hotends = self._hotends
        hotend = hotends[extruder]
        # Repetier-style firmwares report targets on lines of their own, not after each reading.
        field = _reading if self.config.repetier_targets else _reading_and_target
        parts = [field("T", hotend)]
        if self._bed is not None:
            parts.append(field("B", self._bed))
        if self._chamber is not None:
            parts.append(field("C", self._chamber))
        if len(hotends) > 1:
            parts.extend(field(f"T{i}", h) for i, h in enumerate(hotends))
        parts.append(f" @:{hotend.power_127}")
        if self._bed is not None:
            parts.append(f" B@:{self._bed.power_127}")
        if self._chamber is not None:
            parts.append(f" C@:{self._chamber.power_127}")
        if len(hotends) > 1:
            parts.extend(f" @{i}:{h.power_127}" for i, h in enumerate(hotends))
        return "".join(parts)

    def _position_line(self) -> str:
        x, y, z, e = (value + 0.0 for value in self._position)
        counts = [math.floor(value * steps + 0.5) for value, steps in zip((x, y, z), _STEPS_PER_MM, strict=True)]
        return f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count X:{counts[0]} Y:{counts[1]} Z:{counts[2]}"

    # ------------------------------------------------------------------------------------------------ planner

    def _moves_free(self) -> int:
        planner = self._planner
        now = self._t
        while planner and planner[0][0] <= now:
            _, x, y, z, e = planner.popleft()
            self._stepper_position = (x, y, z, e)
        return self.config.planner_buffer_size - 1 - len(planner)

    def _synchronize(self) -> _Task:
        """planner.synchronize(): wait until every planned move has finished."""
        while self._moves_free() < self.config.planner_buffer_size - 1:
            yield self._planner[-1][0]

    def _quick_stop(self) -> None:
        """M410: drop every planned move; the axes stay where the last finished move left them."""
        self._moves_free()
        self._planner.clear()
        self._position = list(self._stepper_position)
        self._poked = True

    # ----------------------------------------------------------------------------------------------- commands

    def _build_handlers(self) -> dict[str, Callable[[_Command], _Task | None]]:
        handlers: dict[str, Callable[[_Command], _Task | None]] = {
            "G0": self._g0_g1,
            "G1": self._g0_g1,
            "G4": self._g4,
            "G28": self._g28,
            "G90": self._g90,
            "G91": self._g91,
            "G92": self._g92,
            "M82": self._m82,
            "M83": self._m83,
            "M104": self._m104,
            "M105": self._m105,
            "M108": self._m108,
            "M109": self._m109,
            "M110": self._no_op,  # the counter was already set when the line was read
            "M112": self._m112,
            "M113": self._m113,
            "M114": self._m114,
            "M115": self._m115,
            "M118": self._m118,
            "M119": self._m119,
            "M27": self._m27,
            "M400": self._m400,
            "M410": self._m410,
            "M503": self._m503,
        }
        for code in _NO_OPS:
            handlers[code] = self._no_op
        if self.config.has_bed:
            handlers["M140"] = self._m140
            handlers["M190"] = self._m190
        if self.config.has_chamber:
            handlers["M141"] = self._m141
            handlers["M191"] = self._m191
        if self.config.autoreport_temp:
            handlers["M155"] = self._m155
        if self.config.password is not None:
            handlers["M511"] = self._m511
        return handlers

    def _no_op(self, command: _Command) -> None:
        return None

    def _unknown(self, command: _Command) -> None:
        self._emit(f'echo:Unknown command: "{command.text}"')

    def _target_extruder(self, command: _Command, parameters: dict[str, float | None]) -> int | None:
        """get_target_extruder_from_command(): T<n> or the active extruder; None (and a message) if invalid."""
        tool = parameters.get("T")
        if tool is None:
            return self._active_extruder
        extruder = int(tool)
        if 0 <= extruder < len(self._hotends):
            return extruder
        self._emit(f"echo:{command.code} Invalid extruder {extruder}")
        return None

    def _g0_g1(self, command: _Command) -> _Task:
        parameters = _parameters(command.args)
        feedrate = parameters.get("F")
        if feedrate is not None and feedrate > 0:
            self._feedrate_mm_s = feedrate / 60.0
        start = list(self._position)
        target = list(start)
        for axis, letter in enumerate("XYZE"):
            value = parameters.get(letter)
            if value is None:
                continue
            relative = self._relative_e if letter == "E" else self._relative_xyz
            target[axis] = start[axis] + value if relative else value
        dx, dy, dz, de = (target[axis] - start[axis] for axis in range(4))
        length = math.sqrt(dx * dx + dy * dy + dz * dz) or abs(de)
        if length == 0.0:
            self._position = target  # Marlin plans no block for a move of no steps
            return
        # buffer_line() waits (in idle(), so lines keep coming in) until the planner has a free block.
        while self._moves_free() == 0:
            yield self._planner[0][0]
        begin = self._planner[-1][0] if self._planner else self._t
        duration = round(length / self._feedrate_mm_s * _US_PER_S * self.config.motion_time_scale)
        self._planner.append((max(begin, self._t) + duration, target[0], target[1], target[2], target[3]))
        self._position = target

    def _g4(self, command: _Command) -> _Task:
        parameters = _parameters(command.args)
        dwell_us = 0
        if (milliseconds := parameters.get("P")) is not None:
            dwell_us = round(milliseconds * 1000)
        if (seconds := parameters.get("S")) is not None:
            dwell_us = _to_us(seconds)
        yield from self._synchronize()
        end = self._t + dwell_us
        while self._t < end:
            yield end

    def _g28(self, command: _Command) -> _Task:
        parameters = _parameters(command.args)
        axes = [axis for axis, letter in enumerate("XYZ") if letter in parameters] or [0, 1, 2]
        yield from self._synchronize()
        end = self._t + _to_us(self.config.homing_s)
        while self._t < end:
            yield end
        for axis in axes:
            self._position[axis] = 0.0
        x, y, z, e = self._position
        self._stepper_position = (x, y, z, e)
        self._emit(self._position_line())

    def _g90(self, command: _Command) -> None:
        self._relative_xyz = self._relative_e = False

    def _g91(self, command: _Command) -> None:
        self._relative_xyz = self._relative_e = True

    def _g92(self, command: _Command) -> None:
        parameters = _parameters(command.args)
        for axis, letter in enumerate("XYZE"):
            value = parameters.get(letter)
            if value is not None:
                self._position[axis] = value

    def _m82(self, command: _Command) -> None:
        self._relative_e = False

    def _m83(self, command: _Command) -> None:
        self._relative_e = True

    def _m27(self, command: _Command) -> None:
        self._emit("Not SD printing")

    def _m104(self, command: _Command) -> None:
        self._set_hotend(command)

    def _m109(self, command: _Command) -> _Task | None:
        return self._set_hotend(command, wait=True)

    def _set_hotend(self, command: _Command, *, wait: bool = False) -> _Task | None:
        parameters = _parameters(command.args)
        extruder = self._target_extruder(command, parameters)
        if extruder is None:
            return None
        heater = self._hotends[extruder]
        return self._set_target(heater, parameters, wait, extruder)

    def _set_target(
        self, heater: Heater, parameters: dict[str, float | None], wait: bool, extruder: int
    ) -> _Task | None:
        """M104/M109, M140/M190, M141/M191: S sets and waits only for heating, R waits both ways."""
        no_wait_for_cooling = parameters.get("S") is not None
        celsius = parameters.get("S") if no_wait_for_cooling else parameters.get("R")
        if celsius is None:
            return None
        self._sync_thermal()
        heater.set_target(float(int(celsius)))  # celsius_t is an integer in Marlin 2.1
        if self.config.repetier_targets:
            self._emit(f"{self._target_label(heater, extruder)}:{int(heater.target_celsius)}")
        heating = heater.target_celsius > heater.celsius
        if wait and (heating or not no_wait_for_cooling):
            return self._wait_for_heater(heater, extruder)
        return None

    def _target_label(self, heater: Heater, extruder: int) -> str:
        """The Repetier name of a heater's target: `TargetExtr<n>`, `TargetBed` or `TargetChamber`."""
        if heater is self._bed:
            return "TargetBed"
        if heater is self._chamber:
            return "TargetChamber"
        return f"TargetExtr{extruder}"

    def _wait_for_heater(self, heater: Heater, extruder: int) -> _Task:
        """Temperature::wait_for_hotend() / wait_for_bed(): a W: line every second, 10 s residency in a 1 C
        window, restarted beyond 3 C; M108 ends it at once; cooling waits give up when cooling stalls."""
        self._wait_for_heatup = True
        target = heater.target_celsius
        wants_to_cool = heater.celsius > target
        next_print = self._t
        residency_start: int | None = None
        first_loop = True
        old_celsius = 9999.0
        next_cool_check: int | None = None
        while True:
            self._sync_thermal()
            now = self._t
            if now >= next_print:
                next_print = now + _WAIT_REPORT_US
                if self.config.plain_wait_lines:
                    self._emit(self._heater_states(extruder))
                else:
                    left = "?" if residency_start is None else str((_RESIDENCY_US - now + residency_start) // _US_PER_S)
                    self._emit(f"{self._heater_states(extruder)} W:{left}")
            celsius = heater.celsius
            difference = abs(target - celsius)
            if residency_start is None:
                if difference < _WINDOW_CELSIUS:
                    # Marlin starts the clock a third later when the heater is already there on the first pass.
                    residency_start = now + (_RESIDENCY_US // 3 if first_loop else 0)
            elif difference > _HYSTERESIS_CELSIUS:
                residency_start = now
            first_loop = False
            if wants_to_cool and (next_cool_check is None or now >= next_cool_check):
                if old_celsius - celsius < _COOLING_SLOPE_CELSIUS:
                    return
                next_cool_check = now + _COOLING_SLOPE_US
                old_celsius = celsius
            if not self._wait_for_heatup:
                return
            # Sleep until the temperature could enter the window (or, once inside, leave the hysteresis band).
            margin = difference - _WINDOW_CELSIUS if residency_start is None else _HYSTERESIS_CELSIUS - difference
            wake = min(next_print, (now // STEP_US + heater.steps_to_change(margin)) * STEP_US)
            if residency_start is not None:
                residency_end = residency_start + _RESIDENCY_US
                if now >= residency_end:
                    return
                wake = min(wake, residency_end)
            if next_cool_check is not None:
                wake = min(wake, next_cool_check)
            yield wake

    def _m105(self, command: _Command) -> None:
        self._skip_ok = True  # M105 answers on its own `ok T:...` line, or not at all
        extruder = self._target_extruder(command, _parameters(command.args))
        if extruder is not None:
            self._emit("ok" + self._heater_states(extruder))

    def _m108(self, command: _Command) -> None:
        if not self.config.emergency_parser:
            self._wait_for_heatup = False  # nothing waits while this runs, so it only matters for M0/M1

    def _m112(self, command: _Command) -> None:
        if not self.config.emergency_parser:
            self._emit("echo:M112 Shutdown")
            self._kill()

    def _m113(self, command: _Command) -> None:
        seconds = _parameters(command.args).get("S")
        if seconds is not None:
            self._keepalive_us = min(max(int(seconds), 0), 60) * _US_PER_S

    def _m114(self, command: _Command) -> None:
        if self.config.m114_on_ok:
            self._skip_ok = True  # the position rides on the ok line itself, like M105's temperatures
            self._emit(f"ok {self._position_line()}")
        else:
            self._emit(self._position_line())

    def _m115(self, command: _Command) -> None:
        config = self.config
        self._emit(
            f"FIRMWARE_NAME:{config.firmware_name} ({_BUILD_DATE}) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin"
            f" PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer KINEMATICS:Cartesian"
            f" EXTRUDER_COUNT:{config.extruders} UUID:{_UUID}"
        )
        configured = {
            "AUTOREPORT_TEMP": config.autoreport_temp,
            "EMERGENCY_PARSER": config.emergency_parser,
            "CHAMBER_TEMPERATURE": config.has_chamber,
        }
        for name, value in _CAPABILITIES:
            flag = int(configured[name]) if value is None else value
            self._emit(f"Cap:{name}:{flag}")

    def _m118(self, command: _Command) -> None:
        text = command.args
        echo = action = False
        for _ in range(3):  # A1, E1 and Pn flags come first, in any order
            if text[:2] in ("A1", "E1") or (text[:1] == "P" and text[1:2].isdigit()):
                echo = echo or text[0] == "E"
                action = action or text[0] == "A"
                text = text[2:].lstrip(" ")
            else:
                break
        self._emit(("echo:" if echo else "") + ("//" if action else "") + text)

    def _m119(self, command: _Command) -> None:
        self._emit("Reporting endstop status")
        for axis in ("x_min", "y_min", "z_min"):
            self._emit(f"{axis}: open")

    def _m140(self, command: _Command) -> None:
        assert self._bed is not None
        self._set_target(self._bed, _parameters(command.args), False, self._active_extruder)

    def _m190(self, command: _Command) -> _Task | None:
        assert self._bed is not None
        return self._set_target(self._bed, _parameters(command.args), True, self._active_extruder)

    def _m141(self, command: _Command) -> None:
        assert self._chamber is not None
        self._set_target(self._chamber, _parameters(command.args), False, self._active_extruder)

    def _m191(self, command: _Command) -> _Task | None:
        assert self._chamber is not None
        return self._set_target(self._chamber, _parameters(command.args), True, self._active_extruder)

    def _m155(self, command: _Command) -> None:
        seconds = _parameters(command.args).get("S")
        if seconds is None:
            return
        self._report_us = min(max(int(seconds), 0), 60) * _US_PER_S
        self._next_report = self._t + self._report_us if self._report_us else None

    def _m400(self, command: _Command) -> _Task:
        yield from self._synchronize()

    def _m410(self, command: _Command) -> None:
        if not self.config.emergency_parser:
            self._quick_stop()

    def _m511(self, command: _Command) -> None:
        """M511 P<password>: unlock (password.cpp compares only while locked)."""
        if not self._locked:
            return
        match = _M511_PASSWORD.search(command.args)
        if match is not None and match.group(1) == self.config.password:
            self._locked = False
        else:
            self._emit("echo:Incorrect Password")

    def _m503(self, command: _Command) -> None:
        for line in _SETTINGS_LINES:
            self._emit(line)

    def _tool_change(self, command: _Command) -> None:
        tool = int(command.code[1:])
        if tool < len(self._hotends):
            self._active_extruder = tool
        else:
            self._emit(f"echo:T{tool} Invalid extruder")
