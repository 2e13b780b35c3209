"""The rules of the layout (docs/architecture.md), checked on the source: each folder of the library imports only
the folders before it, the protocol folder does no I/O (no port, socket, clock or file), the library never imports
the CLI's front ends, and the CLI and the benchmarks use only the library's public names."""

from __future__ import annotations

import ast
import importlib
import inspect
import sys
import typing
from pathlib import Path

import pytest

import marlin_aio
import marlin_aio.protocol

ROOT = Path(__file__).resolve().parent.parent

#: What each folder of the library may import from the library, and from outside the standard library. A folder
#: reads only from the ones before it: errors <- protocol <- aio <- (farm, simulator) <- service. `marlin_aio`
#: alone means the package's public names (its __init__).
LAYERS: dict[str, tuple[set[str], set[str]]] = {
    # `marlin_aio._lazy` sits with the errors, below everything: the packages' names imported on first use.
    "protocol": ({"marlin_aio.errors", "marlin_aio._lazy", "marlin_aio.protocol"}, set()),
    "aio": (
        {"marlin_aio.errors", "marlin_aio._lazy", "marlin_aio.protocol", "marlin_aio.aio"},
        {"serial", "serial_asyncio_fast"},
    ),
    # Of the asyncio client, only the in-memory transport: a memory link is one pair of transports, the simulator
    # listening on one end (serve_memory) and the client on the other, so both sides share that one module.
    "simulator": (
        {"marlin_aio.errors", "marlin_aio.protocol", "marlin_aio.simulator", "marlin_aio.aio.memory"},
        {"serial"},
    ),
    "farm": (
        {
            "marlin_aio",
            "marlin_aio.aio",
            "marlin_aio.errors",
            "marlin_aio.farm",
            "marlin_aio.protocol",
            "marlin_aio.simulator",
            # The MQTT door (the bridge's commands) calls the service's table of verbs, as every door does; the
            # farm's supervisor and jobs never import the service (the import circle check below holds that).
            "marlin_aio.service.verbs",
        },
        # paho-mqtt is aiomqtt's own MQTT client, which the bridge hands its telemetry batches to; orjson is
        # optional (the `fast` extra).
        {"aiomqtt", "paho", "orjson"},
    ),
    # The service is the farm's supervisor shared on a socket: it may import the farm, never its MQTT bridge's
    # library (a service without the [farm] extra still runs).
    "service": (
        {
            "marlin_aio",
            "marlin_aio.aio",
            "marlin_aio.errors",
            # The farm's printers, their print jobs and presets: what the service owns and its verbs act on.
            "marlin_aio.farm.supervisor",
            "marlin_aio.farm.job",
            "marlin_aio.farm.presets",
            "marlin_aio.protocol",
            "marlin_aio.service",
            "marlin_aio.simulator",
        },
        {"aiohttp"},
    ),
}

#: The sans-I/O core touches no port, socket, clock or file: these modules, and these calls, are not for it.
NO_IO_MODULES = {"asyncio", "serial", "serial_asyncio", "serial_asyncio_fast", "socket", "os", "io", "subprocess"}
NO_IO_CALLS = {"open", "read_text", "write_text", "read_bytes", "write_bytes", "stat", "fstat", "time", "monotonic"}

#: Never imported by the library, whatever the folder: the CLI's and the farm's front ends.
FRONT_ENDS = {"typer", "rich", "prompt_toolkit", "marlin_temp", "cli"}

#: The modules whose `__all__` the CLI and the benchmarks may import from.
PUBLIC_MODULES = (
    "marlin_aio",
    "marlin_aio.protocol",
    "marlin_aio.aio",
    "marlin_aio.simulator",
    "marlin_aio.farm.bridge",
    "marlin_aio.farm.commands",
    "marlin_aio.farm.config",
    "marlin_aio.farm.presets",
    "marlin_aio.farm.supervisor",
    "marlin_aio.service",
)

#: Modules outside the package's public names that the CLI may still name: the simulator's command line.
ALLOWED_MODULES = {"marlin_aio.simulator.__main__"}

STDLIB = set(sys.stdlib_module_names)


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) for every import in `path`, nested ones included."""
    found: list[tuple[str, list[str]]] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.extend((alias.name, []) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module is not None and node.level == 0:
            found.append((node.module, [alias.name for alias in node.names]))
    return found


def library_files(folder: str) -> list[Path]:
    return sorted((ROOT / "marlin_aio" / folder).glob("*.py"))


#: Modules that are clients of the library, as an application is, and may import its face (`marlin_aio`) beyond
#: their folder's layer: the client campaign runs `marlin_aio.connect()` against the simulator. Nothing of their
#: folder imports them but its command lines (the simulator's `__init__` never does).
CLIENTS_OF_THE_LIBRARY = {"simulator/_clientcampaign.py": {"marlin_aio"}}


@pytest.mark.parametrize("folder", sorted(LAYERS))
def test_each_folder_imports_only_the_folders_before_it(folder: str) -> None:
    for path in library_files(folder):
        allowed, third_party = LAYERS[folder]
        allowed = allowed | CLIENTS_OF_THE_LIBRARY.get(f"{folder}/{path.name}", set())
        for name, _ in imports(path):
            top = name.split(".")[0]
            where = f"marlin_aio/{folder}/{path.name} imports {name}"
            if top == "marlin_aio":
                assert (name == "marlin_aio" and "marlin_aio" in allowed) or any(
                    name == layer or name.startswith(layer + ".") for layer in allowed - {"marlin_aio"}
                ), where
            else:
                assert top in STDLIB or top in third_party, where


def test_the_protocol_folder_does_no_io() -> None:
    for path in library_files("protocol"):
        for name, _ in imports(path):
            assert name.split(".")[0] not in NO_IO_MODULES, f"marlin_aio/protocol/{path.name} imports {name}"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call):
                called = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", None)
                assert called not in NO_IO_CALLS, f"marlin_aio/protocol/{path.name}:{node.lineno} calls {called}()"


def test_the_library_never_imports_a_front_end() -> None:
    for path in sorted((ROOT / "marlin_aio").rglob("*.py")):
        for name, _ in imports(path):
            assert name.split(".")[0] not in FRONT_ENDS, f"{path.relative_to(ROOT)} imports {name}"


def test_errors_imports_nothing_of_the_library() -> None:
    assert not [name for name, _ in imports(ROOT / "marlin_aio" / "errors.py") if name.startswith("marlin_aio")]


@pytest.mark.parametrize("path", sorted([*ROOT.glob("cli/**/*.py"), *ROOT.glob("benchmarks/*.py")]), ids=str)
def test_the_cli_and_the_benchmarks_use_only_public_names(path: Path) -> None:
    public = {module: set(importlib.import_module(module).__all__) for module in PUBLIC_MODULES}
    for module, names in imports(path):
        if not module.startswith("marlin_aio") or module in ALLOWED_MODULES:
            continue
        assert module in public, f"{path.name} imports the private module {module}"
        private = [name for name in names if name not in public[module]]
        assert not private, f"{path.name} imports {private} from {module}, which does not export them"


#: The package's faces: each `__all__` is what its readers may rely on.
FACES = ("marlin_aio", "marlin_aio.protocol", "marlin_aio.aio", "marlin_aio.simulator")


def test_the_public_faces() -> None:
    # An application's face stays narrow (aiomqtt: 16 names); a driver writer's needs live in marlin_aio.protocol.
    # (46: every error an application may catch is on the face, NotSupportedError the latest.)
    assert len(marlin_aio.__all__) <= 46
    for module_name in FACES:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            assert hasattr(module, name), f"{module_name}.__all__ names {name}, which it does not have"
            value = getattr(module, name)
            if inspect.isclass(value) or inspect.isfunction(value):
                # Its own: not a base class's, and not the signature a dataclass writes when it has none.
                doc = value.__doc__
                assert doc and not doc.startswith(f"{value.__name__}("), f"{module_name}.{name} has no docstring"
    # A driver handles every event a line can become, so each must be importable from the protocol's face.
    events = typing.get_args(marlin_aio.protocol.Event)
    assert events
    missing = [event.__name__ for event in events if event.__name__ not in marlin_aio.protocol.__all__]
    assert not missing, f"marlin_aio.protocol.__all__ lacks the events {missing}"
    assert "Output" in marlin_aio.protocol.__all__


#: The G-code handlers and the board they are written against: the simulator's modules each of them may import.
HANDLER_MODULES = {
    "_board": {"_config", "_intake", "_thermal"},
    "_gcode": {"_board", "_config", "_heating", "_hostactions", "_intake"},
    "_heating": {"_board", "_config", "_intake", "_thermal"},
    "_hostactions": {"_board", "_config", "_intake"},
}


def test_simulator_handlers_see_only_the_board() -> None:
    # The handlers know the printer only as a `Board`: no import of `_printer` (not even for type checking, which
    # would be a circle, since `_printer` imports their tables) and no private name of any object but their own.
    for module, allowed in HANDLER_MODULES.items():
        path = ROOT / "marlin_aio" / "simulator" / f"{module}.py"
        simulator = {
            name.removeprefix("marlin_aio.simulator.")
            for name, _ in imports(path)
            if name.startswith("marlin_aio.simulator")
        }
        assert simulator <= allowed, f"{path.name} imports {sorted(simulator - allowed)} of the simulator"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            where = f"marlin_aio/simulator/{path.name}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{where} imports relatively"
            name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
            assert name != "TYPE_CHECKING", f"{where} imports for type checking only"
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                owner = ast.unparse(node.value)
                assert owner == "self", f"{where} reaches into {owner}.{node.attr}"


#: Past this many lines a module says in its docstring why it is one module ("Over 400 lines because ...").
LONG_MODULE_LINES = 400


@pytest.mark.parametrize(
    "path",
    sorted([*ROOT.glob("marlin_aio/**/*.py"), *ROOT.glob("cli/**/*.py"), *ROOT.glob("benchmarks/*.py")]),
    ids=lambda path: str(path.relative_to(ROOT)),
)
def test_a_long_module_says_why_it_is_one(path: Path) -> None:
    source = path.read_text(encoding="utf-8")
    lines = len(source.splitlines())
    if lines <= LONG_MODULE_LINES:
        return
    docstring = ast.get_docstring(ast.parse(source)) or ""
    assert "over 400 lines" in docstring.lower(), (
        f"{path.relative_to(ROOT)} has {lines} lines: its docstring should say why it is one module "
        f"(a paragraph beginning 'Over 400 lines because ...'), or it should be split"
    )


def library_modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the library by its dotted name (a package by its own name, for its `__init__`)."""
    modules = {}
    for path in sorted((root / "marlin_aio").rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Which of the library's modules each one imports, at module level or inside a function alike (an import moved
    into a function is the same circle: it only fails later, at the first call). `from package import name` is
    an edge to the submodule `name` if there is one, else to the package."""
    modules = library_modules(root)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        targets: set[str] = set()
        for name, names in imports(path):
            targets.update(f"{name}.{n}" if f"{name}.{n}" in modules else name for n in names)
            if not names:  # `import marlin_aio.x`
                targets.add(name)
        graph[module] = targets & modules.keys() - {module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Each circle of imports in `graph`, as the modules on it (found by a depth-first walk: small graph)."""
    cycles: list[list[str]] = []
    seen: set[frozenset[str]] = set()

    def walk(module: str, path: list[str]) -> None:
        for target in sorted(graph[module]):
            if target in path:
                cycle = path[path.index(target) :]
                if frozenset(cycle) not in seen:
                    seen.add(frozenset(cycle))
                    cycles.append([*cycle, target])
            elif target not in done:
                walk(target, [*path, target])
        done.add(module)

    done: set[str] = set()
    for module in sorted(graph):
        if module not in done:
            walk(module, [module])
    return cycles


def test_no_module_of_the_library_imports_itself_in_a_circle() -> None:
    # A circle (aio/printer.py -> aio/served.py -> aio/servicepaths.py -> aio/printer.py, once) works only by the
    # order modules happen to load in, and hides which layer stands on which.
    cycles = import_cycles(import_graph())
    assert not cycles, "import circles: " + "; ".join(" -> ".join(cycle) for cycle in cycles)


def test_the_circle_finder_finds_a_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycles(graph) == [["a", "b", "c", "a"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []
