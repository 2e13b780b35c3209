"""The simulated printer's firmware logic, sans-I/O: every test runs simulated minutes in milliseconds.

Expected lines are copied from the Marlin 2.1 captures in shared/captures/marlin-2.1 (only the firmware name, build
date and the captured board's machine name differ).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.commands import number_command
from marlin_aio.protocol.events import (
    BusyKeepalive,
    ErrorKind,
    ErrorMessage,
    Ok,
    PrinterLocked,
    TargetTemperature,
    TemperatureReport,
)
from marlin_aio.protocol.parsing import parse_position
from marlin_aio.protocol.wire import classify_line
from marlin_aio.simulator import Faults, SimulatedPrinter, SimulatorConfig, generate_moves
from marlin_aio.simulator._wire import Wire

IDLE_M105 = "ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"


def make(faults: Faults | None = None, **config: object) -> SimulatedPrinter:
    """A printer without its boot banner, so replies start clean; its command loop takes no time unless asked
    (`command_time_s`), so each reply comes at the instant its command arrives (the loop's time is tested on
    its own, in test_simulator.py)."""
    config = {"command_time_s": 0.0, "report_time_s": 0.0} | config
    return SimulatedPrinter(SimulatorConfig(**config), faults, boot=False)  # type: ignore[arg-type]


def lines(printer: SimulatedPrinter) -> list[str]:
    return printer.take_output().decode("latin-1").splitlines()


def send(printer: SimulatedPrinter, text: str, now: float = 0.0) -> list[str]:
    printer.receive(text.encode("latin-1") + b"\n", now)
    return lines(printer)


def run(printer: SimulatedPrinter, until: float) -> list[tuple[float, str]]:
    """Advance event by event up to `until`; return each output line with the simulated time it came out."""
    timed: list[tuple[float, str]] = []
    while (wake := printer.next_wakeup()) is not None and wake <= until:
        printer.advance(wake)
        timed.extend((wake, line) for line in lines(printer))
    printer.advance(until)
    timed.extend((until, line) for line in lines(printer))
    return timed


def run_until_ok(printer: SimulatedPrinter, limit: float) -> list[tuple[float, str]]:
    """Advance until an `ok` line appears (or `limit`); return the timed lines up to and including it."""
    timed: list[tuple[float, str]] = []
    while (wake := printer.next_wakeup()) is not None and wake <= limit:
        printer.advance(wake)
        for line in lines(printer):
            timed.append((wake, line))
            if line.startswith("ok"):
                return timed
    raise AssertionError(f"no ok by {limit} s; got {timed[-5:]}")


# ----------------------------------------------------------------------------------------------- banner, identity


def test_boot_banner_has_the_captured_shape() -> None:
    printer = SimulatedPrinter()
    banner = lines(printer)
    assert banner[:3] == ["start", "PowerUp", "Marlin 2.1.2.4"]
    assert banner[3].startswith("echo: Last Updated: ")
    assert banner[4].startswith("echo: Compiled: ")
    assert banner[5] == "echo: Free Memory: 0  PlannerBufferBytes: 1472"
    assert banner[6] == "echo:Hardcoded Default Settings Loaded"
    assert banner[7:9] == ["echo:; Linear Units:", "echo:  G21 ; (mm)"]
    assert banner[-1] == "echo:  M301 P22.20 I1.08 D114.00"
    assert all(line.startswith("echo:") for line in banner[3:])


def test_m115_lists_the_captured_capabilities_with_configured_ones() -> None:
    printer = make(advanced_ok=True)
    reply = send(printer, "M115")
    assert reply[0].startswith("FIRMWARE_NAME:Marlin 2.1.2.4 (")
    assert "SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:" in reply[0]
    assert " EXTRUDER_COUNT:1 UUID:" in reply[0]
    assert reply[1:3] == ["Cap:SERIAL_XON_XOFF:0", "Cap:BINARY_FILE_TRANSFER:0"]
    assert "Cap:AUTOREPORT_TEMP:1" in reply
    assert "Cap:EMERGENCY_PARSER:1" in reply
    assert "Cap:CHAMBER_TEMPERATURE:0" in reply
    assert reply[-2:] == ["Cap:CONFIG_EXPORT:0", "ok P15 B3"]
    assert len(reply) == 1 + 36 + 1

    other = make(extruders=2, autoreport_temp=False, emergency_parser=False, has_chamber=True)
    reply = send(other, "M115")
    assert " EXTRUDER_COUNT:2 " in reply[0]
    assert {"Cap:AUTOREPORT_TEMP:0", "Cap:EMERGENCY_PARSER:0", "Cap:CHAMBER_TEMPERATURE:1"} <= set(reply)


# ------------------------------------------------------------------------------------------------------- M105


def test_m105_answers_on_one_ok_line_without_planner_fields() -> None:
    assert send(make(), "M105") == [IDLE_M105]
    assert send(make(advanced_ok=True), "M105") == [IDLE_M105]


def test_m105_shapes_for_chamber_several_hotends_and_no_bed() -> None:
    assert send(make(has_chamber=True), "M105") == ["ok T:25.00 /0.00 B:25.00 /0.00 C:25.00 /0.00 @:0 B@:0 C@:0"]
    two = make(extruders=2)
    send(two, "M104 T1 S50")
    assert send(two, "M105") == ["ok T:25.00 /0.00 B:25.00 /0.00 T0:25.00 /0.00 T1:25.00 /50.00 @:0 B@:0 @0:0 @1:0"]
    assert send(two, "M105 T1")[0].startswith("ok T:25.00 /50.00 B:")
    assert send(two, "T1") == ["ok"]
    assert send(two, "M105")[0].startswith("ok T:25.00 /50.00 B:")
    assert send(make(has_bed=False), "M105") == ["ok T:25.00 /0.00 @:0"]


def test_m105_for_a_missing_extruder_prints_an_echo_and_no_ok() -> None:
    printer = make()
    assert send(printer, "M105 T9") == ["echo:M105 Invalid extruder 9"]
    assert send(printer, "M105") == [IDLE_M105]
    assert printer.executed == ["M105 T9", "M105"]


def test_other_commands_with_a_missing_extruder_still_get_their_ok() -> None:
    printer = make()
    assert send(printer, "M104 T3 S200") == ["echo:M104 Invalid extruder 3", "ok"]
    assert send(printer, "T4") == ["echo:T4 Invalid extruder", "ok"]


def test_targets_are_clamped_silently() -> None:
    printer = make(has_chamber=True)
    for command in ("M104 S300", "M140 S200", "M141 S90"):
        assert send(printer, command) == ["ok"]
    assert send(printer, "M105") == ["ok T:25.00 /260.00 B:25.00 /140.00 C:25.00 /60.00 @:0 B@:0 C@:0"]


# --------------------------------------------------------------------------------- line numbers and checksums


def test_numbered_lines_and_advanced_ok_match_the_capture() -> None:
    printer = make(advanced_ok=True)
    assert send(printer, "N0 M110 N0*125") == ["ok N0 P15 B3"]
    assert send(printer, "N1 G1 X10 Y10 F3000*77") == ["ok N1 P14 B3"]
    assert send(printer, "N2 G1 X20 Y20 Z5*100") == ["ok N2 P13 B3"]
    assert send(printer, "N3 G1 X50 Y30*44") == ["ok N3 P12 B3"]
    assert send(printer, "N4 M400*35") == []
    timed = run_until_ok(printer, 10.0)
    assert timed[-1][1] == "ok N4 P15 B3"
    # distance / feedrate: 1.22 s; the capture's 1.32 s includes acceleration, which is not simulated.
    assert timed[-1][0] == pytest.approx(1.3, abs=0.1)
    assert send(printer, "N5 M114*34", 2.0) == [
        "X:50.00 Y:30.00 Z:5.00 E:0.00 Count X:4000 Y:2400 Z:2000",
        "ok N5 P15 B3",
    ]


def test_the_three_line_errors_match_the_capture() -> None:
    printer = make(advanced_ok=True)
    for number in range(1, 6):
        send(printer, number_command("M400", number))
    assert send(printer, "N6 G1 X60 Y40*46") == [
        "Error:checksum mismatch, Last Line: 5",
        "Resend: 6",
        "ok",
    ]
    assert send(printer, "N6 G1 X60 Y40*45") == ["ok N6 P14 B3"]
    assert send(printer, "N8 G1 X70*95") == [
        "Error:Line Number is not Last Line Number+1, Last Line: 6",
        "Resend: 7",
        "ok",
    ]
    assert send(printer, "N7 G1 X65*84") == ["ok N7 P13 B3"]
    assert send(printer, "N8 G1 X70*95") == ["ok N8 P12 B3"]
    assert send(printer, "N9 G1 X75") == [
        "Error:No Checksum with line number, Last Line: 8",
        "Resend: 9",
        "ok",
    ]
    assert printer.executed[-3:] == ["G1 X60 Y40", "G1 X65", "G1 X70"]


def test_a_line_error_discards_what_is_left_in_the_receive_buffer() -> None:
    printer = make()
    burst = "N1 G1 X1*0\n" + number_command("G1 X2", 2) + "\n" + number_command("G1 X3", 3) + "\n"
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
    assert printer.executed == []
    printer.receive(("\n".join(number_command(f"G1 X{i}", i) for i in (1, 2, 3)) + "\n").encode(), 1.0)
    assert lines(printer) == ["ok", "ok", "ok"]
    assert printer.executed == ["G1 X1", "G1 X2", "G1 X3"]


def test_line_errors_are_answered_while_a_long_command_blocks() -> None:
    # Marlin reads lines from idle() too, so the Resend comes before the blocking command's ok.
    printer = make()
    assert send(printer, number_command("G4 S5", 1)) == []
    assert send(printer, "N2 M105*1", 1.0) == ["Error:checksum mismatch, Last Line: 1", "Resend: 2", "ok"]
    assert [line for _, line in run(printer, 6.0)] == ["echo:busy: processing", "echo:busy: processing", "ok"]


def test_m110_sets_the_line_counter_in_both_forms() -> None:
    printer = make()
    assert send(printer, "M110 N41") == ["ok"]
    assert send(printer, number_command("M105", 42)) == [IDLE_M105]
    assert send(printer, number_command("M110 N0", 99)) == ["ok"]  # M110 skips the sequence check
    assert send(printer, number_command("M400", 1)) == ["ok"]
    assert send(printer, "M105") == [IDLE_M105]  # unnumbered: accepted, counter unchanged
    assert send(printer, number_command("M400", 2)) == ["ok"]


def test_comments_checksums_and_line_endings_are_handled_like_marlin() -> None:
    printer = make()
    assert send(printer, "G1 X5 ; move right") == ["ok"]
    assert send(printer, "; only a comment") == []
    assert send(printer, "") == []
    # Spaces are stored like any byte, so the line is not empty; the parser then finds no command in it.
    assert send(printer, "   ") == ['echo:Unknown command: ""', "ok"]
    printer.receive(b"M117 a\r\nM117 b\r", 0.0)
    assert lines(printer) == ["ok", "ok"]
    assert send(printer, number_command("G1 X6", 1) + " ; note") == ["ok"]
    assert printer.executed == ["G1 X5", "", "M117 a", "M117 b", "G1 X6"]


def test_unknown_and_lowercase_commands() -> None:
    printer = make(advanced_ok=True)
    assert send(printer, "M9999") == ['echo:Unknown command: "M9999"', "ok P15 B3"]
    assert send(printer, "G999 X1") == ['echo:Unknown command: "G999 X1"', "ok P15 B3"]
    # GCODE_CASE_INSENSITIVE is on in Marlin 2.1's default configuration, and can be turned off.
    assert send(printer, "m105") == [IDLE_M105]
    strict = make(advanced_ok=True, case_insensitive=False)
    assert send(strict, "m105") == ['echo:Unknown command: "m105"', "ok P15 B3"]


def test_over_long_lines_are_cut_at_marlins_command_size() -> None:
    printer = make(rx_buffer_size=1024)
    assert send(printer, "M118 " + "x" * 200) == ["x" * 90, "ok"]


# ------------------------------------------------------------------------------------------ buffers and order


def test_receive_buffer_overflow_drops_bytes_silently() -> None:
    printer = make(command_buffer_size=1, rx_buffer_size=32)
    assert send(printer, "G4 S10") == []
    # 55 bytes while the single slot is busy: only the first 32 fit (two lines and 10 bytes of the third).
    printer.receive(b"".join(f"M118 E1 a{i}\n".encode() for i in range(1, 6)), 1.0)
    assert lines(printer) == []
    assert [line for _, line in run(printer, 11.0) if line.startswith("echo:a")] == ["echo:a1", "echo:a2"]
    # The third line's start waits for its end; what arrives next is glued to it, as on a real board.
    assert send(printer, "M118 E1 z", 12.0) == ["echo:a3M118 E1 z", "ok"]
    assert printer.executed == ["G4 S10", "M118 E1 a1", "M118 E1 a2", "M118 E1 a3M118 E1 z"]


def test_twenty_streamed_moves_count_down_like_the_capture() -> None:
    printer = make(advanced_ok=True, rx_buffer_size=1024, homing_s=3.3)
    moves = [f"G1 X{10 + 5 * i} Y{10 if i % 2 == 0 else 60} F6000" for i in range(20)]
    printer.receive(("G28 X Y\n" + "".join(move + "\n" for move in moves)).encode(), 0.0)
    timed = run(printer, 30.0)
    oks = [line for _, line in timed if line.startswith("ok")]
    assert oks == (
        ["ok P15 B0"]
        + [f"ok P{free} B0" for free in range(14, -1, -1)]
        + ["ok P0 B0", "ok P0 B0", "ok P0 B1", "ok P0 B2", "ok P0 B3"]
    )
    ok_times = [at for at, line in timed if line.startswith("ok")]
    assert ok_times[16] - ok_times[15] == pytest.approx(0.141, abs=0.01)  # the first 14 mm move ends
    assert ok_times[17] - ok_times[16] == pytest.approx(0.502, abs=0.01)  # then each 50 mm move at 100 mm/s
    assert printer.executed == ["G28 X Y", *moves]


def test_oks_come_in_order_one_per_command() -> None:
    printer = make(rx_buffer_size=4096)
    commands = [f"M118 E1 {i}" if i % 3 else f"G1 X{i} F12000" for i in range(60)]
    printer.receive("".join(c + "\n" for c in commands).encode(), 0.0)
    output = [line for _, line in run(printer, 60.0)]
    assert output.count("ok") == len(commands)
    echoes = [line for line in output if line.startswith("echo:")]
    assert echoes == [f"echo:{i}" for i in range(60) if i % 3]
    assert printer.executed == commands


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=40), min_size=1, max_size=30))
def test_any_split_of_the_input_gives_the_same_output(cuts: list[int]) -> None:
    # No line errors and no M108 here: what those throw away or cut short depends on when bytes arrive, on a
    # real board as in the simulation.
    stream = ("M105\n" + number_command("G1 X10", 1) + "\nM118 E1 hi ; c\nG4 P500\nM109 S30\nM400\r\nM114\n").encode()
    whole = make(rx_buffer_size=4096)
    whole.receive(stream, 0.0)
    expected = whole.take_output() + b"".join(line.encode() + b"\n" for _, line in run(whole, 60.0))
    split = make(rx_buffer_size=4096)
    position = 0
    for cut in cuts:
        split.receive(stream[position : position + cut], 0.0)
        position += cut
    split.receive(stream[position:], 0.0)
    got = split.take_output() + b"".join(line.encode() + b"\n" for _, line in run(split, 60.0))
    assert got == expected
    assert split.executed == whole.executed


# ---------------------------------------------------------------------------------------------- waits, timing


def test_m109_prints_wait_lines_with_a_residency_countdown_and_keepalives() -> None:
    printer = make(advanced_ok=True)
    assert send(printer, "M109 S200") == [" T:25.00 /200.00 B:25.00 /0.00 @:0 B@:0 W:?"]
    timed = run_until_ok(printer, 200.0)
    wait_lines = [(at, line) for at, line in timed if " W:" in line]
    waits = [line.rsplit("W:", 1)[1] for _, line in wait_lines]
    countdown = [str(n) for n in range(9, -1, -1)]
    assert waits[-10:] == countdown
    assert set(waits[:-10]) == {"?"}
    assert all(line.startswith(" T:") and "/200.00" in line and " @:" in line for _, line in wait_lines)
    assert [at for at, _ in wait_lines] == pytest.approx([float(n) for n in range(1, len(wait_lines) + 1)])
    busy = [at for at, line in timed if line == "echo:busy: processing"]
    assert busy == pytest.approx([2.0 * n for n in range(1, len(busy) + 1)])
    # When both are due together the keepalive comes first, as in the capture.
    for at in busy:
        same_moment = [line for when, line in timed if when == at]
        assert same_moment[0] == "echo:busy: processing"
    assert timed[-1][1] == "ok P15 B3"
    assert 60.0 <= timed[-1][0] <= 95.0
    assert abs(printer.heater_celsius("T0") - 200.0) < 1.0


def test_m109_on_a_hot_hotend_still_waits_out_the_residency() -> None:
    printer = make()
    send(printer, "M104 S150")
    run(printer, 200.0)
    send(printer, "M109 R150", 200.0)  # S would not wait at all: the hotend is not heating
    timed = run_until_ok(printer, 300.0)
    # Marlin starts the 10 s clock a third later when the target is already reached on the first pass.
    assert [line.rsplit("W:", 1)[1] for _, line in timed if " W:" in line][:2] == ["12", "11"]
    assert timed[-1][0] - 200.0 == pytest.approx(13.333, abs=0.01)


def test_m108_ends_a_wait_at_once_with_the_emergency_parser() -> None:
    printer = make(advanced_ok=True)
    send(printer, "M109 S150")
    run(printer, 3.0)
    assert send(printer, "M108", 3.0) == ["ok P15 B3", "ok P15 B3"]  # M109's ok, then M108's own
    assert printer.executed == ["M109 S150", "M108"]
    assert printer.next_wakeup() is None


def test_without_the_emergency_parser_m108_waits_its_turn() -> None:
    printer = make(advanced_ok=True, emergency_parser=False)
    send(printer, "M109 S150")
    printer.receive(b"M108\n", 3.0)
    printer.receive(b"M105\n", 3.5)
    timed = run(printer, 200.0)
    replies = [(at, line) for at, line in timed if not line.startswith((" T:", "echo:busy"))]
    # M109's ok says B1: M108 and M105 were read in behind it while it waited.
    assert [line for _, line in replies][:2] == ["ok P15 B1", "ok P15 B2"]
    assert replies[2][1].startswith("ok T:")
    assert replies[0][0] > 30.0


def test_m109_s_below_the_current_temperature_does_not_wait_but_r_does() -> None:
    printer = make()
    send(printer, "M104 S200")
    run(printer, 150.0)
    assert send(printer, "M109 S150", 150.0) == ["ok"]
    send(printer, "M104 S200", 151.0)
    run(printer, 300.0)
    send(printer, "M109 R150", 300.0)
    timed = run_until_ok(printer, 1000.0)
    assert timed[0][1].endswith("W:?")
    assert abs(printer.heater_celsius("T0") - 150.0) < 1.0
    assert timed[-1][0] - 300.0 > 60.0  # passive cooling takes a while


def test_m190_waits_for_the_bed() -> None:
    printer = make()
    assert send(printer, "M190 S60") == [" T:25.00 /0.00 B:25.00 /60.00 @:0 B@:0 W:?"]
    timed = run_until_ok(printer, 400.0)
    assert timed[-1][1] == "ok"
    assert 80.0 <= timed[-1][0] <= 140.0
    assert abs(printer.heater_celsius("B") - 60.0) < 1.0


def test_m155_auto_reports_every_interval_also_while_blocked() -> None:
    printer = make()
    assert send(printer, "M155 S1") == ["ok"]
    assert send(printer, "G4 S3", 0.5) == []
    timed = run(printer, 4.2)
    reports = [(at, line) for at, line in timed if line.startswith(" T:")]
    assert [at for at, _ in reports] == [1.0, 2.0, 3.0, 4.0]
    assert all(line == " " + IDLE_M105[3:] for _, line in reports)
    assert ("3.5", "ok") in [(f"{at:g}", line) for at, line in timed]
    assert send(printer, "M155 S0", 4.5) == ["ok"]
    assert run(printer, 20.0) == []
    assert printer.next_wakeup() is None
    send(printer, "M155 S100", 20.0)  # clamped to 60 s
    assert printer.next_wakeup() == pytest.approx(80.0)


def test_g28_takes_homing_time_with_keepalives_and_reports_the_position() -> None:
    printer = make(advanced_ok=True, homing_s=6.0)
    send(printer, "G1 X10 Y20 Z5 F6000")
    assert send(printer, "G28") == []
    timed = run(printer, 20.0)
    assert [line for _, line in timed] == [
        "echo:busy: processing",
        "echo:busy: processing",
        "echo:busy: processing",
        "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
        "ok P15 B3",
    ]
    assert timed[-1][0] == pytest.approx(6.0 + 23.0 / 100.0, abs=0.01)  # the move first (23 mm at 100 mm/s)
    send(printer, "G1 X7 Y8", 20.0)
    send(printer, "G28 X", 20.0)
    assert run(printer, 40.0)[-2][1] == "X:0.00 Y:8.00 Z:0.00 E:0.00 Count X:0 Y:640 Z:0"


def test_m113_changes_the_keepalive_interval() -> None:
    printer = make()
    send(printer, "M113 S0")
    send(printer, "G4 S10")
    assert [line for _, line in run(printer, 11.0)] == ["ok"]
    send(printer, "M113 S3", 11.0)
    send(printer, "G4 S7", 11.0)
    assert [at for at, line in run(printer, 30.0) if line.startswith("echo:busy")] == [14.0, 17.0]


def test_g4_dwells_and_a_full_planner_blocks_g1() -> None:
    printer = make(planner_buffer_size=2)  # one block at a time
    assert send(printer, "G4 P1500") == []
    assert run(printer, 2.0) == [(1.5, "ok")]
    assert send(printer, "G1 X100 F600", 2.0) == ["ok"]  # 10 s move
    assert send(printer, "G1 X0", 2.0) == []  # waits for the first block
    timed = run(printer, 13.0)
    assert [line for _, line in timed] == ["echo:busy: processing"] * 5 + ["ok"]
    assert timed[-1][0] == pytest.approx(12.0)


def test_positions_modes_and_m114() -> None:
    printer = make()
    for command in ("G1 X10 Y20 Z5 E2", "G91", "G1 X1 Y-1 E1", "G90", "M83", "G1 E3", "G92 E0", "M82"):
        assert send(printer, command) == ["ok"]
    assert send(printer, "M114") == ["X:11.00 Y:19.00 Z:5.00 E:0.00 Count X:880 Y:1520 Z:2000", "ok"]


def test_simple_replies() -> None:
    printer = make()
    assert send(printer, "M119") == ["Reporting endstop status", "x_min: open", "y_min: open", "z_min: open", "ok"]
    assert send(printer, "M27") == ["Not SD printing", "ok"]
    assert send(printer, "M118 hello there") == ["hello there", "ok"]
    assert send(printer, "M118 E1 hello") == ["echo:hello", "ok"]
    assert send(printer, "M118 A1 action:pause") == ["//action:pause", "ok"]
    for command in ("M106 S128", "M107", "M110", "M82", "M83", "G90", "G91", "G92", "G21", "M84", "M18", "M117 Hi"):
        assert send(printer, command) == ["ok"], command
    assert send(printer, "M400") == ["ok"]
    assert send(printer, "M503")[-2:] == ["echo:  M301 P22.20 I1.08 D114.00", "ok"]


def test_commands_of_missing_hardware_are_unknown() -> None:
    printer = make(has_bed=False, autoreport_temp=False)
    assert send(printer, "M140 S60") == ['echo:Unknown command: "M140 S60"', "ok"]
    assert send(printer, "M155 S1") == ['echo:Unknown command: "M155 S1"', "ok"]
    assert send(printer, "M141 S40") == ['echo:Unknown command: "M141 S40"', "ok"]


# ------------------------------------------------------------------------------------------------- thermal model


def _seconds_to_reach(printer: SimulatedPrinter, heater: str, target: float, limit: float) -> float:
    now = 0.0
    while now < limit:
        now += 0.1
        printer.advance(now)
        if abs(printer.heater_celsius(heater) - target) < 1.0:
            return now
    raise AssertionError(f"{heater} did not reach {target} C in {limit} s")


def test_hotend_heats_like_the_captured_board() -> None:
    printer = make()
    send(printer, "M104 S200")
    printer.advance(1.0)
    first_second = printer.heater_celsius("T0") - 25.0
    assert 2.5 <= first_second <= 4.0  # the capture shows about 3.3 C/s at first
    assert send(printer, "M105", 1.0)[0].endswith("@:127 B@:0")
    reached = _seconds_to_reach(printer, "T0", 200.0, 200.0)
    assert 60.0 <= reached <= 90.0
    peak = 0.0
    for half_seconds in range(1, 121):
        printer.advance(reached + half_seconds / 2)
        peak = max(peak, printer.heater_celsius("T0"))
    assert 199.0 < peak <= 202.0  # no large overshoot
    holding = send(printer, "M105", 300.0)[0]
    assert holding.startswith("ok T:200.00 /200.00")
    power = int(holding.split(" @:")[1].split()[0])
    assert 5 <= power <= 60


def test_bed_is_several_times_slower() -> None:
    printer = make()
    send(printer, "M140 S60")
    printer.advance(1.0)
    assert printer.heater_celsius("B") - 25.0 < (3.3 / 3)
    assert 80.0 <= _seconds_to_reach(printer, "B", 60.0, 300.0) <= 120.0


def test_heaters_cool_to_ambient_when_off() -> None:
    printer = make()
    send(printer, "M104 S200")
    printer.advance(120.0)
    send(printer, "M104 S0", 120.0)
    printer.advance(180.0)
    cooled = printer.heater_celsius("T0")
    assert 25.0 < cooled < 199.0
    printer.advance(100_000.0)
    assert printer.heater_celsius("T0") == 25.0


def test_temperatures_do_not_depend_on_how_often_time_is_advanced() -> None:
    often, rarely = make(), make()
    for printer in (often, rarely):
        send(printer, "M104 S210")
        send(printer, "M140 S70")
    for step in range(1, 1501):
        often.advance(step * 0.0731)
    rarely.advance(1500 * 0.0731)
    assert often.heater_celsius("T0") == rarely.heater_celsius("T0")
    assert often.heater_celsius("B") == rarely.heater_celsius("B")


def test_advancing_an_idle_printer_is_cheap() -> None:
    printer = make()
    send(printer, "M104 S200")
    send(printer, "M140 S60")
    printer.advance(600.0)  # settled: holding needs no integration any more
    work = printer.thermal_steps
    assert work > 0
    for step in range(20_000):
        printer.advance(600.0 + step * 0.05)
    # Counted, not timed (timing belongs in benchmarks): a thousand seconds of holding integrate nothing.
    assert printer.thermal_steps == work
    assert printer.heater_celsius("T0") == 200.0 and printer.heater_celsius("B") == 60.0
    assert printer.next_wakeup() is None


def test_heater_celsius_names() -> None:
    printer = make(extruders=2, has_chamber=True)
    assert [printer.heater_celsius(name) for name in ("T0", "T1", "B", "C")] == [25.0] * 4
    with pytest.raises(ValueError, match="no heater 'T2'"):
        printer.heater_celsius("T2")


# ------------------------------------------------------------------------------------------- halts and resets


def test_m112_halts_at_once_even_with_a_full_buffer() -> None:
    printer = make(advanced_ok=True)
    send(printer, "G4 S30")
    printer.receive(b"M400\nM400\nM400\nM400\nM400\n", 1.0)
    assert send(printer, "M112", 1.5) == ["echo:M112 Shutdown", "Error:Printer halted. kill() called!"]
    assert printer.halted
    assert send(printer, "M105", 3.0) == []
    assert run(printer, 60.0) == []
    assert printer.next_wakeup() is None
    assert "M112" not in printer.executed


def test_without_the_emergency_parser_m112_halts_in_its_turn() -> None:
    printer = make(emergency_parser=False)
    send(printer, "G4 S5")
    assert send(printer, "M112", 1.0) == []
    assert [line for _, line in run(printer, 10.0)] == [
        "echo:busy: processing",
        "echo:busy: processing",
        "ok",
        "echo:M112 Shutdown",
        "Error:Printer halted. kill() called!",
    ]
    assert printer.halted


def test_m410_drops_planned_moves() -> None:
    printer = make()
    send(printer, "G1 X100 F600")  # 10 s
    send(printer, "G1 X0")
    assert send(printer, "M400", 1.0) == []
    assert send(printer, "M410", 2.0) == ["ok", "ok"]  # M400 ends at once, then M410's own ok
    assert send(printer, "M114", 2.0)[0].startswith("X:0.00 ")


def test_m410_while_a_move_waits_for_a_planner_block() -> None:
    printer = make(planner_buffer_size=2)
    send(printer, "G1 X100 F600")  # 10 s
    assert send(printer, "G1 X50", 1.0) == []  # no free block yet
    assert send(printer, "M410", 2.0) == ["ok", "ok"]  # the waiting move is planned from the stop, then M410
    assert send(printer, "M114", 2.0)[0].startswith("X:50.00 ")
    assert [line for _, line in run(printer, 20.0)] == []


def test_thermal_runaway_prints_the_error_and_halts() -> None:
    printer = make()
    send(printer, "M104 S200")
    send(printer, "G4 S30")
    printer.thermal_runaway(5.0)
    assert lines(printer)[-2:] == [
        "Error:Thermal Runaway, system stopped! Heater_ID: E0",
        "Error:Printer halted. kill() called!",
    ]
    assert printer.halted
    assert send(printer, "M105", 6.0) == []
    hot = printer.heater_celsius("T0")
    printer.advance(60.0)
    assert printer.heater_celsius("T0") < hot  # kill() turned the heaters off
    printer.thermal_runaway(61.0, heater="bed")
    assert lines(printer) == []  # already halted
    with pytest.raises(ValueError, match="one-line"):
        printer.thermal_runaway(62.0, heater="")


def test_reset_loses_what_was_in_flight_and_prints_the_banner_again() -> None:
    printer = make(advanced_ok=True)
    send(printer, "M104 S200")
    send(printer, number_command("M110 N40", 40))
    send(printer, "G4 S30", 1.0)
    send(printer, "M155 S2", 1.0)
    printer.reset(5.0)
    banner = lines(printer)
    assert banner[:2] == ["echo:busy: processing", "echo:busy: processing"]  # the dwell, until the reset
    assert banner[2:5] == ["start", "External Reset", "Marlin 2.1.2.4"]
    assert run(printer, 60.0) == []  # neither the dwell's ok nor auto-reports survive
    assert send(printer, number_command("M105", 1), 60.0)[0].startswith("ok T:")
    assert "/0.00 B:" in send(printer, "M105", 60.0)[0]


def test_reset_revives_a_halted_printer() -> None:
    printer = make()
    send(printer, "M112")
    printer.reset(1.0)
    assert lines(printer)[0] == "start"
    assert not printer.halted
    assert send(printer, "M105", 1.0) == [IDLE_M105]


# ------------------------------------------------------------------------------------------------------- faults


def _reliable_send(printer: SimulatedPrinter, commands: list[str], now: float = 0.0) -> int:
    """A minimal host: one numbered line in flight, resent on `Resend:`; returns how many resends it took."""
    resends = 0
    for number, command in enumerate(commands, start=1):
        line = number_command(command, number).encode() + b"\n"
        while True:
            printer.receive(line, now)
            reply = lines(printer) + [text for _, text in run(printer, now + 5.0)]
            now += 5.0
            if any(text.startswith("Resend:") for text in reply):
                resends += 1
                continue
            assert reply[-1].startswith("ok"), reply
            break
    return resends


def test_corrupted_lines_fail_their_checks_and_resending_executes_each_once() -> None:
    printer = make(Faults(corrupt_rx_ratio=0.3), seed=7)
    commands = [f"G1 X{i} Y{i % 5}" for i in range(100)]
    resends = _reliable_send(printer, commands)
    assert 15 <= resends <= 80
    assert printer.executed == commands


def test_dropped_oks_are_a_share_of_normal_oks_only() -> None:
    printer = make(Faults(drop_ok_ratio=0.5), seed=3)
    oks = sum(send(printer, "M400").count("ok") for _ in range(200))
    assert 70 <= oks <= 130
    assert all(send(printer, "M105") == [IDLE_M105] for _ in range(20))
    assert send(printer, "N5 M105*0") == [
        "Error:Line Number is not Last Line Number+1, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    assert len(printer.executed) == 220


def test_a_silent_printer_executes_but_writes_nothing() -> None:
    faults = Faults(silent=True)
    printer = SimulatedPrinter(SimulatorConfig(command_time_s=0.0, report_time_s=0.0), faults)
    assert send(printer, "M105") == []
    assert send(printer, "G4 S5") == []
    assert run(printer, 10.0) == []
    assert printer.executed == ["M105", "G4 S5"]
    faults.silent = False
    assert send(printer, "M105", 10.0) == [IDLE_M105]


def test_noise_lines_are_garbage_that_never_poses_as_a_reply() -> None:
    printer = make(Faults(noise_ratio=0.5), seed=11)
    raw = b""
    for _ in range(200):
        printer.receive(b"M105\n", 0.0)
        raw += printer.take_output()
    assert b"\r" not in raw
    real = [line for line in raw.split(b"\n")[:-1] if line == IDLE_M105.encode()]
    noise = [line for line in raw.split(b"\n")[:-1] if line != IDLE_M105.encode()]
    assert len(real) == 200
    assert 60 <= len(noise) <= 140
    assert all(1 <= len(line) <= 16 and not 0x20 <= line[0] <= 0x7E for line in noise)
    assert any(b"\x00" in line or any(byte >= 0x80 for byte in line) for line in noise)


def test_same_seed_same_bytes() -> None:
    def session(seed: int) -> bytes:
        printer = make(Faults(corrupt_rx_ratio=0.2, drop_ok_ratio=0.2, noise_ratio=0.2), seed=seed)
        out = b""
        for i in range(50):
            printer.receive(number_command(f"G1 X{i}", i + 1).encode() + b"\n", i * 0.1)
            out += printer.take_output()
        return out

    assert session(1) == session(1)
    assert session(1) != session(2)


def test_faults_can_change_at_any_time() -> None:
    printer = make()
    assert send(printer, "M400") == ["ok"]
    printer.faults.drop_ok_ratio = 1.0
    assert send(printer, "M400") == []
    printer.faults = Faults()
    assert send(printer, "M400") == ["ok"]


# ------------------------------------------------------------------------------------------------ time and config


def test_time_that_goes_backwards_counts_as_now() -> None:
    printer = make()
    send(printer, "G4 S2", 10.0)
    printer.advance(5.0)
    assert lines(printer) == []
    assert printer.next_wakeup() == pytest.approx(12.0)


def test_next_wakeup_is_none_when_nothing_is_scheduled() -> None:
    printer = make()
    assert printer.next_wakeup() is None
    send(printer, "G4 S3")
    assert printer.next_wakeup() == pytest.approx(2.0)  # the first keepalive


@pytest.mark.parametrize(
    "bad",
    [{"command_buffer_size": 0}, {"rx_buffer_size": 0}, {"planner_buffer_size": 1}, {"extruders": 0}, {"extruders": 9}],
)
def test_impossible_configurations_are_refused(bad: dict[str, int]) -> None:
    with pytest.raises(ValueError, match="must be"):
        SimulatorConfig(**bad)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------------ streaming


def test_numbered_lines_run_once_and_are_recorded_without_number_or_checksum() -> None:
    printer = make(ignore_duplicate_lines=False)  # Marlin 2.1.2: a repeat is answered
    commands = ["G1 X1 Y1 F3000", "M117 hello", "G1 X2 Y2"]
    for number, command in enumerate(commands, start=1):
        assert send(printer, number_command(command, number)) == ["ok"]
    # The host missed the ok of line 3 and sends it again: refused, and the next line is asked for (2.1.2;
    # bugfix-2.1.x drops it without a word, the default).
    assert send(printer, number_command(commands[2], 3)) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 3",
        "Resend: 4",
        "ok",
    ]
    assert send(printer, number_command("G1 X3", 4)) == ["ok"]
    assert printer.executed == [*commands, "G1 X3"]
    assert printer.executed_line_numbers == [1, 2, 3, 4]
    assert send(printer, "M105") == [IDLE_M105]  # unnumbered: run, but no number recorded
    assert printer.executed_line_numbers == [1, 2, 3, 4]


def test_newer_firmware_drops_repeats_of_the_last_two_lines_without_a_word() -> None:
    assert SimulatorConfig().ignore_duplicate_lines  # bugfix-2.1.x, the default
    printer = make()
    for number in range(1, 4):
        send(printer, number_command(f"G1 X{number}", number))
    assert send(printer, number_command("G1 X3", 3)) == []
    assert send(printer, number_command("G1 X2", 2)) == []
    assert send(printer, number_command("G1 X1", 1))[:2] == [
        "Error:Line Number is not Last Line Number+1, Last Line: 3",
        "Resend: 4",
    ]
    assert printer.executed_line_numbers == [1, 2, 3]


def test_silent_after_lines_answers_the_last_line_then_stalls() -> None:
    faults = Faults(silent_after_lines=3)
    printer = make(faults, advanced_ok=True)
    assert send(printer, "M155 S1") == ["ok P15 B3"]  # unnumbered lines do not count
    burst = "".join(number_command(f"G1 X{n} F6000", n) + "\n" for n in range(1, 7))
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["ok N1 P14 B0", "ok N2 P13 B0", "ok N3 P12 B0"]  # N4-N6 were read in too
    assert printer.stalled
    assert printer.executed_line_numbers == [1, 2, 3]
    # Hung: no auto-report, no keepalive, no answer; bytes still land in the receive buffer until it is full.
    assert printer.next_wakeup() is None
    assert run(printer, 30.0) == []
    printer.receive(b"M105\n" * 40, 31.0)
    assert lines(printer) == []
    assert printer.executed == ["M155 S1", "G1 X1 F6000", "G1 X2 F6000", "G1 X3 F6000"]
    assert (printer.rx_overflows, printer.rx_dropped_bytes) == (1, 200 - 128)
    # A reset revives it; with the fault still set, the next numbered line stalls it again.
    printer.reset(32.0)
    assert not printer.stalled
    assert lines(printer)[0] == "start"
    assert send(printer, number_command("M400", 1), 32.0) == ["ok N1 P15 B3"]
    assert printer.stalled
    faults.silent_after_lines = None
    printer.reset(33.0)
    lines(printer)
    assert send(printer, number_command("M400", 1), 33.0) == ["ok N1 P15 B3"]
    assert send(printer, number_command("M400", 2), 33.0) == ["ok N2 P15 B3"]


def test_receive_buffer_overflows_are_counted() -> None:
    printer = make()
    # Block the command buffer: a 10 s dwell runs, three lines wait behind it.
    send(printer, "G4 S10\nM400\nM400\nM400")
    assert printer.rx_overflows == 0
    printer.receive(bytes(300), 1.0)
    assert (printer.rx_overflows, printer.rx_dropped_bytes) == (1, 300 - 128)
    printer.receive(b"M105\n", 1.5)
    assert (printer.rx_overflows, printer.rx_dropped_bytes) == (2, 300 - 128 + 5)


def test_lines_move_on_while_a_large_read_comes_in() -> None:
    # 300 bytes in one call are 300 bytes that arrived over time: a board that is not blocked keeps taking
    # lines out of its receive buffer, so nothing is lost.
    printer = make()
    commands = [f"G1 X{n} Y{n} F60000" for n in range(20)]
    data = "".join(command + "\n" for command in commands).encode()
    assert len(data) > 200
    printer.receive(data, 0.0)
    run(printer, 1.0)
    assert (printer.rx_overflows, printer.rx_dropped_bytes) == (0, 0)
    assert printer.executed == commands


def test_motion_time_scale_shortens_moves() -> None:
    def m400_seconds(scale: float) -> float:
        printer = make(motion_time_scale=scale)
        send(printer, "G1 X50 F3000")  # 50 mm at 50 mm/s
        send(printer, "M400")
        return run_until_ok(printer, 10.0)[-1][0] if scale else 0.0

    assert m400_seconds(1.0) == pytest.approx(1.0)
    assert m400_seconds(0.1) == pytest.approx(0.1)
    instant = make(motion_time_scale=0.0)
    assert send(instant, "G1 X50 F3000\nM400\nM114") == [
        "ok",
        "ok",
        "X:50.00 Y:0.00 Z:0.00 E:0.00 Count X:4000 Y:0 Z:0",
        "ok",
    ]
    with pytest.raises(ValueError, match="motion_time_scale"):
        SimulatorConfig(motion_time_scale=-1.0)


def test_generated_moves_are_short_reproducible_and_on_the_bed() -> None:
    moves = generate_moves(2000)
    assert moves == generate_moves(2000)
    assert moves != generate_moves(2000, seed=1)
    assert generate_moves(17_000)[:2000] == moves
    assert moves[0].startswith("G1 X") and moves[0].endswith(" F3000")
    assert 30 <= sum(len(move) + 1 for move in moves) / len(moves) <= 36
    points = [(100.0, 100.0)] + [(float(m.split()[1][1:]), float(m.split()[2][1:])) for m in moves]
    assert all(10.0 <= x <= 190.0 and 10.0 <= y <= 190.0 for x, y in points)
    steps = [math.dist(a, b) for a, b in itertools.pairwise(points)]
    assert min(steps) >= 0.39 and max(steps) <= 0.61
    with pytest.raises(ValueError, match="count"):
        generate_moves(-1)


def test_wire_hands_out_bytes_no_faster_than_the_baud_rate() -> None:
    wire = Wire(250_000)  # 40 us a byte
    assert wire.byte_s == pytest.approx(40e-6)
    wire.put(bytes(range(100)), 1.0)
    assert wire.take(1.0) == b""
    assert wire.take(1.0 + 10 * 40e-6) == bytes(range(10))
    assert wire.take(1.0 + 10.5 * 40e-6) == b""
    assert wire.next_arrival() == pytest.approx(1.0 + 11 * 40e-6)
    # Put in while busy: queued behind what is under way, not from the moment it was put in.
    wire.put(b"xyz", 1.001)
    assert wire.last_arrival() == pytest.approx(1.0 + 103 * 40e-6)
    assert wire.pending == 93
    assert wire.take(1.0 + 102 * 40e-6) == bytes(range(10, 100)) + b"xy"
    assert wire.take(5.0) == b"z"
    assert wire.next_arrival() is None and wire.due(5.0, 0.001) is None
    # An idle wire starts when the bytes come, and a busy one is handed over at most every interval.
    wire.put(bytes(100), 6.0)
    assert wire.due(6.0, 0.001) == pytest.approx(6.001)
    assert wire.due(6.0035, 0.001) == pytest.approx(6.004)  # the end of the burst, not later
    wire.delay(0.5)
    assert wire.take(6.004) == b""
    assert wire.take(6.504) == bytes(100)
    wire.put(b"a", 7.0)
    wire.clear()
    assert wire.pending == 0 and wire.take(8.0) == b""
    with pytest.raises(ValueError, match="baud_rate"):
        Wire(0)


@dataclass
class Streamed:
    seconds: float
    resends: int
    timeouts: int


def stream(
    printer: SimulatedPrinter,
    commands: list[str],
    *,
    window_bytes: int,
    baud_rate: int = 250_000,
    ok_timeout_s: float = 0.5,
    start_s: float = 0.0,
) -> Streamed:
    """A streaming host against `printer` over an ideal serial line, in simulated time.

    Numbered lines, at most `window_bytes` of them unacknowledged (0: one line at a time, ping-pong); each
    `ok` acknowledges the oldest line. On `Resend:` it stops, lets the line go quiet, and goes back to the line
    asked for; when no `ok` comes for `ok_timeout_s` it goes back to the oldest unacknowledged line.
    """
    byte_s = 10 / baud_rate
    quiet_s = 2 * max(window_bytes, 100) * byte_s
    payloads = [number_command(command, n).encode() + b"\n" for n, command in enumerate(commands, start=1)]
    to_printer: deque[tuple[float, bytes]] = deque()  # (arrival, line)
    to_host: deque[tuple[float, str]] = deque()
    line_free = host_line_free = 0.0
    unacked: deque[int] = deque()  # sizes, oldest first
    in_flight = 0
    next_n = 1
    rewind_to: int | None = None
    rewind_at = 0.0
    progress_at = now = start_s
    resends = timeouts = 0
    while True:
        while (
            rewind_to is None
            and next_n <= len(payloads)
            and (not unacked or (window_bytes and in_flight + len(payloads[next_n - 1]) <= window_bytes))
        ):
            payload = payloads[next_n - 1]
            line_free = max(line_free, now) + len(payload) * byte_s
            to_printer.append((line_free, payload))
            unacked.append(len(payload))
            in_flight += len(payload)
            next_n += 1
        due = [
            t
            for t in (
                to_printer[0][0] if to_printer else None,
                to_host[0][0] if to_host else None,
                printer.next_wakeup(),
                rewind_at if rewind_to is not None else None,
                progress_at + ok_timeout_s if unacked and rewind_to is None else None,
            )
            if t is not None
        ]
        if not due:
            return Streamed(now - start_s, resends, timeouts)
        now = max(now, min(due))
        assert now < start_s + 3600, "the stream does not end"
        if to_printer and to_printer[0][0] <= now:
            printer.receive(to_printer.popleft()[1], now)
        else:
            printer.advance(now)
        for line in lines(printer):
            host_line_free = max(host_line_free, now) + (len(line) + 1) * byte_s
            to_host.append((host_line_free, line))
        while to_host and to_host[0][0] <= now:
            line = to_host.popleft()[1]
            if line.startswith("ok") and unacked:
                in_flight -= unacked.popleft()
                progress_at = now
            elif line.startswith("Resend: "):
                resends += 1
                rewind_to = int(line[8:])
                rewind_at = now + quiet_s
        if rewind_to is not None and now >= rewind_at:
            next_n, rewind_to = rewind_to, None
            unacked.clear()
            in_flight = 0
            progress_at = now
        elif unacked and rewind_to is None and now >= progress_at + ok_timeout_s:
            timeouts += 1
            rewind_to = next_n - len(unacked)
            rewind_at = now


# An 8N1 line at 250000 baud carries this many of the generated moves a second, numbered.
_WIRE_LINES_PER_S = 25_000 / (sum(len(number_command(m, n)) + 1 for n, m in enumerate(generate_moves(), 1)) / 17_000)


def _at_bed_centre(**config: object) -> SimulatedPrinter:
    """A printer that has already crossed from 0,0 to where the generated moves start (a 2.8 s move)."""
    printer = make(None, **config)
    send(printer, "G1 X100 Y100 F3000\nM400")
    run_until_ok(printer, 5.0)
    return printer


def test_send_ahead_at_250000_baud_is_planner_bound_unless_moves_are_sped_up() -> None:
    moves = generate_moves(1500)
    # Real-time moves: 0.5 mm at 50 mm/s is 10 ms of motion, so about 100 lines a second, far below the
    # ~570 a second the line carries.
    real = _at_bed_centre()
    streamed = stream(real, moves, window_bytes=128, start_s=3.0)
    assert (streamed.resends, streamed.timeouts) == (0, 0)
    assert 90 <= len(moves) / streamed.seconds <= 110
    # A tenth of the motion time leaves the line as the limit, and the receive buffer never overflows.
    fast = _at_bed_centre(motion_time_scale=0.1)
    streamed = stream(fast, moves, window_bytes=128, start_s=3.0)
    assert len(moves) / streamed.seconds >= 0.95 * _WIRE_LINES_PER_S
    assert fast.rx_dropped_bytes == 0
    assert fast.executed[2:] == moves
    # Ping-pong waits for each ok: about 44 bytes one way and 3 back per line.
    ping_pong = _at_bed_centre(motion_time_scale=0.1)
    streamed = stream(ping_pong, moves[:300], window_bytes=0, start_s=3.0)
    assert 0.85 * _WIRE_LINES_PER_S <= 300 / streamed.seconds <= _WIRE_LINES_PER_S


@pytest.mark.parametrize("window_bytes", [0, 128])
def test_numbered_streaming_survives_every_fault_and_runs_each_line_once(window_bytes: int) -> None:
    faults = Faults(corrupt_rx_ratio=0.05, drop_ok_ratio=0.03, noise_ratio=0.1)
    # This host goes back to the oldest unanswered line when an ok is late: 2.1.2 answers a line it already ran
    # with a Resend of the next, where bugfix-2.1.x (the default) drops it without a word.
    printer = make(faults, motion_time_scale=0.0, seed=5, ignore_duplicate_lines=False)
    moves = generate_moves(600)
    streamed = stream(printer, moves, window_bytes=window_bytes, ok_timeout_s=0.2)
    assert streamed.resends >= 10 and streamed.timeouts >= 1
    assert printer.executed_line_numbers == list(range(1, len(moves) + 1))
    assert printer.executed == moves
    assert printer.rx_dropped_bytes == 0


# ------------------------------------------------------------------------------------------------ dialects
# The switches for the protocol doc's "Dialects a host meets in the field"; each line the host would see is also
# run through the parser, so the simulator and the parser agree on every shape.


def test_checksum_required_refuses_unnumbered_lines_without_an_ok() -> None:
    printer = make(checksum_required=True)
    assert send(printer, "M105") == ["Error: Missing checksum"]
    assert send(printer, "G1 X5") == ["Error: Missing checksum"]
    assert send(printer, "M110 N10") == ["Error: Missing checksum"]  # not even M110 N, unnumbered
    assert printer.executed == []
    assert classify_line("Error: Missing checksum") == ErrorMessage("Missing checksum", ErrorKind.CHECKSUM_REQUIRED)
    # Numbered lines work as usual, M110 included, and so do their errors (with `Last Line`, a resend and an ok).
    assert send(printer, number_command("M110 N0", 0)) == ["ok"]
    assert send(printer, number_command("M105", 1)) == [IDLE_M105]
    assert send(printer, number_command("G1 X5", 2)) == ["ok"]
    assert send(printer, "N3 G1 X6") == ["Error:No Checksum with line number, Last Line: 2", "Resend: 3", "ok"]
    assert printer.executed == ["M110 N0", "M105", "G1 X5"]


def test_plain_wait_lines_have_no_w_field() -> None:
    printer = make(plain_wait_lines=True)
    assert send(printer, "M109 S60") == [" T:25.00 /60.00 B:25.00 /0.00 @:0 B@:0"]
    timed = run_until_ok(printer, 120.0)
    waits = [" T:25.00 /60.00 B:25.00 /0.00 @:0 B@:0"] + [line for _, line in timed if line.startswith(" T:")]
    assert len(waits) > 10
    assert all(" W:" not in line for line in waits)
    for line in waits:
        event = classify_line(line)
        assert isinstance(event, TemperatureReport)
        assert not event.temperatures.waiting
    others = [line for _, line in timed if not line.startswith(" T:")]
    assert set(others[:-1]) == {"echo:busy: processing"}
    assert others[-1] == "ok"


def test_bare_busy_keepalives() -> None:
    printer = make(bare_busy=True, homing_s=5.0)
    assert send(printer, "G28") == []
    assert [line for _, line in run(printer, 10.0)] == [
        "busy:processing",
        "busy:processing",
        "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
        "ok",
    ]
    assert classify_line("busy:processing") == BusyKeepalive(reason="processing")


def test_repetier_targets_get_lines_of_their_own_and_reports_drop_them() -> None:
    printer = make(repetier_targets=True, has_chamber=True, extruders=2)
    assert send(printer, "M105") == ["ok T:25.00 B:25.00 C:25.00 T0:25.00 T1:25.00 @:0 B@:0 C@:0 @0:0 @1:0"]
    target_lines = [
        *send(printer, "M104 S200"),
        *send(printer, "M104 T1 S300"),  # clamped, as the board stores it
        *send(printer, "M140 S60"),
        *send(printer, "M141 S45.7"),  # celsius_t is an integer
    ]
    assert target_lines == [
        *("TargetExtr0:200", "ok", "TargetExtr1:260", "ok"),
        *("TargetBed:60", "ok", "TargetChamber:45", "ok"),
    ]
    assert [classify_line(line) for line in target_lines[::2]] == [
        TargetTemperature("T0", 200.0),
        TargetTemperature("T1", 260.0),
        TargetTemperature("B", 60.0),
        TargetTemperature("C", 45.0),
    ]
    assert send(printer, "M104") == ["ok"]  # no S, no new target, no line
    assert send(printer, "M104 T5 S10") == ["echo:M104 Invalid extruder 5", "ok"]
    report = classify_line(send(printer, "M105")[0])
    assert isinstance(report, Ok)
    assert report.temperatures is not None
    assert set(report.temperatures.heaters) == {"T", "B", "C", "T0", "T1"}
    assert all(reading.target is None for reading in report.temperatures.heaters.values())


def test_repetier_targets_in_waits_and_auto_reports() -> None:
    printer = make(repetier_targets=True)
    assert send(printer, "M155 S1") == ["ok"]
    assert send(printer, "M190 S30", 0.5) == ["TargetBed:30", " T:25.00 B:25.00 @:0 B@:0 W:?"]
    timed = run_until_ok(printer, 200.0)
    reports = [line for _, line in timed if line.startswith(" T:")]
    assert reports[0].startswith(" T:25.00 B:25.")
    assert all(" /" not in line for line in reports)
    assert any(" W:" not in line for line in reports)  # the auto-reports go on during the wait
    assert timed[-1][1] == "ok"
    # M109 that does not need to wait still prints the new target.
    assert send(printer, "M109 S0", timed[-1][0]) == ["TargetExtr0:0", "ok"]


def test_m114_on_ok() -> None:
    for advanced_ok in (False, True):
        printer = make(m114_on_ok=True, advanced_ok=advanced_ok, motion_time_scale=0.0)
        assert send(printer, "M114") == ["ok X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"]
        send(printer, "G1 X10 E1.5")
        reply = send(printer, "M114")
        assert reply == ["ok X:10.00 Y:0.00 Z:0.00 E:1.50 Count X:800 Y:0 Z:0"]
        event = classify_line(reply[0])
        assert isinstance(event, Ok)
        assert parse_position((event.payload,)) == {"X": 10.0, "Y": 0.0, "Z": 0.0, "E": 1.5}
    # A dropped ok must not take the position with it: this ok is an answer, like M105's.
    printer = make(Faults(drop_ok_ratio=1.0), m114_on_ok=True)
    assert send(printer, "M114") == ["ok X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"]


LOCKED = "echo:Printer locked! (Unlock with M511 or LCD)"


def test_password_locks_every_command_until_m511() -> None:
    printer = make(password="1234", motion_time_scale=0.0)
    assert send(printer, "M105") == [LOCKED, "ok"]
    assert send(printer, "G1 X10") == [LOCKED, "ok"]
    assert send(printer, "M104 S200") == [LOCKED, "ok"]
    assert send(printer, number_command("M115", 1)) == [LOCKED, "ok"]  # numbered lines are checked, then refused
    assert printer.executed == []
    assert printer.executed_line_count == 0
    assert classify_line(LOCKED) == PrinterLocked(message=LOCKED.removeprefix("echo:"))
    assert send(printer, "M511 P4321") == ["echo:Incorrect Password", "ok"]
    assert send(printer, "M511") == ["echo:Incorrect Password", "ok"]
    assert send(printer, "M105") == [LOCKED, "ok"]
    assert send(printer, "M511 P1234") == ["ok"]
    assert send(printer, "M105") == [IDLE_M105]
    assert send(printer, "M114") == ["X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok"]  # G1 X10 never ran
    assert send(printer, "M511 P0") == ["ok"]  # unlocked: M511 does nothing
    assert printer.executed == ["M511 P4321", "M511", "M511 P1234", "M105", "M114", "M511 P0"]
    printer.reset(1.0)
    lines(printer)
    assert send(printer, "M105", 1.0) == [LOCKED, "ok"]  # locked again after a reset
    assert send(make(), "M511 P1234") == ['echo:Unknown command: "M511 P1234"', "ok"]  # no PASSWORD_FEATURE


def test_password_lock_with_advanced_ok_and_the_emergency_parser() -> None:
    printer = make(password="7", advanced_ok=True)
    assert send(printer, number_command("M105", 1)) == [LOCKED, "ok N1 P15 B3"]
    send(printer, "M112")  # the emergency parser does not ask for the password
    assert printer.halted


@pytest.mark.parametrize("password", ["", "a b", "x;y", "x*1", "caf\u00e9"])
def test_passwords_that_cannot_be_sent_are_refused(password: str) -> None:
    with pytest.raises(ValueError, match="password"):
        SimulatorConfig(password=password)


LOST = "!! Lost communication with MCU 'mcu'"


def test_not_executed_commands_get_the_bridge_line_and_an_ok() -> None:
    printer = make(Faults(not_executed_ratio=1.0), advanced_ok=True)
    assert send(printer, "G1 X10") == [LOST, "ok P15 B3"]
    assert send(printer, number_command("M105", 1)) == [LOST, "ok N1 P15 B3"]
    assert printer.executed == []
    assert printer.executed_count == 0
    assert classify_line(LOST) == ErrorMessage("Lost communication with MCU 'mcu'", ErrorKind.NOT_EXECUTED)
    printer.faults.not_executed_ratio = 0.0
    assert send(printer, number_command("M105", 2)) == [IDLE_M105]


def test_not_executed_share_has_its_own_random_stream() -> None:
    def outcome(faults: Faults) -> list[bool]:
        printer = make(faults, seed=3)
        result = []
        for index in range(300):
            reply = send(printer, f"M117 {index}")
            result.append(LOST in reply)
        assert printer.executed_count == result.count(False)
        return result

    plain = outcome(Faults(not_executed_ratio=0.2))
    assert 30 < plain.count(True) < 90
    # Other faults drawing from their own streams do not change which commands are lost.
    assert outcome(Faults(not_executed_ratio=0.2, drop_ok_ratio=0.5, noise_ratio=0.3)) == plain


def test_multi_extruder_auto_reports_have_every_hotend_and_its_power() -> None:
    printer = make(extruders=2)
    send(printer, "M104 T1 S200")
    assert send(printer, "M155 S1") == ["ok"]
    reports = [line for _, line in run(printer, 2.0) if line.startswith(" T:")]
    assert reports[0] == " T:25.00 /0.00 B:25.00 /0.00 T0:25.00 /0.00 T1:28.39 /200.00 @:0 B@:0 @0:0 @1:127"
    event = classify_line(reports[0])
    assert isinstance(event, TemperatureReport)
    heaters = event.temperatures.heaters
    assert (heaters["T1"].actual, heaters["T1"].target, heaters["T1"].power) == (28.39, 200.0, 127)
    assert (heaters["T0"].actual, heaters["T0"].target, heaters["T0"].power) == (25.0, 0.0, 0)


# ------------------------------------------------------------------------------------------------ bounded record


def test_the_record_keeps_only_the_last_commands_and_counts_them_all() -> None:
    printer = make(record_limit=5)
    for number in range(1, 13):
        send(printer, number_command(f"M117 {number}", number))
    send(printer, "M117 unnumbered")
    assert printer.executed == [f"M117 {n}" for n in range(9, 13)] + ["M117 unnumbered"]
    assert list(printer.executed) == [f"M117 {n}" for n in range(9, 13)] + ["M117 unnumbered"]
    assert printer.executed_line_numbers == [8, 9, 10, 11, 12]
    assert (printer.executed_count, printer.executed_line_count) == (13, 12)
    assert len(printer.executed) == 5
    assert printer.executed[0] == "M117 9"
    assert printer.executed[-1] == "M117 unnumbered"
    assert printer.executed[-2:] == ["M117 12", "M117 unnumbered"]
    assert "M117 10" in printer.executed
    assert "M117 1" not in printer.executed


def test_the_default_record_is_bounded_and_none_keeps_everything() -> None:
    assert SimulatorConfig().record_limit == 100_000
    assert make().executed.limit == 100_000
    printer = make(record_limit=None)
    for index in range(50):
        send(printer, f"M117 {index}")
    assert len(printer.executed) == printer.executed_count == 50
    with pytest.raises(ValueError, match="record_limit"):
        SimulatorConfig(record_limit=-1)


def test_silent_after_lines_counts_lines_the_record_no_longer_keeps() -> None:
    printer = make(Faults(silent_after_lines=4), record_limit=2)
    for number in range(1, 5):
        assert send(printer, number_command("M400", number)) == ["ok"]
    assert printer.stalled
    assert send(printer, number_command("M400", 5)) == []
    assert printer.executed_line_numbers == [3, 4]


# ------------------------------------------------------------------------------------------- the command loop


def test_the_command_loop_takes_marlins_time_over_each_command() -> None:
    # By default each command costs the loop 1 ms before its ok, and an M105 4.3 ms (its report): about 1,000
    # short lines a second, and an M105 round trip of 6.3 ms at 250000 baud, as Marlin 2.1 on an ATmega2560.
    printer = SimulatedPrinter(boot=False)
    printer.receive(b"M105\n", 0.0)
    assert printer.take_output() == b""
    assert printer.next_wakeup() == pytest.approx(0.0043)
    printer.advance(0.0042)
    assert printer.take_output() == b""
    printer.advance(0.0043)
    assert printer.take_output() == (IDLE_M105 + "\n").encode()
    printer.receive(b"G92 X0\nG92 X1\nG92 X2\n", 1.0)
    printer.advance(1.0025)
    assert printer.take_output() == b"ok\nok\n"  # one a millisecond
    printer.advance(1.003)
    assert printer.take_output() == b"ok\n"
    assert printer.executed[-3:] == ["G92 X0", "G92 X1", "G92 X2"]


def test_the_command_loop_time_can_be_set_or_turned_off() -> None:
    printer = make(command_time_s=0.01, report_time_s=0.02)
    printer.receive(b"G92 X0\nM105\n", 0.0)
    printer.advance(0.0099)
    assert printer.take_output() == b""
    printer.advance(0.03)
    assert printer.take_output() == (f"ok\n{IDLE_M105}\n").encode()
    assert send(make(), "M105") == [IDLE_M105]  # 0: at the instant it arrives
    with pytest.raises(ValueError, match="command_time_s"):
        SimulatorConfig(command_time_s=-1.0)
