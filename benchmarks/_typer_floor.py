"""The floor of a typer + rich command line's start-up: two commands with options and rich help, nothing else.

`python -m benchmarks --only startup` times `python benchmarks/_typer_floor.py --help` beside `marlin-temp --help`:
what any CLI built on the design card's typer and rich pays before it does a thing of its own.
"""

from typing import Annotated

import typer

app = typer.Typer(rich_markup_mode="rich", help="The floor: a typer app with [bold]rich[/] help.")


@app.command()
def watch(port: Annotated[str, typer.Option(help="The port.")] = "sim") -> None:
    """Watch the temperatures."""


@app.command(name="set")
def set_targets(hotend: Annotated[float, typer.Option(help="Hotend target.")] = 0.0) -> None:
    """Set the targets."""


if __name__ == "__main__":
    app()
