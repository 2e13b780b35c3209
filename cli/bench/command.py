"""`marlin-temp bench`: measure the link to the user's own printer, like a cable and firmware check.

Three runs, all read-only on the printer: only M105, `M118 E1 bench <n>` and `G4 P0` are sent (plus the handshake,
and the `M110 N0` that restarts the line numbers of a stream). Nothing moves and no heater changes.

1. Latency: M105 ping-pong, one command in flight. Each round trip is the client's own measure (`Reply.latency_s`:
   from writing the line to reading its `ok`), so it holds the cable, the USB bridge, the firmware's loop and our
   event loop, which is what a host program sees.
2. Correctness: numbered `M118 E1 bench <n>` lines with checksums, several in flight. Marlin prints
   `echo:bench <n>` before the `ok` of each, so a reply that carries its own echo, arriving after every earlier
   one, proves that the oks came back in order and were matched to the right commands. An `ok` lost on the wire
   is not reordering and is told apart (`OrderCheck`): the library proves it lost when a later answer names its
   command, and withholds the replies it cannot attribute (`LostReplyError`) rather than hand them to the
   wrong command. Without ADVANCED_OK only an M105's `ok T:` names its command, so each line gets an M105
   right behind it (a witness); with ADVANCED_OK every `ok N<line>` does, and only the last line needs one.
3. Throughput: `G4 P0` (a dwell of 0 ms) streamed exactly as `marlin-temp print` streams a file
   (`Printer.start_print(..., send_ahead=True)`), against the wire limit of the baud rate.

Send-ahead in the correctness run: the printer is opened by `open_printer` like in every other command, as a
ping-pong client. For that run only, its connection's `max_in_flight` is raised, as `start_print` does for a
stream; what bounds the lines in flight is then the byte window (the printer's 128-byte receive buffer), not a
count. (Without ADVANCED_OK the library keeps one line in flight beside its witness: plain oks cannot be told
apart, and it never risks handing one command another's answer.) Measuring and rendering are apart:
`bench_printer` returns a `BenchResult`, and `bench_table` and `bench_json` are pure functions of it.

Over 400 lines because the three runs share one printer connection and their settings; each run is a function of
its own, and the rendering, pure, is at the end.
"""

from __future__ import annotations

import asyncio
import json
import math
import statistics
from collections.abc import Coroutine, Iterator
from dataclasses import dataclass

from rich import box
from rich.console import Console
from rich.table import Table

import marlin_aio

from ..common.connect import ConnectOptions, open_printer

__all__ = [
    "BenchResult",
    "BenchSettings",
    "CorrectnessResult",
    "LatencyResult",
    "OrderCheck",
    "ThroughputResult",
    "bench_json",
    "bench_printer",
    "bench_table",
    "show_result",
]

LATENCY_COMMAND = "M105"
ECHO_COMMAND = "M118 E1 bench {n}"
_ECHO_PREFIX = "echo:bench "
STREAM_COMMAND = "G4 P0"
#: Sends kept waiting in the correctness run: more than the 128-byte window holds, so the window stays full.
_CORRECTNESS_TASKS = 32
#: More than ever fits the window; the window in bytes is the real limit (as in `start_print`).
_SEND_AHEAD_MAX_IN_FLIGHT = 64
_BITS_PER_BYTE = 10  # a UART frame: start bit, 8 data bits, stop bit
#: A paced link carries at most its baud rate's bytes; past this share of it, nothing paces it (a pty, a socket).
_PACED_MARGIN = 1.05


@dataclass(frozen=True)
class BenchSettings:
    """How long each run lasts: a number of commands, or `duration_s` seconds each when given."""

    round_trips: int = 500
    lines: int = 1000
    duration_s: float | None = None


@dataclass(frozen=True)
class LatencyResult:
    """M105 ping-pong: round trips answered and timed out, their spread, and how long the run took."""

    round_trips: int
    timeouts: int
    median_ms: float | None
    p99_ms: float | None
    max_ms: float | None
    elapsed_s: float

    @property
    def round_trips_per_s(self) -> float:
        """Answered round trips per second over the run, one in flight at a time."""
        return self.round_trips / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass(frozen=True)
class CorrectnessResult:
    """Numbered M118 echoes sent ahead: how many came back with their own echo and in order.

    Every line sent ends up in one of `oks_in_order`, `withheld`, `out_of_order` and `timeouts` (`timeouts` also
    counts the witness M105s). `lost_oks` counts the oks the library proved lost and recovered from; `withheld` the
    lines that ran but whose reply it could not prove to be their own, so gave them none.
    """

    lines_sent: int
    oks_in_order: int
    out_of_order: int
    resends: int
    timeouts: int
    max_in_flight: int
    elapsed_s: float
    lost_oks: int = 0
    withheld: int = 0
    numbered_oks: bool = True  # the printer has ADVANCED_OK; without it lines go one at a time with a witness

    @property
    def clean(self) -> bool:
        """Every line answered, nothing reordered and nothing timed out; lost oks the library recovered are allowed."""
        answered = self.oks_in_order + self.withheld
        return self.out_of_order == 0 and self.timeouts == 0 and answered == self.lines_sent

    @property
    def summary(self) -> str:
        """`3 oks lost (recovered), 0 out of order`: what the order check saw, told apart."""
        lost = f"{self.lost_oks} ok{'s' if self.lost_oks != 1 else ''} lost (recovered)"
        return f"{lost}, {self.out_of_order} out of order"


@dataclass(frozen=True)
class ThroughputResult:
    """G4 P0 streamed like a print: lines and bytes acknowledged over the run's time."""

    lines: int
    bytes_sent: int
    bytes_received: int
    elapsed_s: float
    resends: int
    window_bytes: int
    stall: str | None = None  # the stall message when the stream stopped without an answer

    @property
    def lines_per_s(self) -> float:
        """Lines acknowledged per second."""
        return self.lines / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def bytes_per_s(self) -> float:
        """Bytes of acknowledged lines (with line numbers and checksums, as on the wire) per second, host to printer."""
        return self.bytes_sent / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass(frozen=True)
class BenchResult:
    """Everything one `bench` measured, with what is needed to judge it (port, baud rate, pacing)."""

    port: str
    firmware: str | None
    baud: int
    paced: bool  # False for the in-process simulator: its pty carries bytes as fast as they come
    latency: LatencyResult
    correctness: CorrectnessResult
    throughput: ThroughputResult

    @property
    def wire_limit_bytes_per_s(self) -> float:
        """What the baud rate allows in one direction: 10 bits a byte."""
        return self.baud / _BITS_PER_BYTE

    @property
    def wire_ratio(self) -> float | None:
        """Throughput as a share of the wire limit; None when the link is not paced (the limit does not apply)."""
        return self.throughput.bytes_per_s / self.wire_limit_bytes_per_s if self.paced else None

    @property
    def paced_as_measured(self) -> bool:
        """Whether the link carried bytes like a UART: not the unpaced --sim, and no faster than its baud rate
        allows (a pty or socket with nothing pacing it carries more, whatever baud rate it was opened with)."""
        return self.wire_ratio is not None and self.wire_ratio <= _PACED_MARGIN

    @property
    def problem(self) -> str | None:
        """One line saying what went wrong, or None when every ok came back in order and nothing timed out.

        Lost oks alone are not a problem (see `warning`): the library recovered from them and nothing was reordered.
        """
        parts = []
        correctness = self.correctness
        if correctness.out_of_order:
            parts.append(
                f"{correctness.out_of_order} of {correctness.lines_sent} oks came back out of order "
                "or without their own echo"
            )
        answered = correctness.oks_in_order + correctness.withheld + correctness.out_of_order
        missing = correctness.lines_sent - answered - correctness.timeouts
        if missing > 0:
            parts.append(f"{missing} of {correctness.lines_sent} lines got no answer")
        timeouts = correctness.timeouts + self.latency.timeouts
        if timeouts:
            parts.append(f"{timeouts} command{'s' if timeouts != 1 else ''} timed out")
        if self.throughput.stall is not None:
            parts.append(f"the throughput stream stalled ({self.throughput.stall})")
        if not parts:
            return None
        if correctness.lost_oks:
            # Said apart, so a reader does not take the lost oks for the reordering (or the other way round).
            parts.append(f"{correctness.lost_oks} ok{'s' if correctness.lost_oks != 1 else ''} lost (recovered)")
        return "link check failed: " + "; ".join(parts) + " (check the cable, the baud rate and the grounding)"

    @property
    def warning(self) -> str | None:
        """One line when oks were lost but the check passed: the library recovered, nothing was reordered."""
        correctness = self.correctness
        if self.problem is not None or not correctness.lost_oks:
            return None
        return (
            f"{correctness.summary}: oks went missing on the way, but the library proved each one lost by a later "
            "answer and recovered, and no reply came back out of order (if it keeps happening, check the cable "
            "and the grounding)"
        )


# ------------------------------------------------------------------------------------------- measuring


def _nearest_rank(ordered: list[float], fraction: float) -> float:
    return ordered[max(math.ceil(fraction * len(ordered)) - 1, 0)]


async def _measure_latency(printer: marlin_aio.Printer, settings: BenchSettings) -> LatencyResult:
    loop = asyncio.get_running_loop()
    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s
    latencies: list[float] = []
    timeouts = 0
    start = loop.time()
    sent = 0
    while (sent < settings.round_trips) if deadline is None else (loop.time() < deadline):
        sent += 1
        try:
            reply = await printer.send(LATENCY_COMMAND)
        except marlin_aio.CommandTimeoutError:
            timeouts += 1
            continue
        latencies.append(reply.latency_s)
    elapsed = loop.time() - start
    ordered = sorted(latencies)
    return LatencyResult(
        round_trips=len(ordered),
        timeouts=timeouts,
        median_ms=statistics.median(ordered) * 1000 if ordered else None,
        p99_ms=_nearest_rank(ordered, 0.99) * 1000 if ordered else None,
        max_ms=ordered[-1] * 1000 if ordered else None,
        elapsed_s=elapsed,
    )


class OrderCheck:
    """Judges the order check's answers, in the order their oks were read: in order, withheld, or reordered.

    Pure bookkeeping with no I/O, fed by `_check_order`. The library never hands a command an answer it cannot
    prove to be its own: when an `ok` is lost, a later answer that names its command (`ok N<line>` with
    ADVANCED_OK, or an M105's `ok T:`) shows that the commands before it ran, and each of those whose reply
    lines cannot be told apart fails with `LostReplyError` (or, its own ok lost, gets a reply marked `ok_lost` with
    no lines). Such a reply is withheld, not reordered. What is left
    for this check is what the library trusted: a reply must carry exactly its own echo, after every earlier one.
    """

    def __init__(self) -> None:
        self.in_order = 0
        """Replies that carried exactly their own echo, in sequence."""
        self.withheld = 0
        """Lines that ran, but whose reply the library withheld because an ok (theirs or an earlier one) was lost."""
        self.out_of_order = 0
        """Replies with another line's echo, with none, or after a later line's echo."""
        self.timeouts = 0
        """Commands that got no ok within the timeout."""
        self._last_echo = -1

    def answered(self, line: int, echoes: list[int]) -> None:
        """Judge the reply to bench line `line`, which carried the echoes numbered `echoes` (as read)."""
        if echoes == [line] and line > self._last_echo:
            self.in_order += 1
        else:
            self.out_of_order += 1
        self._last_echo = max([self._last_echo, *echoes])

    def lost_reply(self) -> None:
        """A line ran but its reply was withheld (`LostReplyError`): an ok was lost, and the library recovered."""
        self.withheld += 1

    def timed_out(self) -> None:
        """A command got no ok within the timeout."""
        self.timeouts += 1


def _echo_numbers(lines: tuple[str, ...]) -> list[int]:
    # Only the bench echoes count: a board may print other echo lines (an SD card inserted) at any time.
    numbers = (line.removeprefix(_ECHO_PREFIX) for line in lines if line.startswith(_ECHO_PREFIX))
    return [int(number) for number in numbers if number.isdigit()]


async def _check_order(printer: marlin_aio.Printer, settings: BenchSettings) -> CorrectnessResult:
    loop = asyncio.get_running_loop()
    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s
    before = printer.stats
    check = OrderCheck()
    failure: marlin_aio.MarlinError | None = None
    numbered_oks = False  # the printer names the line in each ok (ADVANCED_OK): no witness needed
    slots = asyncio.Semaphore(_CORRECTNESS_TASKS)
    tasks: set[asyncio.Task[None]] = set()

    def start(coroutine: Coroutine[None, None, None], name: str) -> None:
        # Tasks take their first step in the order they are created, so commands are submitted in that order.
        task = asyncio.create_task(coroutine, name=name)
        tasks.add(task)
        task.add_done_callback(tasks.discard)

    async def witness() -> None:
        # An M105 right behind a line: if the line's ok is lost, this `ok T:` proves that the line ran, and the
        # library recovers at once (LostReplyError) instead of after --timeout. Its own reply is of no interest.
        nonlocal failure
        try:
            await printer.send(LATENCY_COMMAND)
        except marlin_aio.LostReplyError:
            pass  # counted by the library's lost_oks
        except marlin_aio.CommandTimeoutError:
            check.timed_out()
        except marlin_aio.MarlinError as exc:
            failure = failure or exc

    async def one(n: int) -> None:
        nonlocal failure, numbered_oks
        try:
            reply = await printer.send(ECHO_COMMAND.format(n=n))
        except marlin_aio.LostReplyError:
            check.lost_reply()
            return
        except marlin_aio.CommandTimeoutError:
            check.timed_out()
            return
        except marlin_aio.MarlinError as exc:
            failure = failure or exc
            return
        finally:
            slots.release()
        if reply.ok_lost and not reply.lines:
            # It ran (a later answer proves it) but its own ok was lost, and its lines cannot be told apart.
            check.lost_reply()
            return
        numbered_oks = numbered_oks or (reply.ok.line_number is not None and not reply.ok_lost)
        # Tasks resume in the order their futures were resolved, which is the order the oks were read.
        check.answered(n, _echo_numbers(reply.lines))

    start_s = loop.time()
    sent = 0
    with printer.sending_ahead(_SEND_AHEAD_MAX_IN_FLIGHT):
        try:
            while failure is None and ((sent < settings.lines) if deadline is None else (loop.time() < deadline)):
                await slots.acquire()
                start(one(sent), f"marlin-temp bench line {sent}")
                if not numbered_oks:
                    # Without ADVANCED_OK only an M105's ok names its command: a witness behind each line.
                    start(witness(), f"marlin-temp bench witness {sent}")
                sent += 1
            if failure is None and numbered_oks:
                # With ADVANCED_OK the next ok proves a lost one, but nothing follows the last line: this does.
                start(witness(), "marlin-temp bench witness")
            while tasks:
                await asyncio.wait(set(tasks))
        finally:
            for task in tasks:
                task.cancel()
    after = printer.stats
    if failure is not None:
        raise failure
    return CorrectnessResult(
        lines_sent=sent,
        oks_in_order=check.in_order,
        out_of_order=check.out_of_order,
        resends=after.resend_requests - before.resend_requests,
        timeouts=check.timeouts,
        max_in_flight=_SEND_AHEAD_MAX_IN_FLIGHT,
        elapsed_s=loop.time() - start_s,
        lost_oks=after.lost_oks - before.lost_oks,
        withheld=check.withheld,
        numbered_oks=numbered_oks,
    )


async def _measure_throughput(printer: marlin_aio.Printer, settings: BenchSettings) -> ThroughputResult:
    loop = asyncio.get_running_loop()
    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s

    def lines() -> Iterator[str]:
        # Read lazily by the connection as the window opens, so a duration ends the stream on time.
        count = 0
        while (count < settings.lines) if deadline is None else (loop.time() < deadline):
            count += 1
            yield STREAM_COMMAND

    window = printer.send_ahead_window_bytes
    received_before = printer.stats.bytes_received
    handle: marlin_aio.PrintHandle | None = None
    stall = None
    try:
        handle = await printer.start_print(lines(), send_ahead=True)
        await handle.wait()
    except marlin_aio.CommandTimeoutError as exc:
        # A stalled stream (or an unanswered M110 N0 before it) is reported with the figures so far.
        stall = str(exc).split(";")[0]
    if handle is None:
        return ThroughputResult(0, 0, printer.stats.bytes_received - received_before, 0.0, 0, window, stall)
    progress = handle.progress
    return ThroughputResult(
        lines=progress.lines_acked,
        bytes_sent=progress.bytes_acked,
        bytes_received=printer.stats.bytes_received - received_before,
        elapsed_s=progress.elapsed_s,
        resends=progress.resends,
        window_bytes=window,
        stall=stall,
    )


async def bench_printer(options: ConnectOptions, settings: BenchSettings, errors: Console) -> BenchResult:
    """Open the printer the options name and run the three measurements; progress goes to `errors`.

    A timeout in a run is counted, not raised, so the report shows how the link behaved.

    Raises:
        UsageProblem: no port given and none (or several) found.
        MarlinError: opening failed, or the printer halted, reset or went away during a run.
    """
    async with open_printer(options, errors) as (printer, label):
        how = f"{settings.duration_s:g} s each" if settings.duration_s is not None else None
        errors.print(
            f"bench on {label}: M105 round trips ({how or settings.round_trips}), M118 order check "
            f"({how or settings.lines} lines), G4 P0 stream ({how or settings.lines} lines)",
            style="dim",
        )
        latency = await _measure_latency(printer, settings)
        correctness = await _check_order(printer, settings)
        throughput = await _measure_throughput(printer, settings)
        return BenchResult(
            port=label,
            firmware=printer.firmware.name if printer.firmware is not None else None,
            baud=printer.baudrate,
            paced=not options.sim,
            latency=latency,
            correctness=correctness,
            throughput=throughput,
        )


# ------------------------------------------------------------------------------------------- rendering


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} ms"


def _wire_note(result: BenchResult) -> str:
    if result.wire_ratio is None:
        return "n/a: --sim is unpaced (see --help)"
    if not result.paced_as_measured:
        # No UART carries more than its baud rate allows: this is a pty or socket with no pacing behind it.
        return "above the wire limit: this link is not paced"
    return f"of {result.wire_limit_bytes_per_s:,.0f} bytes/s, the wire limit"


def _order_mode(correctness: CorrectnessResult) -> str:
    return "send-ahead" if correctness.numbered_oks else "one at a time + M105 (no ADVANCED_OK)"


def bench_table(result: BenchResult) -> Table:
    """The report as a table of metric, value and a note saying what the number means."""
    latency, correctness, throughput = result.latency, result.correctness, result.throughput
    firmware = result.firmware.split(" (")[0] if result.firmware else "unknown firmware"
    table = Table(
        title=f"{firmware} on {result.port}, {result.baud} baud",
        box=box.SIMPLE_HEAD,
        header_style="bold",
        pad_edge=False,
    )
    table.add_column("metric")
    table.add_column("value", justify="right")
    table.add_column("note", style="dim")
    limit_note = f"{result.baud} baud / 10 bits a byte" + ("" if result.paced else "; --sim is unpaced")
    table.add_row("wire limit", f"{result.wire_limit_bytes_per_s:,.0f} B/s", limit_note)
    table.add_section()
    table.add_row("round trips", str(latency.round_trips), f"{LATENCY_COMMAND} ping-pong, one in flight")
    table.add_row("latency median", _ms(latency.median_ms), "write to ok; half took less")
    table.add_row("latency p99", _ms(latency.p99_ms), "99 % took no longer")
    table.add_row("latency max", _ms(latency.max_ms), "the slowest round trip")
    table.add_row("round trips/s", f"{latency.round_trips_per_s:,.0f}", "sustained, one in flight")
    table.add_section()
    table.add_row(
        "lines sent", str(correctness.lines_sent), f"{ECHO_COMMAND.format(n='<n>')}, {_order_mode(correctness)}"
    )
    table.add_row("oks in order", str(correctness.oks_in_order), "replies with their own echo, in sequence")
    table.add_row("oks lost", str(correctness.lost_oks), "never came; recovered, not reordering")
    table.add_row("replies withheld", str(correctness.withheld), "ran, but an ok lost: no reply to trust")
    table.add_row("out of order", str(correctness.out_of_order), "wrong echo, or after a later line's ok")
    table.add_row("resends", str(correctness.resends), "lines rejected (corrupted) and asked for again")
    table.add_row("timeouts", str(correctness.timeouts + latency.timeouts), "no ok within --timeout")
    if not correctness.clean or latency.timeouts:
        verdict = "[bold red]FAILED[/]"
    elif correctness.lost_oks:
        verdict = "[yellow]clean[/]"
    else:
        verdict = "[green]clean[/]"
    table.add_row("order check", verdict, correctness.summary)
    table.add_section()
    mode = f"{STREAM_COMMAND} like a print, {throughput.window_bytes}-byte send-ahead"
    table.add_row("stream lines/s", f"{throughput.lines_per_s:,.0f}", mode)
    table.add_row("stream bytes/s", f"{throughput.bytes_per_s:,.0f}", "host to printer, as on the wire")
    table.add_row("wire use", "-" if result.wire_ratio is None else f"{result.wire_ratio:.0%}", _wire_note(result))
    table.add_row("stream resends", str(throughput.resends), f"of {throughput.lines} lines streamed")
    return table


def bench_json(result: BenchResult) -> dict[str, object]:
    """The report as one JSON-ready object (times in the unit their key names)."""
    latency, correctness, throughput = result.latency, result.correctness, result.throughput
    return {
        "port": result.port,
        "firmware": result.firmware,
        "baud": result.baud,
        "paced": result.paced_as_measured,  # what the table says: faster than the wire is not paced
        "wire_limit_bytes_per_s": result.wire_limit_bytes_per_s,
        "clean": result.problem is None,
        "problem": result.problem,
        "warning": result.warning,
        "latency": {
            "command": LATENCY_COMMAND,
            "mode": "ping-pong",
            "round_trips": latency.round_trips,
            "timeouts": latency.timeouts,
            "median_ms": latency.median_ms,
            "p99_ms": latency.p99_ms,
            "max_ms": latency.max_ms,
            "round_trips_per_s": latency.round_trips_per_s,
            "elapsed_s": latency.elapsed_s,
        },
        "correctness": {
            "command": ECHO_COMMAND.format(n="<n>"),
            "mode": (
                f"send-ahead: concurrent send(), max_in_flight {correctness.max_in_flight}, 128-byte window"
                if correctness.numbered_oks
                else "one at a time, each followed by an M105 witness (no ADVANCED_OK)"
            ),
            "lines_sent": correctness.lines_sent,
            "oks_in_order": correctness.oks_in_order,
            "lost_oks": correctness.lost_oks,
            "withheld": correctness.withheld,
            "out_of_order": correctness.out_of_order,
            "resends": correctness.resends,
            "timeouts": correctness.timeouts,
            "clean": correctness.clean,
            "elapsed_s": correctness.elapsed_s,
        },
        "throughput": {
            "command": STREAM_COMMAND,
            "mode": f"send-ahead: start_print stream, {throughput.window_bytes}-byte window",
            "lines": throughput.lines,
            "bytes_sent": throughput.bytes_sent,
            "bytes_received": throughput.bytes_received,
            "elapsed_s": throughput.elapsed_s,
            "lines_per_s": throughput.lines_per_s,
            "bytes_per_s": throughput.bytes_per_s,
            "wire_ratio": result.wire_ratio,
            "resends": throughput.resends,
            "stall": throughput.stall,
        },
    }


def show_result(result: BenchResult, console: Console, *, as_json: bool) -> None:
    """Print the report: the table, or with `as_json` one JSON object on one line."""
    if as_json:
        console.out(json.dumps(bench_json(result)), highlight=False)
    else:
        console.print(bench_table(result))
