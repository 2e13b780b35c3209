"""The seam between `Printer` and what reaches the printer: the interface a backend serves (`PrinterBackend`).

bleak's shape: `BleakClient` is one public class that hands every call to one backend chosen at construction.
Here `Printer` is that class, and there are two backends: `marlin_aio.aio.serialbackend.SerialBackend` (the port:
the link, the handshake, the poller, prints streamed from this process) and `marlin_aio.aio.served.ServedBackend`
(a printer of `marlin-temp serve`, reached by JSON-RPC). What `Printer` builds on its backend (moves, homing,
fans, waits for temperatures, `print_file`) lives in `Printer` once, for both.

A backend serves every member below or raises `NotSupportedError` naming the member and saying why; none answers
with a made-up nothing. What a backend tells (link events, the firmware's requests, its failure, readings) goes to
the `Listeners` and the `TemperatureFeed` it was given.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from contextlib import AbstractAsyncContextManager, AbstractContextManager
from pathlib import Path
from typing import Protocol

from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.errors import MarlinError
from marlin_aio.protocol.events import FirmwareInfo
from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.protocol.hostrequests import HostRequest, Prompt
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.temperatures import TemperatureReading
from marlin_aio.protocol.wire import Trace

__all__ = ["PrinterBackend"]


class PrinterBackend(Protocol):
    """What `Printer` asks of the thing that reaches its printer. Each member is `Printer`'s of the same name
    (its docstring there says what it means); a member the backend cannot serve raises `NotSupportedError`."""

    timeout_s: float
    firmware: FirmwareInfo | None
    capabilities: dict[str, bool]

    def set_limits(self, limits: HeaterLimits) -> None:
        """Check every command and print line against `limits` from now on."""

    async def open(self) -> None:
        """Reach the printer (see `Printer.open`)."""

    async def close(self) -> None:
        """Let go of the printer (see `Printer.close`)."""

    @property
    def reset_on_open(self) -> bool:
        """See `Printer.reset_on_open`."""

    async def send(self, command: str, *, timeout_s: float, numbered: bool | None) -> Reply:
        """See `Printer.send`."""

    def emergency_stop(self) -> None:
        """See `Printer.emergency_stop`."""

    def interrupt_wait(self) -> bool:
        """See `Printer.interrupt_wait`."""

    async def read_temperatures(self) -> TemperatureReading:
        """See `Printer.read_temperatures`."""

    def readings_ended(self) -> MarlinError | None:
        """Why a new reader of temperatures gets none (the link lost or not open), or None."""

    def poll_temperatures(self, interval_s: float, auto_report: bool) -> AbstractAsyncContextManager[None]:
        """See `Printer.poll_temperatures` (`interval_s` checked already)."""

    def polled(self) -> bool:
        """True while readings come without asking."""

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool,
        window_bytes: int | None,
        check: bool,
        timeout_s: float | None,
        name: str | None = None,
        stop_on_unknown: bool = False,
    ) -> PrintHandle:
        """See `Printer.start_print`."""

    def failure(self) -> MarlinError | None:
        """Why the printer can take no more commands (lost, halted), or None."""

    @property
    def state(self) -> LinkState:
        """See `Printer.state`."""

    @property
    def is_connected(self) -> bool:
        """See `Printer.is_connected`."""

    @property
    def prompt(self) -> Prompt | None:
        """See `Printer.prompt`."""

    @property
    def waiting_for_user(self) -> bool:
        """See `Printer.waiting_for_user`."""

    @property
    def last_host_request(self) -> HostRequest | None:
        """See `Printer.last_host_request`."""

    async def answer_prompt(self, index: int) -> None:
        """See `Printer.answer_prompt`."""

    @property
    def trace(self) -> Trace:
        """See `Printer.trace`."""

    @property
    def stats(self) -> LinkStats:
        """See `Printer.stats`."""

    @property
    def round_trips(self) -> deque[tuple[float, float]]:
        """See `Printer.round_trips`."""

    @property
    def send_ahead_window_bytes(self) -> int:
        """See `Printer.send_ahead_window_bytes`."""

    def sending_ahead(self, max_in_flight: int) -> AbstractContextManager[None]:
        """See `Printer.sending_ahead`."""

    @property
    def print_poll_interval_s(self) -> float:
        """See `Printer.print_poll_interval_s`."""

    @print_poll_interval_s.setter
    def print_poll_interval_s(self, interval_s: float) -> None: ...
