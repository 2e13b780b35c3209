"""The command line of `marlin-temp serve`: its options and help, the printers checked before `command` runs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..common.connect import Exit
from ..common.options import (
    BaudOption,
    FarmWireLogOption,
    SimSpeedOption,
    checked_wire_log,
    error_console,
    fail,
    run,
)
from ..common.printers import ConfigOption, IntervalOption, PortsOption, SimsOption, printer_specs

__all__ = ["SERVE_HELP", "serve"]

SERVE_HELP = (
    "Own the printers' ports and share them: every other marlin-temp command, and any program, reaches a served "
    "printer as --port serve:NAME (a command asked for a port the service holds uses the service by itself, and "
    "says so)."
    "\n\n"
    "Give the printers as --port NAME=PORT (repeatable), --config FILE (the farm's TOML), --sim for one simulated "
    "printer named sim, or --sims N. Each is kept connected (reconnecting with backoff when unplugged or halted) "
    "and polled at --interval; prints started through the service run inside it, so a print survives the "
    "terminal or SSH session that started it."
    "\n\n"
    "Stopping it (SIGTERM, systemd's stop, or Ctrl-C) mid-print stops feeding, runs the cancel script (hotend, "
    "bed and fan off), records where the print stopped and tells its clients the line to resume from, then exits "
    "(within 30 s; the signal again leaves at once). A service that was killed says at its next start which print it "
    "was running and where to resume, and turns off the heaters of a printer still heating with no print."
    "\n\n"
    "Where things live: the socket is $MARLIN_SERVE_SOCKET, else $XDG_RUNTIME_DIR/marlin-temp/serve.sock, else "
    "/tmp/marlin-temp-UID/serve.sock (--socket overrides), in a folder only you can enter; beside it serve.json "
    "names the ports held, uploads/ the prints sent as content, and api-key the OctoPrint API's key if one was "
    "made. Clients speak JSON-RPC 2.0 on it, one message per line (see the README). The temperature logs go to "
    "--log-dir, one file per printer and day."
    "\n\n"
    "Try it: marlin-temp serve --sim, then in another terminal marlin-temp watch --port serve:sim"
)


def serve(
    ports: PortsOption = None,
    config: ConfigOption = None,
    sim: Annotated[bool, typer.Option("--sim", help="Serve one simulated printer, named sim.")] = False,
    sims: SimsOption = 0,
    sim_speed: SimSpeedOption = 1.0,
    baud: BaudOption = None,
    interval: IntervalOption = 0.1,
    socket: Annotated[
        Path | None, typer.Option("--socket", help="Listen here instead of the default (see above).")
    ] = None,
    octoprint: Annotated[
        str | None,
        typer.Option(
            "--octoprint",
            metavar="[HOST:]PORT",
            help="Also serve OctoPrint's REST API here (127.0.0.1 unless HOST is given), so slicers and Home "
            "Assistant can upload and start prints and read the state. Needs pip install 'marlin-aio\\[serve]'.",
        ),
    ] = None,
    octoprint_printer: Annotated[
        str | None,
        typer.Option("--octoprint-printer", help="The printer the OctoPrint API is for (default: the first)."),
    ] = None,
    api_key_file: Annotated[
        Path | None,
        typer.Option(
            "--api-key-file",
            help="File holding the OctoPrint API key (else $MARLIN_SERVE_API_KEY, else one is made and kept in "
            "api-key beside the socket).",
        ),
    ] = None,
    tcp: Annotated[
        str | None,
        typer.Option(
            "--tcp",
            metavar="[HOST:]PORT",
            help="Also take clients on TCP (127.0.0.1 unless HOST is given), each first giving the token (from "
            "--token-file, $MARLIN_SERVE_TOKEN, or made and kept in token beside the socket). Off by default.",
        ),
    ] = None,
    token_file: Annotated[Path | None, typer.Option("--token-file", help="File holding the TCP token.")] = None,
    log_dir: Annotated[
        Path | None,
        typer.Option(
            "--log-dir",
            help="Where the temperature logs go: one JSON-lines file per printer and day, each row with the print's "
            "file and line while one runs (default: $XDG_STATE_HOME/marlin-temp/logs, else "
            "~/.local/state/marlin-temp/logs).",
        ),
    ] = None,
    log_interval: Annotated[
        float, typer.Option("--log-interval", help="Seconds between logged rows of each printer.", min=0.01)
    ] = 1.0,
    no_log: Annotated[bool, typer.Option("--no-log", help="Write no temperature log.")] = False,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds. Default: until Ctrl-C or SIGTERM.")
    ] = None,
    wire_log: FarmWireLogOption = None,
    leave_heaters: Annotated[
        bool,
        typer.Option(
            "--leave-heaters-after-restart",
            help="When the last service ended mid-print without stopping it (killed, or the machine went down), "
            "leave a printer that still heats with no print as it is, and only say so. Default: turn its heaters "
            "and fan off once it connects.",
        ),
    ] = False,
) -> None:
    """Own the printers and share them on a local socket (the help text is `SERVE_HELP`)."""
    from marlin_aio.farm.supervisor import PrinterSpec

    from .command import run_serve

    if duration is not None and not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration:g}", Exit.USAGE)
    if sim and sims:
        fail("--sim is one simulated printer and --sims N several: give one of them", Exit.USAGE)
    simulated = [PrinterSpec("sim", None, poll_interval_s=interval, sim=True, sim_speed=sim_speed)] if sim else []
    specs = printer_specs(ports, config, sims, baud=baud, interval_s=interval, sim_speed=sim_speed, more=simulated)
    listen = None
    if tcp is not None:
        listen = _address(tcp, "--tcp")
    elif token_file is not None:
        fail("--token-file goes with --tcp", Exit.USAGE)
    http = None
    if octoprint is not None:
        import importlib.util

        if importlib.util.find_spec("aiohttp") is None:
            fail("--octoprint needs aiohttp, which is not installed: pip install 'marlin-aio[serve]'")
        http = _address(octoprint, "--octoprint")
    elif octoprint_printer is not None or api_key_file is not None:
        fail("--octoprint-printer and --api-key-file go with --octoprint", Exit.USAGE)
    if no_log and log_dir is not None:
        fail("--no-log and --log-dir do not go together", Exit.USAGE)
    from .command import ServeOptions, default_log_dir

    options = ServeOptions(
        http=http,
        http_printer=octoprint_printer,
        key_file=api_key_file,
        tcp=listen,
        token_file=token_file,
        log_dir=None if no_log else (log_dir or default_log_dir()),
        log_interval_s=log_interval,
        wire_log=checked_wire_log(wire_log),
        leave_heaters=leave_heaters,
    )
    run(run_serve(specs, socket, duration, error_console(), options))


def _address(text: str, option: str) -> tuple[str, int]:
    """`[HOST:]PORT` as (host, port), 127.0.0.1 when no host is given; a bad one exits 2 with one line."""
    host, _, port_text = text.rpartition(":")
    if not port_text.isdigit() or not 0 < int(port_text) < 65536:
        fail(f"{option} {text!r}: give [HOST:]PORT, a port from 1 to 65535", Exit.USAGE)
    return host.strip("[]") or "127.0.0.1", int(port_text)
