"""The command lines of `marlin-temp ports` (the serial ports, printer bridges marked) and `marlin-temp sim` (the
simulated printer, for other programs).

`sim` takes the options of `marlin-sim`, made into typer options from the simulator's one table of them
(`SIMULATOR_OPTIONS`, which `marlin_aio.simulator.__main__` exports for this): each row gives its flag, its help
text with its default (`option_help`), and the function that reads its value, here run as a typer callback so a
bad value is a usage error like any other command's (one line, exit 2). A row added to that table shows up in
both commands with nothing to change here. The values given go through `settings_from_values`, as marlin-sim's do.
The command is made when `sim` is called (`sim_command`), so the other commands never import the simulator.
"""

from __future__ import annotations

import argparse
import functools
import inspect
import json
from collections.abc import Callable
from typing import Annotated, Any

import typer
from rich.console import Console

import marlin_aio

from ..common.connect import Exit
from ..common.options import fail

__all__ = ["PORTS_HELP", "SIM_EPILOG", "SIM_HELP", "port_record", "ports", "sim_command", "simulate"]

PORTS_HELP = (
    "List serial ports, marking the USB bridges printer boards use (CH340, CP2102, FTDI, STM32, Mega).\n\n--json "
    'prints them as one JSON object: {"ports": [{"device", "description", "vid", "pid", "usb_id", "bridge", '
    '"likely_printer"}, ...]}, the USB ids in hex as lsusb shows them (null for a port that is not USB).'
)


def ports(
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object instead of the table.")] = False,
) -> None:
    """List serial ports (the help text is `PORTS_HELP`)."""
    found = marlin_aio.list_ports()
    if as_json:
        typer.echo(json.dumps({"ports": [port_record(info) for info in found]}))
        return
    from rich.table import Table

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


def port_record(info: marlin_aio.PortInfo) -> dict[str, object]:
    """One port as `ports --json` prints it: the USB vendor and product ids as lsusb writes them (hex, "1a86"),
    null for a port that is not USB."""
    vid, pid = info.usb_id.split(":") if info.usb_id else (None, None)
    return {
        "device": info.device,
        "description": info.description,
        "vid": vid,
        "pid": pid,
        "usb_id": info.usb_id,
        "bridge": info.bridge,
        "likely_printer": info.likely_printer,
    }


# ------------------------------------------------------------------------------------------- sim

SIM_HELP = "\n\n".join(
    (
        "Run the simulated printer on a pseudo-terminal (or TCP) and print its address; Ctrl-C stops it.",
        "The first line on stdout is the URL to open (a device path, or socket://127.0.0.1:PORT with --tcp; one per "
        "printer with --printers N): give it to any host program, e.g. marlin-temp watch --port PATH. The options "
        "are marlin-sim's: one definition serves both commands.",
    )
)
SIM_EPILOG = "Exit codes: 0 stopped (Ctrl-C or SIGTERM); 1 could not serve (no pty, port in use); 2 bad arguments."


def _simulator_parameters() -> tuple[list[inspect.Parameter], dict[str, str]]:
    """The typer parameters of `sim`, one per option of the simulator's table (and a hidden one per older name),
    and which option each parameter's name stands for (its `dest`)."""
    from marlin_aio.simulator.__main__ import GROUP_DESCRIPTIONS, SIMULATOR_OPTIONS, option_help

    parameters: list[inspect.Parameter] = []
    dests: dict[str, str] = {}
    for option in SIMULATOR_OPTIONS:
        panel = f"{option.group.capitalize()}: {GROUP_DESCRIPTIONS[option.group]}" if option.group else None
        for index, flag in enumerate((option.flag, *option.aliases)):
            name = option.dest if index == 0 else f"{option.dest}__{index}"
            dests[name] = option.dest
            shared: dict[str, Any] = {"hidden": index > 0, "rich_help_panel": panel, "show_default": False}
            if option.parse is None:
                annotation: Any = Annotated[bool, typer.Option(flag, help=option_help(option), **shared)]
                default: object = False
            else:
                check = _reader(option.parse, option.choices)
                metavar = option.metavar or flag.lstrip("-").upper()
                annotation = Annotated[
                    str | None,
                    typer.Option(flag, help=option_help(option), metavar=metavar, callback=check, **shared),
                ]
                default = None
            parameters.append(
                inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)
            )
    return parameters, dests


def _reader(parse: Callable[[str], object], choices: object) -> Callable[[object], object]:
    """A typer callback that reads an option's text with the table's `parse`: a value it refuses is a usage error
    (one line, exit 2), in the words marlin-sim uses."""

    def read(value: object) -> object:
        if value is None:
            return None
        text = str(value)
        try:
            parsed = parse(text)
        except argparse.ArgumentTypeError as exc:
            raise typer.BadParameter(str(exc)) from None
        except ValueError:
            raise typer.BadParameter(f"not a {getattr(parse, '__name__', 'valid value')}: {text!r}") from None
        if choices is not None and parsed not in choices:  # type: ignore[operator]
            raise typer.BadParameter(f"{parsed} is not one of {_choices_text(choices)}")
        return parsed

    return read


def _choices_text(choices: object) -> str:
    if isinstance(choices, range):
        return f"{choices.start}-{choices.stop - 1}"
    return ", ".join(str(choice) for choice in choices)  # type: ignore[attr-defined]


def _run(values: dict[str, object], dests: dict[str, str]) -> None:
    from marlin_aio.simulator.__main__ import SIMULATOR_OPTIONS, serve_until_stopped, settings_from_values

    given: dict[str, object] = {}
    for name, value in values.items():
        # A flag not given and a value not given stay out: their fields keep the defaults (an older name of an
        # option gives the same dest).
        if value is not None and value is not False:
            given[dests[name]] = value
    for option in SIMULATOR_OPTIONS:
        if option.negated and option.dest in given:
            given[option.dest] = False  # --no-bed: has_bed off
    try:
        settings = settings_from_values(given)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    raise typer.Exit(serve_until_stopped(settings, prog="marlin-temp sim"))


@functools.cache
def sim_command() -> Any:  # Any: click's types differ between typer releases
    """The `sim` command, made the first time it runs: its options are read from the simulator's table, and
    importing the simulator (a tenth of a second) is for `sim` alone, not for the start of every other command."""
    parameters, dests = _simulator_parameters()

    def simulate(**values: object) -> None:
        _run(values, dests)

    # Typer reads a command's options from its signature: this one is made from the table.
    simulate.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
    simulate.__annotations__ = {parameter.name: parameter.annotation for parameter in parameters}
    made = typer.Typer(add_completion=False)
    made.command("sim", help=SIM_HELP, epilog=SIM_EPILOG)(simulate)
    return typer.main.get_command(made)


def simulate() -> None:
    """`marlin-temp sim` as `marlin-temp --help` lists it, with no options: the command that runs is
    `sim_command()`, which the command group puts in its place when `sim` is called."""
    sim_command().main(args=[], prog_name="marlin-temp sim")  # the simulator with its defaults, if ever called
