"""The printers of a command that runs many (`farm`, `serve`): `--port NAME=PORT`, `--config FILE`, `--sims N`,
each polled every `--interval`; made into the farm's `PrinterSpec`s in one place."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

import marlin_aio

from .connect import PASSWORD_ENV, Exit
from .options import fail

if TYPE_CHECKING:
    from marlin_aio.farm.supervisor import PrinterSpec

__all__ = ["ConfigOption", "IntervalOption", "PortsOption", "SimsOption", "printer_specs"]

PortsOption = Annotated[
    list[str] | None, typer.Option("--port", "-p", help="A printer as NAME=PORT (or just PORT); repeatable.")
]
ConfigOption = Annotated[Path | None, typer.Option("--config", help="TOML file listing the printers.")]
SimsOption = Annotated[int, typer.Option("--sims", help="N simulated printers (sim1, sim2, ...).", min=0, metavar="N")]
IntervalOption = Annotated[
    float, typer.Option("--interval", help="Seconds between M105 polls of each printer.", min=0.005)
]


def printer_specs(
    ports: list[str] | None,
    config: Path | None,
    sims: int,
    *,
    baud: int | None,
    interval_s: float,
    sim_speed: float,
    more: Sequence[PrinterSpec] = (),
) -> list[PrinterSpec]:
    """The printers of the config file, `more`, then `--port` and `--sims` (those only when given, or when nothing
    else is); a bad name, a name or port given twice, or an unreadable file exits 2 with one line."""
    from marlin_aio.farm.config import check_unique, load_config, specs_from_options

    try:
        specs = [*(load_config(config) if config is not None else []), *more]
        if ports or sims or not specs:
            # A locked printer on --port is unlocked with $MARLIN_PASSWORD, as every other command does (the error
            # of a locked printer says to set it); a config file's printers carry their own `password`.
            password = os.environ.get(PASSWORD_ENV) or None
            specs += [
                spec if spec.sim else dataclasses.replace(spec, password=password)
                for spec in specs_from_options(
                    ports or [],
                    sims,
                    baud=baud or marlin_aio.DEFAULT_BAUDRATE,
                    poll_interval_s=interval_s,
                    sim_speed=sim_speed,
                )
            ]
        return check_unique(specs)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{config}: {exc.strerror or exc}", Exit.USAGE)
