"""An in-memory link: two asyncio transports joined back to back inside one event loop, and named listeners.

`open_link("memory://NAME", ...)` (in `_serial`) connects to whoever listens at NAME in this process, such as a
simulator served with `marlin_aio.simulator.serve_memory()`. The client and the printer then exchange the same
bytes they would over a pty or a socket, through the same `asyncio.Protocol` methods, with no file descriptor, no
thread and no kernel in between: tests of the client that a pty adds nothing to run on it, and in-process tools
(a farm of simulated printers) can too.

What it keeps of a real transport, so the code above it cannot tell the difference:

- Nothing is called synchronously. `write()` hands its bytes to the peer's `data_received` on the loop's next
  turn (`call_soon`), never from inside the writer's call, so a protocol that writes from `data_received` (the
  link and the simulator both do) is never re-entered. Writes made in one turn may arrive as one chunk, as on a
  stream socket. `connection_made` and `connection_lost` come from the loop too.
- `close()` ends both sides: the peer first gets the bytes already written to it (unless it paused reading), then
  `connection_lost(None)`, as after a socket's orderly close; the closer gets nothing more. `abort()` drops those
  bytes as well.
- `pause_reading()` holds the bytes for the protocol until `resume_reading()` (the simulator's pause and its
  paced wire use it), as a pty or a socket keeps them in the kernel meanwhile.

What it leaves out: there is no write buffer and no `pause_writing()` (nothing here honours it), so bytes written
to a peer that paused reading wait in memory without a bound; and there are no modem lines (DTR) or input buffer
to flush, so `_serial.keep_dtr_on_close` and `_serial.flush_input` do nothing on it. The baud rate a client asks
for is ignored, as on `socket://`. A listener and its clients belong to the loop it was made on.

This module imports nothing of the serial packages: the simulator may import it (and only it) from `aio/`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from marlin_aio.errors import ConnectError, PortNotFoundError

__all__ = ["SCHEME", "MemoryListener", "MemoryTransport", "connect", "listen"]

SCHEME = "memory://"
"""How a memory link's URL starts: `memory://NAME`."""

ProtocolFactory = Callable[[], asyncio.Protocol]

#: Who listens at each name, in this process.
_listeners: dict[str, MemoryListener] = {}


class MemoryTransport(asyncio.Transport):
    """One end of a memory link; its peer is the other end. Made in pairs by `connect()`, never by hand."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol, url: str) -> None:
        super().__init__(extra={"url": url})
        self._loop = loop
        self._protocol = protocol
        self._peer: MemoryTransport | None = None
        self._inbox = bytearray()  # bytes the peer wrote, not yet handed to the protocol
        self._delivery: asyncio.Handle | None = None
        self._reading = True
        self._held = False  # the client's end, until connect() has returned: see there
        self._closing = False
        self._lost = False  # connection_lost was called: nothing more reaches the protocol

    # ------------------------------------------------------------------------------------------- writing

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Hand `data` to the peer's protocol on the loop's next turn; nothing happens once either end closed."""
        peer = self._peer
        if self._closing or peer is None or not data:
            return  # both ends are closing from the moment either closes
        peer._inbox += data  # copied: the caller may reuse its buffer
        peer._schedule_delivery()

    def can_write_eof(self) -> bool:
        """False: a memory link ends only as a whole, with `close()`."""
        return False

    def get_write_buffer_size(self) -> int:
        """0: every write is handed to the peer at once (see the module's docstring)."""
        return 0

    def get_write_buffer_limits(self) -> tuple[int, int]:
        """(0, 0): there is no write buffer to limit."""
        return (0, 0)

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        """Accepted and ignored: there is no write buffer to limit."""

    # ------------------------------------------------------------------------------------------- reading

    def pause_reading(self) -> None:
        """Hold what the peer writes until `resume_reading()`."""
        self._reading = False
        if self._delivery is not None:
            self._delivery.cancel()
            self._delivery = None

    def resume_reading(self) -> None:
        """Hand over what was held, and what comes after, on the loop's next turn."""
        if self._reading:
            return
        self._reading = True
        self._schedule_delivery()

    def is_reading(self) -> bool:
        """Whether the peer's bytes reach the protocol (not paused, not closed)."""
        return self._reading and not self._closing

    def _schedule_delivery(self) -> None:
        if self._reading and not self._held and not self._lost and self._delivery is None and self._inbox:
            self._delivery = self._loop.call_soon(self._deliver)

    def _deliver(self) -> None:
        self._delivery = None
        if not self._reading or self._lost or not self._inbox:
            return
        data = bytes(self._inbox)
        self._inbox.clear()
        self._protocol.data_received(data)

    # ------------------------------------------------------------------------------------------- closing

    def is_closing(self) -> bool:
        """True once either end closed or aborted the link."""
        return self._closing

    def close(self) -> None:
        """End the link: the peer still gets the bytes already written to it, then both protocols get
        `connection_lost(None)` on the loop's next turn. Safe to call twice."""
        self._end(drop_peer_bytes=False)

    def abort(self) -> None:
        """End the link at once: as `close()`, but the bytes not yet handed to the peer are dropped too."""
        self._end(drop_peer_bytes=True)

    def _end(self, *, drop_peer_bytes: bool) -> None:
        if self._closing:
            return
        self._closing = True
        self._forget_inbox()
        self._loop.call_soon(self._connection_lost)
        peer = self._peer
        if peer is not None and not peer._closing:
            peer._closing = True
            if drop_peer_bytes:
                peer._forget_inbox()
            # Behind its delivery, if one is due: the peer reads what was written before it hears of the close.
            self._loop.call_soon(peer._connection_lost)

    def _forget_inbox(self) -> None:
        self._inbox.clear()
        if self._delivery is not None:
            self._delivery.cancel()
            self._delivery = None

    def _connection_lost(self) -> None:
        if self._lost:
            return
        self._lost = True
        self._forget_inbox()
        self._peer = None
        self._protocol.connection_lost(None)

    # ------------------------------------------------------------------------------------------- protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        """Hand this end to another protocol.

        Raises:
            TypeError: `protocol` is not a streaming `asyncio.Protocol`.
        """
        if not isinstance(protocol, asyncio.Protocol):
            raise TypeError(f"a memory link needs an asyncio.Protocol, got {type(protocol).__name__}")
        self._protocol = protocol

    def get_protocol(self) -> asyncio.BaseProtocol:
        """The protocol this end hands its bytes to."""
        return self._protocol


class MemoryListener:
    """Who listens at `memory://NAME`: each `connect()` to the name gets a new pair of transports, the listener's
    end going to a protocol from its factory. Made by `listen()`."""

    def __init__(self, name: str, protocol_factory: ProtocolFactory, loop: asyncio.AbstractEventLoop) -> None:
        self.name = name
        """The name clients connect to."""
        self._protocol_factory = protocol_factory
        self._loop = loop

    @property
    def url(self) -> str:
        """What a client opens: `memory://NAME`."""
        return SCHEME + self.name

    def close(self) -> None:
        """Stop listening: the name is free again, and links already made stay open. Safe to call twice."""
        if _listeners.get(self.name) is self:
            del _listeners[self.name]


def listen(name: str, protocol_factory: ProtocolFactory) -> MemoryListener:
    """Listen at `memory://NAME` on the running event loop.

    Raises:
        ValueError: `name` is empty or has a `/`, or someone already listens at it.
        RuntimeError: no event loop is running.
    """
    if not name or "/" in name:
        raise ValueError(f"a memory link's name must be non-empty and have no '/', got {name!r}")
    if name in _listeners:
        raise ValueError(f"someone already listens at {SCHEME}{name}")
    listener = MemoryListener(name, protocol_factory, asyncio.get_running_loop())
    _listeners[name] = listener
    return listener


async def connect(url: str, protocol_factory: ProtocolFactory) -> tuple[MemoryTransport, asyncio.Protocol]:
    """Connect to whoever listens at `url` (`memory://NAME`) and return the client's end and its protocol.

    Both ends' `connection_made` have been called when this returns, the listener's first. What the listener
    wrote from there (a banner) reaches the client's protocol on a later turn of the loop, never before the caller
    has resumed: as with asyncio's own connections, where the caller's task runs before the first read.

    Raises:
        PortNotFoundError: nobody listens at `url` in this process.
        ConnectError: the listener belongs to another event loop.
    """
    loop = asyncio.get_running_loop()
    listener = _listeners.get(url.removeprefix(SCHEME)) if url.startswith(SCHEME) else None
    if listener is None:
        raise PortNotFoundError(
            f"nothing is listening at {url} (a {SCHEME} link reaches only a listener in this process, "
            "such as a simulator started with serve_memory())"
        )
    if listener._loop is not loop:
        raise ConnectError(f"{url} listens on another event loop; a {SCHEME} link stays inside one loop")
    client_protocol = protocol_factory()
    server_protocol = listener._protocol_factory()
    client = MemoryTransport(loop, client_protocol, url)
    client._held = True
    server = MemoryTransport(loop, server_protocol, url)
    client._peer, server._peer = server, client
    # As asyncio's own transports do: connection_made from the loop, and the caller resumes after both.
    made: asyncio.Future[None] = loop.create_future()
    loop.call_soon(server_protocol.connection_made, server)
    loop.call_soon(client_protocol.connection_made, client)
    loop.call_soon(_resolve, made)
    try:
        await made
    except asyncio.CancelledError:
        client.close()
        raise
    client._held = False
    client._schedule_delivery()
    return client, client_protocol


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)
