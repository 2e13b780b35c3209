"""One client of `marlin-temp serve`: its reader, its writer task and bounded outgoing queue, its subscriptions.

The serial side never waits for a client: a notification that finds the queue full is dropped and counted, a client
whose unread responses pass twice the bound is let go, and requests run in tasks of the client's own, at most
`MAX_REQUESTS_IN_FLIGHT` at once (the service's methods are a table it looks requests up in).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
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
from marlin_aio.service.verbs import urgent_verbs

__all__ = [
    "CLIENT_QUEUE_BYTES",
    "CLIENT_QUEUE_MESSAGES",
    "MAX_REQUESTS_IN_FLIGHT",
    "PRIORITY_METHODS",
    "Handler",
    "ServiceLike",
    "Session",
    "param",
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
#: How long a TCP client has to send its token.
AUTH_TIMEOUT_S = 10.0
#: Bytes a client may have unsent in its transport before messages wait in the queue (where the bound applies).
WRITE_AHEAD_BYTES = 64 * 1024
#: Requests one client may have under way at once (a long M109 among them); more are refused as busy.
MAX_REQUESTS_IN_FLIGHT = 32


class ServiceLike(Protocol):
    """What a session needs of its service: the table of methods requests are looked up in."""

    @property
    def methods(self) -> Mapping[str, Handler]:
        """Each method's handler, by name."""


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
        self.remote = token is not None
        """A client over TCP: it may print only what it uploaded (a path would be the service's machine's)."""

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
        writer_task = asyncio.create_task(self.write_loop(), name=f"client {self.number} writer")
        try:
            while not self.closing:
                try:
                    # A TCP client that does not prove itself soon is let go: no idle connection holds a place.
                    bound = AUTH_TIMEOUT_S if self._token is not None else None
                    line = await asyncio.wait_for(self.reader.readline(), bound)
                except TimeoutError:
                    _log.warning("client %d did not authenticate within %g s: disconnected", self.number, bound)
                    break
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
                    break
                except OSError:
                    break
                if not line.endswith(b"\n"):
                    break
                self.take(line)
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
        task = asyncio.create_task(self._handle(request_id, handler, params), name=f"client {self.number} {method}")
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
        self._token = None
        return None

    async def _handle(self, request_id: object, handler: Handler, params: dict[str, Any]) -> None:
        # The handler's coroutine is made here, inside the task: a task cancelled before it ran leaves none behind.
        try:
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
            data = encode_message(response(request_id, result, error))
        except (TypeError, ValueError) as exc:
            unanswerable = error_to_json(RuntimeError(f"unanswerable: {str(exc)[:200]}"))
            try:
                data = encode_message(response(request_id, error=unanswerable))
            except (TypeError, ValueError):
                data = encode_message(response(None, error=unanswerable))  # the id itself was too big to echo
        self.answered += 1
        self.push(data, droppable=False)


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
