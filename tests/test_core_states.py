"""The state tables (`marlin_aio.protocol.states`): every move is in the table, final states stay final, and the core's
link state is moved by the table (no flags behind it)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from marlin_aio.errors import ConnectionLostError as RuntimeErrorLost
from marlin_aio.protocol.connection import Command, Connection
from marlin_aio.protocol.printjob import PrintJob, PrintState
from marlin_aio.protocol.states import (
    FINAL_LINE_STATES,
    LINE_TRANSITIONS,
    LINK_TRANSITIONS,
    ImpossibleTransitionError,
    LineEvent,
    LineState,
    LinkEvent,
    LinkState,
    next_line_state,
    next_link_state,
)

M105_OK = "ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"


def state_of(conn: Connection) -> LinkState:
    """The link's state (a call, so the type checker does not carry one assertion's narrowing to the next)."""
    return conn.state


def line_state(command: Command) -> LineState:
    return command.state


def test_every_state_has_a_row_and_every_move_leads_to_a_state() -> None:
    assert set(LINK_TRANSITIONS) == set(LinkState)
    assert set(LINE_TRANSITIONS) == set(LineState)
    for link_moves in LINK_TRANSITIONS.values():
        assert all(isinstance(target, LinkState) for target in link_moves.values())
    for line_moves in LINE_TRANSITIONS.values():
        assert all(isinstance(target, LineState) for target in line_moves.values())


def test_final_line_states_have_no_way_out() -> None:
    # Nothing that ended can run again: ACCEPTED, REJECTED, WITHDRAWN and FAILED are final.
    assert {LineState.ACCEPTED, LineState.REJECTED, LineState.WITHDRAWN, LineState.FAILED} == FINAL_LINE_STATES
    for state in FINAL_LINE_STATES:
        for event in LineEvent:
            with pytest.raises(ImpossibleTransitionError):
                next_line_state(state, event)


def test_a_line_is_written_only_from_queued_or_to_resend() -> None:
    writable = {state for state in LineState if LineEvent.WRITTEN in LINE_TRANSITIONS[state]}
    assert writable == {LineState.QUEUED, LineState.TO_RESEND}


def test_a_line_in_doubt_is_settled_only_by_the_printer() -> None:
    # No time-based move takes a line out of doubt: only an answer (OK, REFUSED, MANGLED), a resend request, or
    # the end of everything (FAILED).
    moves = LINE_TRANSITIONS[LineState.IN_DOUBT]
    assert LineEvent.WITHDRAWN not in moves and LineEvent.WRITTEN not in moves
    assert moves[LineEvent.OVERDUE] is LineState.IN_DOUBT


def test_the_link_table_keeps_a_kill_final_until_a_reset() -> None:
    assert next_link_state(LinkState.STOPPED, LinkEvent.HALTED) is LinkState.HALTED
    assert next_link_state(LinkState.HALTED, LinkEvent.STOPPED) is LinkState.HALTED  # a stop never softens a kill
    assert next_link_state(LinkState.HALTED, LinkEvent.RESET) is LinkState.READY
    with pytest.raises(ImpossibleTransitionError):
        next_link_state(LinkState.HALTED, LinkEvent.RESUMED)
    with pytest.raises(ImpossibleTransitionError):
        next_link_state(LinkState.LOST, LinkEvent.RESET)


def test_a_print_moves_the_link_through_printing_and_stopping() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    conn.submit("M110 N0", timeout_s=5.0, now=0.0)
    conn.data_to_send(0.0)
    conn.receive(b"ok N0 P15 B3\n", 0.0)
    assert state_of(conn) is LinkState.READY
    conn.attach(PrintJob(["G1 X1", "G1 X2", "G1 X3", "G1 X4"], name="t"), timeout_s=5.0)
    output = conn.tick(0.0)
    assert output.data.count(b"\n") == 4
    assert state_of(conn) is LinkState.PRINTING
    # The printer refuses line 1 (locked): the print stops, its other lines are still on the wire.
    conn.receive(b"echo:Printer locked! (Unlock with M511 or LCD)\nok N1 P15 B3\n", 0.1)
    assert state_of(conn) is LinkState.LOCKED
    conn.receive(b"echo:Printer locked! (Unlock with M511 or LCD)\nok N2 P15 B3\n", 0.2)
    assert state_of(conn) is LinkState.LOCKED and conn.job is None


def test_a_print_that_stops_with_lines_on_the_wire_is_stopping_until_they_are_answered() -> None:
    conn = Connection(max_in_flight=4, advanced_ok=True)
    job = PrintJob(["G1 X1", "G1 X2", "G1 X3"], name="t", stop_on_unknown=True)
    conn.attach(job, timeout_s=5.0)
    conn.tick(0.0)
    conn.receive(b'echo:Unknown command: "G1 X1"\nok N1 P15 B3\n', 0.1)  # refused as such: the print stops
    assert state_of(conn) is LinkState.STOPPING
    conn.receive(b"ok N2 P15 B3\n", 0.2)
    assert state_of(conn) is LinkState.STOPPING
    conn.receive(b"ok N3 P15 B3\n", 0.3)
    assert state_of(conn) is LinkState.READY


def test_an_impossible_move_asked_by_the_printer_is_ignored_not_raised() -> None:
    conn = Connection()
    conn.submit("M105", timeout_s=5.0, now=0.0)
    conn.data_to_send(0.0)
    conn.receive(b"Error:Printer halted. kill() called!\n", 0.1)
    assert state_of(conn) is LinkState.HALTED
    conn.receive(b"echo:Printer locked! (Unlock with M511 or LCD)\nok\n", 0.2)  # nonsense now: logged, ignored
    assert state_of(conn) is LinkState.HALTED


def test_lines_carry_their_state() -> None:
    conn = Connection()
    command = conn.submit("M105", timeout_s=5.0, now=0.0)
    assert line_state(command) is LineState.QUEUED
    conn.data_to_send(0.0)
    assert line_state(command) is LineState.ON_WIRE
    conn.receive(f"{M105_OK}\n".encode(), 0.1)
    assert line_state(command) is LineState.ACCEPTED
    withdrawn = conn.submit("M114", timeout_s=5.0, now=0.2)
    assert conn.cancel(withdrawn) and line_state(withdrawn) is LineState.WITHDRAWN


def test_a_print_whose_lines_raise_fails_instead_of_ending_done() -> None:
    # The lines of a print may come from the caller's own generator; what it raises must end the print, not the
    # link, and never as "done" (before, the print reported done and the error was lost).
    def lines() -> Iterator[str]:
        yield "G1 X1"
        raise RuntimeError("the slicer's generator broke")

    conn = Connection()
    job = PrintJob(lines(), name="generated")
    conn.attach(job, timeout_s=5.0)
    conn.tick(0.0)
    conn.receive(b"ok\n", 0.1)
    conn.tick(0.2)
    assert job.state is PrintState.FAILED
    assert job.error is not None and "the slicer's generator broke" in str(job.error)
    assert state_of(conn) is LinkState.READY


def test_the_core_owns_connecting_and_lost_a_boot_banner_keeps_it_connecting() -> None:
    # Issue 34: CONNECTING and LOST were decided in the client layer, beside the core's own state; now the core's
    # state machine moves through them, and a reset during the handshake (the board's boot banner) is not a reset
    # of a connected printer.
    conn = Connection(connecting=True)
    assert state_of(conn) is LinkState.CONNECTING
    conn.submit("M115", timeout_s=1.0, now=0.0)
    conn.data_to_send(0.0)
    conn.receive_data(b"start\n", 0.01)
    assert state_of(conn) is LinkState.CONNECTING
    conn.handshake_done()
    assert state_of(conn) is LinkState.READY
    conn.handshake_done()  # only CONNECTING moves on it
    assert state_of(conn) is LinkState.READY
    waiting = conn.submit("M114", timeout_s=1.0, now=0.1)
    conn.data_to_send(0.1)
    conn.lose(RuntimeErrorLost("the port went away"))
    assert state_of(conn) is LinkState.LOST
    [(_, error)] = [r for r in conn.take_results() if r[0] is waiting]
    assert isinstance(error, RuntimeErrorLost)
    conn.receive_data(b"start\n", 0.2)  # nothing moves a lost link
    assert state_of(conn) is LinkState.LOST


def test_a_connection_made_without_a_handshake_starts_ready() -> None:
    assert state_of(Connection()) is LinkState.READY
