"""The rules of the layout (docs/architecture.md), checked on the source: the protocol core does no I/O, and the
CLI and the benchmarks use only the library's public names."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import marlin_aio
import marlin_aio.simulator

ROOT = Path(__file__).resolve().parent.parent

#: The sans-I/O core: bytes and times in, bytes and results out. Nothing here may import asyncio or serial.
CORE = (
    "commands",
    "connection",
    "corestate",
    "deadlines",
    "errors",
    "events",
    "framing",
    "heaters",
    "linkstate",
    "matching",
    "motion",
    "parsing",
    "printjob",
    "receiving",
    "replies",
    "resends",
    "states",
    "stats",
    "streaming",
    "temperatures",
    "trace",
)

#: Modules outside the package's public names that the CLI may still name: the simulator's command line.
ALLOWED_MODULES = {"marlin_aio.simulator.__main__"}


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) for every import in `path`, nested ones included."""
    found: list[tuple[str, list[str]]] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.extend((alias.name, []) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module is not None and node.level == 0:
            found.append((node.module, [alias.name for alias in node.names]))
    return found


@pytest.mark.parametrize("module", CORE)
def test_the_core_does_no_io(module: str) -> None:
    path = ROOT / "marlin_aio" / "protocol" / f"{module}.py"
    for name, _ in imports(path if path.exists() else ROOT / "marlin_aio" / f"{module}.py"):
        assert name.split(".")[0] not in {"asyncio", "serial", "serial_asyncio", "serial_asyncio_fast", "socket"}, (
            f"marlin_aio/{module}.py imports {name}"
        )


@pytest.mark.parametrize("path", sorted([*ROOT.glob("cli/**/*.py"), *ROOT.glob("benchmarks/*.py")]), ids=str)
def test_the_cli_and_the_benchmarks_use_only_public_names(path: Path) -> None:
    public = {"marlin_aio": set(marlin_aio.__all__), "marlin_aio.simulator": set(marlin_aio.simulator.__all__)}
    for module, names in imports(path):
        if not module.startswith("marlin_aio") or module in ALLOWED_MODULES or module.startswith("marlin_aio.farm."):
            continue
        assert module in public, f"{path.name} imports the private module {module}"
        private = [name for name in names if name not in public[module]]
        assert not private, f"{path.name} imports {private} from {module}, which does not export them"
