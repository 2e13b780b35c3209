"""Where the presets file is and how a command loads it (`marlin_aio.farm.presets` reads it): `--presets FILE`,
else `$MARLIN_TEMP_PRESETS`, else `presets.toml` in the user's config folder (`$XDG_CONFIG_HOME/marlin-temp/`, or
`~/.config/marlin-temp/`).

That last one may be missing: then the presets are the defaults (`DEFAULT_PRESETS`, what `marlin-temp presets
--init` writes there). A file named by the option or the variable must exist. Anything wrong with the file is one
line naming it, the preset and the key, and exit code 2, before the command connects to anything.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer

from marlin_aio.farm.presets import DEFAULT_PRESETS, Preset, load_presets

from .connect import Exit
from .options import fail

__all__ = ["PRESETS_ENV", "PresetsFile", "PresetsOption", "default_presets_path", "load_presets_file", "presets_path"]

PRESETS_ENV = "MARLIN_TEMP_PRESETS"
"""The environment variable naming the presets file (`--presets` overrides it)."""

PresetsOption = Annotated[
    Path | None,
    typer.Option(
        "--presets",
        help=f"The presets file (TOML). Default: ${PRESETS_ENV}, else $XDG_CONFIG_HOME/marlin-temp/presets.toml "
        "(~/.config/marlin-temp/presets.toml); with no file, PLA, PETG, ABS and cooldown.",
        show_default=False,
        metavar="FILE",
    ),
]


@dataclass(frozen=True)
class PresetsFile:
    """The presets in use and where they come from."""

    path: Path
    """The file in use, or the one that would be (the default place, where `presets --init` writes)."""
    presets: tuple[Preset, ...]
    exists: bool
    """False: there is no file at `path`, and the presets are the defaults."""

    @property
    def source(self) -> str:
        """Where the presets come from, for messages: the file, or "the default presets (no PATH)"."""
        return str(self.path) if self.exists else f"the default presets (no {self.path})"


def default_presets_path() -> Path:
    """`presets.toml` in the user's config folder: `$XDG_CONFIG_HOME/marlin-temp/`, else `~/.config/marlin-temp/`."""
    config_home = os.environ.get("XDG_CONFIG_HOME", "")
    # The XDG spec says a relative $XDG_CONFIG_HOME is invalid and to be ignored.
    base = Path(config_home) if os.path.isabs(config_home) else Path.home() / ".config"
    return base / "marlin-temp" / "presets.toml"


def presets_path(option: Path | None) -> tuple[Path, bool]:
    """The presets file to use, and whether the user named it (`--presets`, `$MARLIN_TEMP_PRESETS`)."""
    if option is not None:
        return option, True
    named = os.environ.get(PRESETS_ENV)
    if named:
        return Path(named).expanduser(), True
    return default_presets_path(), False


def load_presets_file(option: Path | None) -> PresetsFile:
    """The presets of the file in use (the defaults when the default file does not exist); a file the user named
    that is missing, unreadable or not a valid presets file fails with one line and exit code 2."""
    path, named = presets_path(option)
    flag = "--presets" if option is not None else f"${PRESETS_ENV}" if named else "presets file"
    if not path.exists() and not named:
        return PresetsFile(path, DEFAULT_PRESETS, exists=False)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "does not exist"
        fail(f"{flag} {path} {what} (marlin-temp presets --init writes one)", Exit.USAGE)
    try:
        presets = load_presets(path)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{flag} {path}: {exc.strerror or exc}", Exit.USAGE)
    return PresetsFile(path, presets, exists=True)
