"""The command line of `marlin-temp bench`: its options and help; `command` measures and shows the result."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from ..common.connect import ConnectOptions
from ..common.options import error_console, fail, run, with_connect_options

__all__ = ["BENCH_HELP", "bench"]

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
BENCH_HELP = "\n\n".join(
    (
        "Check the link to your printer (cable, USB bridge, baud rate, firmware): latency, order, throughput.",
        "Read-only: sends only M105, M118 (an echo) and G4 P0 (a dwell of 0 ms); nothing moves or heats.",
        "Latency: --count M105 round trips, one at a time. median, p99 and max are the time from writing the line "
        "to reading its ok (half, 99 % and all of them took no longer); round trips/s is how many were answered "
        "per second.",
        "Order check: --lines numbered 'M118 E1 bench <n>' lines with checksums, several in flight (send-ahead). "
        "Each reply must carry its own echo and come after the earlier ones: 'oks in order' should equal 'lines "
        "sent', and 'out of order' be 0. A lost ok is not reordering and is counted apart: 'oks lost' counts the "
        "oks that never came, which the library proved lost by a later answer and recovered from, and 'replies "
        "withheld' the lines that ran but whose reply it could not prove to be their own, so gave them none. "
        "Without ADVANCED_OK in the firmware only an M105's ok names its command, so each line gets an M105 behind "
        "it and lines go one at a time. 'resends' counts the lines the printer rejected (corrupted on the way) and "
        "asked for again; 'timeouts' the commands that got no ok within --timeout.",
        "Throughput: --lines G4 P0 lines streamed as 'marlin-temp print' streams a file (send-ahead in the "
        "printer's 128-byte buffer). 'stream lines/s' and 'stream bytes/s' (as on the wire, with line numbers and "
        "checksums) are compared with the wire limit of the baud rate, baud/10 bytes per second ('wire use'). The "
        "built-in --sim is not paced, so the limit does not apply there: run 'marlin-sim --baud 250000' and give "
        "its device as --port to see the ratio.",
        "Exits 1 with one line when an ok came back out of order, a line got no answer or a command timed out. "
        "Lost oks that the library recovered are not a failure of the link's order: they give a warning line "
        "('3 oks lost (recovered), 0 out of order') and exit 0.",
    )
)


@with_connect_options()
def bench(
    count: Annotated[int, typer.Option("--count", "-n", help="M105 round trips in the latency run.", min=1)] = 500,
    lines: Annotated[
        int, typer.Option("--lines", help="Lines in the order check and in the throughput stream.", min=1)
    ] = 1000,
    duration: Annotated[
        float | None,
        typer.Option(
            "--duration",
            help="Run each of the three parts this many seconds instead (default: --count and --lines).",
            min=0.01,
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object instead of the table.")] = False,
    *,
    options: ConnectOptions,
) -> None:
    """Measure latency, order and throughput of the link to the printer (the help text is `BENCH_HELP`)."""
    from .command import BenchSettings, bench_printer, show_result

    settings = BenchSettings(round_trips=count, lines=lines, duration_s=duration)
    result = run(bench_printer(options, settings, error_console()))
    show_result(result, Console(highlight=False, emoji=False), as_json=json_output)
    if result.problem is not None:
        fail(result.problem)
    if result.warning is not None:
        error_console().print(f"[yellow]warning:[/] {escape(result.warning)}", markup=True)
