"""Connection, driven by hand: bytes in, bytes out, and every `now` given explicitly (no clock, no asyncio, no I/O).

The printer's side of each exchange is written as Marlin 2.1 prints it (see the captures); at the end a tiny ideal
firmware, simulated in the test, checks the whole resend machinery against random corruption.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Iterator

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandNotExecutedError,
    CommandTimeoutError,
    LostReplyError,
    MarlinError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
    RemoteProtocolError,
    ResendLimitError,
    ThermalRunawayError,
)
from marlin_aio.protocol.commands import checksum, encode_command, number_command
from marlin_aio.protocol.connection import CALM_LINES, MAX_REPLY_LINES, Command, Connection, Reply
from marlin_aio.protocol.events import BusyKeepalive, EchoMessage, Event, Ok, TemperatureReport, UnrecognisedLine
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.parsing import parse_endstops
from marlin_aio.protocol.printjob import PrintJob, PrintState

Outcome = Reply | MarlinError

M105_OK = "ok T:25.00 /200.00 B:25.00 /0.00 @:0 B@:0"
AUTO_REPORT = " T:195.91 /200.00 B:35.56 /60.00 @:25 B@:127"
WAIT_LINE = " T:196.82 /200.00 B:36.33 /60.00 @:26 B@:127 W:?"


def state_of(conn: Connection) -> LinkState:
    """The connection's state, read afresh (an assert on `conn.state` would narrow its type for the next one)."""
    return conn.state


def receive(conn: Connection, *lines: str, now: float = 0.0) -> list[Event]:
    return conn.receive_data("".join(line + "\n" for line in lines).encode(), now)


def sent(data: bytes) -> list[str]:
    """The lines written, without the bare line ends that complete a line whose own end may have been damaged."""
    assert data == b"" or data.endswith(b"\n")
    return [line for line in data.decode("ascii").splitlines() if line]


def wire(text: str, line_number: int) -> str:
    return number_command(text, line_number)


def submit_all(conn: Connection, *texts: str, now: float = 0.0, timeout_s: float = 5.0) -> list[Command]:
    return [conn.submit(text, timeout_s=timeout_s, now=now) for text in texts]


def outcomes(conn: Connection) -> list[tuple[str, Outcome]]:
    return [(command.text, outcome) for command, outcome in conn.take_results()]


def replies(conn: Connection) -> list[tuple[str, Reply]]:
    done = outcomes(conn)
    assert all(isinstance(outcome, Reply) for _, outcome in done), done
    return [(text, outcome) for text, outcome in done if isinstance(outcome, Reply)]


# ----------------------------------------------------------------------------------------------- construction


@pytest.mark.parametrize(
    ("max_in_flight", "rx_buffer_bytes", "problem"),
    [(0, 128, "max_in_flight"), (1, 15, "rx_buffer_bytes")],
)
def test_bad_settings_are_rejected(max_in_flight: int, rx_buffer_bytes: int, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        Connection(max_in_flight=max_in_flight, rx_buffer_bytes=rx_buffer_bytes)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("M105\nM105", "line break"),
        ("M117 caf\u00e9", "non-ASCII"),
        ("; nothing", "empty"),
        ("", "empty"),
        ("M117 " + "A" * 100, "95-byte limit"),
    ],
)
def test_invalid_commands_never_reach_the_queue(text: str, problem: str) -> None:
    conn = Connection()
    with pytest.raises(ValueError, match=problem):
        conn.submit(text, timeout_s=5.0, now=0.0)
    assert conn.queued == 0
    assert sent(conn.data_to_send(0.0)) == []


def test_command_too_long_once_numbered_is_rejected_at_submit() -> None:
    # 89 bytes are fine bare, but not with a line number and checksum: refused up front, with a message that says so.
    text = "M117 " + "A" * 84
    assert len(encode_command(text)) <= 96
    conn = Connection()
    with pytest.raises(ValueError, match=r"with its line number and checksum it would exceed Marlin's 95-byte limit"):
        conn.submit(text, timeout_s=5.0, now=0.0)
    assert conn.queued == 0


def test_a_command_that_fits_once_numbered_is_accepted() -> None:
    text = "M117 " + "A" * 80  # 85 bytes: "N1001 " + 85 + "*cs" is still within 95
    conn = Connection()
    conn.submit(text, timeout_s=5.0, now=0.0)
    assert conn.data_to_send(0.0) == encode_command(text, 1)


def test_timeout_must_be_positive() -> None:
    conn = Connection()
    with pytest.raises(ValueError, match="timeout_s"):
        conn.submit("M105", timeout_s=0.0, now=0.0)
    assert conn.queued == 0


# ----------------------------------------------------------------------------------------------- FIFO


def test_first_lines_are_numbered_from_one() -> None:
    conn = Connection()
    submit_all(conn, "M105 ; poll")
    assert conn.data_to_send(0.0) == b"N1 M105*38\n"


def test_unnumbered_connection_sends_bare_commands() -> None:
    conn = Connection(numbered=False, max_in_flight=4)
    submit_all(conn, "M105", "G28 ; home")
    assert sent(conn.data_to_send(0.0)) == ["M105", "G28"]
    receive(conn, M105_OK, "ok")
    assert [text for text, _ in replies(conn)] == ["M105", "G28"]


def test_fifo_matching_with_several_in_flight() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    commands = submit_all(conn, "M104 S200", "M140 S60", "G28", "M114", "M105")
    assert sent(conn.data_to_send(0.0)) == [
        wire("M104 S200", 1),
        wire("M140 S60", 2),
        wire("G28", 3),
        wire("M114", 4),
    ]
    assert conn.in_flight == 4
    assert conn.queued == 1
    assert conn.oldest_waiting() is commands[0]

    # ADVANCED_OK names the line in each ok.
    receive(conn, "ok N1 P15 B3", now=0.5)
    assert replies(conn) == [
        ("M104 S200", Reply("M104 S200", (), Ok(1, planner_free=15, buffer_free=3), sent_s=0.0, answered_s=0.5))
    ]
    assert sent(conn.data_to_send(0.5)) == [wire("M105", 5)]  # the window opened by one

    receive(conn, "ok N2 P15 B3", now=1.0)
    receive(conn, "X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000", "ok N3 P15 B3", now=16.0)
    receive(conn, "X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000", "ok N4 P15 B3", now=16.5)
    receive(conn, M105_OK, now=17.0)
    done = replies(conn)
    assert [text for text, _ in done] == ["M140 S60", "G28", "M114", "M105"]
    assert [reply.latency_s for _, reply in done] == [1.0, 16.0, 16.5, 16.5]
    assert done[1][1].lines == ("X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000",)
    assert done[3][1].temperatures is not None
    assert done[3][1].temperatures.heaters["T"].target == 200.0
    assert conn.in_flight == 0
    assert conn.oldest_waiting() is None
    assert conn.stats().stray_oks == 0


def test_max_in_flight_is_respected() -> None:
    conn = Connection(max_in_flight=3, rx_buffer_bytes=1024, advanced_ok=True)
    submit_all(conn, *(f"G1 X{i}" for i in range(10)))
    assert len(sent(conn.data_to_send(0.0))) == 3
    assert sent(conn.data_to_send(0.0)) == []
    for step in range(7):
        receive(conn, f"ok N{step + 1}")
        assert conn.in_flight == 2
        assert len(sent(conn.data_to_send(0.0))) == 1
        assert conn.in_flight == 3
        assert conn.queued == 6 - step
    assert [text for text, _ in replies(conn)] == [f"G1 X{i}" for i in range(7)]


def test_ping_pong_by_default() -> None:
    conn = Connection()
    submit_all(conn, "M105", "M105")
    assert sent(conn.data_to_send(0.0)) == ["N1 M105*38"]
    assert sent(conn.data_to_send(0.0)) == []


def test_m119_reply_collects_its_lines() -> None:
    conn = Connection()
    submit_all(conn, "M119")
    conn.data_to_send(0.0)
    receive(conn, "Reporting endstop status", "x_min: open", "y_min: TRIGGERED", "z_min: open", "ok P15 B3")
    [(text, reply)] = replies(conn)
    assert text == "M119"
    assert reply.lines == ("Reporting endstop status", "x_min: open", "y_min: TRIGGERED", "z_min: open")
    assert parse_endstops(reply.lines) == {"x_min": False, "y_min": True, "z_min": False}


def test_m115_reply_collects_firmware_and_capability_lines() -> None:
    conn = Connection()
    submit_all(conn, "M115")
    conn.data_to_send(0.0)
    lines = [
        "FIRMWARE_NAME:Marlin bugfix-2.1.x (Nov 21 2026 04:20:52) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:SimRap 1.4 KINEMATICS:Cartesian EXTRUDER_COUNT:1 UUID:cede2a2f",
        "Cap:SERIAL_XON_XOFF:0",
        "Cap:AUTOREPORT_TEMP:1",
        "Cap:EMERGENCY_PARSER:1",
    ]
    receive(conn, *lines, "ok P15 B3")
    [(_, reply)] = replies(conn)
    assert reply.lines == tuple(lines)


def test_reply_collects_echo_and_error_lines_but_not_reports_or_keepalives() -> None:
    conn = Connection(max_in_flight=2, advanced_ok=True)
    submit_all(conn, "M9999", "G28")
    conn.data_to_send(0.0)
    receive(conn, 'echo:Unknown command: "M9999"', AUTO_REPORT, "echo:busy: processing", "Error:Something odd", "ok N1")
    receive(conn, "ok N2")
    done = replies(conn)
    assert done[0][1].lines == ('echo:Unknown command: "M9999"', "Error:Something odd")
    assert done[1][1].lines == ()


def test_unsolicited_lines_while_nothing_is_pending() -> None:
    conn = Connection()
    lines = [
        "start",
        "echo: Last Updated: 2024-10-12 | Author: (none, default config)",
        "PowerUp",
        AUTO_REPORT,
        WAIT_LINE,
        "echo:busy: processing",
        "Error:Something odd",
        "Cap:EEPROM:0",
        "//action:pause",
        "\ufffd\ufffd noise",
    ]
    events = receive(conn, *lines)
    assert len(events) == len(lines)
    assert isinstance(events[3], TemperatureReport)
    assert isinstance(events[5], BusyKeepalive)
    assert conn.take_results() == []
    assert conn.halted is None
    assert conn.next_deadline() is None
    assert conn.stats().stray_oks == 0
    receive(conn, "ok", M105_OK)
    assert conn.stats().stray_oks == 2
    assert conn.take_results() == []
    # Nothing left over: the next command gets the next ok.
    submit_all(conn, "M114")
    conn.data_to_send(1.0)
    receive(conn, "ok", now=1.0)
    assert [text for text, _ in replies(conn)] == ["M114"]


def test_receive_returns_events_and_keeps_partial_lines() -> None:
    conn = Connection()
    submit_all(conn, "M105")
    conn.data_to_send(0.0)
    assert conn.receive_data(b"ok T:25.00 /0.0", 0.1) == []
    assert conn.take_results() == []
    [event] = conn.receive_data(b"0\n", 0.2)
    assert isinstance(event, Ok)
    [(_, reply)] = replies(conn)
    assert reply.answered_s == 0.2


# ----------------------------------------------------------------------------------------------- ADVANCED_OK, ok T:


def test_advanced_ok_completes_older_commands_whose_oks_were_lost() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "G1 X1", "G1 X2", "G1 X3", "G1 X4")
    conn.data_to_send(0.0)
    receive(conn, "ok N3 P12 B3", now=1.0)  # the oks of N1 and N2 were lost on the wire
    done = outcomes(conn)
    assert [text for text, _ in done] == ["G1 X1", "G1 X2", "G1 X3"]
    # The first two ran (the printer answered a later line), but their own answers never came: each gets a reply
    # that says so (never line 3's lines, never an error that would invite running it again).
    assert all(isinstance(outcome, Reply) and outcome.ok_lost and outcome.lines == () for _, outcome in done[:2])
    reply = done[2][1]
    assert isinstance(reply, Reply) and reply.ok.line_number == 3
    assert conn.stats().lost_oks == 2
    assert conn.in_flight == 1
    receive(conn, "ok N4 P11 B3", now=2.0)
    assert [text for text, _ in replies(conn)] == ["G1 X4"]
    assert conn.stats().stray_oks == 0


def test_advanced_ok_for_the_head_completes_one() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "G1 X1", "G1 X2")
    conn.data_to_send(0.0)
    receive(conn, "ok N1 P14 B3")
    assert [text for text, _ in replies(conn)] == ["G1 X1"]
    assert conn.in_flight == 1


def test_ok_with_temperatures_completes_up_to_the_m105() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "M104 S200", "M140 S60", "M105", "G28")
    conn.data_to_send(0.0)
    receive(conn, M105_OK, now=1.0)  # the two plain oks before it were lost
    done = outcomes(conn)
    assert [text for text, _ in done] == ["M104 S200", "M140 S60", "M105"]
    assert all(isinstance(outcome, Reply) and outcome.ok_lost for _, outcome in done[:2])
    reply = done[2][1]
    assert isinstance(reply, Reply) and reply.temperatures is not None
    assert conn.in_flight == 1
    assert conn.oldest_waiting() is not None
    receive(conn, "ok N4 P15 B3", now=2.0)
    assert [text for text, _ in replies(conn)] == ["G28"]


def test_stray_ok_with_temperatures_completes_nothing() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "G28", "M114")
    conn.data_to_send(0.0)
    receive(conn, M105_OK)  # answers an M105 we gave up on; no M105 is in flight
    assert conn.take_results() == []
    assert conn.stats().stray_oks == 1
    assert conn.in_flight == 2
    receive(conn, "ok N1", "ok N2")
    assert [text for text, _ in replies(conn)] == ["G28", "M114"]


def test_late_advanced_ok_of_a_timed_out_command_completes_nothing() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "G28")
    conn.data_to_send(0.0)
    conn.check_timeouts(5.0)
    [(text, error)] = outcomes(conn)
    assert (text, type(error)) == ("G28", CommandTimeoutError)
    submit_all(conn, "M114", now=5.0)
    conn.data_to_send(5.0)
    receive(conn, "ok N1 P15 B3", now=6.0)  # G28 (line 1) finished after all
    assert conn.take_results() == []
    assert conn.in_flight == 1
    receive(conn, "X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000", "ok N2 P15 B3", now=6.1)
    [(text, reply)] = replies(conn)
    assert text == "M114"
    assert reply.ok.line_number == 2


# ----------------------------------------------------------------------------------------------- resends


def test_m110_sets_the_next_line_number() -> None:
    conn = Connection()
    submit_all(conn, "M110 N5", "M105")
    assert conn.data_to_send(0.0) == (wire("M110 N5", 5) + "\n").encode()
    receive(conn, "ok N5 P15 B3")
    assert conn.data_to_send(0.0) == (wire("M105", 6) + "\n").encode()


def test_m110_n0_as_in_the_capture() -> None:
    conn = Connection()
    submit_all(conn, "M110 N0", "G1 X10 Y10 F3000")
    assert conn.data_to_send(0.0) == b"N0 M110 N0*125\n"
    receive(conn, "ok N0 P15 B3")
    assert conn.data_to_send(0.0) == b"N1 G1 X10 Y10 F3000*77\n"


def test_checksum_error_resends_the_line_byte_identical() -> None:
    conn = Connection()
    submit_all(conn, "M110 N5", "G1 X60 Y40")
    conn.data_to_send(0.0)
    receive(conn, "ok N5 P15 B3")
    replies(conn)
    first = conn.data_to_send(0.0)
    assert first == b"N6 G1 X60 Y40*45\n"

    receive(conn, "Error:checksum mismatch, Last Line: 5", "Resend: 6", "ok", now=0.1)
    assert conn.take_results() == []  # the ok after a resend request answers nothing
    assert conn.stats().stray_oks == 0
    assert conn.stats().resend_requests == 1
    assert conn.data_to_send(0.1) == first
    receive(conn, "ok N6 P14 B3", now=0.2)
    [(text, reply)] = replies(conn)
    assert text == "G1 X60 Y40"
    assert reply.ok.line_number == 6
    assert conn.in_flight == 0


@pytest.mark.parametrize(
    "error",
    [
        "Error:checksum mismatch, Last Line: 0",
        "Error:Line Number is not Last Line Number+1, Last Line: 0",
        "Error:No Checksum with line number, Last Line: 0",
    ],
)
@pytest.mark.parametrize("resend", ["Resend: 1", "Resend:1", "rs 1", "rs N1"])
def test_every_line_error_and_resend_form(error: str, resend: str) -> None:
    conn = Connection()
    submit_all(conn, "M105", "M114")
    first = conn.data_to_send(0.0)
    receive(conn, error, resend, "ok")
    assert conn.take_results() == []
    assert conn.data_to_send(0.0) == first
    receive(conn, M105_OK)
    assert [text for text, _ in replies(conn)] == ["M105"]
    assert conn.data_to_send(0.0) == (wire("M114", 2) + "\n").encode()


def test_resend_without_the_ok_of_older_firmware() -> None:
    # Some 2.0.x builds print no ok after `Resend:`; told so, the connection takes the next ok as a real answer.
    conn = Connection(ok_after_resend=False)
    submit_all(conn, "M105")
    first = conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1")
    assert conn.data_to_send(0.0) == first
    receive(conn, "echo:busy: processing", M105_OK)
    assert [text for text, _ in replies(conn)] == ["M105"]


def test_a_noise_line_between_resend_and_its_ok_does_not_make_that_ok_an_answer() -> None:
    # Defect: any non-ok line used to end the wait for the ok that follows `Resend:`, so that ok answered the
    # rejected line and the print's count ran one ahead of the printer.
    conn = Connection()
    submit_all(conn, "G1 X1")
    first = conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "\x93\x01garbage", "ok")
    assert conn.take_results() == []
    assert conn.data_to_send(0.1) == first
    receive(conn, "ok", now=0.2)
    assert [text for text, _ in replies(conn)] == ["G1 X1"]
    assert conn.stats().garbage_lines == 1


def test_reply_lines_are_bounded_and_counted() -> None:
    conn = Connection()
    submit_all(conn, "M503")
    conn.data_to_send(0.0)
    receive(conn, *(f"echo:line {i}" for i in range(MAX_REPLY_LINES + 50)), "ok")
    [(_, reply)] = replies(conn)
    assert len(reply.lines) == MAX_REPLY_LINES
    assert reply.lines[-1] == f"echo:line {MAX_REPLY_LINES + 49}"
    assert reply.lines_dropped == 50


def test_noise_is_not_a_reply_line() -> None:
    conn = Connection()
    submit_all(conn, "M119")
    conn.data_to_send(0.0)
    receive(conn, "\xff\xfe\x01", "x_min: open", "ok")
    [(_, reply)] = replies(conn)
    assert reply.lines == ("x_min: open",)


def test_commands_behind_a_dead_head_fail_at_their_own_bound_and_none_is_written() -> None:
    # Defect: 20 commands queued behind a silent printer failed one timeout after another (10 s for all) and were
    # still written, so the printer ran them all when it woke up. Then (issue 34) they failed with the head's
    # timeout, whenever they were submitted: each now ends at its own bound while the printer is silent (here
    # 0.2 s after the head), and none is ever written.
    conn = Connection()
    [head] = submit_all(conn, "G1 X0", timeout_s=0.5)
    written = sent(conn.data_to_send(0.0))
    assert len(written) == 1
    behind = [conn.submit(f"G1 X{i}", timeout_s=0.5, now=0.2) for i in range(1, 20)]
    conn.check_timeouts(0.5)
    [(text, head_error)] = outcomes(conn)
    assert text == head.text and isinstance(head_error, CommandTimeoutError)
    assert conn.queued == 19
    written = sent(conn.data_to_send(0.5))
    while (deadline := conn.next_deadline()) is not None and deadline < 0.7:  # a probe goes behind the head
        conn.check_timeouts(deadline)
        written += sent(conn.data_to_send(deadline))
        assert outcomes(conn) == []
    assert [line for line in written if "G1" in line] == []
    assert conn.next_deadline() == pytest.approx(0.7)
    conn.check_timeouts(0.7)
    results = outcomes(conn)
    assert [text for text, _ in results] == [c.text for c in behind]
    assert all(isinstance(error, CommandTimeoutError) for _, error in results)
    assert "waited behind 'G1 X0'" in str(results[0][1])
    assert conn.queued == 0
    assert [line for line in sent(conn.data_to_send(1.0)) if "G1" in line] == []


def test_a_command_submitted_later_behind_a_dead_head_keeps_its_whole_timeout() -> None:
    conn = Connection()
    submit_all(conn, "G1 X0", timeout_s=0.5)
    conn.data_to_send(0.0)
    late = conn.submit("M400", timeout_s=2.0, now=0.4)
    conn.check_timeouts(0.5)
    [(text, _)] = outcomes(conn)
    assert text == "G1 X0"
    conn.data_to_send(0.5)
    while (deadline := conn.next_deadline()) is not None and deadline < 2.4:  # probes may go; the M400 waits
        conn.check_timeouts(deadline)
        conn.data_to_send(deadline)
        assert outcomes(conn) == []
    assert conn.next_deadline() == pytest.approx(2.4)
    conn.check_timeouts(2.4)
    [(text, error)] = outcomes(conn)
    assert text == late.text and isinstance(error, CommandTimeoutError)


def test_after_a_line_error_nothing_is_written_until_the_stale_lines_are_answered_then_one_at_a_time() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    texts = [f"G1 X{i}" for i in range(1, 6)]
    submit_all(conn, *texts)
    assert sent(conn.data_to_send(0.0)) == [wire(texts[i], i + 1) for i in range(4)]
    receive(conn, "ok N1 P14 B3")
    assert sent(conn.data_to_send(0.0)) == [wire(texts[4], 5)]

    # Line 2 arrives corrupted; lines 3, 4, 5 reach the printer after it flushed its buffer and are each rejected.
    # Writing line 2 again while they arrive would put it in the way of the next flush: wait for quiet.
    receive(conn, "Error:checksum mismatch, Last Line: 1", "Resend: 2", "ok", now=0.01)
    assert sent(conn.data_to_send(0.01)) == []
    for step in range(3):
        now = 0.02 + step * 0.01
        receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok", now=now)
        assert sent(conn.data_to_send(now)) == []
    assert conn.stats().resend_requests == 4
    assert [text for text, _ in replies(conn)] == ["G1 X1"]
    quiet_at = conn.next_deadline()
    assert quiet_at is not None and 0.04 < quiet_at <= 0.04 + 0.5
    assert sent(conn.data_to_send(quiet_at - 0.001)) == []

    # Quiet: every line goes out again, in order, one at a time (none on the wire behind another until the link
    # has been clean for a while).
    written = []
    for number in range(2, 6):
        written += sent(conn.data_to_send(quiet_at))
        assert conn.in_flight == 1
        receive(conn, f"ok N{number} P14 B3", now=quiet_at)
    assert written == [wire(texts[i], i + 1) for i in range(1, 5)]
    assert [text for text, _ in replies(conn)] == texts[1:]
    assert conn.in_flight == 0
    assert conn.stats().stray_oks == 0


def test_the_window_opens_again_once_the_link_has_been_clean_for_a_while() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    count = CALM_LINES + 20
    texts = [f"G1 X{i}" for i in range(1, count + 1)]
    conn.attach(PrintJob(texts), timeout_s=10.0)
    assert len(sent(conn.data_to_send(0.0))) == 4
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", now=0.001)
    now = conn.next_deadline() or 0.0
    widths = []
    answered = 0
    while answered < count:
        batch = sent(conn.data_to_send(now))
        widths.append(conn.in_flight)
        for _ in batch:
            answered += 1
            receive(conn, f"ok N{answered}", now=now)
        now += 0.001
    assert widths[:CALM_LINES] == [1] * CALM_LINES
    assert max(widths[CALM_LINES:]) == 4


def test_discarded_lines_are_resent_when_the_printer_drops_them_silently() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    texts = [f"G1 X{i}" for i in range(1, 5)]
    submit_all(conn, *texts)
    conn.data_to_send(0.0)
    # Line 1 is corrupted, and 2..4 sat in the receive buffer Marlin flushed: no word about them.
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")
    now = conn.next_deadline() or 0.0
    written = []
    for number in range(1, 5):
        written += sent(conn.data_to_send(now))
        receive(conn, f"ok N{number}", now=now)
    assert written == [wire(texts[i], i + 1) for i in range(4)]
    assert [text for text, _ in replies(conn)] == texts


def test_resent_line_corrupted_again_is_resent_again_at_once() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    texts = [f"G1 X{i}" for i in range(1, 5)]
    submit_all(conn, *texts)
    conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")  # 2..4 flushed silently
    quiet_at = conn.next_deadline() or 0.0
    assert sent(conn.data_to_send(quiet_at)) == [wire(texts[0], 1)]
    # The resent line is hit by noise again. Nothing else was on the wire (the quiet proved it), so this rejection is
    # a fresh one: line 1 goes out again at once, with nothing to wait for.
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", now=quiet_at)
    assert sent(conn.data_to_send(quiet_at)) == [wire(texts[0], 1)]
    for number in range(1, 5):
        receive(conn, f"ok N{number}", now=quiet_at)
        conn.data_to_send(quiet_at)
    assert [text for text, _ in replies(conn)] == texts


@pytest.mark.parametrize("advanced_ok", [True, False])
def test_a_lost_ok_while_lines_wait_to_be_resent_is_probed_behind_them(advanced_ok: bool) -> None:
    # After a line error lines go out one at a time; if the ok of the one on the wire is lost, the lines waiting
    # go out after a short wait with an M105 behind them, whose `ok T:` proves every line ahead of it ran even
    # when the printer's oks do not name their lines (otherwise every later ok would be credited one line early).
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=advanced_ok)
    texts = [f"G1 X{i}" for i in range(1, 5)]
    job = PrintJob(texts)
    conn.attach(job, timeout_s=10.0)
    conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")
    quiet_at = conn.next_deadline() or 0.0
    assert sent(conn.data_to_send(quiet_at)) == [wire(texts[0], 1)]
    # Its ok is lost; nothing more goes out until the probe delay has passed.
    assert sent(conn.data_to_send(quiet_at + 0.01)) == []
    probe_at = conn.next_deadline()
    assert probe_at is not None and probe_at <= quiet_at + 1.0
    conn.check_timeouts(probe_at)
    assert sent(conn.data_to_send(probe_at)) == [wire(texts[i], i + 1) for i in range(1, 4)] + [wire("M105", 5)]
    oks = [f"ok N{n}" if advanced_ok else "ok" for n in (2, 3, 4)]
    receive(conn, *oks, M105_OK, now=probe_at)
    assert job.lines_acked == 4 and conn.stats().lost_oks == 1
    assert conn.in_flight == 0 and conn.stats().stray_oks == 0


def test_the_tail_of_a_line_cut_by_a_flush_is_recognised_and_its_ok_answers_nothing() -> None:
    # Line 1 is rejected while line 2 is half received: the flush keeps the first bytes of line 2, and the rest
    # ("X2*...") arrives as a line of its own, which Marlin refuses as an unknown command, with an ok.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024)
    texts = ["G1 X1", "G1 X2", "G1 X3"]
    job = PrintJob(texts)
    conn.attach(job, timeout_s=10.0)
    conn.data_to_send(0.0)
    tail = wire("G1 X2", 2)[6:].split("*")[0]
    assert tail == "X2"
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", f'echo:Unknown command: "{tail}"', "ok")
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    assert conn.stats().fragments == 1 and conn.stats().fragments_run == 0
    now = conn.next_deadline() or 0.0
    for number in range(1, 4):
        assert sent(conn.data_to_send(now)) == [wire(texts[number - 1], number)]
        receive(conn, "ok", now=now)
    assert job.lines_acked == 3
    assert conn.stats().stray_oks == 0 and conn.stats().lost_oks == 0


def test_an_unknown_command_that_is_a_whole_print_line_still_stops_a_print_that_stops_on_unknown() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024)
    job = PrintJob(["G1 X1", "M9999", "G1 X3"], stop_on_unknown=True)
    conn.attach(job, timeout_s=10.0)
    conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")
    now = conn.next_deadline() or 0.0
    conn.data_to_send(now)
    receive(conn, "ok", now=now)
    conn.data_to_send(now)
    receive(conn, 'echo:Unknown command: "M9999"', "ok", now=now)
    assert job.state is PrintState.FAILED
    assert "M9999" in str(job.error)


def test_a_cut_line_whose_tail_ran_stops_the_print_with_a_diagnosis() -> None:
    # The flush cut line 2 right before its command: "G1 X2*..." arrived on its own and ran (a line out of place).
    # Its ok is one that no command earned: the print stops and says so.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024)
    job = PrintJob(["G1 X1", "G1 X2", "G1 X3"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    conn.data_to_send(0.0)
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", "ok")
    assert conn.stats().fragments_run == 1
    assert job.state is PrintState.FAILED
    message = str(job.error)
    assert "ran out of place" in message and "send_ahead=False" in message and "part.gcode" in message


def test_with_advanced_ok_a_plain_ok_answers_a_numbered_line_the_printer_took_unnumbered() -> None:
    # Its `N` was damaged into `n`: Marlin skips `n1` as a line number and runs the rest, unnumbered (no `N` in its
    # ok). It ran: when the printer later asks for line 1, a placeholder takes the number, not G28 again.
    conn = Connection(max_in_flight=1, advanced_ok=True)
    submit_all(conn, "G28", "M114")
    conn.data_to_send(0.0)
    receive(conn, "ok P15 B3")
    assert [text for text, _ in replies(conn)] == ["G28"]
    assert sent(conn.data_to_send(0.1)) == [wire("M114", 2)]
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok")
    assert sent(conn.data_to_send(0.2)) == [wire("M110 N1", 1)]
    receive(conn, "ok N1 P15 B3")
    assert sent(conn.data_to_send(0.3)) == [wire("M114", 2)]
    receive(conn, "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok N2 P15 B3")
    assert [text for text, _ in replies(conn)] == ["M114"]


def test_max_resends_exceeded_fails_with_resend_limit_error() -> None:
    conn = Connection(max_resends=2)
    submit_all(conn, "M105", "M114")
    first = conn.data_to_send(0.0)
    for _ in range(2):
        receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")
        assert conn.take_results() == []
        assert conn.data_to_send(0.0) == first
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok")
    done = outcomes(conn)
    assert [text for text, _ in done] == ["M105", "M114"]
    error = done[0][1]
    assert isinstance(error, ResendLimitError)
    assert "line 1" in str(error)
    assert "M105" in str(error)
    assert done[1][1] is error
    assert sent(conn.data_to_send(0.0)) == []
    assert conn.in_flight == 0
    assert conn.queued == 0


def test_resend_of_a_line_never_sent_is_a_remote_protocol_error() -> None:
    conn = Connection()
    submit_all(conn, "M105")
    conn.data_to_send(0.0)
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 40", "Resend: 41", "ok")
    [(text, error)] = outcomes(conn)
    assert text == "M105"
    assert isinstance(error, RemoteProtocolError)
    assert "41" in str(error)


# ----------------------------------------------------------------------------------------------- timeouts


def test_next_deadline_follows_the_head() -> None:
    # Unnumbered, so no probe asks earlier (`test_a_lost_ok_outside_a_print_costs_a_probe_not_the_queue`).
    conn = Connection(max_in_flight=2, numbered=False)
    assert conn.next_deadline() is None
    submit_all(conn, "G28", "M105", now=0.0)
    assert conn.next_deadline() is None  # nothing written yet
    conn.data_to_send(1.0)
    assert conn.next_deadline() == 6.0
    receive(conn, "ok", now=2.0)
    replies(conn)
    assert conn.next_deadline() == 7.0  # M105 became the head at 2.0


def test_keepalives_and_wait_lines_push_the_deadline_auto_reports_do_not() -> None:
    conn = Connection(numbered=False)  # no probe: the time-out's deadline alone
    submit_all(conn, "M109 S200", timeout_s=5.0)
    conn.data_to_send(0.0)
    assert conn.next_deadline() == 5.0
    events = receive(conn, "echo:busy: processing", now=3.0)
    assert isinstance(events[0], BusyKeepalive)
    assert conn.next_deadline() == 8.0
    receive(conn, WAIT_LINE, now=7.0)
    assert conn.next_deadline() == 12.0
    receive(conn, " T:199.09 /200.00 B:39.00 /60.00 @:24 B@:127 W:8", now=8.0)
    assert conn.next_deadline() == 13.0
    # Firmwares that print their wait lines without W: (plain reports) show life the same way while M109 waits.
    receive(conn, "T:199.50 /200.00 B:39.10 /60.00 @:24 B@:127", now=12.0)
    assert conn.next_deadline() == 17.0
    receive(conn, "busy:processing", now=12.5)  # the bare keepalive of the same firmwares
    assert conn.next_deadline() == 17.5
    conn.check_timeouts(17.4)
    assert conn.take_results() == []
    receive(conn, "ok P15 B3", now=17.4)
    assert [text for text, _ in replies(conn)] == ["M109 S200"]


def test_auto_reports_do_not_push_the_deadline_of_a_command_that_is_not_a_heater_wait() -> None:
    conn = Connection(numbered=False)  # no probe: the time-out's deadline alone
    submit_all(conn, "G28", timeout_s=5.0)
    conn.data_to_send(0.0)
    receive(conn, AUTO_REPORT, now=3.0)
    assert conn.next_deadline() == 5.0
    receive(conn, "echo:busy: paused for user", now=4.0)
    assert conn.next_deadline() == 9.0


def test_a_locked_printer_refuses_commands_with_its_own_error() -> None:
    conn = Connection()
    submit_all(conn, "M115")
    conn.data_to_send(0.0)
    receive(conn, "echo:Printer locked! (Unlock with M511 or LCD)", "ok")
    [(_, error)] = outcomes(conn)
    assert isinstance(error, PrinterLockedError)
    assert "M511" in str(error)
    assert conn.locked and state_of(conn) is LinkState.LOCKED
    submit_all(conn, "M511 P1234", "M115")
    conn.data_to_send(0.1)
    receive(conn, "ok", now=0.1)
    assert [text for text, _ in replies(conn)] == ["M511 P1234"]
    assert conn.locked  # M511's own ok says nothing: a wrong password is answered with an ok too
    conn.data_to_send(0.2)
    receive(conn, "ok", now=0.2)
    assert [text for text, _ in replies(conn)] == ["M115"]
    assert not conn.locked and state_of(conn) is LinkState.READY


def test_a_print_line_the_printer_did_not_run_stops_the_print_with_its_message() -> None:
    conn = Connection(max_in_flight=8)
    job = PrintJob([f"G1 X{i}" for i in range(10)])
    conn.attach(job, timeout_s=5.0)
    written = sent(conn.data_to_send(0.0))
    assert len(written) > 2
    receive(conn, "ok", "!! Lost communication with MCU 'mcu'", "ok", now=0.1)
    assert job.error is not None
    assert isinstance(job.error, CommandNotExecutedError)
    assert "line 2 of" in str(job.error) and "Lost communication" in str(job.error)
    assert job.lines_acked == 1
    assert sent(conn.data_to_send(0.2)) == []  # nothing more of the file is written


@pytest.mark.parametrize("stop_on_unknown", [False, True], ids=["goes-on", "stops"])
def test_an_unknown_command_in_a_print_is_skipped_or_stops_it_and_a_users_own_gets_its_reply(
    stop_on_unknown: bool,
) -> None:
    conn = Connection()
    submit_all(conn, "G999")
    conn.data_to_send(0.0)
    receive(conn, 'echo:Unknown command: "G999"', "ok")
    [(_, reply)] = replies(conn)
    assert reply.lines == ('echo:Unknown command: "G999"',)
    job = PrintJob(["G1 X1", "G999", "G1 X2"], stop_on_unknown=stop_on_unknown)
    conn.attach(job, timeout_s=5.0)
    conn.data_to_send(0.1)
    receive(conn, "ok", now=0.2)
    conn.data_to_send(0.2)
    receive(conn, 'echo:Unknown command: "G999"', "ok", now=0.3)
    if stop_on_unknown:
        assert job.error is not None and "G999" in str(job.error)
        assert job.lines_acked == 1
        return
    # Marlin skipped it (the echo is the line as sent: the firmware lacks it); the print goes on.
    assert job.error is None and job.progress(0.3).unknown_codes == ("G999",)
    [line] = sent(conn.data_to_send(0.3))
    assert " G1 X2*" in line
    receive(conn, "ok", now=0.4)
    assert job.state is PrintState.DONE and job.lines_acked == 3


def test_a_firmware_that_requires_checksums_fails_the_unnumbered_command_and_numbers_the_rest() -> None:
    conn = Connection()
    submit_all(conn, "M105")
    conn.submit("M105", timeout_s=5.0, now=0.0, numbered=False)
    assert sent(conn.data_to_send(0.0)) == [wire("M105", 1)]
    receive(conn, M105_OK, now=0.01)
    replies(conn)
    assert sent(conn.data_to_send(0.01)) == ["M105"]
    receive(conn, "Error: Missing checksum", now=0.02)
    [(_, error)] = outcomes(conn)
    assert isinstance(error, ChecksumRequiredError)
    assert "Missing checksum" in str(error)
    assert conn.in_flight == 0
    conn.submit("M105", timeout_s=5.0, now=0.1, numbered=False)
    assert sent(conn.data_to_send(0.1)) == [wire("M105", 2)]


def test_check_timeouts_fails_only_the_head() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    submit_all(conn, "G28", timeout_s=10.0, now=0.0)
    submit_all(conn, "M105", "M114", timeout_s=3.0, now=0.0)
    conn.data_to_send(0.0)
    receive(conn, "echo:busy: processing", now=2.0)
    receive(conn, AUTO_REPORT, now=11.0)
    conn.check_timeouts(11.9)
    assert conn.take_results() == []

    conn.check_timeouts(12.0)
    [(text, error)] = outcomes(conn)
    assert text == "G28"
    assert isinstance(error, CommandTimeoutError)
    assert isinstance(error, TimeoutError)
    assert error.command == "G28"
    message = str(error)
    assert "'G28'" in message
    assert "12.0 s" in message  # how long it waited
    assert "last received ' T:195.91 /200.00 B:35.56 /60.00 @:25 B@:127' 1.0 s ago" in message
    assert "last sent 'N3 M114*" in message
    assert "2 more commands waiting behind it" in message
    assert conn.stats().timeouts == 1

    # The G28 keeps its place, in doubt, so that a late ok lands on it; the commands behind it wait on, each for
    # its own timeout from the printer's last word (11.0, before the G28 went in doubt). M105's answer shows that
    # the G28 ran, and frees its place.
    assert conn.in_flight == 3
    assert conn.next_deadline() == 14.0
    receive(conn, M105_OK, now=13.9)
    assert [text for text, _ in replies(conn)] == ["M105"]
    assert conn.in_flight == 1


def test_timeout_message_when_the_printer_is_silent() -> None:
    conn = Connection()
    submit_all(conn, "M105", timeout_s=2.0)
    conn.data_to_send(0.0)
    conn.check_timeouts(2.5)
    [(_, error)] = outcomes(conn)
    assert isinstance(error, CommandTimeoutError)
    assert "nothing ever received" in str(error)
    assert "2.5 s" in str(error)


@pytest.mark.parametrize("max_in_flight", [1, 8])
def test_a_lost_ok_outside_a_print_costs_a_probe_not_the_queue(max_in_flight: int) -> None:
    # A board drops the ok of G4 P200 while five M118 wait behind it: a moment later a bare line end and a
    # numbered probe go behind it; the probe's `ok T:` proves G4 ran (its caller gets `ok_lost`), the queue goes on.
    conn = Connection(max_in_flight=max_in_flight)
    submit_all(conn, "M115", now=0.0)
    conn.data_to_send(0.0)
    receive(conn, "FIRMWARE_NAME:Marlin", "ok", now=0.004)  # the link's pace: a round trip of 4 ms
    replies(conn)
    submit_all(conn, "G4 P200", *(f"M118 U{k}" for k in range(5)), now=0.01)
    assert sent(conn.data_to_send(0.01)) == [wire("G4 P200", 2)]
    deadline = conn.next_deadline()
    assert deadline is not None and deadline < 0.2  # a few round trips (at least 50 ms), not the 5 s time-out
    conn.check_timeouts(deadline)
    assert conn.data_to_send(deadline) == f"\n{wire('M105', 3)}\n".encode()
    receive(conn, M105_OK, now=0.21)  # G4's own ok never comes
    [(text, reply)] = replies(conn)
    assert text == "G4 P200" and reply.ok_lost
    for k in range(5):
        assert sent(conn.data_to_send(0.22 + k / 100)) == [wire(f"M118 U{k}", 4 + k)]
        receive(conn, f"U{k}", "ok", now=0.225 + k / 100)
        [(text, reply)] = replies(conn)
        assert text == f"M118 U{k}" and reply.lines == (f"U{k}",) and not reply.ok_lost
    assert conn.stats().lost_oks == 1


def test_a_damaged_line_end_outside_a_print_is_completed_in_a_moment() -> None:
    # The printer holds `N1 M105*..` without its line end: nothing comes until the bare line end completes it.
    conn = Connection()
    submit_all(conn, "M105", "G4 P0", "M114", now=0.0)
    assert sent(conn.data_to_send(0.0)) == [wire("M105", 1)]
    deadline = conn.next_deadline()
    assert deadline is not None and deadline <= 1.0
    conn.check_timeouts(deadline)
    assert conn.data_to_send(deadline) == b"\n"  # no second M105 beside the first
    receive(conn, M105_OK, now=deadline + 0.002)
    assert [text for text, _ in replies(conn)] == ["M105"]
    assert sent(conn.data_to_send(deadline + 0.003)) == [wire("G4 P0", 2)]


def test_m105_t9_never_answered_times_out_and_the_queue_goes_on() -> None:
    conn = Connection()
    submit_all(conn, "M105 T9", timeout_s=2.0)
    assert sent(conn.data_to_send(0.0)) == [wire("M105 T9", 1)]
    receive(conn, "echo:M105 Invalid extruder 9", now=0.01)  # and no ok, ever
    assert sent(conn.data_to_send(0.5)) == []
    # After a moment a bare line end goes, once (its own might have been damaged); no second M105 (whose `ok T:`
    # could not be told from this one's).
    assert conn.next_deadline() == 1.0
    conn.check_timeouts(1.0)
    assert conn.data_to_send(1.0) == b"\n"
    conn.check_timeouts(1.5)
    assert conn.data_to_send(1.5) == b""
    assert conn.next_deadline() == 2.0
    conn.check_timeouts(2.0)
    [(text, error)] = outcomes(conn)
    assert text == "M105 T9"
    assert isinstance(error, CommandTimeoutError)
    assert "echo:M105 Invalid extruder 9" in str(error)

    # An M105 sent now could be answered by a late answer to the one that timed out: it waits out the quarantine.
    submit_all(conn, "M105", timeout_s=2.0, now=2.0)
    assert sent(conn.data_to_send(2.0)) == []
    conn.check_timeouts(4.0)
    assert sent(conn.data_to_send(4.0)) == [wire("M105", 2)]
    assert conn.next_deadline() == 5.0  # a bare line end, a moment from now; its time-out at 6.0
    receive(conn, M105_OK, now=4.01)
    [(text, reply)] = replies(conn)
    assert text == "M105"
    assert reply.temperatures is not None


# ----------------------------------------------------------------------------------------------- halts and resets


def test_thermal_runaway_fails_everything_and_blocks_submit() -> None:
    conn = Connection(max_in_flight=2)
    commands = submit_all(conn, "M109 S200", "M105", "G28")
    conn.data_to_send(0.0)
    receive(conn, WAIT_LINE, "Error:Thermal Runaway, system stopped! Heater_ID: E0")
    done = conn.take_results()
    assert [command for command, _ in done] == commands
    assert all(isinstance(outcome, ThermalRunawayError) for _, outcome in done)
    receive(conn, "Error:Printer halted. kill() called!")
    assert conn.take_results() == []  # failed once only
    assert isinstance(conn.halted, ThermalRunawayError)
    assert "Thermal Runaway" in str(conn.halted)
    with pytest.raises(ThermalRunawayError, match="Thermal Runaway"):
        conn.submit("M105", timeout_s=5.0, now=1.0)
    assert sent(conn.data_to_send(1.0)) == []
    assert conn.next_deadline() is None


@pytest.mark.parametrize(
    "line",
    [
        "Error:Heating failed, system stopped! Heater_ID: E0",
        "Error:MAXTEMP triggered, system stopped! Heater_ID: E0",
        "Error:MINTEMP triggered, system stopped! Heater_ID: bed",
    ],
)
def test_other_thermal_protection_trips(line: str) -> None:
    conn = Connection()
    submit_all(conn, "M105")
    conn.data_to_send(0.0)
    receive(conn, line, "Error:Printer halted. kill() called!")
    [(_, error)] = outcomes(conn)
    assert isinstance(error, ThermalRunawayError)
    assert isinstance(conn.halted, ThermalRunawayError)


def test_plain_halt_fails_everything_with_printer_halted_error() -> None:
    conn = Connection(max_in_flight=2)
    submit_all(conn, "G28", "M105", "M114")
    conn.data_to_send(0.0)
    receive(conn, "echo:M112 Shutdown", "Error:Printer halted. kill() called!")
    done = outcomes(conn)
    assert [text for text, _ in done] == ["G28", "M105", "M114"]
    for _, error in done:
        assert type(error) is PrinterHaltedError
        assert "kill() called" in str(error)
    assert type(conn.halted) is PrinterHaltedError
    assert state_of(conn) is LinkState.HALTED  # kill(): only a reset helps
    with pytest.raises(PrinterHaltedError):
        conn.submit("M105", timeout_s=5.0, now=1.0)
    conn.submit("M999", timeout_s=5.0, now=1.0)  # the one command a halted printer may still take
    assert conn.queued == 1
    conn.data_to_send(1.0)
    receive(conn, "ok", now=1.1)
    assert state_of(conn) is LinkState.HALTED  # M999 does not undo a kill()
    receive(conn, "start", now=2.0)
    assert state_of(conn) is LinkState.READY


def test_m999_after_stop_lets_commands_through_again() -> None:
    conn = Connection()
    submit_all(conn, "M105")
    conn.data_to_send(0.0)
    receive(conn, "Error:Printer stopped due to errors. Fix the error and use M999 to restart.")
    [(_, error)] = outcomes(conn)
    assert type(error) is PrinterHaltedError
    assert state_of(conn) is LinkState.STOPPED
    submit_all(conn, "M999", now=1.0)
    assert conn.data_to_send(1.0) == (wire("M999", 2) + "\n").encode()
    # Marlin's M999 clears the stop, then flush_and_request_resend() asks for the next line, then M999's own ok.
    receive(conn, "Resend: 3", "ok", "ok", now=1.1)
    assert [text for text, _ in replies(conn)] == ["M999"]
    assert conn.halted is None and state_of(conn) is LinkState.READY
    submit_all(conn, "M105", now=2.0)
    assert conn.data_to_send(2.0) == (wire("M105", 3) + "\n").encode()


def test_resend_of_the_next_line_asks_for_nothing() -> None:
    conn = Connection()
    submit_all(conn, "M999")
    conn.data_to_send(0.0)
    receive(conn, "Resend: 2", "ok")
    assert conn.take_results() == []
    receive(conn, "ok")
    assert [text for text, _ in replies(conn)] == ["M999"]


def test_start_mid_session_fails_everything_and_restarts_numbering() -> None:
    conn = Connection(max_in_flight=2)
    submit_all(conn, "G1 X1", "G1 X2", "G1 X3", "G1 X4")
    conn.data_to_send(0.0)
    receive(conn, "ok N1 P15 B3")
    conn.data_to_send(0.0)
    assert [text for text, _ in replies(conn)] == ["G1 X1"]
    events = receive(conn, "start", "External Reset", "Marlin bugfix-2.1.x", "echo: Last Updated: 2024-10-12")
    assert isinstance(events[1], UnrecognisedLine)
    assert isinstance(events[3], EchoMessage)
    done = outcomes(conn)
    assert [text for text, _ in done] == ["G1 X2", "G1 X3", "G1 X4"]
    assert all(isinstance(error, PrinterResetError) for _, error in done)
    assert conn.stats().resets == 1
    assert conn.in_flight == 0
    assert conn.queued == 0
    submit_all(conn, "M105")
    assert conn.data_to_send(1.0) == b"N1 M105*38\n"


def test_start_clears_a_halt() -> None:
    conn = Connection()
    receive(conn, "Error:Printer halted. kill() called!")
    assert conn.halted is not None
    receive(conn, "start")
    assert conn.halted is None
    submit_all(conn, "M105")
    assert conn.data_to_send(0.0) == b"N1 M105*38\n"


def test_fail_all() -> None:
    conn = Connection()
    submit_all(conn, "M105", "M114")
    conn.data_to_send(0.0)
    lost = PrinterResetError("gone")
    conn.fail_all(lost)
    assert [(text, error) for text, error in outcomes(conn)] == [("M105", lost), ("M114", lost)]
    assert conn.in_flight == 0


# ----------------------------------------------------------------------------------------------- window, cancel


def flying_bytes(conn: Connection, commands: list[Command]) -> int:
    """Bytes written and not answered: the in-flight commands are the oldest written ones without a result."""
    written = [c for c in commands if c.sends]
    return sum(len(c.wire) for c in written[len(written) - conn.in_flight :])


def test_window_respects_rx_buffer_bytes() -> None:
    conn = Connection(max_in_flight=8, rx_buffer_bytes=40, advanced_ok=True)
    commands = submit_all(conn, *(f"G1 X{i}" for i in range(1, 10)))
    assert all(len(number_command(c.text, i + 1)) + 1 == 12 for i, c in enumerate(commands))
    assert len(sent(conn.data_to_send(0.0))) == 3  # 3 x 12 bytes fit in 40, a fourth does not
    assert flying_bytes(conn, commands) == 36
    for number in range(1, 7):
        receive(conn, f"ok N{number}")
        assert len(sent(conn.data_to_send(0.0))) == 1
        assert flying_bytes(conn, commands) <= 40
    assert conn.queued == 0


def test_window_lets_a_single_long_command_through() -> None:
    conn = Connection(rx_buffer_bytes=16)
    submit_all(conn, "M117 " + "A" * 40)
    assert len(conn.data_to_send(0.0)) > 16  # alone on the wire, or it could never be sent


def test_window_never_exceeds_rx_buffer_bytes_with_three_digit_checksums() -> None:
    first = encode_command("M105", 1)
    second = encode_command("M104 S0", 2)
    assert checksum(second.split(b"*")[0]) >= 100
    conn = Connection(max_in_flight=4, rx_buffer_bytes=len(first) + len(second) - 1)
    commands = submit_all(conn, "M105", "M104 S0")
    conn.data_to_send(0.0)
    assert flying_bytes(conn, commands) <= conn.rx_buffer_bytes


def test_cancel_of_a_queued_command_means_it_is_never_written() -> None:
    conn = Connection()
    first, second, third = submit_all(conn, "M105", "G28", "M114")
    conn.data_to_send(0.0)
    assert conn.cancel(second) is True
    assert conn.queued == 1
    receive(conn, M105_OK)
    assert [text for text, _ in replies(conn)] == ["M105"]
    assert conn.data_to_send(0.0) == (wire("M114", 2) + "\n").encode()  # no gap in the numbering either
    assert second.sends == 0
    assert conn.cancel(second) is False  # already gone
    receive(conn, "ok")
    assert [text for text, _ in replies(conn)] == ["M114"]
    assert third.sends == 1
    assert first.sends == 1


def test_cancel_of_a_written_command_drops_only_its_result() -> None:
    conn = Connection(max_in_flight=2, advanced_ok=True)
    first, second = submit_all(conn, "G28", "M114")
    conn.data_to_send(0.0)
    assert conn.cancel(first) is False
    assert conn.in_flight == 2  # the printer will still answer it
    receive(conn, "ok N1", "ok N2")
    assert [text for text, _ in replies(conn)] == ["M114"]
    assert second.sends == 1


# ----------------------------------------------------------------------------------------------- emergency, trace


def test_emergency_returns_the_bare_command() -> None:
    conn = Connection(max_in_flight=2)
    submit_all(conn, "M109 S200", "M105", "G28")
    conn.data_to_send(0.0)
    assert conn.emergency("M112", now=1.0) == b"M112\n"
    assert conn.in_flight == 2  # M112 halts: no ok will come, so it takes no place
    assert conn.emergency("M108 ; stop waiting", now=1.0) == b"M108\n"
    assert conn.in_flight == 3  # M108's own ok will come, after M109's and M105's
    assert conn.queued == 1
    assert conn.trace.last_sent is not None
    assert conn.trace.last_sent.text == "M108"
    receive(conn, "ok", "ok")
    assert conn.stats().stray_oks == 0
    assert conn.data_to_send(2.0) == (wire("G28", 3) + "\n").encode()  # numbering unaffected


@pytest.mark.parametrize("text", ["G28", "M105", "M104 S0"])
def test_emergency_rejects_other_commands(text: str) -> None:
    conn = Connection()
    with pytest.raises(ValueError, match="not an emergency command"):
        conn.emergency(text, now=0.0)
    assert conn.trace.entries() == []


def test_emergency_rejects_malformed_commands() -> None:
    conn = Connection()
    with pytest.raises(ValueError, match="line break"):
        conn.emergency("M112\nG28", now=0.0)


# Marlin 2.1 with EMERGENCY_PARSER (captures/marlin-2.1/session-emergency-parser.log, lines 1-13): M108 ends the
# heater wait as its bytes arrive, and its queued copy is then answered with its own plain ok, in order.
CAPTURED_M105_OK = "ok T:33.15 /150.00 B:25.00 /0.00 @:127 B@:0"


def test_the_captured_m108_gets_its_own_ok_and_every_command_its_own() -> None:
    conn = Connection(numbered=False, max_in_flight=4)
    (m109,) = submit_all(conn, "M109 S150", now=0.3)
    assert sent(conn.data_to_send(0.3)) == ["M109 S150"]
    receive(conn, " T:25.00 /150.00 B:25.00 /0.00 @:0 B@:0 W:?", "echo:busy: processing", now=2.5)
    assert conn.emergency("M108", now=3.312) == b"M108\n"
    m105, g28 = submit_all(conn, "M105", "G28 X Y", now=3.312)
    # M105's `ok T:` cannot be taken for another's; the G28 (a plain ok) waits until M108's ok is in.
    assert sent(conn.data_to_send(3.313)) == ["M105"]
    receive(conn, "ok P15 B3", now=3.313)  # M109's: the wait ended
    assert [(text, reply.ok.temperatures) for text, reply in replies(conn)] == [("M109 S150", None)]
    assert sent(conn.data_to_send(3.313)) == []
    receive(conn, "ok P15 B2", now=3.315)  # M108's own
    assert replies(conn) == []  # nobody waits for it, and nobody is handed it
    assert sent(conn.data_to_send(3.315)) == ["G28 X Y"]
    receive(conn, CAPTURED_M105_OK, now=3.322)
    ((text, reply),) = replies(conn)
    assert text == "M105" and reply.temperatures is not None and "33.15" in reply.ok.payload
    receive(conn, "ok P15 B3", now=20.0)
    assert [text for text, _ in replies(conn)] == ["G28 X Y"]
    stats = conn.stats()
    assert (stats.stray_oks, stats.lost_oks, stats.failed, stats.in_flight) == (0, 0, 0, 0)
    assert not any(command.orphan for command in (m109, m105, g28))


@pytest.mark.parametrize("advanced_ok", [False, True])
def test_a_g1_submitted_after_m108_is_not_answered_by_m108s_ok(advanced_ok: bool) -> None:
    conn = Connection(max_in_flight=4, advanced_ok=advanced_ok)
    submit_all(conn, "M109 S150")
    conn.data_to_send(0.0)
    conn.emergency("M108", now=1.0)
    submit_all(conn, "G1 X10", now=1.0)
    written = sent(conn.data_to_send(1.0))
    # With line numbers in the oks the G1's answer cannot be mistaken: it may go at once; else it waits.
    assert written == ([wire("G1 X10", 2)] if advanced_ok else [])
    receive(conn, "ok N1 P15 B3" if advanced_ok else "ok P15 B3", now=1.1)  # M109's
    if advanced_ok:
        assert [text for text, _ in replies(conn)] == ["M109 S150"]
    else:
        # A plain ok with the M108 right behind the M109: the M109's, or the M108's had the M109 never arrived.
        # Taken as the M108's, the M109 is answered by the ok that follows (issue 34, core seed 1643).
        assert replies(conn) == []
        assert sent(conn.data_to_send(1.1)) == []  # still behind the M109
    receive(conn, "ok P15 B2", now=1.2)  # M108's own
    if advanced_ok:
        assert replies(conn) == []  # the G1 is not answered by it
    else:
        assert [text for text, _ in replies(conn)] == ["M109 S150"]  # the G1 is not answered by it
        assert sent(conn.data_to_send(1.2)) == [wire("G1 X10", 2)]
    receive(conn, "X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0", "ok N2 P15 B3" if advanced_ok else "ok", now=1.3)
    ((text, reply),) = replies(conn)
    assert text == "G1 X10" and reply.lines == ("X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0",)
    assert not reply.ok_lost
    assert (conn.stats().stray_oks, conn.stats().lost_oks) == (0, 0)


def test_an_m108_the_printer_threw_away_is_settled_by_the_answer_behind_it() -> None:
    conn = Connection(max_in_flight=4)
    submit_all(conn, "G28")
    conn.data_to_send(0.0)
    conn.emergency("M108", now=0.5)
    submit_all(conn, "M105", now=0.5)
    assert sent(conn.data_to_send(0.5)) == [wire("M105", 2)]
    receive(conn, "ok", M105_OK, now=1.0)  # G28's, then M105's: no ok for the M108
    # The plain ok could be the M108's (had the G28 never arrived): taken as its, the M105's answer proves the G28
    # ran, its own ok counted lost (issue 34, core seed 1643).
    assert [(text, reply.ok_lost) for text, reply in replies(conn)] == [("G28", True), ("M105", False)]
    stats = conn.stats()
    assert (stats.in_flight, stats.lost_oks, stats.failed, stats.timeouts) == (0, 1, 0, 0)


def test_an_m108_never_answered_is_probed_and_holds_nobody_up_for_long() -> None:
    conn = Connection(max_in_flight=4)
    conn.emergency("M876 S0", now=0.0)
    (g1,) = submit_all(conn, "G1 X5", now=0.0)
    # Numbered, it goes behind the M876: the M876's ok comes first; if the printer threw the M876 away, the G1's
    # ok settles the M876's entry and a probe proves the G1 ran (issue 34: waiting for an ok that never comes
    # held callers up while emergency commands kept being written, core seed 509).
    assert sent(conn.data_to_send(0.0)) == [wire("G1 X5", 1)]
    receive(conn, "ok", now=0.1)  # the G1's: the M876 was thrown away
    assert replies(conn) == []
    deadline = conn.next_deadline()
    assert deadline is not None and deadline <= 1.1
    out = conn.tick(deadline)
    assert sent(out.data) == [wire("M105", 2)]  # a probe: its `ok T:` proves the G1 ran
    receive(conn, M105_OK, now=deadline + 0.1)
    [(text, reply)] = replies(conn)
    assert text == "G1 X5" and reply.ok_lost
    stats = conn.stats()
    assert (stats.in_flight, stats.failed, stats.timeouts) == (0, 0, 0)
    assert not g1.orphan


def test_an_m108_is_never_written_again_by_a_resend() -> None:
    conn = Connection(max_in_flight=4)
    submit_all(conn, "M105")
    conn.data_to_send(0.0)
    conn.emergency("M108", now=0.1)
    # The M105 arrived damaged; the printer threw away its buffer, the M108's line with it.
    receive(conn, "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", now=0.2)
    written: list[str] = []
    for step in range(1, 40):
        written += sent(conn.tick(0.2 + step * 0.1).data)
    assert written == [wire("M105", 1)]
    receive(conn, M105_OK, now=5.0)
    assert [text for text, _ in replies(conn)] == ["M105"]
    assert (conn.stats().in_flight, conn.stats().failed) == (0, 0)


def test_a_printer_that_refuses_unnumbered_lines_answers_no_emergency_command() -> None:
    conn = Connection(max_in_flight=4)
    conn.emergency("M108", now=0.0)
    assert conn.in_flight == 1
    receive(conn, "Error: Missing checksum", now=0.01)  # as the simulator's --checksum-required firmware does
    assert (conn.in_flight, conn.stats().failed, conn.requires_numbers) == (0, 0, True)
    assert outcomes(conn) == []
    conn.emergency("M108", now=1.0)
    assert conn.in_flight == 0  # known now: no ok will come


def test_no_place_for_an_emergency_command_on_a_halted_printer() -> None:
    conn = Connection()
    receive(conn, "Error:Printer halted. kill() called!", now=0.0)
    assert conn.emergency("M108", now=1.0) == b"M108\n"
    assert conn.in_flight == 0


def test_trace_keeps_the_last_entries() -> None:
    conn = Connection(trace_size=3, max_in_flight=2)
    submit_all(conn, "M105", "M114")
    conn.data_to_send(1.0)
    receive(conn, M105_OK, now=2.0)
    receive(conn, "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok", now=3.0)
    entries = conn.trace.entries()
    assert [(e.time_s, e.direction, e.text) for e in entries] == [
        (2.0, "received", M105_OK),
        (3.0, "received", "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"),
        (3.0, "received", "ok"),
    ]
    assert conn.trace.last_sent is not None
    assert conn.trace.last_sent.text == wire("M114", 2)
    text = conn.trace.format(now=4.0)
    assert text.splitlines()[0] == f"   -2.000 s << {M105_OK}"
    assert len(text.splitlines()) == 3


# ----------------------------------------------------------------------------------------------- simulated firmware

_NUMBERED = re.compile(r"^N(\d+) (.*)\*(\d+)$")


class IdealFirmware:
    """Marlin's line handling, minus everything else: numbered lines in order, one ok each, line errors.

    `corruptions` says, line by line, whether noise hit it on the way in. A rejected line gets Marlin's triple
    (error, `Resend:`, ok). With `flush` the printer also throws away every line still in its receive buffer, as
    Marlin does; without, those lines arrive after the flush and are each rejected in turn.
    """

    def __init__(self, corruptions: Iterator[bool], *, flush: bool, advanced_ok: bool) -> None:
        self.corruptions = corruptions
        self.flush = flush
        self.advanced_ok = advanced_ok
        self.last_n = 0
        self.receive_buffer: deque[str] = deque()
        self.executed: list[str] = []

    def receive(self, data: bytes) -> None:
        self.receive_buffer.extend(data.decode("ascii").splitlines())

    def step(self) -> bytes:
        line = self.receive_buffer.popleft()
        match = _NUMBERED.match(line)
        assert match is not None, line
        number, command = int(match[1]), match[2]
        assert checksum(f"N{number} {command}".encode()) == int(match[3])
        if next(self.corruptions, False):
            return self._reject("checksum mismatch")
        if number != self.last_n + 1:
            return self._reject("Line Number is not Last Line Number+1")
        self.last_n = number
        self.executed.append(command)
        if command == "M105":
            return f"{M105_OK}\n".encode()  # M105 answers on its own ok line, without N, P or B
        return f"ok N{number} P15 B3\n".encode() if self.advanced_ok else b"ok\n"

    def _reject(self, why: str) -> bytes:
        if self.flush:
            self.receive_buffer.clear()
        return f"Error:{why}, Last Line: {self.last_n}\nResend: {self.last_n + 1}\nok\n".encode()


def run_session(
    texts: list[str], corruptions: list[bool], *, max_in_flight: int, flush: bool, advanced_ok: bool
) -> None:
    conn = Connection(max_in_flight=max_in_flight, max_resends=1000)
    firmware = IdealFirmware(iter(corruptions), flush=flush, advanced_ok=advanced_ok)
    commands = [conn.submit(text, timeout_s=5.0, now=0.0) for text in texts]
    results: list[tuple[Command, Outcome]] = []
    now = 0.0
    for _ in range(10_000):
        firmware.receive(conn.data_to_send(now))
        if firmware.receive_buffer:
            conn.receive_data(firmware.step(), now)
        elif conn.in_flight or conn.queued:
            # Nothing on the wire, yet commands wait: only a timeout can move things on.
            deadline = conn.next_deadline()
            assert deadline is not None
            now = max(now, deadline)
            conn.check_timeouts(now)
        else:
            break
        results.extend(conn.take_results())
        now += 0.001
    assert [command for command, _ in results] == commands  # every command completed exactly once, in order
    assert all(isinstance(outcome, Reply) for _, outcome in results), results
    assert firmware.executed == texts  # and the printer ran each one exactly once, in order
    assert conn.stats().stray_oks == 0


_TEXTS = st.lists(st.sampled_from(["G1 X10", "G1 Y5", "M105", "M114", "G4 P0", "M400", "M104 S0"]), max_size=12)
_CORRUPTIONS = st.lists(st.booleans(), max_size=30)


@pytest.mark.parametrize(
    ("max_in_flight", "flush"),
    [
        (1, True),
        (1, False),
        (4, True),
        (4, False),
    ],
)
@settings(max_examples=60, deadline=None)
@given(texts=_TEXTS, corruptions=_CORRUPTIONS, advanced_ok=st.booleans())
@example(texts=["G1 X10", "G1 Y5", "M114", "M400"], corruptions=[True, True], advanced_ok=False)
def test_ideal_firmware_every_command_completes_once_in_order(
    max_in_flight: int, flush: bool, texts: list[str], corruptions: list[bool], advanced_ok: bool
) -> None:
    run_session(texts, corruptions, max_in_flight=max_in_flight, flush=flush, advanced_ok=advanced_ok)


@settings(max_examples=60, deadline=None)
@given(texts=_TEXTS, corruptions=_CORRUPTIONS, advanced_ok=st.booleans())
def test_ideal_firmware_with_flush_when_no_resent_line_is_hit_again(
    texts: list[str], corruptions: list[bool], advanced_ok: bool
) -> None:
    # The flushing firmware with four in flight when noise never hits two lines in a row: the first line written
    # again always gets through, so no resend deadline is needed.
    spaced = [hit and not (index and corruptions[index - 1]) for index, hit in enumerate(corruptions)]
    run_session(texts, spaced, max_in_flight=4, flush=True, advanced_ok=advanced_ok)


def test_a_damaged_m110_is_written_again() -> None:
    # Marlin's counter stays where it was, so it asks for its old "last + 1", which equals our next line number;
    # that is a rejection of the M110 (an error line came first), not M999's "I have everything".
    conn = Connection()
    submit_all(conn, "M110 N0", "M105")
    first = conn.data_to_send(0.0)
    assert first == b"N0 M110 N0*125\n"
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok")
    assert conn.take_results() == []
    assert conn.data_to_send(0.0) == first
    receive(conn, "ok")
    assert [text for text, _ in replies(conn)] == ["M110 N0"]


def test_without_advanced_ok_commands_answered_by_plain_oks_go_one_at_a_time() -> None:
    # Defect: with 8 in flight and plain oks, one lost ok shifted every later answer to the next caller. A plain ok
    # cannot say whom it answers, so a command someone waits for is never in flight beside another such command.
    conn = Connection(max_in_flight=8)
    submit_all(conn, "M118 A", "M105", "M118 B", "M118 C")
    assert sent(conn.data_to_send(0.0)) == [wire("M118 A", 1), wire("M105", 2)]  # M105's answer looks different
    receive(conn, M105_OK, now=0.1)  # A's lines and ok were lost: M105's answer proves A ran
    [(text_a, lost), (text_m105, reply)] = outcomes(conn)
    assert text_a == "M118 A" and isinstance(lost, Reply) and lost.ok_lost and lost.lines == ()
    assert text_m105 == "M105" and isinstance(reply, Reply) and reply.temperatures is not None
    assert sent(conn.data_to_send(0.1)) == [wire("M118 B", 3)]
    receive(conn, "B", "ok", now=0.2)
    assert sent(conn.data_to_send(0.2)) == [wire("M118 C", 4)]
    receive(conn, "C", "ok", now=0.3)
    assert [(text, r.lines) for text, r in replies(conn)] == [("M118 B", ("B",)), ("M118 C", ("C",))]


def test_a_plain_ok_skips_an_m105_whose_answer_was_lost_and_keeps_the_lines_of_the_command_behind_it() -> None:
    conn = Connection(max_in_flight=8)
    submit_all(conn, "M105", "M119")
    conn.data_to_send(0.0)
    receive(conn, "Reporting endstop status", "x_min: open", "ok", now=0.1)  # M105's `ok T:` was lost
    [(text_m105, lost), (text_m119, reply)] = outcomes(conn)
    assert text_m119 == "M119"
    assert text_m105 == "M105" and isinstance(lost, Reply) and lost.ok_lost
    assert isinstance(reply, Reply) and reply.lines == ("Reporting endstop status", "x_min: open")


def test_lines_that_could_be_a_skipped_commands_are_given_to_nobody() -> None:
    conn = Connection(max_in_flight=8, advanced_ok=True)
    submit_all(conn, "M118 A", "M118 B")
    conn.data_to_send(0.0)
    receive(conn, "A", "B", "ok N2 P15 B3", now=0.1)  # A's ok was lost: is "A" or "B" the reply of B? Both.
    [(_, first), (_, second)] = outcomes(conn)
    assert isinstance(first, Reply) and first.ok_lost and first.lines == ()
    assert isinstance(second, LostReplyError)
    assert "the ok of a command before it was lost" in str(second)


def test_the_late_ok_of_a_timed_out_command_never_reaches_the_next_caller() -> None:
    # Defect: a G28 with a short timeout timed out, its ok came late, and the next caller received it.
    conn = Connection()
    submit_all(conn, "G28", timeout_s=1.0)
    conn.data_to_send(0.0)
    conn.check_timeouts(1.0)
    [(_, error)] = outcomes(conn)
    assert isinstance(error, CommandTimeoutError)
    submit_all(conn, "M119", timeout_s=1.0, now=1.0)
    assert sent(conn.data_to_send(1.0)) == []  # it waits while the G28's answer may still come
    receive(conn, "ok", now=1.5)  # G28's late ok
    assert conn.take_results() == []
    assert sent(conn.data_to_send(1.5)) == [wire("M119", 2)]
    receive(conn, "Reporting endstop status", "x_min: open", "ok", now=1.6)
    [(text, reply)] = replies(conn)
    assert text == "M119" and reply.lines == ("Reporting endstop status", "x_min: open")


def test_a_timed_out_command_is_settled_by_a_probe_and_the_command_behind_it_goes_on() -> None:
    conn = Connection()
    submit_all(conn, "G28", timeout_s=1.0)
    conn.data_to_send(0.0)
    receive(conn, "echo:busy: processing", now=0.5)
    conn.check_timeouts(1.5)
    [(_, error)] = outcomes(conn)
    assert isinstance(error, CommandTimeoutError)
    submit_all(conn, "M119", timeout_s=1.0, now=1.5)
    conn.check_timeouts(1.5)
    # The G28 keeps its place in doubt; an M105 behind it asks whether it ran (its ok may be lost).
    assert sent(conn.data_to_send(1.5)) == [wire("M105", 2)]
    receive(conn, M105_OK, now=1.6)  # it answers: the G28 ran and its ok was lost
    assert conn.take_results() == []  # nobody waits for the G28 any more, nor for the probe
    assert sent(conn.data_to_send(1.6)) == [wire("M119", 3)]


def test_a_command_waiting_behind_one_in_doubt_ends_within_its_own_timeout() -> None:
    conn = Connection()
    submit_all(conn, "G28", timeout_s=1.0)
    conn.data_to_send(0.0)
    receive(conn, "echo:busy: processing", now=0.5)
    conn.check_timeouts(1.5)
    outcomes(conn)
    submit_all(conn, "M119", timeout_s=1.0, now=1.5)
    conn.check_timeouts(1.5)
    conn.data_to_send(1.5)  # the probe; the printer says nothing more (a G28 with no keepalives)
    assert conn.next_deadline() == 2.5
    conn.check_timeouts(2.5)
    [(text, error)] = outcomes(conn)
    assert text == "M119" and isinstance(error, CommandTimeoutError) and "waited behind 'G28'" in str(error)
    receive(conn, "ok", M105_OK, now=9.0)  # the G28 and the probe, late: they complete nothing
    assert conn.take_results() == [] and conn.in_flight == 0


def test_one_probe_waits_behind_a_poll_that_no_probe_may_follow() -> None:
    # The client campaign's seed 249: the poller's M105 was the oldest command of a print when the board fell
    # silent. No M105 may follow it, so the probe waited; before, another was queued every probe delay (40 in the
    # 2 s timeout), and once the poll was let go they all went out together, each then let go one timeout after
    # another.
    conn = Connection()
    conn.attach(PrintJob(["G1 X1"]), timeout_s=5.0)
    conn.submit("M105", timeout_s=5.0, now=0.0)
    assert sent(conn.data_to_send(0.0)) == [wire("M105", 1)]
    for now in (1.0, 2.0, 3.0, 4.0):
        assert conn.next_deadline() == now
        conn.check_timeouts(now)
        assert conn.data_to_send(now) == b"\n"  # a line end, in case the poll's own was damaged; no more probes
    assert conn.stats().probes == 1 and conn.queued == 1
    conn.check_timeouts(5.0)  # the poll times out, in doubt: it is let go after one more timeout
    assert sent(conn.data_to_send(5.0)) == []
    conn.check_timeouts(10.0)
    assert sent(conn.data_to_send(10.0)) == [wire("M105", 2)]  # the one probe
    receive(conn, M105_OK, now=10.01)
    assert sent(conn.data_to_send(10.01)) == [wire("G1 X1", 3)]  # and the print goes on


def test_a_caller_behind_lines_in_doubt_ends_at_its_own_bound_when_an_m105_among_them_is_let_go() -> None:
    # Seed 249 again: a caller waited behind the probes of a stalled print, each an M105 in doubt, let go one
    # timeout after another; each time the next line in doubt started the caller's bound again (28 s for a 2 s
    # send). The line in doubt behind the M105 let go has been in doubt as long: the bound counts from then.
    conn = Connection(max_in_flight=2)
    job = PrintJob(["G1 X1", "G1 X2", "G1 X3"])
    conn.attach(job, timeout_s=2.0)
    assert sent(conn.data_to_send(0.0)) == [wire("G1 X1", 1), wire("G1 X2", 2)]
    conn.check_timeouts(1.0)  # the oks are late: a probe
    assert sent(conn.data_to_send(1.0)) == [wire("M105", 3)]
    receive(conn, "ok", "ok", now=1.05)
    assert sent(conn.data_to_send(1.05)) == [wire("G1 X3", 4)]  # behind the probe, which is not answered
    conn.submit("M118 U1", timeout_s=2.0, now=1.5)  # waits: a plain ok could be the print line's
    assert sent(conn.data_to_send(1.5)) == []
    conn.check_timeouts(2.05)
    assert sent(conn.data_to_send(2.05)) == [wire("M105", 5)]  # another probe
    conn.check_timeouts(3.05)  # the first probe times out: the print stalls, its lines on the wire in doubt
    assert job.state is PrintState.FAILED and conn.take_results() == []
    # M118 U1 waits behind lines in doubt; the printer has said nothing since before it was submitted (1.05), so
    # it ends at its own bound, 1.5 + 2 s (issue 34: a silent printer fails each caller at its own bound).
    assert conn.next_deadline() == 3.5
    conn.check_timeouts(3.5)
    [(text, error)] = outcomes(conn)
    assert text == "M118 U1" and isinstance(error, CommandTimeoutError) and "waited behind 'M105'" in str(error)
    conn.check_timeouts(5.05)  # the probe in doubt is let go
    assert conn.in_flight == 2 and conn.queued == 0
    # The late answers land on their own lines, in doubt; the next caller gets its own reply.
    receive(conn, "ok", M105_OK, now=6.0)
    assert conn.take_results() == [] and conn.in_flight == 0
    conn.submit("M119", timeout_s=2.0, now=6.0)
    assert sent(conn.data_to_send(6.0)) == [wire("M119", 6)]
    receive(conn, "Reporting endstop status", "x_min: open", "ok", now=6.1)
    [(text, reply)] = replies(conn)
    assert text == "M119" and reply.lines == ("Reporting endstop status", "x_min: open")


def test_an_ok_that_a_held_line_or_a_cut_tail_may_have_earned_stops_the_print() -> None:
    # `Line Number is not Last Line Number+1` for line 1 comes when line 2 met the check after line 1 ran unnumbered
    # (its `N` damaged into `n`), and also when line 1's own digits were damaged (it did not run) and the flush cut
    # line 3, whose tail ran. The first ok no command earned is line 1's in the one case, the tail's in the other.
    # Before: it was taken for line 1's, a placeholder took its number, and the print went on with line 1 unrun.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024)
    job = PrintJob(["G1 X1", "G1 X2", "G1 X3"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    assert len(sent(conn.data_to_send(0.0))) == 3
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    assert job.active  # line 1 is held: it may have run unnumbered
    receive(conn, "ok", now=0.02)
    assert job.state is PrintState.FAILED and conn.stats().fragments_run == 1
    message = str(job.error)
    assert "ran out of place" in message and "'G1 X1'" in message and "send_ahead=False" in message
    # Once the printer is quiet, line 1 is never written again: a placeholder takes its number.
    now = conn.next_deadline() or 1.0
    assert sent(conn.data_to_send(now)) == [wire("M110 N1", 1)]


def test_an_ok_after_a_line_error_may_be_the_tail_of_the_line_right_behind_the_held_one() -> None:
    # Line 2 is the last on the wire. `Line Number is not Last Line Number+1` for line 1 comes when line 2 met the
    # check after line 1 ran unnumbered (its `N` damaged into `n`), and also when line 1's own digits were damaged
    # (it did not run): the flush then came as line 1 was read and cut line 2, whose tail ran. Plain oks give the
    # same bytes either way, and Marlin with a command ring sends the line error before the oks of the lines
    # already in it. Before: the lines behind the flush were counted from line 2 on, leaving none; the plain ok was
    # taken for line 1's, a placeholder took its number, and the print went on with line 1 unrun.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024)
    job = PrintJob(["G1 X1", "G1 X2"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    assert sent(conn.data_to_send(0.0)) == [wire("G1 X1", 1), wire("G1 X2", 2)]
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    assert job.active  # line 1 is held: it may have run unnumbered
    receive(conn, "ok", now=0.02)
    assert job.state is PrintState.FAILED and conn.stats().fragments_run == 1
    message = str(job.error)
    assert "cannot be told" in message and "'G1 X2'" in message
    now = conn.next_deadline() or 1.0
    assert sent(conn.data_to_send(now)) == [wire("M110 N1", 1)]  # line 1 is never written again


def test_with_advanced_ok_a_plain_ok_while_an_m105_is_held_is_a_cut_tail_s() -> None:
    # The held line is an M105, whose own ok carries temperatures: a plain ok is the tail's of the cut line 3.
    # Before: it was taken for the M105's, and the print went on with line 2 run out of place.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    job = PrintJob(["G1 X1", "G1 X2"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    poll = conn.submit("M105", timeout_s=5.0, now=0.0)
    assert sent(conn.data_to_send(0.0)) == [wire("M105", 1), wire("G1 X1", 2), wire("G1 X2", 3)]
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    receive(conn, "ok P15 B3", now=0.02)
    assert job.state is PrintState.FAILED and "ran out of place" in str(job.error)
    assert poll.line_number == 1 and conn.take_results() == []  # the M105 did not run: it goes again
    now = conn.next_deadline() or 1.0
    assert sent(conn.data_to_send(now)) == [wire("M105", 1)]


def test_an_ok_only_the_held_line_can_have_earned_is_its_own() -> None:
    # Only an M105 is behind the held line: a tail of it answers `ok T:...`, so a plain ok is the held line's own
    # (it ran unnumbered), and a placeholder takes its number; the print goes on.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    job = PrintJob(["G1 X1", "G1 X2"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    assert sent(conn.data_to_send(0.0)) == [wire("G1 X1", 1), wire("G1 X2", 2)]
    receive(conn, "ok N1 P15 B3", now=0.01)
    conn.submit("M105", timeout_s=5.0, now=0.01)
    assert sent(conn.data_to_send(0.01)) == [wire("M105", 3)]
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok", now=0.02)
    receive(conn, "ok P15 B3", now=0.03)
    assert job.state is PrintState.DONE and conn.stats().fragments_run == 0
    now = conn.next_deadline() or 1.0
    assert sent(conn.data_to_send(now)) == [wire("M110 N2", 2)]


def test_a_cancelled_print_ends_only_once_the_tails_of_its_withdrawn_lines_cannot_run() -> None:
    # The print is cancelled with lines 2 and 3 on the wire behind the poller's M105. The M105's digits are damaged
    # (`Line Number is not Last Line Number+1` for it): the flush cuts line 3, whose tail runs later. Lines 2 and 3
    # are withdrawn (a placeholder takes their numbers), but the print may not end CANCELLED until the printer has
    # been quiet: the tail's ok then comes while the print still runs, and stops it saying why.
    # Before: the withdrawal ended the print CANCELLED at once, and the tail's ok, coming after, was not reported.
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    job = PrintJob(["G1 X1", "G1 X2"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    conn.submit("M105", timeout_s=5.0, now=0.0)
    assert sent(conn.data_to_send(0.0)) == [wire("M105", 1), wire("G1 X1", 2), wire("G1 X2", 3)]
    job.cancel(0.005)
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    assert job.active and job.cancelling  # the tail of a withdrawn line may still run
    receive(conn, "ok P15 B3", now=0.02)
    assert job.state is PrintState.FAILED and conn.stats().fragments_run == 1
    assert "ran out of place" in str(job.error)


def test_a_cancelled_print_whose_withdrawn_lines_left_no_tail_ends_cancelled_once_the_printer_is_quiet() -> None:
    conn = Connection(max_in_flight=4, rx_buffer_bytes=1024, advanced_ok=True)
    job = PrintJob(["G1 X1", "G1 X2"], name="part.gcode")
    conn.attach(job, timeout_s=10.0)
    conn.submit("M105", timeout_s=5.0, now=0.0)
    assert len(sent(conn.data_to_send(0.0))) == 3
    job.cancel(0.005)
    receive(conn, "Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok", now=0.01)
    assert job.active
    now = conn.next_deadline() or 1.0
    conn.tick(now)  # quiet: the M105 did not run, and goes again; the withdrawn lines cannot run any more
    assert job.state is PrintState.CANCELLED
