"""What a printer tells the code that uses it, whichever backend reaches it: link events (`LinkEvent`), the
firmware's requests (`HostRequest`), and why it can take no more commands.

`Printer.on_link_event`, `on_host_request`, `host_requests()` and `wait_for_failure()` read from one `Listeners`;
a backend (`marlin_aio.aio.backend`) only tells it what happened. No user code runs where a backend tells: each
listener is called from the loop soon after (`loop.call_soon`), and one that raises is logged, never able to stop
the link or the other listeners.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncGenerator, Callable
from dataclasses import dataclass, field
from typing import Literal, TypeVar

from marlin_aio.aio.feed import TemperatureFeed
from marlin_aio.errors import MarlinError, PrinterHaltedError
from marlin_aio.protocol.hostrequests import HostRequest

__all__ = ["LinkEvent", "Listeners"]

_log = logging.getLogger("marlin_aio")
_T = TypeVar("_T")


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """Something that happened to a printer's link, for `Printer.on_link_event`.

    `kind` is `connected` (the handshake is done), `reset` (the board restarted while connected: it printed
    `start`, and its targets and settings are gone), `halted` (a kill or emergency stop: it needs a reset; `error`
    says why) or `disconnected` (the port went away, or was closed, `close()` included; `error` says why).
    `message` says it for people.
    """

    kind: Literal["connected", "reset", "halted", "disconnected"]
    message: str
    error: MarlinError | None = None
    time_s: float = field(default_factory=time.time)
    """Wall-clock time (epoch seconds)."""


class Listeners:
    """The listeners of one printer, and the readers waiting for its failure or its requests.

    `loop` is the loop the backend runs on, set when it opens; nothing is told before that (nothing can happen).
    """

    def __init__(self, feed: TemperatureFeed) -> None:
        self.feed = feed
        self.loop: asyncio.AbstractEventLoop | None = None
        self._link: list[Callable[[LinkEvent], None]] = []
        self._requests: list[Callable[[HostRequest], None]] = []
        self._request_queues: list[asyncio.Queue[HostRequest | MarlinError]] = []  # of `host_requests()` readers
        self._failure_waiters: list[asyncio.Future[MarlinError]] = []

    def on_link_event(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        """Call `callback` with each link event from now on; return the function that stops the calls."""
        return _add(self._link, callback)

    def on_host_request(self, callback: Callable[[HostRequest], None]) -> Callable[[], None]:
        """Call `callback` with each request of the firmware from now on; return the function that stops them."""
        return _add(self._requests, callback)

    def link_event(self, event: LinkEvent) -> None:
        """Tell the link listeners of `event`, soon (from the loop)."""
        if self._link and self.loop is not None:
            self.loop.call_soon(_tell, self._link, event, "a link event listener failed on %s", event.kind)

    def host_request(self, request: HostRequest) -> None:
        """Tell the request listeners (and the `host_requests()` readers) of `request`, soon (from the loop)."""
        if self._requests and self.loop is not None:
            message = "a host request listener failed on %s"
            self.loop.call_soon(_tell, self._requests, request, message, request.action)

    def failed(self, error: MarlinError) -> None:
        """The printer halted or the link went away: readers of temperatures, `wait_for_failure()`, the link
        listeners and the `host_requests()` readers learn of it."""
        self.feed.fail(error)
        waiters, self._failure_waiters = self._failure_waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(error)
        kind: Literal["halted", "disconnected"] = "halted" if isinstance(error, PrinterHaltedError) else "disconnected"
        self.link_event(LinkEvent(kind, str(error), error))
        if self.loop is not None:
            for queue in self._request_queues:
                # After the requests already scheduled (a disconnect request comes before the loss it causes).
                self.loop.call_soon(queue.put_nowait, error)

    async def wait_for_failure(self, failure: MarlinError | None) -> MarlinError:
        """`failure` if there is one already, else the next one told to `failed`."""
        if failure is not None:
            return failure
        waiter: asyncio.Future[MarlinError] = asyncio.get_running_loop().create_future()
        self._failure_waiters.append(waiter)
        try:
            return await waiter
        finally:
            if waiter in self._failure_waiters:
                self._failure_waiters.remove(waiter)

    async def host_requests(self, failure: Callable[[], MarlinError | None]) -> AsyncGenerator[HostRequest, None]:
        """Every request told from now on, until a failure (`failure()` at once, if it gives one).

        Raises:
            MarlinError: the failure that ended them.
        """
        queue: asyncio.Queue[HostRequest | MarlinError] = asyncio.Queue()
        stop = self.on_host_request(queue.put_nowait)
        self._request_queues.append(queue)
        try:
            failed = failure()
            if failed is not None:
                raise failed
            while True:
                item = await queue.get()
                if isinstance(item, MarlinError):
                    raise item
                yield item
        finally:
            stop()
            self._request_queues.remove(queue)


def _add(listeners: list[Callable[[_T], None]], callback: Callable[[_T], None]) -> Callable[[], None]:
    listeners.append(callback)

    def stop() -> None:
        if callback in listeners:
            listeners.remove(callback)

    return stop


def _tell(listeners: list[Callable[[_T], None]], item: _T, message: str, what: str) -> None:
    for listener in list(listeners):  # as they are now: one that stopped meanwhile is not called
        try:
            listener(item)
        except Exception:  # a listener's bug must not reach the link
            _log.exception(message, what)
