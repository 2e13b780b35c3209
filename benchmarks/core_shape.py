"""The protocol core's shape, measured: its mutable fields by owner, the writes into another part's fields, and the
files one `ok` crosses on its way from the port to its caller.

    python -m benchmarks.core_shape

Issue 34 asks that each part of the core own its fields (nothing writes another's) and that an `ok` cross few
files; this prints both, so a change to the core can be measured the same way every time:

- **fields by owner**: every attribute a class of `marlin_aio/protocol` assigns on `self` (or declares as a field
  of a dataclass that is not frozen), per class;
- **foreign writes**: assignments `x.attr = ...` (and `x.attr += ...`) in `marlin_aio/protocol` where `x` is not
  `self`: a part writing another's field;
- **the path of an ok**: the files of `marlin_aio` whose functions run, in order, from the moment the client's link
  is handed the bytes of an `ok` (`Link.data_received`) until the caller's `send` has its reply, for one `G1` on
  the simulated printer (in memory, simulated time; the simulator's own files are not counted).
"""

from __future__ import annotations

import ast
import asyncio
import os
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, run_in_simulated_time, serve_memory

PACKAGE = Path(marlin_aio.__file__).parent
CORE = PACKAGE / "protocol"


def _frozen(node: ast.ClassDef) -> bool:
    for decorator in node.decorator_list:
        if isinstance(decorator, ast.Call):
            for keyword in decorator.keywords:
                if keyword.arg == "frozen" and isinstance(keyword.value, ast.Constant) and keyword.value.value:
                    return True
    return False


def _is_dataclass(node: ast.ClassDef) -> bool:
    for decorator in node.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        if isinstance(target, ast.Name) and target.id == "dataclass":
            return True
    return False


def _stored_attributes(tree: ast.AST) -> list[ast.Attribute]:
    """Every `x.attr` that an assignment in `tree` stores to (`=`, an annotated `=`, `+=`)."""
    stored: list[ast.Attribute] = []
    for node in ast.walk(tree):
        targets: list[ast.expr] = []
        if isinstance(node, ast.Assign):
            targets = list(node.targets)
        elif isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        for target in targets:
            stored.extend(
                leaf for leaf in ast.walk(target) if isinstance(leaf, ast.Attribute) and isinstance(leaf.ctx, ast.Store)
            )
    return stored


def _on_self(attribute: ast.Attribute) -> bool:
    return isinstance(attribute.value, ast.Name) and attribute.value.id == "self"


def fields_by_owner() -> dict[str, set[str]]:
    """`module.Class` -> the mutable fields it owns."""
    owners: dict[str, set[str]] = {}
    for path in sorted(CORE.glob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.ClassDef):
                continue
            fields: set[str] = set()
            if _is_dataclass(node) and not _frozen(node):
                for item in node.body:
                    if (
                        isinstance(item, ast.AnnAssign)
                        and isinstance(item.target, ast.Name)
                        and "ClassVar" not in ast.unparse(item.annotation)
                    ):
                        fields.add(item.target.id)
            fields.update(
                leaf.attr
                for leaf in _stored_attributes(node)
                if isinstance(leaf.value, ast.Name) and leaf.value.id == "self"
            )
            if fields:
                owners[f"{path.stem}.{node.name}"] = fields
    return owners


def _fresh_instances(tree: ast.AST) -> set[str]:
    """Names bound to `cls.__new__(cls)` in a class's own methods: an instance the class is building (a
    constructor that skips `__init__`), whose fields are its own to write."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Assign)
            and isinstance(node.value, ast.Call)
            and ast.unparse(node.value) == "cls.__new__(cls)"
        ):
            names.update(target.id for target in node.targets if isinstance(target, ast.Name))
    return names


def foreign_writes() -> dict[str, int]:
    """`module` -> how many assignments it makes to an attribute of something that is not `self` (nor an instance
    its own class is building)."""
    counts: dict[str, int] = {}
    for path in sorted(CORE.glob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        fresh = _fresh_instances(tree)
        foreign = sum(
            not _on_self(leaf) and not (isinstance(leaf.value, ast.Name) and leaf.value.id in fresh)
            for leaf in _stored_attributes(tree)
        )
        if foreign:
            counts[path.stem] = foreign
    return dict(counts)


async def _ok_path() -> list[str]:
    link_file = str(PACKAGE / "aio" / "link.py")  # the client's link, found by name: not a public module
    seen: list[str] = []
    recording = False

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        nonlocal recording
        if event != "call":
            return
        code = frame.f_code
        if code.co_name == "data_received" and code.co_filename == link_file:
            recording = True
        filename = code.co_filename
        if recording and filename.startswith(str(PACKAGE)) and f"{os.sep}simulator{os.sep}" not in filename:
            name = os.path.relpath(filename, PACKAGE)
            if not seen or seen[-1] != name:
                seen.append(name)

    async with (
        serve_memory(SimulatorConfig(motion_time_scale=0.0), Faults()) as server,
        marlin_aio.connect(server.url) as printer,
    ):
        await printer.send("G1 X1")
        task = asyncio.ensure_future(printer.send("G1 X2"))
        sys.setprofile(profile)
        try:
            await task
        finally:
            sys.setprofile(None)
    return seen


def main() -> None:
    owners = fields_by_owner()
    total = sum(len(fields) for fields in owners.values())
    print(f"mutable fields of marlin_aio/protocol: {total}, by owner:")
    for owner, fields in sorted(owners.items(), key=lambda item: -len(item[1])):
        print(f"  {len(fields):3d}  {owner}: {', '.join(sorted(fields))}")
    writes = foreign_writes()
    print(f"writes into another's fields (x.attr = ..., x not self): {sum(writes.values())}")
    for module, count in sorted(writes.items(), key=lambda item: -item[1]):
        print(f"  {count:3d}  {module}")
    path = run_in_simulated_time(_ok_path())
    files = list(dict.fromkeys(path))
    core = [name for name in files if name.startswith("protocol")]
    reentered = sorted({name for name in path if path.count(name) > 1})
    print(f"one ok, port to caller: {len(files)} files ({len(core)} of the core), re-entering {len(reentered)}:")
    print("  " + " -> ".join(path))


if __name__ == "__main__":
    main()
