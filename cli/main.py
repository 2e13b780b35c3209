"""The `marlin-temp` command."""

from __future__ import annotations

from typing import Annotated

import typer

from marlin_aio import __version__

app = typer.Typer(
    name="marlin-temp",
    help="Watch, set and log the temperatures of a Marlin 3D printer.",
    no_args_is_help=True,
)


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"marlin-temp {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Watch, set and log the temperatures of a Marlin 3D printer."""
