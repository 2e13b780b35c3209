"""How the simulated board is built (`SimulatorConfig`) and the faults it shows (`Faults`), with the fixed texts
that its build prints about itself (the boot banner's settings and M115's capability lines).

Dialects a host meets in the field (Marlin forks, Repetier-compatible boards, options) are switches of
`SimulatorConfig`, each off by default: `checksum_required`, `plain_wait_lines`, `bare_busy`, `repetier_targets`,
`m114_on_ok` and `password` (PASSWORD_FEATURE). A host-side bridge that drops commands is the fault
`Faults.not_executed_ratio`.

How the board reads its lines follows Marlin bugfix-2.1.x by default: `ignore_duplicate_lines` and
`case_insensitive` are on (turn the first off for 2.1.2's answer to a repeated line). `boot_delay_s` is the
bootloader's silence after a reset. On the wire, `Faults.flip_bit_ratio` and `Faults.flip_once` flip bits of the
host's bytes before the board sees them; `Faults.corrupt_rx_ratio` damages whole received lines, sparing the `N`.

Simulated time is integer microseconds throughout the simulator (`US_PER_S`, `to_us()`), so ties between timers
are exact; configuration is given in seconds and converted once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = [
    "BUILD_DATE",
    "CAPABILITIES",
    "SETTINGS_LINES",
    "US_PER_S",
    "UUID",
    "Faults",
    "SimulatorConfig",
    "to_us",
]

US_PER_S = 1_000_000

BUILD_DATE = "Jan  1 2024 12:00:00"
UUID = "cede2a2f-41a2-4748-9b12-c55c62f367ff"

#: What M503 prints, and the boot banner after "Hardcoded Default Settings Loaded" (from boot-banner.txt).
SETTINGS_LINES = (
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
CAPABILITIES: tuple[tuple[str, int | None], ...] = (
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


def to_us(seconds: float) -> int:
    """Simulated seconds as the simulator's integer microseconds."""
    return round(seconds * US_PER_S)


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
    command_time_s: float = 0.001
    """How long Marlin's command loop takes over each command before it runs it and prints its `ok` (parsing,
    the planner, `idle()`): Marlin 2.1 on an ATmega2560 tops out near 1,000 short lines a second, whatever the
    baud rate. 0 runs every command the moment it reaches the head of the buffer."""
    report_time_s: float = 0.0043
    """How long an M105 takes in place of `command_time_s` (formatting each sensor's reading): with its 45-byte
    answer at 250000 baud, a round trip of 6.3 ms as measured on that board."""
    ignore_duplicate_lines: bool = True
    """Drop a numbered line repeating one of the last two numbers (`n == last` or `n == last - 1`) without any
    answer (no error, no `Resend:`, no `ok`), as bugfix-2.1.x's `queue.cpp` does ("a request-for-resend line was
    already in transit"). False gives Marlin 2.1.2's answer instead: the line-number error and `Resend:`."""
    case_insensitive: bool = True
    """GCODE_CASE_INSENSITIVE (on in Marlin 2.1's default configuration): command letters and parameter letters
    may be lowercase (`m105`, `g1 x5`, `n15 G1 X0.1` with its line number skipped). Off, a lowercase command is
    an unknown command and lowercase parameters are not seen. A line is numbered only by an uppercase `N` either
    way (queue.cpp does not fold case), so `n15 G1 X0.1` runs unnumbered."""
    boot_delay_s: float = 0.0
    """How long a board stays in its bootloader after power-up or `reset()`, in simulated seconds: it reads
    nothing (bytes arriving are dropped) and says nothing, then prints `start` and its banner. Real AVR boards
    take 1-3 s; 0 prints the banner at once. A pty served with `reset_on_open` waits at least a moment of real
    time after an open whatever this says (see `serve_pty`)."""
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
        for name in ("command_time_s", "report_time_s"):
            value = getattr(self, name)
            if not 0.0 <= value < math.inf:
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
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
        if not 0.0 <= self.boot_delay_s < math.inf:
            raise ValueError(f"boot_delay_s must be a finite number >= 0, got {self.boot_delay_s}")


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
    flip_bit_ratio: float = 0.0
    """Share of the host's bytes that get one random bit (0-7) flipped on the wire, before the board sees them
    (before the emergency parser and the receive buffer). A flip can hit anything: the leading `N` (the line
    then runs unnumbered, or is an unknown command), an `M110`, a `*`, a digit, or a line end (`\\n` turned into
    another byte joins two lines; a `*` turned into `\\n` splits one). Which bytes are hit depends only on the
    seed and each byte's place in the host's stream, never on how the bytes were split into `receive()` calls.
    `SimulatedPrinter.bits_flipped` counts the flips."""
    runout_at_line: int | None = None
    """A filament runout just before the numbered line with this number runs (a print's line N, counted from its
    `M110 N0`; or the first numbered line after it that is not a poll's M105 or an M110): the runout prompt and
    `//action:paused filament_runout 0`, then an M600 that holds the line until the host answers its prompt
    (`M876 S0`) or sends M108. It strikes once, then this is set back to None."""
    flip_once: list[tuple[str, int, int]] = field(default_factory=list)
    """Targeted flips for tests, each `(substring, byte_offset, bit)`: flip bit `bit` (0-7) of byte
    `byte_offset` of the first line the host sends that contains `substring` (matched on the line as sent,
    before any flip; the offset counts from the line's first byte, and the offset of its length is the line's
    `\\n`), then the entry is removed from this list. `("N15 ", 0, 5)` turns `N15 G1 X0.1*75` into
    `n15 G1 X0.1*75`, `("N15 ", 0, 0)` into `O15 G1 X0.1*75`. While entries are left, the bytes of a line are
    held back until its end has arrived, so that any byte of it can be hit; applied where `flip_bit_ratio` is."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.flip_bit_ratio <= 1.0:
            raise ValueError(f"flip_bit_ratio must be between 0 and 1, got {self.flip_bit_ratio}")
        for substring, offset, bit in self.flip_once:
            if offset < 0 or not 0 <= bit <= 7:
                raise ValueError(f"flip_once entries need an offset >= 0 and a bit 0-7, got {(substring, offset, bit)}")
