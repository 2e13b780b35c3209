"""One connection to `marlin-temp serve`: JSON-RPC requests matched to their responses by id, notifications
handed to a callback (`ServedPrinter` is built on it; see `marlin_aio.protocol.rpc` for the messages)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
from collections.abc import Callable
from typing import Any

from marlin_aio.errors import ConnectionLostError, MarlinError
from marlin_aio.protocol.rpc import (
    MAX_MESSAGE_BYTES,
    RpcError,
    decode_message,
    encode_message,
    error_from_json,
    request,
)

__all__ = ["SILENCE_S", "RpcClient"]

_log = logging.getLogger("marlin_aio")

#: How long the service may say nothing before its connection is taken as lost (it speaks once a second).
SILENCE_S = 10.0


class RpcClient:
    """One connection to the service: requests matched to their responses by id, notifications to a handler.

    The read loop only resolves futures and hands notifications on (no user code runs in it); it ends when the
    service closes the socket, failing every request still waiting. The service says something at least once a
    second (an `alive` notification when it has nothing else to say): after `SILENCE_S` of nothing the connection
    is given up as lost, so no wait on a stopped or stuck service lasts for ever.
    """

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        on_notification: Callable[[str, dict[str, Any]], None],
        on_closed: Callable[[MarlinError], None],
        where: str,
    ) -> None:
        self._reader = reader
        self._writer = writer
        self._on_notification = on_notification
        self._on_closed = on_closed
        self._where = where
        self._ids = itertools.count(1)
        self._waiting: dict[int, asyncio.Future[Any]] = {}
        self._on_result: dict[int, Callable[[Any], None]] = {}
        self.closed: MarlinError | None = None
        self._steering: dict[int, str] = {}  # requests written with call_soon, by id: their refusals are logged
        loop = asyncio.get_running_loop()
        self._heard_s = loop.time()
        self._task = loop.create_task(self._read(), name=f"served printer reader {where}")
        self._watchdog = loop.call_later(SILENCE_S / 2, self._check_silence)

    def _check_silence(self) -> None:
        loop = asyncio.get_running_loop()
        silent_s = loop.time() - self._heard_s
        if silent_s >= SILENCE_S:
            self._close(ConnectionLostError(f"the service at {self._where} has said nothing for {silent_s:.0f} s"))
            self._task.cancel()
            return
        self._watchdog = loop.call_later(SILENCE_S / 2, self._check_silence)

    def call_soon(self, method: str, params: dict[str, Any]) -> None:
        """Write a request now and ignore its answer (an emergency stop, which must not wait for a turn).

        Raises:
            ConnectionLostError: the service is gone.
        """
        if self.closed is not None:
            raise ConnectionLostError(str(self.closed))
        request_id = next(self._ids)
        self._steering[request_id] = method
        self._writer.write(encode_message(request(request_id, method, params)))

    async def call(self, method: str, params: dict[str, Any], *, on_result: Callable[[Any], None] | None = None) -> Any:
        """Send a request and return its result, or raise the error the service answered with.

        `on_result` is called with the result in the read loop, before any later message is handed on: what must
        be in place for the notifications that follow the answer (a print's handle, for its progress).

        Raises:
            ConnectionLostError: the service went away before answering.
            MarlinError, ValueError, RuntimeError, OSError: as the service raised them.
        """
        if self.closed is not None:
            raise ConnectionLostError(str(self.closed))
        request_id = next(self._ids)
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._waiting[request_id] = future
        if on_result is not None:
            self._on_result[request_id] = on_result
        try:
            self._writer.write(encode_message(request(request_id, method, params)))
            return await future
        except asyncio.CancelledError:
            # The caller gave up: have the service give up too, so a command not yet written to the printer never
            # is (a caller that then retries must not get it run twice).
            # (The task's cancel cancelled the future too: cancelled, not answered.)
            if self.closed is None and (future.cancelled() or not future.done()):
                self._writer.write(encode_message(request(next(self._ids), "cancel_request", {"id": request_id})))
            raise
        finally:
            # Given up (cancelled) or answered: either way nobody waits for this id any more.
            self._waiting.pop(request_id, None)
            self._on_result.pop(request_id, None)

    async def _read(self) -> None:
        reason = f"the service at {self._where} closed the connection"
        try:
            while True:
                try:
                    line = await self._reader.readline()
                except ValueError:  # asyncio's LimitOverrunError: a line past MAX_MESSAGE_BYTES
                    reason = f"the service at {self._where} sent a message over {MAX_MESSAGE_BYTES} bytes"
                    break
                if not line.endswith(b"\n"):
                    break
                self._heard_s = asyncio.get_running_loop().time()
                try:
                    message = decode_message(line)
                except RpcError as exc:
                    reason = f"the service at {self._where} sent what is not JSON-RPC: {exc}"
                    break
                self._dispatch(message)
        except OSError as exc:
            reason = f"the connection to the service at {self._where} failed: {exc}"
        finally:
            self._close(ConnectionLostError(reason))

    def _dispatch(self, message: dict[str, Any]) -> None:
        if "method" in message:
            params = message.get("params")
            if isinstance(params, dict):
                self._on_notification(str(message["method"]), params)
            return
        request_id = message.get("id")
        steering = self._steering.pop(request_id, None) if isinstance(request_id, int) else None
        if steering is not None and "error" in message:
            _log.warning("the service at %s refused %s: %s", self._where, steering, error_from_json(message["error"]))
        future = self._waiting.get(request_id)  # type: ignore[arg-type]
        if future is None or future.done():
            return  # the answer to a request given up, or to one written with call_soon
        if "error" in message:
            future.set_exception(error_from_json(message["error"]))
            return
        result = message.get("result")
        on_result = self._on_result.pop(request_id, None)  # type: ignore[arg-type]
        if on_result is not None:
            try:
                on_result(result)
            except Exception as exc:  # a malformed result: the caller's error, never the read loop's
                future.set_exception(exc)
                return
        future.set_result(result)

    def _close(self, error: MarlinError) -> None:
        if self.closed is not None:
            return
        self.closed = error
        self._watchdog.cancel()
        for future in self._waiting.values():
            if not future.done():
                future.set_exception(error)
        self._waiting.clear()
        self._writer.close()
        self._on_closed(error)

    async def aclose(self) -> None:
        """Close the connection and wait for the reader to end."""
        self._close(ConnectionLostError(f"the connection to the service at {self._where} was closed"))
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        with contextlib.suppress(OSError):
            await self._writer.wait_closed()
