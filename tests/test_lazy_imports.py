"""The packages import their names on first use (`marlin_aio._lazy`): what the type checker reads and what runs
agree, every exported name resolves to its module's object, and a program pays only for what it uses (`import
marlin_aio` and `marlin-temp --help` load neither the client nor the core)."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGES = ("marlin_aio", "marlin_aio.protocol", "marlin_aio.aio")


def _type_checking_imports(package: str) -> dict[str, tuple[str, ...]]:
    """The `from M import a, b` lines under `if TYPE_CHECKING:` in the package's `__init__`, by module."""
    module = importlib.import_module(package)
    assert module.__file__ is not None
    tree = ast.parse(Path(module.__file__).read_text())
    found: dict[str, tuple[str, ...]] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for line in node.body:
                assert isinstance(line, ast.ImportFrom) and line.module is not None
                found[line.module] = found.get(line.module, ()) + tuple(alias.name for alias in line.names)
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_the_lazy_table_is_what_the_type_checker_reads_and_every_name_resolves(package: str) -> None:
    module = importlib.import_module(package)
    table: dict[str, tuple[str, ...]] = module._EXPORTS
    assert table == _type_checking_imports(package)
    names = {name for names in table.values() for name in names}
    assert names <= set(module.__all__)
    assert set(dir(module)) >= set(module.__all__)
    for origin, exported in table.items():
        for name in exported:
            assert getattr(module, name) is getattr(importlib.import_module(origin), name), name
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        _ = module.no_such_name


def _loaded_after(code: str) -> set[str]:
    script = f"import sys\n{code}\nprint(' '.join(sorted(sys.modules)))"
    completed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    return set(completed.stdout.split())


#: What a program that only imports, or only asks for help, must not load.
HEAVY = {
    "asyncio",
    "marlin_aio.aio.printer",
    "marlin_aio.protocol.connection",
    "marlin_aio.farm.supervisor",
    "marlin_aio.simulator",
    "serial",
}


def test_import_marlin_aio_loads_nothing_it_does_not_use() -> None:
    assert not _loaded_after("import marlin_aio") & HEAVY
    # The first use loads the client, once; the core alone never loads asyncio.
    assert "marlin_aio.aio.printer" in _loaded_after("import marlin_aio; marlin_aio.connect")
    assert "asyncio" not in _loaded_after("import marlin_aio.protocol; marlin_aio.protocol.Connection")


def test_marlin_temp_help_loads_neither_the_client_nor_the_core() -> None:
    code = (
        "from typer.testing import CliRunner\nfrom marlin_temp.main import app\n"
        "assert CliRunner().invoke(app, ['--help']).exit_code == 0"
    )
    assert not _loaded_after(code) & (HEAVY - {"asyncio"})  # typer's test runner may load asyncio itself
