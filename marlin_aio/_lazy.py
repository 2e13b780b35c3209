"""A package's names imported on first use (PEP 562), so `import marlin_aio` costs what is used, not everything.

A program that reads one constant (the CLI's `--help` reads the default baud rate) does not pay for the asyncio
client, the core and the parsers; the first access to `marlin_aio.connect` imports them, once. The packages list
each name with its module twice: for the type checker, as plain imports under `TYPE_CHECKING`, and for the
runtime, in the table given here; `tests/test_lazy_imports.py` checks the two agree.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, exports: dict[str, tuple[str, ...]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The `__getattr__` and `__dir__` of `package`, which exports the names `exports` lists by module.

    A name is imported from its module on first access and then kept in the package (the next access is a plain
    attribute). Another name that is a submodule of `package` is imported, as `import package.name` would.
    """
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is not None:
            value = getattr(importlib.import_module(module), name)
            setattr(sys.modules[package], name, value)
            return value
        if not name.startswith("__"):  # dunders are asked for by tools (`__wrapped__`, ...): never a submodule
            try:
                return importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise  # the submodule exists and failed to import something: that is its error
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(where) | set(vars(sys.modules[package])))

    return __getattr__, __dir__
