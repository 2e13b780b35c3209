"""classify_line and EventParser: one event per line, for every kind of line Marlin sends, and never an exception.

The golden tests read the real Marlin 2.1 sessions in tests/captures/marlin-2.1 (copied from shared/captures;
`MARLIN_CAPTURES` overrides it) and state, rule by rule, which event each printer line must give.
"""

from __future__ import annotations

import os
import re
import typing
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.events import (
    BusyKeepalive,
    Capability,
    EchoMessage,
    ErrorKind,
    ErrorMessage,
    Event,
    FirmwareInfo,
    HostAction,
    Ok,
    OverlongLine,
    PrinterLocked,
    ResendRequest,
    Start,
    TargetTemperature,
    TemperatureReport,
    UnknownCommand,
    UnrecognisedLine,
)
from marlin_aio.protocol.parsing import parse_endstops, parse_position
from marlin_aio.protocol.temperatures import HeaterReading
from marlin_aio.protocol.wire import EventParser, classify_line

EVENT_TYPES: tuple[type, ...] = typing.get_args(Event)

CAPTURE_DIR = Path(os.environ.get("MARLIN_CAPTURES", Path(__file__).parent / "captures" / "marlin-2.1"))
SESSION_FILES = ("session-basic.log", "session-emergency-parser.log", "session-m109-g28-moves.log")

# ----------------------------------------------------------------------------------------------- ok


def test_plain_ok() -> None:
    assert classify_line("ok") == Ok()


@pytest.mark.parametrize(
    ("line", "number", "planner", "buffer"),
    [
        ("ok P15 B3", None, 15, 3),
        ("ok N0 P15 B3", 0, 15, 3),
        ("ok N6 P14 B3", 6, 14, 3),
        ("ok P0 B0", None, 0, 0),
        ("ok N12", 12, None, None),
        ("ok N12 P3", 12, 3, None),
    ],
)
def test_advanced_ok(line: str, number: int | None, planner: int | None, buffer: int | None) -> None:
    event = classify_line(line)
    assert event == Ok(line_number=number, planner_free=planner, buffer_free=buffer)


def test_ok_with_temperatures_has_no_advanced_ok_fields() -> None:
    event = classify_line("ok T:200.56 /0.00 B:42.06 /0.00 @:19 B@:127")
    assert isinstance(event, Ok)
    assert (event.line_number, event.planner_free, event.buffer_free) == (None, None, None)
    assert event.payload == "T:200.56 /0.00 B:42.06 /0.00 @:19 B@:127"
    assert event.temperatures is not None
    assert event.temperatures.heaters == {
        "T": HeaterReading(actual=200.56, target=0.0, power=19),
        "B": HeaterReading(actual=42.06, target=0.0, power=127),
    }
    assert not event.temperatures.waiting


def test_ok_with_other_payload_has_no_temperatures() -> None:
    event = classify_line("ok P15 B3 something else")
    assert event == Ok(planner_free=15, buffer_free=3, payload="something else")


@pytest.mark.parametrize("line", ["okay", "ok:", "oK", "OK", "ok1"])
def test_words_starting_with_ok_are_not_ok(line: str) -> None:
    assert not isinstance(classify_line(line), Ok)


# ----------------------------------------------------------------------------------------------- temperature lines


def test_auto_report_line_with_leading_space() -> None:
    event = classify_line(" T:195.91 /200.00 B:35.56 /60.00 @:25 B@:127")
    assert isinstance(event, TemperatureReport)
    assert event.temperatures.heaters == {
        "T": HeaterReading(actual=195.91, target=200.0, power=25),
        "B": HeaterReading(actual=35.56, target=60.0, power=127),
    }
    assert not event.temperatures.waiting
    assert event.temperatures.wait_remaining_s is None


@pytest.mark.parametrize(("suffix", "remaining"), [("W:?", None), ("W:5", 5.0), ("W:0", 0.0)])
def test_wait_line(suffix: str, remaining: float | None) -> None:
    event = classify_line(f" T:199.03 /200.00 B:38.50 /60.00 @:18 B@:127 {suffix}")
    assert isinstance(event, TemperatureReport)
    assert event.temperatures.waiting
    assert event.temperatures.wait_remaining_s == remaining
    assert event.temperatures.heaters["T"] == HeaterReading(actual=199.03, target=200.0, power=18)


# ----------------------------------------------------------------------------------------------- busy, resend, errors


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("echo:busy: processing", "processing"),
        ("echo:busy: paused for user", "paused for user"),
        ("echo:busy: paused for input", "paused for input"),
    ],
)
def test_busy_keepalive(line: str, reason: str) -> None:
    assert classify_line(line) == BusyKeepalive(reason=reason)


@pytest.mark.parametrize(
    ("line", "number"),
    [("Resend: 6", 6), ("Resend:6", 6), ("Resend: 123456", 123456), ("rs 42", 42), ("rs N42", 42)],
)
def test_resend_request(line: str, number: int) -> None:
    assert classify_line(line) == ResendRequest(line_number=number)


@pytest.mark.parametrize(
    "message",
    [
        "Line Number is not Last Line Number+1, Last Line: 41",
        "checksum mismatch, Last Line: 41",
        "No Checksum with line number, Last Line: 41",
    ],
)
def test_line_errors(message: str) -> None:
    assert classify_line(f"Error:{message}") == ErrorMessage(message=message, kind=ErrorKind.LINE)


@pytest.mark.parametrize(
    "message",
    [
        "Thermal Runaway, system stopped! Heater_ID: E0",
        "Thermal Runaway, system stopped! Heater_ID: 0",
        "Thermal Runaway, system stopped! Heater_ID: bed",
        "Thermal Runaway, system stopped! Heater_ID: chamber",
        "Thermal Malfunction, system stopped! Heater_ID: E0",
        "Heating failed, system stopped! Heater_ID: E0",
        "MAXTEMP triggered, system stopped! Heater_ID: E0",
        "MINTEMP triggered, system stopped! Heater_ID: bed",
    ],
)
def test_thermal_errors(message: str) -> None:
    assert classify_line(f"Error:{message}") == ErrorMessage(message=message, kind=ErrorKind.THERMAL)


@pytest.mark.parametrize(
    ("message", "kind"),
    [
        ("Printer halted. kill() called!", ErrorKind.HALTED),
        (
            "Printer stopped due to errors. Fix the error and use M999 to restart. (Temperature is reset. Set it "
            "after restarting)",
            ErrorKind.STOPPED,  # stop(), which M999 clears, unlike kill()
        ),
    ],
)
def test_halt_errors(message: str, kind: ErrorKind) -> None:
    assert classify_line(f"Error:{message}") == ErrorMessage(message=message, kind=kind)


@pytest.mark.parametrize("message", ["Unknown thing", "M105 Invalid extruder 9", "Z probe failed"])
def test_other_errors(message: str) -> None:
    assert classify_line(f"Error:{message}") == ErrorMessage(message=message, kind=ErrorKind.OTHER)


# ----------------------------------------------------------------------------------------------- the rest


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("echo:M105 Invalid extruder 9", "M105 Invalid extruder 9"),
        ("echo:  G21 ; (mm)", "G21 ; (mm)"),
        ("echo:M112 Shutdown", "M112 Shutdown"),
    ],
)
def test_echo(line: str, message: str) -> None:
    assert classify_line(line) == EchoMessage(message=message)


def test_start() -> None:
    assert classify_line("start") == Start()


def test_firmware_name_with_spaces_in_values() -> None:
    line = (
        "FIRMWARE_NAME:Marlin bugfix-2.1.x (Nov 21 2026 04:20:52) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:SimRap 1.4 KINEMATICS:Cartesian EXTRUDER_COUNT:1 "
        "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff"
    )
    assert classify_line(line) == FirmwareInfo(
        name="Marlin bugfix-2.1.x (Nov 21 2026 04:20:52)",
        fields={
            "FIRMWARE_NAME": "Marlin bugfix-2.1.x (Nov 21 2026 04:20:52)",
            "SOURCE_CODE_URL": "github.com/MarlinFirmware/Marlin",
            "PROTOCOL_VERSION": "1.0",
            "MACHINE_TYPE": "SimRap 1.4",
            "KINEMATICS": "Cartesian",
            "EXTRUDER_COUNT": "1",
            "UUID": "cede2a2f-41a2-4748-9b12-c55c62f367ff",
        },
    )


def test_firmware_name_from_the_protocol_doc() -> None:
    event = classify_line(
        "FIRMWARE_NAME:Marlin 2.1.2.4 (Jan  1 2024 12:00:00) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer EXTRUDER_COUNT:1 UUID:x"
    )
    assert isinstance(event, FirmwareInfo)
    assert event.name == "Marlin 2.1.2.4 (Jan  1 2024 12:00:00)"
    assert event.fields["MACHINE_TYPE"] == "3D Printer"
    assert event.fields["EXTRUDER_COUNT"] == "1"


@pytest.mark.parametrize(
    ("line", "name", "enabled"),
    [
        ("Cap:AUTOREPORT_TEMP:1", "AUTOREPORT_TEMP", True),
        ("Cap:EEPROM:0", "EEPROM", False),
        ("Cap:SERIAL_XON_XOFF:0", "SERIAL_XON_XOFF", False),
    ],
)
def test_capability(line: str, name: str, enabled: bool) -> None:
    assert classify_line(line) == Capability(name=name, enabled=enabled)


@pytest.mark.parametrize("line", ["Cap:EEPROM", "Cap:EEPROM:2", "Cap::1"])
def test_malformed_capability_is_unrecognised(line: str) -> None:
    assert classify_line(line) == UnrecognisedLine(text=line)


@pytest.mark.parametrize(
    ("line", "action", "argument"),
    [
        ("//action:pause", "pause", ""),
        ("//action:resume", "resume", ""),
        ("//action:cancel", "cancel", ""),
        ("//action:prompt_begin Filament runout", "prompt_begin", "Filament runout"),
        ("//action:notification Heating done", "notification", "Heating done"),
    ],
)
def test_host_action(line: str, action: str, argument: str) -> None:
    assert classify_line(line) == HostAction(action=action, argument=argument)


@pytest.mark.parametrize(
    "line",
    [
        "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
        "X:50.00 Y:30.00 Z:5.00 E:0.00 Count X:4000 Y:2400 Z:2000",
        "Reporting endstop status",
        "x_min: open",
        "z_probe: TRIGGERED",
        "PowerUp",
        "Marlin bugfix-2.1.x",
        "SD printing byte 1024/65536",
        "Not SD printing",
        "\ufffd\ufffd\ufffd garbage ~~~",
        "",
        "   ",
    ],
)
def test_unrecognised_lines(line: str) -> None:
    assert classify_line(line) == UnrecognisedLine(text=line)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=80))
def test_classify_line_is_total(text: str) -> None:
    assert isinstance(classify_line(text), EVENT_TYPES)


@pytest.mark.parametrize("line", ["Resend: " + "1" * 5000, "ok N" + "1" * 5000])
def test_classify_line_is_total_for_huge_numbers(line: str) -> None:
    assert isinstance(classify_line(line), EVENT_TYPES)


# ----------------------------------------------------------------------------------------------- dialects
# The protocol doc's "Dialects a host meets in the field". Each line is classified whole and fed to an EventParser
# one byte at a time: both must give the same single event.


def classify_both_ways(line: str) -> Event:
    """The event for `line`, after checking that a byte-by-byte EventParser gives exactly the same one."""
    event = classify_line(line)
    parser = EventParser()
    got: list[tuple[str, Event]] = []
    for byte in (line + "\n").encode():
        got.extend(parser.receive_data(bytes([byte])))
    assert got == [(line, event)]
    return event


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("busy:processing", "processing"),
        ("busy: processing", "processing"),
        ("busy: paused for user", "paused for user"),
        ("echo:busy:processing", "processing"),
    ],
)
def test_busy_keepalive_without_echo(line: str, reason: str) -> None:
    assert classify_both_ways(line) == BusyKeepalive(reason=reason)


@pytest.mark.parametrize(
    ("line", "heater", "celsius"),
    [
        ("TargetExtr0:200", "T0", 200.0),
        ("TargetExtr1:0", "T1", 0.0),
        ("TargetExtr12:215.5", "T12", 215.5),
        ("TargetBed:60", "B", 60.0),
        ("TargetBed:60.50", "B", 60.5),
        ("TargetChamber:45", "C", 45.0),
        ("echo:TargetExtr0:200", "T0", 200.0),
        ("echo:TargetBed:60.0", "B", 60.0),
        ("TargetExtr0: 200", "T0", 200.0),
    ],
)
def test_repetier_target_lines(line: str, heater: str, celsius: float) -> None:
    assert classify_both_ways(line) == TargetTemperature(heater=heater, celsius=celsius)


@pytest.mark.parametrize("line", ["TargetExtr:200", "TargetExtr0:", "TargetBed:hot", "TargetNozzle:200", "Targets"])
def test_malformed_target_lines_are_not_targets(line: str) -> None:
    assert not isinstance(classify_both_ways(line), TargetTemperature)


def test_printer_locked() -> None:
    event = classify_both_ways("echo:Printer locked! (Unlock with M511 or LCD)")
    assert event == PrinterLocked(message="Printer locked! (Unlock with M511 or LCD)")


def test_incorrect_password_is_an_echo() -> None:
    assert classify_both_ways("echo:Incorrect Password") == EchoMessage(message="Incorrect Password")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("Error: Missing checksum", "Missing checksum"),
        ("Error:Missing checksum", "Missing checksum"),
        # The doc's other spelling of the same refusal: without `Last Line` no resend follows.
        ("Error:No Checksum with line number", "No Checksum with line number"),
    ],
)
def test_checksum_required(line: str, message: str) -> None:
    assert classify_both_ways(line) == ErrorMessage(message=message, kind=ErrorKind.CHECKSUM_REQUIRED)


@pytest.mark.parametrize(
    "line",
    ["Error:No Checksum with line number, Last Line: 41", "Error:Missing checksum, Last Line: 41"],
)
def test_checksum_errors_with_a_last_line_stay_line_errors(line: str) -> None:
    event = classify_both_ways(line)
    assert isinstance(event, ErrorMessage)
    assert event.kind is ErrorKind.LINE


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("!! Lost communication with MCU 'mcu'", "Lost communication with MCU 'mcu'"),
        ("!!Timer too close", "Timer too close"),
        ("!! Move out of range: 250.000 0.000 0.000 [0.000]", "Move out of range: 250.000 0.000 0.000 [0.000]"),
    ],
)
def test_bang_lines_are_not_executed(line: str, message: str) -> None:
    assert classify_both_ways(line) == ErrorMessage(message=message, kind=ErrorKind.NOT_EXECUTED)


@pytest.mark.parametrize(
    ("line", "kind"),
    [
        ("!! Thermal Runaway, system stopped! Heater_ID: E0", ErrorKind.THERMAL),
        ("!! Printer halted. kill() called!", ErrorKind.HALTED),
    ],
)
def test_bang_halts_stay_halts(line: str, kind: ErrorKind) -> None:
    event = classify_both_ways(line)
    assert isinstance(event, ErrorMessage)
    assert event.kind is kind


@pytest.mark.parametrize(
    ("line", "command"),
    [
        ('echo:Unknown command: "G999"', "G999"),
        ('echo:Unknown command: "M9999"', "M9999"),
        ('echo:Unknown command: "G999 X1"', "G999 X1"),
        ('echo:Unknown command: "M117 say "hi""', 'M117 say "hi"'),
        ("echo:Unknown command: G999", "G999"),
        ('echo:Unknown command: ""', ""),
    ],
)
def test_unknown_command(line: str, command: str) -> None:
    assert classify_both_ways(line) == UnknownCommand(command=command)


def test_plain_wait_line_without_leading_space_or_w() -> None:
    event = classify_both_ways("T:187.3 /200.0 B:59.1 /60.0 @:127 B@:0")
    assert isinstance(event, TemperatureReport)
    assert event.temperatures.heaters == {
        "T": HeaterReading(actual=187.3, target=200.0, power=127),
        "B": HeaterReading(actual=59.1, target=60.0, power=0),
    }
    assert not event.temperatures.waiting


def test_multi_extruder_report_gives_every_hotend_its_power() -> None:
    event = classify_both_ways("T:200.0 /200.0 B:60.0 /60.0 T0:200.0 /200.0 T1:25.0 /0.0 @:64 B@:0 @0:64 @1:0")
    assert isinstance(event, TemperatureReport)
    assert event.temperatures.heaters == {
        "T": HeaterReading(actual=200.0, target=200.0, power=64),
        "B": HeaterReading(actual=60.0, target=60.0, power=0),
        "T0": HeaterReading(actual=200.0, target=200.0, power=64),
        "T1": HeaterReading(actual=25.0, target=0.0, power=0),
    }


def test_repetier_report_without_targets() -> None:
    event = classify_both_ways("T:21.50 B:21.30 @:0 B@:0")
    assert isinstance(event, TemperatureReport)
    assert event.temperatures.heaters == {
        "T": HeaterReading(actual=21.5, power=0),
        "B": HeaterReading(actual=21.3, power=0),
    }


def test_ok_carrying_an_m114_position() -> None:
    event = classify_both_ways("ok X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0")
    assert isinstance(event, Ok)
    assert (event.line_number, event.planner_free, event.buffer_free, event.temperatures) == (None, None, None, None)
    assert event.payload == "X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0"
    assert parse_position((event.payload,)) == {"X": 10.0, "Y": 0.0, "Z": 0.0, "E": 0.0}


def test_advanced_ok_carrying_an_m114_position() -> None:
    event = classify_both_ways("ok N7 P15 B3 X:-1.50 Y:20.00 Z:0.20 E:0.00 Count X:-120 Y:1600 Z:80")
    assert isinstance(event, Ok)
    assert (event.line_number, event.planner_free, event.buffer_free) == (7, 15, 3)
    assert parse_position((event.payload,)) == {"X": -1.5, "Y": 20.0, "Z": 0.2, "E": 0.0}


# ----------------------------------------------------------------------------------------------- golden: captures

_RECEIVED = re.compile(r"^\[\s*\d+\.\d+\] << (.*)$")
_M114 = re.compile(r"^X:-?\d+\.\d\d Y:-?\d+\.\d\d Z:-?\d+\.\d\d E:-?\d+\.\d\d Count X:-?\d+ Y:-?\d+ Z:-?\d+$")
_M119 = re.compile(r"^[xyz]_(?:min|max): (?:open|TRIGGERED)$")
_FIELD_PAIR = re.compile(r"(?<!\S)([TB]):(-?\d+\.\d\d) /(-?\d+\.\d\d)")
_POWER = re.compile(r"(?<!\S)(B?)@:(\d+)")


def received_lines(name: str) -> list[str]:
    path = CAPTURE_DIR / name
    if not path.is_file():
        pytest.skip(f"capture {path} not available (set MARLIN_CAPTURES)")
    return [m[1] for m in map(_RECEIVED.match, path.read_text().splitlines()) if m is not None]


def check_temperatures_match_text(text: str, heaters: dict[str, HeaterReading]) -> None:
    """The T and B readings, targets and powers equal the numbers printed in the line."""
    pairs = {letter: (float(actual), float(target)) for letter, actual, target in _FIELD_PAIR.findall(text)}
    powers = {(letter or "T"): int(power) for letter, power in _POWER.findall(text)}
    assert set(pairs) == {"T", "B"}
    assert {"T", "B"} <= set(heaters)
    for letter, (actual, target) in pairs.items():
        assert heaters[letter].actual == actual
        assert heaters[letter].target == target
        assert heaters[letter].target is not None
        assert heaters[letter].power == powers[letter]


def check_capture_line(text: str) -> type:
    """Assert the event `text` gives, by the rules below; return the event type for counting."""
    event = classify_line(text)
    if text.startswith("ok"):
        # Every line starting with ok is an Ok; its N/P/B fields are the numbers printed; M105's carries temperatures.
        assert isinstance(event, Ok), text
        for letter, attribute in (("N", "line_number"), ("P", "planner_free"), ("B", "buffer_free")):
            found = re.search(rf" {letter}(\d+)(?: |$)", text)
            assert getattr(event, attribute) == (int(found[1]) if found else None), text
        if text.startswith("ok T:"):
            assert event.temperatures is not None, text
            check_temperatures_match_text(text, event.temperatures.heaters)
            assert not event.temperatures.waiting
        else:
            assert event.temperatures is None, text
    elif text.startswith(" T:"):
        # Every line starting with a space and T: is an auto-report or a wait line, with T and B and their targets.
        assert isinstance(event, TemperatureReport), text
        check_temperatures_match_text(text, event.temperatures.heaters)
        wait = re.search(r" W:(\?|\d+)$", text)
        assert event.temperatures.waiting == (wait is not None), text
        if wait is not None:
            expected = None if wait[1] == "?" else float(wait[1])
            assert event.temperatures.wait_remaining_s == expected, text
    elif text.startswith("echo:busy:"):
        assert event == BusyKeepalive(reason=text.removeprefix("echo:busy:").strip()), text
    elif text.startswith('echo:Unknown command: "'):
        assert event == UnknownCommand(command=text.removeprefix('echo:Unknown command: "')[:-1]), text
    elif text.startswith("echo:"):
        assert event == EchoMessage(message=text.removeprefix("echo:").strip()), text
    elif text.startswith("Error:"):
        assert isinstance(event, ErrorMessage), text
        assert event.message == text.removeprefix("Error:")
        if "Last Line:" in text:
            assert event.kind is ErrorKind.LINE, text
        elif "Printer halted" in text:
            assert event.kind is ErrorKind.HALTED, text
        else:
            raise AssertionError(f"no rule for this error line: {text!r}")
    elif text.startswith("Resend:"):
        assert event == ResendRequest(line_number=int(text.split(":")[1])), text
    elif text.startswith("FIRMWARE_NAME:"):
        assert isinstance(event, FirmwareInfo), text
        assert event.name == "Marlin bugfix-2.1.x (Nov 21 2026 04:20:52)"
        assert event.fields["MACHINE_TYPE"] == "SimRap 1.4"
        assert event.fields["EXTRUDER_COUNT"] == "1"
        assert event.fields["UUID"] == "cede2a2f-41a2-4748-9b12-c55c62f367ff"
    elif text.startswith("Cap:"):
        name, value = text.removeprefix("Cap:").split(":")
        assert event == Capability(name=name, enabled=value == "1"), text
    elif _M114.match(text) or _M119.match(text) or text == "Reporting endstop status":
        # The only lines no event stands for: M114 positions and M119's endstop report.
        assert event == UnrecognisedLine(text=text), text
    else:
        raise AssertionError(f"capture line with no expectation rule: {text!r}")
    return type(event)


@pytest.mark.parametrize("name", SESSION_FILES)
def test_golden_capture(name: str) -> None:
    lines = received_lines(name)
    counts: dict[type, int] = {}
    for text in lines:
        kind = check_capture_line(text)
        counts[kind] = counts.get(kind, 0) + 1
    assert len(lines) > 25
    assert counts[Ok] >= 10
    assert counts[TemperatureReport] >= 3
    assert counts[BusyKeepalive] >= 1


def test_golden_capture_covers_every_kind() -> None:
    kinds = {check_capture_line(text) for name in SESSION_FILES for text in received_lines(name)}
    assert kinds == {
        Ok,
        TemperatureReport,
        BusyKeepalive,
        EchoMessage,
        UnknownCommand,
        ErrorMessage,
        ResendRequest,
        FirmwareInfo,
        Capability,
        UnrecognisedLine,
    }


def test_golden_boot_banner() -> None:
    path = CAPTURE_DIR / "boot-banner.txt"
    if not path.is_file():
        pytest.skip(f"capture {path} not available (set MARLIN_CAPTURES)")
    lines = [line for line in path.read_text().splitlines() if line]
    assert classify_line(lines[0]) == Start()
    for text in lines[1:]:
        event = classify_line(text)
        if text.startswith("echo:"):
            assert event == EchoMessage(message=text.removeprefix("echo:").strip())
        else:
            # The reset cause and the version line: nothing to act on.
            assert text in ("PowerUp", "Marlin bugfix-2.1.x")
            assert event == UnrecognisedLine(text=text)


# ----------------------------------------------------------------------------------------------- EventParser

# Lines copied from the captures, one of each shape, so the stream properties run without the capture files.
SAMPLE_LINES = [
    "start",
    "echo: Last Updated: 2024-10-12 | Author: (none, default config)",
    "FIRMWARE_NAME:Marlin bugfix-2.1.x (Nov 21 2026 04:20:52) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
    "PROTOCOL_VERSION:1.0 MACHINE_TYPE:SimRap 1.4 KINEMATICS:Cartesian EXTRUDER_COUNT:1 UUID:cede2a2f",
    "Cap:AUTOREPORT_TEMP:1",
    "Cap:EEPROM:0",
    "ok P15 B3",
    "ok N6 P14 B3",
    "ok",
    "ok T:25.00 /200.00 B:25.00 /0.00 @:0 B@:0",
    " T:195.91 /200.00 B:35.56 /60.00 @:25 B@:127",
    " T:196.82 /200.00 B:36.33 /60.00 @:26 B@:127 W:?",
    " T:199.09 /200.00 B:39.00 /60.00 @:24 B@:127 W:8",
    "echo:busy: processing",
    "Reporting endstop status",
    "x_min: open",
    "X:50.00 Y:30.00 Z:5.00 E:0.00 Count X:4000 Y:2400 Z:2000",
    "Error:checksum mismatch, Last Line: 5",
    "Resend: 6",
    "Error:Line Number is not Last Line Number+1, Last Line: 6",
    'echo:Unknown command: "M9999"',
    "echo:M112 Shutdown",
    "Error:Printer halted. kill() called!",
    # The dialects of the protocol doc's last section.
    "TargetExtr0:200",
    "TargetBed:60",
    "busy:processing",
    " T:187.3 /200.0 B:59.1 /60.0 @:127 B@:0",
    "T:200.0 /200.0 B:60.0 /60.0 T0:200.0 /200.0 T1:25.0 /0.0 @:64 B@:0 @0:64 @1:0",
    "ok X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0",
    "Error: Missing checksum",
    "echo:Printer locked! (Unlock with M511 or LCD)",
    "!! Lost communication with MCU 'mcu'",
]


def test_event_parser_pairs_text_with_event() -> None:
    parser = EventParser()
    data = b"".join(line.encode() + b"\n" for line in SAMPLE_LINES)
    assert parser.receive_data(data) == [(line, classify_line(line)) for line in SAMPLE_LINES]


def test_event_parser_reports_overlong_lines() -> None:
    parser = EventParser(max_line_bytes=8)
    assert parser.receive_data(b"ok T:21.00 /0.00\nok\n") == [
        ("ok T:21.", OverlongLine(head="ok T:21.", length=16)),
        ("ok", Ok()),
    ]


@st.composite
def capture_streams(draw: st.DrawFn) -> tuple[list[str], bytes, list[int]]:
    lines = draw(st.lists(st.sampled_from(SAMPLE_LINES), min_size=1, max_size=25))
    data = b"".join(line.encode() + draw(st.sampled_from([b"\n", b"\r\n"])) for line in lines)
    cuts = sorted(set(draw(st.lists(st.integers(min_value=0, max_value=len(data)), max_size=15))))
    return lines, data, cuts


@settings(max_examples=150, deadline=None)
@given(capture_streams())
def test_any_split_of_a_valid_stream_gives_the_same_events(stream: tuple[list[str], bytes, list[int]]) -> None:
    lines, data, cuts = stream
    parser = EventParser()
    got: list[tuple[str, Event]] = []
    start = 0
    for cut in [*cuts, len(data)]:
        got.extend(parser.receive_data(data[start:cut]))
        start = cut
    assert got == EventParser().receive_data(data)
    assert got == [(line, classify_line(line)) for line in lines]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=100), max_size=6))
def test_any_bytes_give_only_events(chunks: list[bytes]) -> None:
    parser = EventParser(max_line_bytes=64)
    for chunk in chunks:
        for text, event in parser.receive_data(chunk):
            assert isinstance(text, str)
            assert isinstance(event, EVENT_TYPES)


# Bytes built from the tokens Marlin's lines are made of reach the number parsers, which random bytes rarely do.
_TOKENS = [
    b"ok",
    b"ok ",
    b" ",
    b"T:",
    b"T0:",
    b"B:",
    b"@:",
    b"B@:",
    b"@0:",
    b"W:",
    b"/",
    b"(",
    b")",
    b"-",
    b".",
    b"?",
    b"1",
    b"27",
    b"nan",
    b"inf",
    b"N",
    b"P",
    b"Resend:",
    b"rs ",
    b"Error:",
    b"echo:",
    b"busy:",
    b"TargetExtr",
    b"TargetBed:",
    b"TargetChamber:",
    b"!!",
    b"Unknown command:",
    b'"',
    b"Printer locked",
    b"Missing checksum",
    b"Cap:",
    b"FIRMWARE_NAME:",
    b"//action:",
    b"start",
    b"\n",
    b"\r",
    b"\x00",
    b"\xff",
]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(_TOKENS), max_size=40))
@example([b" ", b"T:", b"1", b" ", b"@:", b"nan", b"\n"])
@example([b"ok ", b"T:", b"1", b" ", b"@:", b"inf", b"\n"])
def test_any_protocol_like_bytes_give_only_events(tokens: list[bytes]) -> None:
    parser = EventParser()
    for text, event in parser.receive_data(b"".join(tokens) + b"\n"):
        assert isinstance(text, str)
        assert isinstance(event, EVENT_TYPES)


# ----------------------------------------------------------------------------------------------- M119, M114 bodies


def test_parse_endstops_on_capture_lines() -> None:
    lines = ["Reporting endstop status", "x_min: open", "y_min: open", "z_min: open"]
    assert parse_endstops(lines) == {"x_min": False, "y_min": False, "z_min": False}


def test_parse_endstops_triggered_and_extra_lines() -> None:
    lines = ("Reporting endstop status", "x_min: open", "y_min: TRIGGERED", "z_probe: TRIGGERED", "filament: open")
    assert parse_endstops(lines) == {"x_min": False, "y_min": True, "z_probe": True, "filament": False}


def test_parse_endstops_ignores_other_lines() -> None:
    assert parse_endstops(["Reporting endstop status", "echo:busy: processing", "x_min: maybe"]) == {}


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}),
        ("X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000", {"X": 0.0, "Y": 0.0, "Z": 5.0, "E": 0.0}),
        ("X:50.00 Y:30.00 Z:5.00 E:0.00 Count X:4000 Y:2400 Z:2000", {"X": 50.0, "Y": 30.0, "Z": 5.0, "E": 0.0}),
        ("X:-1.50 Y:20.00 Z:0.20 E:-2.00 Count X:-120 Y:1600 Z:80", {"X": -1.5, "Y": 20.0, "Z": 0.2, "E": -2.0}),
    ],
)
def test_parse_position(line: str, expected: dict[str, float]) -> None:
    # The stepper counts after `Count` must not overwrite the millimetres.
    assert parse_position([line]) == expected


def test_parse_position_skips_lines_before_the_position() -> None:
    lines = ["echo:busy: processing", "X:50.00 Y:30.00 Z:5.00 E:0.00 Count X:4000 Y:2400 Z:2000"]
    assert parse_position(lines) == {"X": 50.0, "Y": 30.0, "Z": 5.0, "E": 0.0}


def test_parse_position_without_a_position_line() -> None:
    assert parse_position(["echo:busy: processing", "x_min: open"]) is None
    assert parse_position([]) is None
