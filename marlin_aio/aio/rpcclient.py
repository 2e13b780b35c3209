"""One connection to `marlin-temp serve`: JSON-RPC requests matched to their responses by id, notifications
handed to a callback (`ServedPrinter` is built on it; see `marlin_aio.protocol.rpc` for the messages)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
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

__all__ = ["RpcClient"]


class RpcClient:
    """One connection to the service: requests matched to their responses by id, notifications to a handler.

    The read loop only resolves futures and hands notifications on (no user code runs in it); it ends when the
    service closes the socket, failing every request still waiting.
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
        self.closed: MarlinError | None = None
        self._task = asyncio.get_running_loop().create_task(self._read(), name=f"served printer reader {where}")

    def call_soon(self, method: str, params: dict[str, Any]) -> None:
        """Write a request now and ignore its answer (an emergency stop, which must not wait for a turn).

        Raises:
            ConnectionLostError: the service is gone.
        """
        if self.closed is not None:
            raise ConnectionLostError(str(self.closed))
        self._writer.write(encode_message(request(next(self._ids), method, params)))

    async def call(self, method: str, params: dict[str, Any]) -> Any:
        """Send a request and return its result, or raise the error the service answered with.

        Raises:
            ConnectionLostError: the service went away before answering.
            MarlinError, ValueError, RuntimeError, OSError: as the service raised them.
        """
        if self.closed is not None:
            raise ConnectionLostError(str(self.closed))
        request_id = next(self._ids)
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._waiting[request_id] = future
        try:
            self._writer.write(encode_message(request(request_id, method, params)))
            return await future
        finally:
            # Given up (cancelled) or answered: either way nobody waits for this id any more.
            self._waiting.pop(request_id, None)

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
        future = self._waiting.get(message.get("id"))  # type: ignore[arg-type]
        if future is None or future.done():
            return  # the answer to a request given up, or to one written with call_soon
        if "error" in message:
            future.set_exception(error_from_json(message["error"]))
        else:
            future.set_result(message.get("result"))

    def _close(self, error: MarlinError) -> None:
        if self.closed is not None:
            return
        self.closed = error
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
