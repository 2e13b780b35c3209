"""`marlin-sim`: serve a simulated Marlin printer on a pseudo-terminal (default) or a TCP port.

The first line on stdout is the URL to open (a device path such as `/dev/pts/3`, or `socket://127.0.0.1:PORT`),
flushed at once so a script can read it; everything meant for people goes to stderr. Runs until SIGINT or
SIGTERM and then exits 0. argparse keeps this dependency-free and quick to start.

The event loop runs on `select()` rather than the default epoll: epoll sleeps in whole milliseconds, which would
hold each short reply of a `--baud` wire back by up to a millisecond, while `select()` wakes to the microsecond.
With a pty or one TCP client there are only a couple of file descriptors, where select costs no more.
"""

from __future__ import annotations

import argparse
import asyncio
import selectors
import signal
import sys
from collections.abc import Sequence

from marlin_aio.simulator._printer import Faults, SimulatorConfig
from marlin_aio.simulator._serve import serve_pty, serve_tcp

__all__ = ["main"]


def _ratio(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {text}")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _not_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def _password(text: str) -> str:
    try:
        SimulatorConfig(password=text)  # the rule lives with the option it guards
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


# The on/off dialect switches of SimulatorConfig: each is a flag named after its field (`--bare-busy` sets
# `bare_busy`), so adding one here is all it takes.
_DIALECT_SWITCHES: tuple[tuple[str, str], ...] = (
    ("checksum_required", "refuse unnumbered lines: 'Error: Missing checksum', no ok, not run"),
    ("plain_wait_lines", "M109/M190/M191 wait lines without ' W:'"),
    ("bare_busy", "keepalives as 'busy:processing', without 'echo:'"),
    ("repetier_targets", "'TargetExtr0:200'-style target lines, reports without ' /target'"),
    ("m114_on_ok", "M114 answers on its ok line: 'ok X:.. Y:.. Z:.. E:.. Count ...'"),
)


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="marlin-sim",
        description="Serve a simulated Marlin 2.1 printer. Prints the URL to open as the first line on stdout.",
    )
    parser.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP 127.0.0.1:PORT (0 picks a free port)")
    parser.add_argument("--host", default="127.0.0.1", help="TCP address to listen on (default %(default)s)")
    parser.add_argument(
        "--time-scale", type=_positive, default=1.0, help="simulated seconds per real second (default 1)"
    )
    parser.add_argument(
        "--baud",
        type=_positive_int,
        metavar="RATE",
        help="pace both directions like a UART at RATE bits/s, 10 bits a byte, in real time (default: unpaced)",
    )
    parser.add_argument(
        "--motion-time-scale",
        type=_not_negative,
        default=1.0,
        metavar="FACTOR",
        help="factor on how long moves take; 0 makes them instant (default 1)",
    )
    parser.add_argument(
        "--reset-on-open",
        action="store_true",
        help="pty (Linux): reset and print the banner when a client opens the port, as DTR resets a board"
        " (a TCP client always finds the board reset)",
    )
    parser.add_argument("--advanced-ok", action="store_true", help="ok N<line> P<planner> B<buffer> (ADVANCED_OK)")
    parser.add_argument("--extruders", type=int, default=1, choices=range(1, 9), metavar="N", help="hotends (1-8)")
    parser.add_argument("--chamber", action="store_true", help="add a heated chamber (M141, C: in M105)")
    parser.add_argument("--no-bed", action="store_true", help="no heated bed")
    parser.add_argument("--no-emergency-parser", action="store_true", help="M108/M112/M410 wait their turn")
    parser.add_argument("--rx-buffer", type=int, default=128, metavar="BYTES", help="serial receive buffer")
    parser.add_argument("--seed", type=int, default=0, help="seed for every random fault decision")
    parser.add_argument("--corrupt-rx", type=_ratio, default=0.0, metavar="RATIO", help="share of lines corrupted")
    parser.add_argument("--drop-ok", type=_ratio, default=0.0, metavar="RATIO", help="share of oks not sent")
    parser.add_argument("--noise", type=_ratio, default=0.0, metavar="RATIO", help="share of lines after noise")
    parser.add_argument(
        "--silent-after-lines",
        type=_positive_int,
        metavar="N",
        help="stall, answering nothing more, after running N numbered lines",
    )
    parser.add_argument(
        "--not-executed",
        type=_ratio,
        default=0.0,
        metavar="RATIO",
        help="share of commands answered \"!! Lost communication with MCU 'mcu'\" and ok, and not run",
    )
    dialects = parser.add_argument_group("dialects", "firmware variants and options a host meets in the field")
    for field, help_text in _DIALECT_SWITCHES:
        dialects.add_argument("--" + field.replace("_", "-"), dest=field, action="store_true", help=help_text)
    dialects.add_argument(
        "--password",
        type=_password,
        metavar="PASSWORD",
        help="PASSWORD_FEATURE: locked until 'M511 P<PASSWORD>' (again after every reset)",
    )
    return parser


def _settings(arguments: argparse.Namespace) -> tuple[SimulatorConfig, Faults]:
    """The printer's configuration and faults the parsed command line asks for."""
    config = SimulatorConfig(
        advanced_ok=arguments.advanced_ok,
        extruders=arguments.extruders,
        has_bed=not arguments.no_bed,
        has_chamber=arguments.chamber,
        emergency_parser=not arguments.no_emergency_parser,
        rx_buffer_size=arguments.rx_buffer,
        motion_time_scale=arguments.motion_time_scale,
        password=arguments.password,
        seed=arguments.seed,
        **{field: getattr(arguments, field) for field, _ in _DIALECT_SWITCHES},
    )
    faults = Faults(
        corrupt_rx_ratio=arguments.corrupt_rx,
        drop_ok_ratio=arguments.drop_ok,
        noise_ratio=arguments.noise,
        silent_after_lines=arguments.silent_after_lines,
        not_executed_ratio=arguments.not_executed,
    )
    return config, faults


async def _serve(arguments: argparse.Namespace) -> None:
    config, faults = _settings(arguments)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    if arguments.tcp is not None:
        server = serve_tcp(
            config,
            faults,
            host=arguments.host,
            port=arguments.tcp,
            time_scale=arguments.time_scale,
            baud_rate=arguments.baud,
        )
    else:
        server = serve_pty(
            config,
            faults,
            time_scale=arguments.time_scale,
            baud_rate=arguments.baud,
            reset_on_open=arguments.reset_on_open,
        )
    async with server:
        print(server.url, flush=True)
        baud = f", {arguments.baud} baud" if arguments.baud is not None else ""
        dialects = "".join(f", {field}" for field, _ in _DIALECT_SWITCHES if getattr(config, field))
        locked = ", locked (M511)" if config.password is not None else ""
        print(
            f"marlin-sim: {config.firmware_name} on {server.url}, time scale {arguments.time_scale:g}{baud}"
            f"{', ADVANCED_OK' if config.advanced_ok else ''}{dialects}{locked}; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        await stop.wait()
    printer = server.printer
    print(
        f"marlin-sim: stopped; {printer.executed_count} commands run, {printer.executed_line_count} of them"
        f" numbered; {printer.rx_dropped_bytes} received bytes dropped in {printer.rx_overflows} overflows",
        file=sys.stderr,
        flush=True,
    )


def _new_loop() -> asyncio.AbstractEventLoop:
    return asyncio.SelectorEventLoop(selectors.SelectSelector())


def main(argv: Sequence[str] | None = None) -> int:
    """Run `marlin-sim` with `argv` (default: the command line); return the exit status."""
    arguments = _build_parser().parse_args(argv)
    try:
        with asyncio.Runner(loop_factory=_new_loop) as runner:
            runner.run(_serve(arguments))
    except KeyboardInterrupt:
        pass  # Ctrl-C before the signal handlers were in place: still a clean stop
    except OSError as exc:
        print(f"marlin-sim: cannot serve: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
