"""`marlin-sim`: serve a simulated Marlin printer on a pseudo-terminal (default) or a TCP port.

The first line on stdout is the URL to open (a device path such as `/dev/pts/3`, or `socket://127.0.0.1:PORT`),
flushed at once so a script can read it; everything meant for people goes to stderr. Runs until SIGINT or
SIGTERM and then exits 0. The options are defined once, in `_options`, for this command and any other that
serves the simulator (`marlin-temp sim` makes its typer options of `SIMULATOR_OPTIONS` and serves with
`serve_until_stopped`).

With `--printers N` it serves N independent printers from one process, one URL per line.

The event loop runs on `select()` rather than the default epoll: epoll sleeps in whole milliseconds, which would
hold each short reply of a `--baud` wire back by up to a millisecond, while `select()` wakes to the microsecond.
With a pty or one TCP client there are only a couple of file descriptors, where select costs no more (50 printers
are 50 descriptors, still well inside select's limit of 1024).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import selectors
import signal
import sys
from collections.abc import Sequence

from marlin_aio.simulator._config import Faults, SimulatorConfig
from marlin_aio.simulator._options import (
    DIALECT_SWITCHES,
    GROUP_DESCRIPTIONS,
    SIMULATOR_OPTIONS,
    SimulatorSettings,
    build_parser,
    option_help,
    settings_from_values,
    simulator_settings,
)

# The options' table and its readers too: another command line (marlin-temp sim) makes its options of them.
__all__ = [
    "GROUP_DESCRIPTIONS",
    "SIMULATOR_OPTIONS",
    "main",
    "option_help",
    "run_simulator",
    "serve_until_stopped",
    "settings_from_values",
]


def _build_parser() -> argparse.ArgumentParser:
    return build_parser()


def _settings(arguments: argparse.Namespace) -> tuple[SimulatorConfig, Faults]:
    """The printer's configuration and faults the parsed command line asks for."""
    settings = simulator_settings(arguments)
    return settings.config, settings.faults


async def run_simulator(settings: SimulatorSettings, *, prog: str = "marlin-sim") -> None:
    """Serve the simulator as `settings` say until SIGINT or SIGTERM: the URL on stdout, the rest on stderr.

    Raises:
        OSError: if the pty or the socket cannot be opened.
    """
    config = settings.config
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    servers = settings.servers()
    async with contextlib.AsyncExitStack() as stack:
        for server in servers:
            await stack.enter_async_context(server)
            print(server.url, flush=True)
        baud = f", {settings.baud_rate} baud" if settings.baud_rate is not None else ""
        dialects = "".join(f", {field}" for field, _ in DIALECT_SWITCHES if getattr(config, field))
        locked = ", locked (M511)" if config.password is not None else ""
        boot = f", {config.boot_delay_s:g} s bootloader" if config.boot_delay_s else ""
        where = servers[0].url if len(servers) == 1 else f"{len(servers)} printers ({servers[0].url} ...)"
        print(
            f"{prog}: {config.firmware_name} on {where}, sim speed {settings.time_scale:g}{baud}"
            f"{', ADVANCED_OK' if config.advanced_ok else ''}{dialects}{locked}{boot}; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        await stop.wait()
    printers = [server.printer for server in servers]
    flipped = sum(p.bits_flipped for p in printers)
    print(
        f"{prog}: stopped; {sum(p.executed_count for p in printers)} commands run, "
        f"{sum(p.executed_line_count for p in printers)} of them numbered; "
        f"{sum(p.rx_dropped_bytes for p in printers)} received bytes dropped in "
        f"{sum(p.rx_overflows for p in printers)} overflows"
        f"{f'; {flipped} bits flipped on the wire' if flipped else ''}",
        file=sys.stderr,
        flush=True,
    )


def _new_loop() -> asyncio.AbstractEventLoop:
    return asyncio.SelectorEventLoop(selectors.SelectSelector())


def main(argv: Sequence[str] | None = None, *, prog: str = "marlin-sim") -> int:
    """Run the simulator command line `argv` (default: this process's) as `prog`; return the exit status.

    Bad options print one line and exit 2, `--help` prints the options and exits 0 (argparse's SystemExit).
    """
    parser = build_parser(prog)
    arguments = parser.parse_args(argv)
    try:
        settings = simulator_settings(arguments)
    except ValueError as exc:  # options the configuration refuses (--rx-buffer 0): a usage error too
        parser.error(str(exc))
    return serve_until_stopped(settings, prog=prog)


def serve_until_stopped(settings: SimulatorSettings, *, prog: str = "marlin-sim") -> int:
    """Serve the simulator as `settings` say (`run_simulator`) until SIGINT or SIGTERM; return the exit status:
    0 when stopped, 1 when it could not serve (one line on stderr). Any command line that reads the simulator's
    options (`marlin-sim`, `marlin-temp sim`) ends here."""
    try:
        with asyncio.Runner(loop_factory=_new_loop) as runner:
            runner.run(run_simulator(settings, prog=prog))
    except KeyboardInterrupt:
        pass  # Ctrl-C before the signal handlers were in place: still a clean stop
    except OSError as exc:
        print(f"{prog}: cannot serve: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
