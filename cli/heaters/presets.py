"""`marlin-temp presets`: list the presets and the file they come from; `--init` writes the default file.

The presets are the heaters' named targets (`set --preset NAME`, watch's keys 1-9, the farm's `preset` command),
so the command lives with `set`. It talks to no printer.
"""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from marlin_aio.farm.presets import DEFAULT_PRESETS, presets_toml

from ..common.connect import Exit
from ..common.options import error_console, fail
from ..common.presets import PresetsFile, PresetsOption, load_presets_file, presets_path

__all__ = ["PRESETS_HELP", "presets"]

WATCH_KEYS = 9
"""Watch gives the first nine presets the keys 1-9."""

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
PRESETS_HELP = "\n\n".join(
    (
        "List the presets (named hotend and bed targets) and the file they come from; --init writes the default file.",
        "The presets file is TOML: one \\[preset.NAME] table per preset, with hotend = C and/or bed = C (0 turns "
        "that heater off), e.g. \\[preset.PLA] hotend = 200, bed = 60 on lines of their own. It is --presets FILE, "
        "else $MARLIN_TEMP_PRESETS, else presets.toml in $XDG_CONFIG_HOME/marlin-temp/ (~/.config/marlin-temp/). "
        "With no file the presets are PLA 200/60 C, PETG 240/80 C, ABS 250/100 C and cooldown 0/0 C, which is "
        "what --init writes.",
        "set --preset NAME sets one (the name in any case); watch's keys 1-9 are the first nine, in the file's "
        'order; marlin-temp farm takes {"action": "preset", "name": NAME} commands. A preset above a '
        "printer's limits (--max-hotend, --max-bed) is refused when it is used.",
    )
)


def presets(
    init: Annotated[
        bool, typer.Option("--init", help="Write the default presets to the file (never over an existing one).")
    ] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print the presets as one JSON object.")] = False,
    presets_file: PresetsOption = None,
) -> None:
    """List the presets and their file; write the default file (the help text is `PRESETS_HELP`)."""
    if init:
        path, _ = presets_path(presets_file)
        if path.exists():
            fail(f"{path} exists already; not overwritten (edit it, or remove it first)", Exit.USAGE)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # "x": should another process write the file meanwhile, that one stays.
            with path.open("x", encoding="utf-8") as file:
                file.write(presets_toml(DEFAULT_PRESETS))
        except OSError as exc:
            fail(f"{path}: {exc.strerror or exc}", Exit.USAGE)
        error_console().print(f"wrote the default presets to {path}", style="dim", markup=False)
    loaded = load_presets_file(presets_file)
    console = Console(highlight=False, emoji=False)
    if json_output:
        typer.echo(json.dumps(presets_json(loaded)))
        return
    console.print(f"presets: {loaded.source}", markup=False, soft_wrap=True)
    table = Table(box=None, pad_edge=False)
    for column in ("key", "name", "hotend", "bed"):
        table.add_column(column, justify="right" if column in ("hotend", "bed") else "left")
    for index, preset in enumerate(loaded.presets, 1):
        key = str(index) if index <= WATCH_KEYS else ""
        cells = [
            f"{celsius:g} C" if celsius is not None else "-" for celsius in (preset.hotend_celsius, preset.bed_celsius)
        ]
        table.add_row(key, preset.name, *cells)
    console.print(table)
    if not loaded.exists:
        console.print(f"marlin-temp presets --init writes them to {loaded.path} to edit", markup=False, soft_wrap=True)


def presets_json(loaded: PresetsFile) -> dict[str, Any]:
    """`presets --json`: the file (and whether it exists) and each preset with its watch key (None past 9)."""
    return {
        "file": str(loaded.path),
        "exists": loaded.exists,
        "presets": [
            {
                "key": str(index) if index <= WATCH_KEYS else None,
                "name": preset.name,
                "hotend": preset.hotend_celsius,
                "bed": preset.bed_celsius,
            }
            for index, preset in enumerate(loaded.presets, 1)
        ],
    }
