"""`marlin-temp bench`: measure the link to the user's own printer, like a cable and firmware check.

Three runs, all read-only on the printer: only M105, `M118 E1 bench <n>` and `G4 P0` are sent (plus the handshake,
and the `M110 N0` that restarts the line numbers of a stream). Nothing moves and no heater changes.

1. Latency: M105 ping-pong, one command in flight. Each round trip is the client's own measure (`Reply.latency_s`:
   from writing the line to reading its `ok`), so it holds the cable, the USB bridge, the firmware's loop and our
   event loop, which is what a host program sees.
2. Correctness: numbered `M118 E1 bench <n>` lines with checksums, several in flight. Marlin prints
   `echo:bench <n>` before the `ok` of each, so a reply that carries its own echo, arriving after every earlier
   one, proves that the oks came back in order and were matched to the right commands.
3. Throughput: `G4 P0` (a dwell of 0 ms) streamed exactly as `marlin-temp print` streams a file
   (`Printer.start_print(..., send_ahead=True)`), against the wire limit of the baud rate.

Send-ahead in the correctness run: the printer is opened by `open_printer` like in every other command, as a
ping-pong client. For that run only, its connection's `max_in_flight` is raised, as `start_print` does for a
stream; what bounds the lines in flight is then the byte window (the printer's 128-byte receive buffer), not a
count. Measuring and rendering are apart: `bench_printer` returns a `BenchResult`, and `bench_table` and
`bench_json` are pure functions of it.
"""

from __future__ import annotations

import asyncio
import json
import math
import statistics
from collections.abc import Iterator
from dataclasses import dataclass

from rich import box
from rich.console import Console
from rich.table import Table

import marlin_aio

from .connect import ConnectOptions, open_printer

__all__ = [
    "BenchResult",
    "BenchSettings",
    "CorrectnessResult",
    "LatencyResult",
    "ThroughputResult",
    "bench_json",
    "bench_printer",
    "bench_table",
    "show_result",
]

LATENCY_COMMAND = "M105"
ECHO_COMMAND = "M118 E1 bench {n}"
STREAM_COMMAND = "G4 P0"
#: Sends kept waiting in the correctness run: more than the 128-byte window holds, so the window stays full.
_CORRECTNESS_TASKS = 32
#: More than ever fits the window; the window in bytes is the real limit (as in `start_print`).
_SEND_AHEAD_MAX_IN_FLIGHT = 64
_BITS_PER_BYTE = 10  # a UART frame: start bit, 8 data bits, stop bit


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
    """Numbered M118 echoes sent ahead: how many came back with their own echo and in order."""

    lines_sent: int
    oks_in_order: int
    out_of_order: int
    resends: int
    timeouts: int
    max_in_flight: int
    elapsed_s: float

    @property
    def clean(self) -> bool:
        """Every line answered, in order, with its own echo."""
        return self.out_of_order == 0 and self.timeouts == 0 and self.oks_in_order == self.lines_sent


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
    def problem(self) -> str | None:
        """One line saying what went wrong, or None when every ok came back in order and nothing timed out."""
        parts = []
        correctness = self.correctness
        if correctness.out_of_order:
            parts.append(
                f"{correctness.out_of_order} of {correctness.lines_sent} oks came back out of order "
                "or without their own echo"
            )
        missing = correctness.lines_sent - correctness.oks_in_order - correctness.out_of_order - correctness.timeouts
        if missing > 0:
            parts.append(f"{missing} of {correctness.lines_sent} lines got no answer")
        timeouts = correctness.timeouts + self.latency.timeouts
        if timeouts:
            parts.append(f"{timeouts} command{'s' if timeouts != 1 else ''} timed out")
        if self.throughput.stall is not None:
            parts.append(f"the throughput stream stalled ({self.throughput.stall})")
        if not parts:
            return None
        return "link check failed: " + "; ".join(parts) + " (check the cable, the baud rate and the grounding)"


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


async def _check_order(printer: marlin_aio.Printer, settings: BenchSettings) -> CorrectnessResult:
    loop = asyncio.get_running_loop()
    deadline = None if settings.duration_s is None else loop.time() + settings.duration_s
    resends_before = printer.connection.resend_requests
    in_order = out_of_order = timeouts = 0
    latest = -1  # the highest line answered so far
    failure: marlin_aio.MarlinError | None = None
    slots = asyncio.Semaphore(_CORRECTNESS_TASKS)
    tasks: set[asyncio.Task[None]] = set()

    async def one(n: int) -> None:
        nonlocal in_order, out_of_order, timeouts, latest, failure
        try:
            reply = await printer.send(ECHO_COMMAND.format(n=n))
        except marlin_aio.CommandTimeoutError:
            timeouts += 1
            return
        except marlin_aio.MarlinError as exc:
            failure = failure or exc
            return
        finally:
            slots.release()
        # Only the bench echoes count: a board may print other echo lines (an SD card inserted) at any time.
        echoes = [line for line in reply.lines if line.startswith("echo:bench ")]
        # Tasks resume in the order their futures were resolved, which is the order the oks were read.
        if echoes == [f"echo:bench {n}"] and n > latest:
            in_order += 1
        else:
            out_of_order += 1
        latest = max(latest, n)

    saved = printer.connection.max_in_flight
    printer.connection.max_in_flight = _SEND_AHEAD_MAX_IN_FLIGHT
    start = loop.time()
    sent = 0
    try:
        while failure is None and ((sent < settings.lines) if deadline is None else (loop.time() < deadline)):
            await slots.acquire()
            # Tasks start in the order they are created, so the lines are submitted (and numbered) in order n.
            task = asyncio.create_task(one(sent), name=f"marlin-temp bench line {sent}")
            tasks.add(task)
            task.add_done_callback(tasks.discard)
            sent += 1
        if tasks:
            await asyncio.wait(tasks)
    finally:
        printer.connection.max_in_flight = saved
        for task in tasks:
            task.cancel()
    if failure is not None:
        raise failure
    return CorrectnessResult(
        lines_sent=sent,
        oks_in_order=in_order,
        out_of_order=out_of_order,
        resends=printer.connection.resend_requests - resends_before,
        timeouts=timeouts,
        max_in_flight=_SEND_AHEAD_MAX_IN_FLIGHT,
        elapsed_s=loop.time() - start,
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

    connection = printer.connection
    window = connection.rx_buffer_bytes - connection.probe_reserve_bytes
    received_before = printer.bytes_received
    handle: marlin_aio.PrintHandle | None = None
    stall = None
    try:
        handle = await printer.start_print(lines(), send_ahead=True)
        await handle.wait()
    except marlin_aio.CommandTimeoutError as exc:
        # A stalled stream (or an unanswered M110 N0 before it) is reported with the figures so far.
        stall = str(exc).split(";")[0]
    if handle is None:
        return ThroughputResult(0, 0, printer.bytes_received - received_before, 0.0, 0, window, stall)
    progress = handle.progress
    return ThroughputResult(
        lines=progress.lines_acked,
        bytes_sent=progress.bytes_acked,
        bytes_received=printer.bytes_received - received_before,
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
    if result.wire_ratio > 1.05:
        # No UART carries more than its baud rate allows: this is a pty or socket with no pacing behind it.
        return "above the wire limit: this link is not paced"
    return f"of {result.wire_limit_bytes_per_s:,.0f} bytes/s, the wire limit"


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
    table.add_row("lines sent", str(correctness.lines_sent), f"{ECHO_COMMAND.format(n='<n>')}, send-ahead")
    table.add_row("oks in order", str(correctness.oks_in_order), "replies with their own echo, in sequence")
    table.add_row("out of order", str(correctness.out_of_order), "wrong echo, or after a later line's ok")
    table.add_row("resends", str(correctness.resends), "lines rejected (corrupted) and asked for again")
    table.add_row("timeouts", str(correctness.timeouts + latency.timeouts), "no ok within --timeout")
    verdict = "[green]clean[/]" if correctness.clean and latency.timeouts == 0 else "[bold red]FAILED[/]"
    table.add_row("order check", verdict, "every ok in order, nothing timed out")
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
        "paced": result.paced,
        "wire_limit_bytes_per_s": result.wire_limit_bytes_per_s,
        "clean": result.problem is None,
        "problem": result.problem,
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
            "mode": f"send-ahead: concurrent send(), max_in_flight {correctness.max_in_flight}, 128-byte window",
            "lines_sent": correctness.lines_sent,
            "oks_in_order": correctness.oks_in_order,
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
