"""The `marlin-temp` entry point: the command line, or one line saying which extra to install.

`pip install marlin-aio` installs the library alone (pyserial-asyncio-fast); the command line's packages (typer,
rich, prompt_toolkit) come with `pip install 'marlin-aio[cli]'`. The `marlin-temp` script is installed either way,
so without them it says what to install instead of a traceback.
"""

from __future__ import annotations

import sys

__all__ = ["main"]

_CLI_PACKAGES = {"typer", "rich", "prompt_toolkit", "click"}


def main() -> None:
    """Run marlin-temp."""
    try:
        from marlin_temp.main import app
    except ModuleNotFoundError as exc:
        if exc.name not in _CLI_PACKAGES:
            raise
        sys.stderr.write(
            f"marlin-temp: the command line needs {exc.name}, which is not installed: pip install 'marlin-aio[cli]'\n"
        )
        raise SystemExit(1) from None
    app()
