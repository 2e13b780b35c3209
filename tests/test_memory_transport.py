"""The in-memory link (`marlin_aio.aio.memory`) on its own, then the simulator served on it (`serve_memory`).

Its promises: bytes reach the peer on a later turn of the loop, never from inside `write()`; closing reaches both
ends; a paused reader gets its bytes on resume; a name nobody listens at is a `PortNotFoundError` that says so.
Every wait is on a condition (`until`) or an event, never a fixed sleep.
"""

from __future__ import annotations

import asyncio

import pytest
from conftest import TIME_SCALE, until

import marlin_aio
from marlin_aio.aio import _serial, memory
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_memory


class Recorder(asyncio.Protocol):
    """Keeps what it is told; with `echo`, writes every chunk straight back from `data_received`."""

    def __init__(self, *, echo: bool = False) -> None:
        self.echo = echo
        self.transport: asyncio.Transport | None = None
        self.received = bytearray()
        self.lost: list[Exception | None] = []
        self.depth = 0  # data_received calls under way: more than one would be re-entrancy
        self.deepest = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.depth += 1
        self.deepest = max(self.deepest, self.depth)
        self.received += data
        if self.echo:
            assert self.transport is not None
            self.transport.write(data)
        self.depth -= 1

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.append(exc)


@pytest.fixture
async def pair() -> tuple[Recorder, Recorder, memory.MemoryTransport]:
    """A client `Recorder` connected to an echoing one listening at a fresh name, and the client's transport."""
    server = Recorder(echo=True)
    listener = memory.listen(f"test-{id(server)}", lambda: server)
    client = Recorder()
    try:
        transport, protocol = await memory.connect(listener.url, lambda: client)
    finally:
        listener.close()
    assert protocol is client and client.transport is transport and server.transport is not None
    return client, server, transport


# ------------------------------------------------------------------------------------------- the transport


async def test_writes_arrive_on_a_later_turn_in_order_and_never_re_enter(
    pair: tuple[Recorder, Recorder, memory.MemoryTransport],
) -> None:
    client, server, transport = pair
    transport.write(b"ping ")
    assert server.received == b""  # not from inside write()
    for index in range(100):
        transport.write(f"{index} ".encode())
    expected = b"ping " + b"".join(f"{index} ".encode() for index in range(100))
    await until(lambda: client.received == expected, "the echo of every write, in order")
    # The server wrote from data_received, and the client's data_received was never called inside it.
    assert server.deepest == client.deepest == 1
    assert transport.get_extra_info("url").startswith("memory://test-")
    assert transport.get_write_buffer_size() == 0


async def test_close_lets_the_peer_read_what_was_written_then_both_ends_hear_of_it(
    pair: tuple[Recorder, Recorder, memory.MemoryTransport],
) -> None:
    client, server, transport = pair
    transport.write(b"last words")
    transport.close()
    transport.close()  # twice is harmless: each end still hears of it once
    assert transport.is_closing()
    assert server.transport is not None and server.transport.is_closing()
    transport.write(b"after the close")  # goes nowhere
    await until(lambda: bool(client.lost and server.lost), "connection_lost on both ends")
    assert server.received == b"last words"
    assert client.received == b""  # the echo came after the close: the closer hears nothing more
    assert client.lost == server.lost == [None]


async def test_abort_drops_what_the_peer_has_not_read_yet(
    pair: tuple[Recorder, Recorder, memory.MemoryTransport],
) -> None:
    client, server, transport = pair
    transport.write(b"never read")
    transport.abort()
    await until(lambda: bool(client.lost and server.lost), "connection_lost on both ends")
    assert server.received == b""


async def test_a_paused_reader_gets_its_bytes_on_resume(
    pair: tuple[Recorder, Recorder, memory.MemoryTransport],
) -> None:
    client, server, transport = pair
    transport.pause_reading()
    assert not transport.is_reading()
    transport.write(b"held")
    await until(lambda: server.received == b"held", "the server to read")
    assert client.received == b""  # the echo waits while the client does not read
    transport.resume_reading()
    await until(lambda: client.received == b"held", "the echo after resume_reading")


async def test_a_name_nobody_listens_at_is_port_not_found_in_words() -> None:
    with pytest.raises(marlin_aio.PortNotFoundError, match=r"nothing is listening at memory://nobody \(a memory://"):
        async with marlin_aio.connect("memory://nobody"):
            pass


async def test_a_name_is_listened_at_once() -> None:
    listener = memory.listen("taken", asyncio.Protocol)
    try:
        with pytest.raises(ValueError, match="already listens at memory://taken"):
            memory.listen("taken", asyncio.Protocol)
    finally:
        listener.close()
    memory.listen("taken", asyncio.Protocol).close()  # free again once closed
    for bad in ("", "a/b"):
        with pytest.raises(ValueError, match="name"):
            memory.listen(bad, asyncio.Protocol)


def test_a_listener_is_reached_from_its_own_event_loop_only() -> None:
    async def make() -> memory.MemoryListener:
        return memory.listen("one-loop", asyncio.Protocol)

    listener = asyncio.run(make())
    try:
        with pytest.raises(marlin_aio.ConnectError, match="listens on another event loop"):
            asyncio.run(memory.connect(listener.url, asyncio.Protocol))
    finally:
        listener.close()


async def test_the_serial_helpers_do_nothing_on_a_memory_link(
    pair: tuple[Recorder, Recorder, memory.MemoryTransport],
) -> None:
    client, _, transport = pair
    assert _serial.keep_dtr_on_close(transport) is False  # no modem lines
    transport.write(b"kept")
    _serial.flush_input(transport)  # no operating-system buffer to drop
    await until(lambda: client.received == b"kept", "the echo")


# ------------------------------------------------------------------------------------------- the simulator on it


async def test_each_server_has_a_name_of_its_own() -> None:
    async with serve_memory(time_scale=TIME_SCALE) as first, serve_memory(time_scale=TIME_SCALE) as second:
        assert first.url.startswith("memory://sim-") and second.url.startswith("memory://sim-")
        assert first.url != second.url
    with pytest.raises(marlin_aio.PortNotFoundError, match="nothing is listening"):
        async with marlin_aio.connect(first.url):
            pass


async def test_a_server_that_hangs_up_fails_what_waits_with_connection_lost(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    pending = asyncio.create_task(mem_printer.send("G4 S20"))
    await until(lambda: "G4 S20" in mem_sim.printer.executed, "the dwell to start")
    await mem_sim.disconnect()
    with pytest.raises(marlin_aio.ConnectionLostError, match=r"the connection to memory://sim-\d+ was lost"):
        await pending
    with pytest.raises(marlin_aio.ConnectionLostError):
        await mem_printer.send("M105")
    assert not mem_printer.is_connected


async def test_a_client_that_closes_leaves_the_server_free_for_the_next(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url) as printer:
        assert mem_sim.connected
        await printer.send("M104 S50")
        reading = await printer.temperatures()
        assert reading.hotend is not None and reading.hotend.target == 50
    await until(lambda: not mem_sim.connected, "the server to see the client go")
    # Each connect resets the board, as DTR does on a USB serial port and as a TCP connection does here.
    async with marlin_aio.connect(mem_sim.url) as printer:
        assert printer.reset_on_open
        reading = await printer.temperatures()
        assert reading.hotend is not None and reading.hotend.target == 0


async def test_a_second_client_is_refused_while_one_is_connected(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url) as first:
        # Like a serial port held by another program, or the one-client TCP port: the second link is dropped.
        with pytest.raises(marlin_aio.ConnectionLostError, match="was lost"):
            async with marlin_aio.connect(mem_sim.url, timeout_s=1.0):
                pass
        reply = await first.send("M118 E1 still mine")
        assert reply.lines == ("echo:still mine",)


async def test_a_paced_memory_link_carries_every_line() -> None:
    # The simulated UART pauses and resumes reading on its transport: here the memory link's.
    async with (
        serve_memory(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=115_200) as server,
        marlin_aio.connect(server.url) as printer,
    ):
        replies = await asyncio.gather(*(printer.send(f"M118 E1 line {index}") for index in range(50)))
    assert [reply.lines for reply in replies] == [(f"echo:line {index}",) for index in range(50)]
    assert server.baud_rate == 115_200
