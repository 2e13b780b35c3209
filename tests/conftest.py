"""Shared fixtures: the simulated printer served in memory, on a real pty or on TCP, and a client connected to it.

Client tests run on the in-memory link (`mem_sim`, `mem_printer`) unless a real port is what they test: the
client, its core and the simulator are the same code either way, and a memory link costs no pty, socket or
kernel round trip. What a real port adds stays on one (`pty_sim`, `printer`, `dead_pty`): pyserial's opening,
port errors, the exclusive lock, DTR and HUPCL, a paced UART, a hang-up as pyserial reports it, and real bytes
through the serial stack. `sim` serves a handful of end-to-end tests once on a pty and once on TCP.
"""

from __future__ import annotations

import asyncio
import os
import pty
import subprocess
import tty
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from tmux_screen import Tmux

import marlin_aio
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_memory, serve_pty, serve_tcp

if TYPE_CHECKING:
    from test_farm import Broker

# Simulated seconds per real second: heating and homing finish quickly, yet the client sees Marlin's timing shapes.
TIME_SCALE = 20.0

_CAMPAIGN_REPORT = pytest.StashKey[list[str]]()


@pytest.fixture(autouse=True)
def _own_service_socket(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test has a `marlin-temp serve` socket of its own (`$MARLIN_SERVE_SOCKET`): a farm or a service one
    test starts never meets another test's, nor a service the developer runs on this machine."""
    monkeypatch.setenv("MARLIN_SERVE_SOCKET", str(tmp_path_factory.mktemp("serve") / "serve.sock"))


@pytest.fixture(autouse=True)
def _own_config_folder(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test has an empty config folder of its own (`$XDG_CONFIG_HOME`), so the presets are the defaults unless
    a test writes a presets file: never the developer's own `~/.config/marlin-temp/presets.toml`."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path_factory.mktemp("config")))
    monkeypatch.delenv("MARLIN_TEMP_PRESETS", raising=False)


@pytest.fixture
def campaign_report(pytestconfig: pytest.Config) -> list[str]:
    """Lines the fault campaign reports (run counts, failing seeds); printed at the end of the test session."""
    return pytestconfig.stash.setdefault(_CAMPAIGN_REPORT, [])


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Under pytest-xdist (the suite runs on every core), hand a worker's campaign lines to the controller, which
    prints the summary."""
    output = getattr(session.config, "workeroutput", None)
    if output is not None:
        output["campaign_report"] = session.config.stash.get(_CAMPAIGN_REPORT, [])


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: object) -> None:
    """The controller's side of `pytest_sessionfinish`: collect each worker's campaign lines."""
    lines = getattr(node, "workeroutput", {}).get("campaign_report", [])
    node.config.stash.setdefault(_CAMPAIGN_REPORT, []).extend(lines)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter, config: pytest.Config) -> None:
    """Print what the fault campaign counted, pass or fail, so every CI log keeps its run counts and seeds."""
    lines = config.stash.get(_CAMPAIGN_REPORT, [])
    if lines:
        terminalreporter.section("fault campaign")
        for line in lines:
            terminalreporter.write_line(line)


@pytest.fixture(params=["pty", "tcp"])
async def sim(request: pytest.FixtureRequest) -> AsyncIterator[SimulatorServer]:
    """The simulated printer, served once on a pseudo-terminal and once on TCP (socket://)."""
    serve = serve_pty if request.param == "pty" else serve_tcp
    async with serve(SimulatorConfig(), Faults(), time_scale=TIME_SCALE) as server:
        yield server


@pytest.fixture
async def pty_sim() -> AsyncIterator[SimulatorServer]:
    """The simulated printer on a pseudo-terminal only."""
    async with serve_pty(SimulatorConfig(), Faults(), time_scale=TIME_SCALE) as server:
        yield server


@pytest.fixture
async def fast_sim() -> AsyncIterator[SimulatorServer]:
    """The simulated printer on a pseudo-terminal, its moves taking no time and its clock 50 times faster: the link,
    not the planner, sets the pace of a print."""
    async with serve_pty(SimulatorConfig(motion_time_scale=0), Faults(), time_scale=50) as server:
        yield server


@pytest.fixture
async def mem_sim() -> AsyncIterator[SimulatorServer]:
    """The simulated printer on an in-memory link (`memory://sim-N`), in the test's own event loop."""
    async with serve_memory(SimulatorConfig(), Faults(), time_scale=TIME_SCALE) as server:
        yield server


@pytest.fixture
async def fast_mem_sim() -> AsyncIterator[SimulatorServer]:
    """`fast_sim` on an in-memory link: moves take no time, the clock runs 50 times faster."""
    async with serve_memory(SimulatorConfig(motion_time_scale=0), Faults(), time_scale=50) as server:
        yield server


@pytest.fixture
async def mem_printer(mem_sim: SimulatorServer) -> AsyncIterator[marlin_aio.Printer]:
    """A client connected to `mem_sim`, with a short command timeout so fault tests stay quick.

    The banner of the reset on connect arrives within a turn or two of the loop here, so a short quiet ends the
    handshake's boot wait (0.3 s by default, for a real board's bootloader): a real second saved every three tests.
    """
    async with marlin_aio.connect(mem_sim.url, timeout_s=2.0, boot_quiet_s=0.05) as connected:
        yield connected


@pytest.fixture
async def printer(pty_sim: SimulatorServer) -> AsyncIterator[marlin_aio.Printer]:
    """A client connected to `pty_sim`, with a short command timeout so fault tests stay quick."""
    async with marlin_aio.connect(pty_sim.url, timeout_s=2.0) as connected:
        yield connected


@pytest.fixture
def dead_pty() -> Iterator[tuple[int, str]]:
    """A pty nobody answers on: the master end is the test's, to keep silent or to fill with garbage."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    """A real Mosquitto on 127.0.0.1 and a free port (`test_farm.Broker`), stopped at the end; the MQTT tests skip
    themselves when Mosquitto is not installed."""
    from test_farm import Broker

    running = Broker(tmp_path)
    running.start()
    try:
        yield running
    finally:
        running.stop()


def heaters_off(reading: marlin_aio.TemperatureReading | None) -> bool:
    """True when `reading` says the hotend's and the bed's targets are 0 (a cancel script's work, seen at the
    printer)."""
    return (
        reading is not None
        and reading.hotend is not None
        and reading.hotend.target == 0
        and reading.bed is not None
        and reading.bed.target == 0
    )


async def until(condition: Callable[[], bool], what: str, limit_s: float = 60.0, every_s: float = 0.02) -> None:
    """Poll `condition` until it holds, bounded by `limit_s` (then fail naming `what`).

    The one wait-for-a-condition of the suite, for what gives no event to await: a file on disk, what the
    simulator ran, a counter. Each poll yields to the loop, so a front end running on it goes on meanwhile; it is
    not a fixed sleep: it returns as soon as the condition holds.
    """
    loop = asyncio.get_running_loop()
    end = loop.time() + limit_s
    while not condition():
        if loop.time() > end:
            raise AssertionError(f"timed out after {limit_s:g} s waiting for {what}")
        await asyncio.sleep(every_s)  # polling a condition, bounded; not a fixed wait


@pytest.fixture
def tmux() -> Iterator[Tmux]:
    """A tmux server of the test's own (`tests/tmux_screen.py`), killed after the test."""
    server = Tmux()
    yield server
    subprocess.run(["tmux", "-L", server.socket, "kill-server"], capture_output=True, check=False)
