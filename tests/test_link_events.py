"""`Printer.on_link_event`: connected, reset, halted and disconnected, each told once as it happens, through the
simulator on the in-memory link (which can be unplugged); a listener that raises costs nobody else anything."""

from __future__ import annotations

import asyncio
import logging

import pytest

import marlin_aio
from marlin_aio.aio.printer import LinkEvent
from marlin_aio.simulator import SimulatorConfig, serve_memory


class Listener:
    """The events told, in order; `until()` waits for one of a kind."""

    def __init__(self) -> None:
        self.events: list[LinkEvent] = []
        self._changed = asyncio.Event()

    def __call__(self, event: LinkEvent) -> None:
        self.events.append(event)
        self._changed.set()

    def kinds(self) -> list[str]:
        return [event.kind for event in self.events]

    async def until(self, kind: str) -> LinkEvent:
        async with asyncio.timeout(20):
            while kind not in self.kinds():
                self._changed.clear()
                await self._changed.wait()
        return next(event for event in self.events if event.kind == kind)


async def test_connected_then_a_reset_while_connected_then_halted() -> None:
    listener = Listener()
    async with serve_memory(SimulatorConfig(), time_scale=20) as sim:
        printer = marlin_aio.Printer(sim.url)
        printer.on_link_event(listener)
        async with printer:
            connected = await listener.until("connected")
            assert sim.url in connected.message and connected.error is None
            # The boot banner of the handshake is not a reset; one after it is.
            assert listener.kinds() == ["connected"]
            sim.printer.reset(sim.now())
            sim.poke()
            reset = await listener.until("reset")
            assert "reset" in reset.message
            printer.emergency_stop()
            halted = await listener.until("halted")
            assert isinstance(halted.error, marlin_aio.PrinterHaltedError)
    # Each once, in order; closing the port afterwards is a disconnection too.
    assert listener.kinds() == ["connected", "reset", "halted", "disconnected"]


async def test_an_unplugged_printer_is_disconnected_and_a_raising_listener_harms_no_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    listener = Listener()

    def broken(event: LinkEvent) -> None:
        raise RuntimeError("a listener's bug")

    async with serve_memory(SimulatorConfig(), time_scale=20) as sim:
        printer = marlin_aio.Printer(sim.url)
        printer.on_link_event(broken)
        printer.on_link_event(listener)
        async with printer:
            await listener.until("connected")
            await sim.disconnect()
            disconnected = await listener.until("disconnected")
            assert isinstance(disconnected.error, marlin_aio.ConnectionLostError)
    assert "a link event listener failed on connected" in caplog.text
    assert [r.levelno for r in caplog.records if "listener failed" in r.getMessage()][:1] == [logging.ERROR]


async def test_a_stopped_listener_hears_nothing_more() -> None:
    listener, witness = Listener(), Listener()
    async with serve_memory(SimulatorConfig(), time_scale=20) as sim:
        printer = marlin_aio.Printer(sim.url)
        stop = printer.on_link_event(listener)
        printer.on_link_event(witness)
        async with printer:
            await listener.until("connected")
            stop()
            sim.printer.reset(sim.now())
            sim.poke()
            await witness.until("reset")  # told to every listener in one call: the stopped one would have it now
    assert listener.kinds() == ["connected"]
