"""The command lines of `marlin-temp ports` (the serial ports, printer bridges marked) and `marlin-temp sim` (the
simulator's own command line, `marlin-sim`, under marlin-temp)."""

from __future__ import annotations

import typer
from rich.console import Console

import marlin_aio

__all__ = ["SIM_CONTEXT", "ports", "simulate"]


def ports() -> None:
    """List serial ports, marking the USB bridges printer boards use (CH340, CP2102, FTDI, STM32, Mega)."""
    from rich.table import Table

    found = marlin_aio.list_ports()
    console = Console(highlight=False, emoji=False)
    if not found:
        console.print("no serial ports found")
        return
    table = Table(box=None, header_style="bold")
    for column in ("port", "description", "usb id", "printer bridge"):
        table.add_column(column)
    for info in found:
        style = "bold" if info.likely_printer else "dim"
        table.add_row(info.device, info.description, info.usb_id or "-", info.bridge or "-", style=style)
    console.print(table)


#: `sim` passes every argument, --help included, on to the simulator's parser.
SIM_CONTEXT = {"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []}


def simulate(ctx: typer.Context) -> None:
    """Run the simulated printer on a pseudo-terminal (or TCP) and print its address; Ctrl-C stops it.

    Takes every marlin-sim option (marlin-temp sim --help lists them): one definition serves both commands. Open
    the printed device path (or socket:// URL) with any host program, e.g. marlin-temp watch --port PATH.
    """
    from marlin_aio.simulator.__main__ import main as simulator_main

    # --sim-speed, as in every other command (the older --speed and --time-scale are still accepted).
    raise typer.Exit(simulator_main(ctx.args, prog="marlin-temp sim"))
