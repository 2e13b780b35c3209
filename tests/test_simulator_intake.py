"""How the simulated board reads its serial input, sans-I/O and in simulated time: Marlin bugfix-2.1.x's
`queue.cpp` and `parser.cpp`, the wire's bit flips (`Faults.flip_bit_ratio`, `Faults.flip_once`), and the
bootloader's delay after a reset.

The golden test replays what a real board received in shared/captures/marlin-2.1/line-faults-avr.txt (an
ATmega2560 build of bugfix-2.1.x with ADVANCED_OK and the emergency parser, one bit of a host byte flipped on the
way in) and expects its replies, the planner's free blocks (`P`) excepted: the simulator plans moves without
acceleration, so its planner drains at another pace.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.commands import checksum, number_command
from marlin_aio.simulator import Faults, SimulatedPrinter, SimulatorConfig

IDLE_M105 = "ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"
SHARED_CAPTURE = Path("/work/shared/captures/marlin-2.1/line-faults-avr.txt")

# The sections of line-faults-avr.txt about line numbers and checksums, verbatim. `?` stands for a byte that is
# not printable: the `N` of `N15` with one bit flipped.
CAPTURE = """\
## the three line errors (host sent these on purpose)
>> N0 M110 N0*125
<< ok N0 P15 B3
>> N1 G1 X1 F3000*5
<< ok N1 P14 B3
>> N3 G1 X3*97
<< Error:checksum mismatch, Last Line: 2
<< Resend: 3
<< ok
>> N5 G1 X5*96
<< Error:Line Number is not Last Line Number+1, Last Line: 3
<< Resend: 4
<< ok
>> N5 G1 X5
<< Error:No Checksum with line number, Last Line: 4
<< Resend: 5
<< ok
>> M9999
<< echo:Unknown command: "M9999"
<< ok P13 B3

## a flipped bit on the leading N: the line is unnumbered, not run, not counted (host sent N15 G1 X0.1*75)
>> ?15 G1 X0.1*75
<< echo:Unknown command: "?15 G1 X0.1"
<< ok P6 B3
>> N16 M105*16
<< Error:Line Number is not Last Line Number+1, Last Line: 14
<< Resend: 15
<< ok
# line 15 was never run: sending N15 now runs it once, in its place
>> N15 G1 X0.1*75
<< ok N15 P10 B3

## a corrupted M110 changes nothing (host sent N0 M110 N0*125 while the firmware's last line was 2)
>> N0 M010 N0*125
<< Error:Line Number is not Last Line Number+1, Last Line: 2
<< Resend: 3
<< ok
# the counter is still 2: a line numbered 1 or 2 is now dropped without any reply
>> N1 M400*38
# (nothing: no error, no ok)

## two flips of the same bit in one line cancel in the XOR checksum (host sent N91 G1 X0.1*71)
>> N91 Gq`X0.1*71
<< echo:Unknown command: "Gq`X0.1"
<< ok N91 P0 B3
"""

# What the host sent that the capture leaves out, before the line it is keyed by: numbered lines that were
# simply taken (as the `Last Line` of each error shows), and the counter set to where the capture has it.
FILLERS = {
    "N3 G1 X3*97": ["N2 G1 X2"],
    "N5 G1 X5*96": ["N3 G1 X3"],
    "N5 G1 X5": ["N4 G1 X4"],
    "?15 G1 X0.1*75": [f"N{n} G1 X{n / 10:.1f}" for n in range(5, 15)],
    "N0 M010 N0*125": ["M110 N2"],
    "N91 Gq`X0.1*71": ["M110 N90"],
}
FLIPPED_N = b"\xce"  # N (0x4E) with bit 7 flipped, which the capture prints as ?


def make(faults: Faults | None = None, **config: object) -> SimulatedPrinter:
    """A printer without its boot banner, so replies start clean; its command loop takes no time unless asked
    (`command_time_s`), so each reply comes at the instant its command arrives (the loop's time is tested on
    its own, in test_simulator.py)."""
    config = {"command_time_s": 0.0, "report_time_s": 0.0} | config
    return SimulatedPrinter(SimulatorConfig(**config), faults, boot=False)  # type: ignore[arg-type]


def lines(printer: SimulatedPrinter) -> list[str]:
    return printer.take_output().decode("latin-1").splitlines()


def send(printer: SimulatedPrinter, data: str | bytes, now: float = 0.0) -> list[str]:
    raw = data.encode("latin-1") if isinstance(data, str) else data
    printer.receive(raw + b"\n", now)
    return lines(printer)


def printable(line: str) -> str:
    """A line as the capture shows it: every byte that is not printable ASCII as `?`."""
    return "".join(c if " " <= c <= "~" else "?" for c in line)


def without_planner(line: str) -> str:
    return re.sub(r" P\d+ B", " P_ B", line)


def capture_exchanges(text: str) -> list[tuple[str, list[str]]]:
    """Each `>>` line of a capture with the `<<` lines that answered it."""
    exchanges: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith(">> "):
            exchanges.append((line[3:], []))
        elif line.startswith("<< "):
            exchanges[-1][1].append(line[3:])
    return exchanges


# ------------------------------------------------------------------------------------------------ the capture


def test_the_embedded_capture_is_the_shared_one() -> None:
    if not SHARED_CAPTURE.exists():
        pytest.skip("the shared captures are not on this machine")
    assert CAPTURE in SHARED_CAPTURE.read_text()


def test_line_faults_are_answered_as_the_avr_board_answered_them() -> None:
    printer = make(advanced_ok=True, emergency_parser=True, rx_buffer_size=128)
    now = 0.0
    for sent, expected in capture_exchanges(CAPTURE):
        for filler in FILLERS.get(sent, []):
            wire = number_command(filler.split(" ", 1)[1], int(filler[1:].split()[0])) if filler[0] == "N" else filler
            reply = send(printer, wire, now)
            assert len(reply) == 1 and re.fullmatch(r"ok( N\d+)? P\d+ B3", reply[0]), (filler, reply)
            now += 0.5
        raw = sent.encode("latin-1")
        if raw.startswith(b"?"):
            raw = FLIPPED_N + raw[1:]  # what the board really received
        reply = send(printer, raw, now)
        assert [without_planner(printable(line)) for line in reply] == [without_planner(e) for e in expected], sent
        now += 0.5
    # The line with the flipped N was not counted; line 15 ran once, when it was sent again, and so did 91.
    assert printer.executed_line_numbers.count(15) == 1
    assert printer.executed.count("G1 X0.1") == 1
    assert printer.executed_line_numbers[-1] == 91
    assert "M400" not in printer.executed  # N1 M400 was dropped without a word


def test_the_unprintable_byte_is_echoed_raw() -> None:
    printer = make()
    printer.receive(FLIPPED_N + b"15 G1 X0.1*75\n", 0.0)
    assert printer.take_output() == b'echo:Unknown command: "\xce15 G1 X0.1"\nok\n'


def test_a_corrupted_m110_leaves_the_counter_and_the_next_line_is_taken() -> None:
    printer = make(advanced_ok=True)
    for number in (1, 2):
        send(printer, number_command("M400", number))
    assert send(printer, "N0 M010 N0*125")[:2] == [
        "Error:Line Number is not Last Line Number+1, Last Line: 2",
        "Resend: 3",
    ]
    assert send(printer, number_command("M400", 2)) == []
    assert send(printer, number_command("M400", 3)) == ["ok N3 P15 B3"]


# ---------------------------------------------------------------------------------------- numbered or not


def test_a_lowercase_n_is_no_line_number_and_the_command_runs_unnumbered() -> None:
    printer = make(advanced_ok=True, motion_time_scale=0.0)
    assert send(printer, "n15 G1 X0.1*75") == ["ok P15 B3"]  # no N in the ok: the line was not numbered
    assert printer.executed == ["G1 X0.1"]
    assert list(printer.executed_line_numbers) == []
    assert send(printer, number_command("M400", 1)) == ["ok N1 P15 B3"]  # the counter did not move
    strict = make(case_insensitive=False)
    assert send(strict, "n15 G1 X0.1*75") == ['echo:Unknown command: "n15 G1 X0.1"', "ok"]


def test_case_insensitive_commands_and_parameters() -> None:
    printer = make(motion_time_scale=0.0)
    assert send(printer, "g1 x5 y7 f600") == ["ok"]
    assert send(printer, "m114") == ["X:5.00 Y:7.00 Z:0.00 E:0.00 Count X:400 Y:560 Z:0", "ok"]
    # M118's text is a string argument, read raw: it keeps its case, and its flags must be uppercase (M118.cpp).
    assert send(printer, "m118 E1 Mixed Case") == ["echo:Mixed Case", "ok"]
    assert send(printer, "m118 e1 Mixed Case") == ["e1 Mixed Case", "ok"]
    strict = make(motion_time_scale=0.0, case_insensitive=False)
    assert send(strict, "G1 x5 Y7") == ["ok"]
    assert send(strict, "M114")[0].startswith("X:0.00 Y:7.00 ")  # the lowercase x was not seen


def test_leading_spaces_are_skipped_but_the_ok_then_has_no_line_number() -> None:
    printer = make(advanced_ok=True)
    # The check starts after the spaces; ADVANCED_OK echoes the N only when the stored line starts with it.
    assert send(printer, "  " + number_command("M400", 1)) == ["ok P15 B3"]
    assert printer.executed_line_numbers == [1]
    # Only spaces are skipped: after a tab there is no line number, and no command either.
    assert send(printer, "\t" + number_command("M400", 2)) == ['echo:Unknown command: "\tN2 M400"', "ok P15 B3"]


def test_the_checksum_number_is_read_as_strtol_reads_it() -> None:
    printer = make()
    line = "N1 M400"
    assert send(printer, f"{line}*0{checksum(line.encode())}") == ["ok"]  # a leading zero
    line = "N2 M400"
    assert send(printer, f"{line}* {checksum(line.encode())}junk") == ["ok"]  # a space before, junk after
    assert send(printer, "N3 M400*") == ["Error:checksum mismatch, Last Line: 2", "Resend: 3", "ok"]  # reads 0


def test_the_checksum_covers_everything_before_the_last_star() -> None:
    printer = make()
    line = "N1 M118 E1 a*b"
    assert send(printer, f"{line}*{checksum(line.encode())}") == ["echo:a", "ok"]  # the text ends at the first *


# ----------------------------------------------------------------------------------- process_stream_char()


def test_a_comment_loses_the_checksum_after_it() -> None:
    printer = make()
    line = "N1 G1 X1 ; move"
    assert send(printer, f"{line}*{checksum(line.encode())}") == [
        "Error:No Checksum with line number, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    assert send(printer, "G1 X2 ; unnumbered, the comment goes") == ["ok"]
    assert printer.executed == ["G1 X2"]


def test_backspace_erases_the_byte_before() -> None:
    printer = make()
    assert send(printer, b"M118 E1 ab\x08c") == ["echo:ac", "ok"]
    assert send(printer, b"\x08\x08M105") == [IDLE_M105]  # nothing to erase at the start
    # The checksum is over the bytes as stored, after the erasing.
    line = "N1 M118 E1 xy"
    assert send(printer, f"N1 M118 E1 xyz\x08*{checksum(line.encode())}") == ["echo:xy", "ok"]


def test_a_backslash_makes_the_next_byte_plain() -> None:
    printer = make()
    assert send(printer, "M118 E1 a\\;b") == ["echo:a;b", "ok"]
    line = "N1 M118 E1 a;b"  # stored without the backslash: the checksum is over that
    assert send(printer, f"N1 M118 E1 a\\;b*{checksum(line.encode())}") == ["echo:a;b", "ok"]


def test_a_nul_ends_the_text_of_its_line() -> None:
    printer = make()
    assert send(printer, b"M118 E1 ab\x00cd") == ["echo:ab", "ok"]


def test_a_line_beyond_95_bytes_is_cut() -> None:
    printer = make(rx_buffer_size=1024)
    assert send(printer, "M118 E1 " + "x" * 200) == ["echo:" + "x" * (95 - 8), "ok"]
    # A numbered line that long loses its checksum with the rest.
    line = "N1 M118 E1 " + "y" * 90
    assert send(printer, f"{line}*{checksum(line.encode())}") == [
        "Error:No Checksum with line number, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    # Backspaces before the cut make room; after it they are skipped like everything else.
    assert send(printer, "M118 E1 " + "z" * 80 + "\x08" * 10 + "!") == ["echo:" + "z" * 70 + "!", "ok"]
    assert send(printer, "M118 E1 " + "w" * 90 + "\x08" * 10) == ["echo:" + "w" * 87, "ok"]


def test_a_line_arriving_in_pieces_is_read_as_a_whole() -> None:
    printer = make()
    for piece in (b"M118 E1 a", b"b\\", b";c\x08", b"d;e", b"\n"):
        printer.receive(piece, 0.0)
    assert lines(printer) == ["echo:ab;d", "ok"]


def test_a_full_receive_ring_drops_bytes_silently_and_joins_what_is_left() -> None:
    printer = make(command_buffer_size=1, rx_buffer_size=16)
    assert send(printer, "G4 S5") == []
    # The dwell holds the only command slot: 16 bytes fit, the rest is lost without a word.
    printer.receive(b"M118 E1 first\nM104 S200\n", 1.0)
    assert (printer.rx_overflows, printer.rx_dropped_bytes) == (1, 24 - 16)
    printer.advance(6.0)
    assert lines(printer)[-3:] == ["ok", "echo:first", "ok"]
    # What is left of the cut line waits for a line end, and the next line joins it into another command.
    assert send(printer, "M400", 7.0) == ['echo:Unknown command: "M1M400"', "ok"]


# --------------------------------------------------------------------------------------------------- M110


def test_lines_sent_right_behind_an_m110_are_checked_against_the_new_counter() -> None:
    printer = make()
    burst = "M110 N41\n" + number_command("M400", 42) + "\n" + number_command("M400", 43) + "\n"
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["ok", "ok", "ok"]
    burst = number_command("M110 N0", 0) + "\n" + number_command("M400", 1) + "\n" + number_command("M400", 2) + "\n"
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["ok", "ok", "ok"]
    assert list(printer.executed_line_numbers) == [42, 43, 0, 1, 2]
    # Also behind commands that finish at once: on the wire they would have run before the M110 came in.
    burst = "M400\nM105\nG92 X1\nM110 N7\n" + number_command("M400", 8) + "\n"
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["ok", IDLE_M105, "ok", "ok", "ok"]
    assert printer.executed_line_numbers[-1] == 8


def test_an_m110_queued_behind_a_long_command_sets_the_counter_when_it_runs() -> None:
    # Marlin reads the lines behind it while the dwell runs, against the old counter; the M110 sets the new one
    # when its turn comes.
    printer = make()
    burst = "G4 S1\nM110 N10\n" + number_command("M400", 11) + "\n"
    printer.receive(burst.encode(), 0.0)
    assert lines(printer) == ["Error:Line Number is not Last Line Number+1, Last Line: 0", "Resend: 1", "ok"]
    printer.advance(1.0)
    assert lines(printer) == ["ok", "ok"]  # the dwell's and the M110's
    assert send(printer, number_command("M400", 11), 1.0) == ["ok"]


def test_a_numbered_m110_takes_the_number_after_it_and_skips_the_sequence_check() -> None:
    printer = make()
    assert send(printer, number_command("M110 N7", 99)) == ["ok"]
    assert send(printer, number_command("M400", 8)) == ["ok"]
    assert send(printer, number_command("M110", 20)) == ["ok"]  # no N after it: its own number
    assert send(printer, number_command("M400", 21)) == ["ok"]
    # The checksum is still checked.
    assert send(printer, "N5 M110 N5*0") == ["Error:checksum mismatch, Last Line: 21", "Resend: 22", "ok"]


# ---------------------------------------------------------------------------------------------- bit flips


def test_flip_once_on_the_leading_n() -> None:
    faults = Faults(flip_once=[("N15 ", 0, 5)])
    printer = make(faults, advanced_ok=True, motion_time_scale=0.0)
    for number in range(1, 15):
        send(printer, number_command(f"G1 X{number}", number))
    assert send(printer, "N15 G1 X0.1*75") == ["ok P15 B3"]  # n15: run, unnumbered
    assert faults.flip_once == []
    assert printer.bits_flipped == 1
    assert printer.executed[-1] == "G1 X0.1"
    assert send(printer, "N16 M400*40")[:2] == [
        "Error:Line Number is not Last Line Number+1, Last Line: 14",
        "Resend: 15",
    ]
    assert send(printer, "N15 G1 X0.1*75") == ["ok N15 P15 B3"]  # used up: this one arrives as sent
    assert printer.executed.count("G1 X0.1") == 2  # the move ran twice: no host can tell

    printer = make(Faults(flip_once=[("N15 ", 0, 0)]))
    assert send(printer, "N15 G1 X0.1*75") == ['echo:Unknown command: "O15 G1 X0.1"', "ok"]


def test_flip_once_on_an_m110_and_on_a_line_end() -> None:
    printer = make(Faults(flip_once=[("M110", 4, 0)]))  # byte 4 of the line is M110's first 1
    send(printer, number_command("M400", 1))
    send(printer, number_command("M400", 2))
    assert send(printer, "N0 M110 N0*125") == [
        "Error:Line Number is not Last Line Number+1, Last Line: 2",
        "Resend: 3",
        "ok",
    ]
    assert send(printer, "N0 M110 N0*125") == ["ok"]  # the entry is used up
    # A flip of the \n (0x0A -> 0x02) joins the line to the next: the checksum then fails.
    printer = make(Faults(flip_once=[("N1 ", len(number_command("M400", 1)), 3)]))
    printer.receive((number_command("M400", 1) + "\n" + number_command("M400", 2) + "\n").encode(), 0.0)
    assert lines(printer) == ["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]


def test_flip_once_reaches_a_line_that_arrives_in_pieces() -> None:
    printer = make(Faults(flip_once=[("X0.1", 0, 0)]))
    for piece in (b"N", b"15 G1", b" X0", b".1*75\nM40", b"0\n"):
        printer.receive(piece, 0.0)
    assert lines(printer) == ['echo:Unknown command: "O15 G1 X0.1"', "ok", "ok"]
    assert printer.executed == ["O15 G1 X0.1", "M400"]


def test_flip_once_set_in_the_middle_of_a_line_starts_with_the_next() -> None:
    faults = Faults()
    printer = make(faults)
    printer.receive(b"M118 E1 ", 0.0)
    faults.flip_once.append(("M118", 8, 5))
    printer.receive(b"ab\nM118 E1 cd\n", 0.0)
    assert lines(printer) == ["echo:ab", "ok", "echo:Cd", "ok"]


def test_flip_once_entries_are_checked() -> None:
    with pytest.raises(ValueError, match="bit 0-7"):
        Faults(flip_once=[("x", 0, 8)])
    with pytest.raises(ValueError, match="flip_bit_ratio"):
        Faults(flip_bit_ratio=1.5)


def _stream() -> bytes:
    """Unnumbered lines whose characters no single flip turns into a leading N or into M108/M112/M410, so no
    flip can bring a line error (which throws away whatever has arrived, so depends on the split) or a halt."""
    commands = []
    for index in range(120):
        commands.append(f"G1 X{index % 50}.5 Y{(index * 7) % 90}" if index % 3 else ("M105" if index % 2 else "M114"))
    return "".join(command + "\n" for command in commands).encode()


def _session(chunks: list[bytes], seed: int, ratio: float = 0.03) -> tuple[bytes, list[str], int]:
    printer = make(Faults(flip_bit_ratio=ratio), motion_time_scale=0.0, seed=seed)
    for chunk in chunks:
        printer.receive(chunk, 0.0)
    return printer.take_output(), list(printer.executed), printer.bits_flipped


def test_random_flips_are_reproducible_for_a_seed() -> None:
    stream = _stream()
    first = _session([stream], seed=4)
    assert first == _session([stream], seed=4)
    assert first != _session([stream], seed=5)
    output, executed, flipped = first
    assert 0.015 * len(stream) <= flipped <= 0.05 * len(stream)
    assert b"Unknown command" in output
    assert len(executed) >= 100
    clean_output, _, clean_flipped = _session([stream], seed=4, ratio=0.0)
    assert clean_flipped == 0
    assert b"Unknown command" not in clean_output


@settings(max_examples=60, deadline=None)
@given(cuts=st.lists(st.integers(min_value=1, max_value=90), max_size=60))
def test_random_flips_do_not_depend_on_how_the_bytes_were_split(cuts: list[int]) -> None:
    stream = _stream()
    chunks = []
    position = 0
    for cut in cuts:
        chunks.append(stream[position : position + cut])
        position += cut
    chunks.append(stream[position:])
    assert _session(chunks, seed=4) == _session([stream], seed=4)


def test_a_ratio_of_one_flips_one_bit_of_every_byte() -> None:
    printer = make(Faults(flip_bit_ratio=1.0))
    printer.receive(bytes(4000), 0.0)  # every NUL gets one bit: a line end (0x0A needs two) never arises
    assert printer.bits_flipped == 4000


# ------------------------------------------------------------------------------------------------ booting


def test_a_board_says_and_reads_nothing_in_its_bootloader() -> None:
    printer = SimulatedPrinter(SimulatorConfig(boot_delay_s=1.5, command_time_s=0.0, report_time_s=0.0))
    assert printer.take_output() == b""
    assert printer.booting
    assert printer.next_wakeup() == pytest.approx(1.5)
    printer.receive(b"M104 S200\nM105\n", 1.0)  # dropped: nobody is reading yet
    printer.thermal_runaway(1.2)  # no firmware, no thermal protection
    assert printer.take_output() == b""
    printer.advance(1.5)
    assert not printer.booting
    banner = lines(printer)
    assert banner[:2] == ["start", "PowerUp"]
    assert send(printer, "M105", 2.0) == [IDLE_M105]
    assert printer.executed == ["M105"]


def test_a_reset_boots_again_and_the_delay_can_be_given() -> None:
    printer = make(boot_delay_s=2.0)
    send(printer, "M104 S200")
    printer.reset(10.0)
    assert lines(printer) == []
    assert send(printer, "M105", 11.0) == []
    assert printer.next_wakeup() == pytest.approx(12.0)
    printer.advance(12.0)
    assert lines(printer)[:2] == ["start", "External Reset"]
    reply = send(printer, "M105", 12.0)
    assert reply[0].startswith("ok T:") and " /0.00 B:" in reply[0]  # the target died with the reset
    printer.reset(13.0, boot_delay_s=0.0)
    assert lines(printer)[:2] == ["start", "External Reset"]
    with pytest.raises(ValueError, match="boot_delay_s"):
        printer.reset(14.0, boot_delay_s=-1.0)
    with pytest.raises(ValueError, match="boot_delay_s"):
        SimulatorConfig(boot_delay_s=-0.5)
    assert SimulatorConfig().boot_delay_s == 0.0


def test_an_emergency_line_acts_at_once_and_is_answered_in_its_turn_as_the_capture_shows() -> None:
    # shared/captures/marlin-2.1/session-emergency-parser.log, lines 1-13: M108 ends M109's wait as it arrives,
    # M109 is answered, then M108's queued copy gets its own plain ok (no `N`: it was not numbered), then M105's.
    printer = make(advanced_ok=True)
    printer.receive(b"M109 S150\n", 0.3)
    printer.advance(3.3)
    assert all(" W:" in line or "busy" in line for line in lines(printer))  # still waiting
    m109_ok, m108_ok, m105_ok = send(printer, "M108\nM105", 3.312)
    assert (m109_ok, m108_ok) == ("ok P15 B3", "ok P15 B2")  # as captured
    assert m105_ok.startswith("ok T:") and "/150.00" in m105_ok
    assert printer.executed[-2:] == ["M108", "M105"]  # queued and run (a no-op) in its turn


def test_a_firmware_that_wants_checksums_acts_on_an_emergency_line_and_refuses_it_without_an_ok() -> None:
    printer = make(checksum_required=True)
    printer.receive((number_command("M109 S150", 1) + "\n").encode(), 0.0)
    printer.advance(2.0)
    lines(printer)
    # The emergency parser reads the bytes before the line checks: the wait ends, and the line is refused as read.
    assert send(printer, "M108", 2.0) == ["ok", "Error: Missing checksum"]  # M109's ok, then the refusal
    assert "M108" not in printer.executed
