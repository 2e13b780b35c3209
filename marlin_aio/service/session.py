"""One client of `marlin-temp serve`: its reader, its writer task and bounded outgoing queue, its subscriptions.

The serial side never waits for a client: a notification that finds the queue full is dropped and counted, a client
whose unread responses pass twice the bound is let go, and requests run in tasks of the client's own, at most
`MAX_REQUESTS_IN_FLIGHT` at once (the service's methods are a table it looks requests up in).

Each client gets its own share and no more:
- Backpressure on that client alone: while more than `UNREAD_BOUND_BYTES` of its answers wait unread, its socket
  is not read, so a client that asks and never reads holds a bounded backlog and the loop's time goes to others.
- A heavy request (`HEAVY_METHODS`: a `history` is hundreds of kilobytes) runs one at a time per client, and only
  once the client has read the last one's answer.
- Over TCP, a client proves itself (`auth`, the token) within `AUTH_TIMEOUT_S` of connecting, whatever it sends
  meanwhile; the service lets at most `MAX_AUTHENTICATING` wait at once, evicting the oldest, so a crowd of clients
  without the token never locks out one that has it (which authenticates with its first line).
- A client that ends its sending side (`printf ... | socat`) still gets the answers to what it sent; one that
  closed altogether (found out when writing to it fails) has its requests cancelled.

A client that reads nothing waits for itself: even its emergency stop is read only once it has read its backlog
(the library's client reads all the time; an emergency stop goes out at once from any other client).

Over 400 lines because a client's reading, its writing, its bounds and the dispatch of its requests all turn on
the same few fields (its queue, its requests under way, its deadline): apart, each part would reach into the others.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import select
from collections import deque
from collections.abc import Awaitable, Callable, Iterable, Mapping
from typing import Any, Protocol

import marlin_aio
from marlin_aio.protocol.rpc import (
    INVALID_PARAMS,
    INVALID_REQUEST,
    MAX_MESSAGE_BYTES,
    METHOD_NOT_FOUND,
    RpcError,
    decode_message,
    encode_message,
    error_to_json,
    response,
)
from marlin_aio.service.verbs import Encoded, heavy_verbs, urgent_verbs

__all__ = [
    "AUTH_TIMEOUT_S",
    "CLIENT_QUEUE_BYTES",
    "CLIENT_QUEUE_MESSAGES",
    "HEAVY_METHODS",
    "MAX_AUTHENTICATING",
    "MAX_REQUESTS_IN_FLIGHT",
    "MAX_TCP_CLIENTS",
    "PRIORITY_METHODS",
    "UNREAD_BOUND_BYTES",
    "Encoded",
    "Handler",
    "ServiceLike",
    "Session",
    "param",
    "tcp_clients",
]

_log = logging.getLogger("marlin_aio.service")

#: Messages a client may have waiting to be read before notifications to it are dropped.
CLIENT_QUEUE_MESSAGES = 1_000
#: Bytes of messages a client may have waiting (whichever bound comes first: a few big answers are as many bytes
#: as thousands of readings).
CLIENT_QUEUE_BYTES = 16 * 1024 * 1024
#: Methods never refused as busy, and never waiting behind a client's other requests: they stop or steer what is
#: under way (an emergency stop must get through however many requests its client has out).
# The table's urgent verbs (`Queue.URGENT`), and the session's own way to give up a request.
PRIORITY_METHODS = urgent_verbs() | {"cancel_request"}
#: How long a TCP client has to send its token, counted from when it connected (whatever it sends meanwhile).
AUTH_TIMEOUT_S = 10.0
#: TCP clients waiting to authenticate at once; one more evicts the one waiting longest.
MAX_AUTHENTICATING = 16
#: TCP clients authenticated at once (the Unix socket's are the owner's own: not bounded).
MAX_TCP_CLIENTS = 64
#: Bytes of a client's answers and notifications that may wait unread before its socket is no longer read.
UNREAD_BOUND_BYTES = 256 * 1024
#: Methods whose answers are big (a history: up to hundreds of kilobytes): one at a time per client, and only
#: once the client has read what it was answered before (the table's `Queue.HEAVY` verbs).
HEAVY_METHODS = heavy_verbs()
#: Bytes a client may have unsent in its transport before messages wait in the queue (where the bound applies).
WRITE_AHEAD_BYTES = 64 * 1024
#: Requests one client may have under way at once (a long M109 among them); more are refused as busy.
MAX_REQUESTS_IN_FLIGHT = 32


class ServiceLike(Protocol):
    """What a session needs of its service: the table of methods requests are looked up in, and its clients."""

    @property
    def methods(self) -> Mapping[str, Handler]:
        """Each method's handler, by name."""

    @property
    def sessions(self) -> set[Session]:
        """The clients connected now."""


class Session:
    """One client: its reader, its writer task and its bounded outgoing queue, its subscriptions."""

    def __init__(
        self,
        service: ServiceLike,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        number: int,
        token: str | None = None,
    ):
        self.service = service
        self.reader = reader
        self.writer = writer
        self.number = number
        self.queue: deque[bytes] = deque()
        self.wakeup = asyncio.Event()
        self.drained = asyncio.Event()  # set by the writer each time it has written all that was queued
        self.dropped = 0
        self.answered = 0  # responses given (errors included)
        self.subscriptions: dict[str, set[str]] = {}
        self.requests: set[asyncio.Task[None]] = set()
        self.by_id: dict[object, asyncio.Task[None]] = {}  # requests under way by their id, for `cancel_request`
        self.queued_bytes = 0
        self.uploads: set[str] = set()  # uploads this client began and has not finished
        self.closing = False
        # A client over TCP proves itself first (`auth` with the token); one on the owner-only socket already has.
        self._token = token
        self._auth_deadline_s = asyncio.get_running_loop().time() + AUTH_TIMEOUT_S if token is not None else None
        self._auth_timeout: asyncio.Timeout | None = None
        self._heavy = asyncio.Lock()
        self.remote = token is not None
        """A client over TCP: it may print only what it uploaded (a path would be the service's machine's)."""

    @property
    def authenticating(self) -> bool:
        """A TCP client that has not given the token yet (and is not being let go)."""
        return self._token is not None and not self.closing

    def subscribed(self, printer: str, topic: str) -> bool:
        return topic in self.subscriptions.get(printer, ())

    def push(self, data: bytes, *, droppable: bool = True) -> None:
        """Queue a message; a notification finding the queue full is dropped, a response closes the session."""
        if self.closing:
            return
        if len(self.queue) >= CLIENT_QUEUE_MESSAGES or self.queued_bytes >= CLIENT_QUEUE_BYTES:
            if droppable:
                self.dropped += 1
                return
            if len(self.queue) >= 2 * CLIENT_QUEUE_MESSAGES or self.queued_bytes >= 2 * CLIENT_QUEUE_BYTES:
                _log.warning("client %d reads nothing: disconnected", self.number)
                self.close(abort=True)
                return
        if not self.queue and self.writer.transport.get_write_buffer_size() < WRITE_AHEAD_BYTES:
            # The client keeps up: straight to the transport (no writer task to wake per message, which is most
            # of a served round trip's cost). Past this much unsent, messages queue and the bound applies.
            self.writer.write(data)
            return
        self.queue.append(data)
        self.queued_bytes += len(data)
        self.wakeup.set()

    def close(self, *, abort: bool = False) -> None:
        """Stop taking messages and close the connection: after what was written has gone out, or with `abort` at
        once (a client that reads nothing would hold a closing connection open for ever)."""
        self.closing = True
        self.wakeup.set()
        self.drained.set()  # nothing waits for a client's reading any more
        if abort:
            self.writer.transport.abort()
        else:
            self.writer.close()

    async def write_loop(self) -> None:
        with contextlib.suppress(OSError):
            while not self.closing:
                if not self.queue:
                    self.wakeup.clear()
                    await self.wakeup.wait()
                    continue
                batch = b"".join(self.queue)
                self.queue.clear()
                self.queued_bytes = 0
                self.writer.write(batch)
                await self.writer.drain()
                self.drained.set()

    async def run(self) -> None:
        """Serve the client until it leaves or is let go."""
        writer_task = asyncio.create_task(self.write_loop(), name=f"client {self.number} writer")
        try:
            if await self._read() and not self.closing:
                await self._finish_taken()  # it ended its sending side: what it sent is still answered
        finally:
            for task in self.requests:
                task.cancel()  # a client that left waits for nothing; a print it started goes on in the farm
            if self.queue and not self.closing:
                # What was answered before the client hung up its sending side still reaches it.
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._flushed(), 1.0)
            self.close()
            writer_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, OSError):
                await writer_task
            try:
                await asyncio.wait_for(self.writer.wait_closed(), 1.0)
            except (TimeoutError, OSError):
                self.writer.transport.abort()  # what it did not read in a second it will not read

    async def _read(self) -> bool:
        """Take the client's lines until it ends its sending side (True) or is let go (False)."""
        try:
            # A TCP client that does not prove itself soon is let go, counted from when it connected: a line now
            # and then (even a bad one) holds no place for longer. Authenticating lifts the deadline.
            async with asyncio.timeout_at(self._auth_deadline_s) as self._auth_timeout:
                return await self._read_lines()
        except TimeoutError:
            _log.warning("client %d did not authenticate within %g s: disconnected", self.number, AUTH_TIMEOUT_S)
            return False
        except OSError:
            return False

    async def _read_lines(self) -> bool:
        while not self.closing:
            if self._backlogged():
                await self._caught_up()
                continue
            try:
                line = await self.reader.readline()
            except ValueError:  # a line past the limit: answered once, then the client is let go
                self.push(
                    encode_message(
                        response(
                            None,
                            error=error_to_json(
                                RpcError(INVALID_REQUEST, f"a message is at most {MAX_MESSAGE_BYTES} bytes")
                            ),
                        )
                    ),
                    droppable=False,
                )
                return False
            if not line.endswith(b"\n"):
                return True  # the end of what it sends (a last line without its newline is no message)
            self.take(line)
        return False

    @property
    def unread_bytes(self) -> int:
        """Bytes of answers and notifications written for the client and not yet taken by its socket."""
        return self.queued_bytes + self.writer.transport.get_write_buffer_size()

    def _backlogged(self) -> bool:
        return self.unread_bytes > UNREAD_BOUND_BYTES or len(self.queue) >= CLIENT_QUEUE_MESSAGES // 2

    async def _caught_up(self) -> None:
        """Wait until the client has read its backlog down to the bound (or is let go).

        Raises:
            OSError: the connection was lost meanwhile.
        """
        while self._backlogged() and not self.closing:
            if self.queue:
                self.drained.clear()
                await self.drained.wait()  # the writer task moves the queue out as the client reads
            else:
                await self.writer.drain()  # all of it is in the transport's buffer

    async def _finish_taken(self) -> None:
        """The client ended its sending side: let the requests it sent finish (each is bounded by its own timeout),
        unless it turns out to have closed altogether; `run` then flushes their answers and closes."""
        if self._hung_up():
            return
        # A client that closed altogether over TCP looks the same until a write to it fails (the `alive` the
        # service sends every second): the connection is then lost, and what it asked is cancelled.
        lost = asyncio.ensure_future(self._lost())
        try:
            while self.requests and not self.closing and not lost.done():
                await asyncio.wait({*self.requests, lost}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            if not lost.done():
                lost.cancel()

    def _hung_up(self) -> bool:
        """Whether the client closed its socket altogether (not only its sending side); Unix sockets say so."""
        sock = self.writer.get_extra_info("socket")
        if sock is None:
            return False
        poller = select.poll()
        poller.register(sock.fileno(), select.POLLHUP)
        return any(events & select.POLLHUP for _, events in poller.poll(0))

    async def _lost(self) -> None:
        # Shielded: cancelling this wait must not cancel the transport's own "closed" future, awaited later.
        with contextlib.suppress(OSError):
            await asyncio.shield(self.writer.wait_closed())

    async def _flushed(self) -> None:
        while self.queue:
            self.drained.clear()
            await self.drained.wait()

    def take(self, line: bytes) -> None:
        """Handle one received line: a request gets a task of its own, a malformed one an error at once."""
        request_id: object = None
        try:
            message = decode_message(line)
            request_id = message.get("id")
            method = message.get("method")
            params = message.get("params", {})
            if message.get("jsonrpc") != "2.0" or not isinstance(method, str):
                raise RpcError(INVALID_REQUEST, 'a request has "jsonrpc": "2.0" and a "method"')
            if not isinstance(params, dict):
                raise RpcError(INVALID_PARAMS, "params are an object: by name, not by position")
            if self._token is not None:
                refused = self._refused(method, params)
                self.answer(request_id, {"authenticated": True} if refused is None else None, error=refused)
                if refused is not None:
                    self.close()  # after the one error line: nothing more is taken from it
                return
            if method == "cancel_request":
                # The client gave up waiting for an answer: what it asked is cancelled where it stands (a command
                # not yet written to the printer is never written), so a retry cannot make it run twice.
                task = self.by_id.get(params.get("id"))
                if task is not None:
                    task.cancel()
                self.answer(request_id, task is not None)
                return
            handler = self.service.methods.get(method)
            if handler is None:
                raise RpcError(
                    METHOD_NOT_FOUND, f"no method {method[:60]!r}; there are {', '.join(sorted(self.service.methods))}"
                )
            if len(self.requests) >= MAX_REQUESTS_IN_FLIGHT and method not in PRIORITY_METHODS:
                raise RpcError(INVALID_REQUEST, f"busy: {MAX_REQUESTS_IN_FLIGHT} requests of this client are under way")
        except RpcError as exc:
            self.answer(request_id, error=error_to_json(exc))
            return
        heavy = method in HEAVY_METHODS
        task = asyncio.create_task(
            self._handle(request_id, handler, params, heavy=heavy), name=f"client {self.number} {method}"
        )
        self.requests.add(task)
        task.add_done_callback(self.requests.discard)
        if isinstance(request_id, int | str) and request_id not in self.by_id:
            self.by_id[request_id] = task
            task.add_done_callback(lambda _: self.by_id.pop(request_id, None))

    def _refused(self, method: str, params: dict[str, Any]) -> dict[str, Any] | None:
        """Check a TCP client's first request; the error to answer it with, or None once it is let in."""
        given = params.get("token")
        if method != "auth" or not isinstance(given, str):
            return error_to_json(RpcError(INVALID_REQUEST, 'over TCP the first request is "auth" with the token'))
        assert self._token is not None
        # surrogatepass: a lone surrogate in the JSON must be a wrong token, not an encoding error.
        if not hmac.compare_digest(given.encode("utf-8", "surrogatepass"), self._token.encode()):
            _log.warning("client %d gave a wrong token: disconnected", self.number)
            return error_to_json(RpcError(INVALID_REQUEST, "wrong token"))
        if tcp_clients(self.service.sessions) >= MAX_TCP_CLIENTS:
            # Counted here, not at connect: clients waiting to authenticate have a bound of their own.
            _log.warning("client %d: already %d TCP clients: disconnected", self.number, MAX_TCP_CLIENTS)
            return error_to_json(RpcError(INVALID_REQUEST, f"busy: {MAX_TCP_CLIENTS} TCP clients are connected"))
        self._token = None
        if self._auth_timeout is not None:
            self._auth_timeout.reschedule(None)
        return None

    async def _handle(self, request_id: object, handler: Handler, params: dict[str, Any], *, heavy: bool) -> None:
        # The handler's coroutine is made here, inside the task: a task cancelled before it ran leaves none behind.
        try:
            if heavy:
                async with self._heavy:
                    await self._caught_up()  # a client that reads nothing gets one big answer, not one per request
                    result = await handler(self, params)
            else:
                result = await handler(self, params)
        except asyncio.CancelledError:
            raise
        except (RpcError, marlin_aio.MarlinError, ValueError, RuntimeError, OSError) as exc:
            self.answer(request_id, error=error_to_json(exc))
        except Exception as exc:  # a bug of ours: answered and logged, never the end of the service
            _log.exception("request failed")
            self.answer(request_id, error=error_to_json(RuntimeError(f"the service failed: {exc!r}")))
        else:
            self.answer(request_id, result)

    def answer(self, request_id: object, result: object = None, *, error: dict[str, Any] | None = None) -> None:
        if request_id is None and error is None:
            return  # a notification from the client: nothing to answer
        try:
            data = (
                _encoded_response(request_id, result)
                if isinstance(result, Encoded) and error is None
                else encode_message(response(request_id, result, error))
            )
        except (TypeError, ValueError) as exc:
            unanswerable = error_to_json(RuntimeError(f"unanswerable: {str(exc)[:200]}"))
            try:
                data = encode_message(response(request_id, error=unanswerable))
            except (TypeError, ValueError):
                data = encode_message(response(None, error=unanswerable))  # the id itself was too big to echo
        self.answered += 1
        self.push(data, droppable=False)


def tcp_clients(sessions: Iterable[Session]) -> int:
    """How many of `sessions` are TCP clients let in: authenticated, and not being let go."""
    return sum(session.remote and not session.closing and not session.authenticating for session in sessions)


def _encoded_response(request_id: object, result: Encoded) -> bytes:
    """`encode_message(response(request_id, result))` for a result already encoded: the same bytes, spliced.

    Raises:
        ValueError: it is longer than `MAX_MESSAGE_BYTES`.
    """
    echoed = json.dumps(request_id, separators=(",", ":"), allow_nan=False).encode("ascii")
    data = b'{"jsonrpc":"2.0","id":' + echoed + b',"result":' + result.json + b"}\n"
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message of {len(data)} bytes is over the limit of {MAX_MESSAGE_BYTES}")
    return data


#: A method of the service: the session that asked, and the request's parameters; its result is the answer.
Handler = Callable[["Session", dict[str, Any]], Awaitable[object]]


def param(
    params: dict[str, Any], name: str, kind: type | tuple[type, ...], default: Any = ..., *, optional: bool = False
) -> Any:
    """The request parameter `name`, checked to be of `kind` (missing: `default`, or an error if none is given).

    Raises:
        RpcError: `INVALID_PARAMS`, naming the parameter.
    """
    value = params.get(name, default)
    if value is ...:
        raise RpcError(INVALID_PARAMS, f"missing parameter {name!r}")
    if value is None and (optional or default is None):
        return None
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):  # JSON's true is no number
        raise RpcError(INVALID_PARAMS, f"parameter {name!r} has the wrong type ({type(value).__name__})")
    return value
