"""The core's fast lanes (`Connection.submit_and_write`, the `ok T:` lane of `Connection.receive`) do exactly what
the general path does for the inputs they take.

Two connections get the same operations: one through the public calls with their fast lanes (a command written at
once when the link is idle, an `ok T:` read in one step), the other through the general path only (`submit` then
`tick`; each chunk through `receive_data` and the general step's output, which is what `receive` does whenever its
lane does not apply). After every step both must have written the same bytes, finished the same commands with the
same replies or errors, and agree on state, deadline, counters, the FIFO and the queue.
"""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.connection import Connection, Output
from marlin_aio.protocol.matching import Command
from marlin_aio.protocol.replies import Reply

_COMMANDS = ["M105", "M105", "M105", "G1 X1", "M114", "M110 N0", "M999", "M115"]
_REPLIES = [
    b"ok T:20.00 /0.00 B:21.00 /0.00 @:0 B@:0\n",
    b"ok T:20.00 /0.00 B:21.00 /0.00 @:0 B@:0\n",
    b"ok\n",
    b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n",
    b"echo:busy: processing\n",
    b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\n",
    b"Error:Line Number is not Last Line Number+1, Last Line: 0\nResend: 1\nok\n",
    b"ok T:20.00 /0.00 B:21.00 /0.00 @:0 B@:0\nok\n",
    b"ok T:20.0 /0.0",  # half a line: the rest comes in the next chunk
    b" B:21.0 /0.0 @:0\n",
    b"Error:Printer stopped due to errors. Fix the error and use M999 to restart.\n",
    b"ok N3 P15 B3\n",
    b"\xffok T:1\n",
    b"ok T:20.00 /0.00 @:0\r\n",
    b"start\n",
]


@dataclass
class _Side:
    conn: Connection
    fast: bool
    written: bytes = b""

    def outcome(self, results: list[tuple[Command, Reply | MarlinError]]) -> list[tuple[int, str, object]]:
        return [(c.id, c.text, _view(r)) for c, r in results]


def _view(outcome: Reply | MarlinError) -> object:
    if isinstance(outcome, Reply):
        return (outcome.command, outcome.lines, outcome.ok, outcome.sent_s, outcome.answered_s, outcome.ok_lost)
    return (type(outcome).__name__, str(outcome))


def _core_state(conn: Connection) -> tuple[object, ...]:
    """What else a step may change: the core's own record, the resend state and the trace."""
    core = conn._core
    resends = core.resends
    return (
        conn._after_command,
        core.exact_oks,
        core.link.requires_numbers,
        core.send_eol,
        conn._now,
        repr(core.link.halt),
        core.link.thermal_message,
        resends.next_line,
        resends.accepted_through,
        resends.nudge_pending,
        resends.idle,
        [(e.time_s, e.direction, e.text) for e in core.trace.entries()],
    )


def _finished(output: Output) -> list[tuple[Command, Reply | MarlinError]]:
    return list(output.finished)


_steps = st.lists(
    st.one_of(
        st.tuples(st.just("send"), st.sampled_from(_COMMANDS)),
        st.tuples(st.just("read"), st.sampled_from(_REPLIES)),
        st.tuples(st.just("wait"), st.sampled_from([0.001, 0.5, 6.0])),
    ),
    max_size=40,
)


@settings(max_examples=400, deadline=None)
@given(steps=_steps, numbered=st.booleans())
def test_the_fast_lanes_do_what_the_general_path_does(steps: list[tuple[str, object]], numbered: bool) -> None:
    sides = [_Side(Connection(numbered=numbered), fast=True), _Side(Connection(numbered=numbered), fast=False)]
    now = 0.0
    for kind, value in steps:
        if kind == "wait":
            assert isinstance(value, float)
            now += value
        outcomes = []
        for side in sides:
            conn = side.conn
            finished: list[tuple[Command, Reply | MarlinError]] = []
            if kind == "send":
                assert isinstance(value, str)
                try:
                    command = conn.submit_and_write(value, timeout_s=5.0, now=now) if side.fast else None
                    if command is not None:
                        side.written += command.wire
                    else:
                        conn.submit(value, timeout_s=5.0, now=now)
                        output = conn.tick(now)
                        side.written += output.data
                        finished += _finished(output)
                except MarlinError as exc:
                    finished.append((Command(-1, value, "", False, 0, now), exc))
            elif kind == "read":
                assert isinstance(value, bytes)
                if side.fast:
                    output = conn.receive(value, now)
                else:
                    output = conn._output(tuple(conn._receiving.receive_data(value, now)), now)
                side.written += output.data
                finished += _finished(output)
            else:
                output = conn.tick(now)
                side.written += output.data
                finished += _finished(output)
            outcomes.append(
                (
                    side.outcome(finished),
                    side.written,
                    conn.state,
                    conn.next_deadline(),
                    conn.stats(),
                    [(c.text, c.state) for c in conn._core.in_flight],
                    [c.text for c in conn._core.queue],
                    _core_state(conn),
                )
            )
        fast, general = outcomes
        assert fast == general, (kind, value)
