"""A simulated Marlin 2.1 printer, for tests and for trying a host without hardware.

`SimulatedPrinter` is the firmware itself, sans-I/O: bytes and simulated time in, bytes out. `serve_pty()` and
`serve_tcp()` put it behind a pseudo-terminal or a TCP port, where a client opens it like a real board
(`/dev/pts/N` with pyserial, or `socket://127.0.0.1:PORT`); `serve_memory()` behind an in-memory link that a
client in the same event loop opens as `memory://sim-N`. `marlin-sim` (or `python -m marlin_aio.simulator`)
does the same from a shell. With `baud_rate` (`--baud`) the link runs at a UART's speed in both directions.
`generate_moves()` writes a reproducible file of short moves for streaming tests and benchmarks. `run_print()`
runs one print of the fault campaign (a `Scenario`; `mixed_scenario(seed)` draws one) in simulated time and
checks the protocol's invariants. `run_in_simulated_time()` runs a coroutine on a `SimulatedTimeLoop`, an
event loop whose clock jumps to its next timer: a client and a `serve_memory()` printer in it spend simulated
seconds (a G28, a heat-up, a timeout) in milliseconds of CPU, the same run every time.
"""

from __future__ import annotations

from marlin_aio.simulator._campaign import CampaignResult, Scenario, mixed_scenario, run_print
from marlin_aio.simulator._config import Faults, SimulatorConfig
from marlin_aio.simulator._printer import SimulatedPrinter
from marlin_aio.simulator._record import BoundedRecord
from marlin_aio.simulator._serve import SimulatorServer, serve_memory, serve_pty, serve_tcp
from marlin_aio.simulator._virtual import SimulatedTimeLoop, run_in_simulated_time
from marlin_aio.simulator._workload import generate_moves

__all__ = [
    "BoundedRecord",
    "CampaignResult",
    "Faults",
    "Scenario",
    "SimulatedPrinter",
    "SimulatedTimeLoop",
    "SimulatorConfig",
    "SimulatorServer",
    "generate_moves",
    "mixed_scenario",
    "run_in_simulated_time",
    "run_print",
    "serve_memory",
    "serve_pty",
    "serve_tcp",
]
