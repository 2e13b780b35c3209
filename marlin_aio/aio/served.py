"""A printer that `marlin-temp serve` owns, with `Printer`'s API: `marlin_aio.connect("serve:NAME")`.

The service holds the serial port and keeps the printer connected; any number of clients share it through its
Unix socket (JSON-RPC 2.0, one message per line: `marlin_aio.protocol.rpc`). `ServedPrinter` is a `Printer` whose
commands travel as requests instead of G-code lines, so a program written for a port runs against a served
printer unchanged: `send`, `set_temperatures`, `wait_for_temperatures`, `temperature_readings`, `on_reading`,
`start_print` and the rest, each request answered by its own reply. What differs, and why:

- Readings come from the service's own polling (`marlin-temp serve --interval`): `poll_temperatures()` asks for
  nothing more, so ten clients watching one printer put no more M105s on its wire than one.
- A print runs inside the service: it goes on when the client that started it exits. Its `PrintHandle` follows
  the service's progress notifications, and `pause`, `resume` and `cancel` are requests.
- The link's own counters (`stats`, `trace`, `round_trips`) are the service's business: here they stay empty.
- When the service loses the printer, this printer fails as a lost port would (`wait_for_failure()` returns,
  readers of temperatures end, commands fail with the service's error); open it again once the service has
  reconnected (`keep_connected` does that).

Where: `serve:NAME` is printer NAME at the default socket (`default_socket_path()`), `serve:NAME@/path/to.sock`
at that socket, and `serve:` alone the service's only printer.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import tempfile
import time
from collections.abc import AsyncGenerator, AsyncIterator, Callable, Generator, Iterable, Sequence
from pathlib import Path
from typing import Any

from marlin_aio.aio.printer import SERVE_PREFIX, LinkEvent, Printer
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.errors import (
    ConnectError,
    ConnectionLostError,
    MarlinError,
    PortNotFoundError,
    PortPermissionError,
    PrinterHaltedError,
)
from marlin_aio.protocol.events import FirmwareInfo
from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.printjob import PrintProgress, PrintState
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.rpc import (
    MAX_MESSAGE_BYTES,
    RpcError,
    decode_message,
    encode_message,
    error_from_json,
    progress_from_json,
    reading_from_json,
    reply_from_json,
    request,
)
from marlin_aio.protocol.temperatures import TemperatureReading

__all__ = ["SOCKET_ENV", "ServedPrinter", "default_socket_path", "parse_served_port", "service_holding"]

_log = logging.getLogger("marlin_aio")

#: Names the service's socket instead of the default (`marlin-temp serve --socket` sets it for its children too).
SOCKET_ENV = "MARLIN_SERVE_SOCKET"


def default_socket_path() -> Path:
    """Where `marlin-temp serve` listens unless told otherwise: `$MARLIN_SERVE_SOCKET`, else
    `$XDG_RUNTIME_DIR/marlin-temp/serve.sock` (a per-user folder the system empties at logout), else
    `/tmp/marlin-temp-UID/serve.sock`."""
    named = os.environ.get(SOCKET_ENV)
    if named:
        return Path(named)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    folder = Path(runtime) / "marlin-temp" if runtime else Path(tempfile.gettempdir()) / f"marlin-temp-{os.getuid()}"
    return folder / "serve.sock"


def parse_served_port(port: str) -> tuple[str | None, Path]:
    """(printer name or None for the only one, socket path) of `serve:NAME`, `serve:NAME@/path.sock` or `serve:`.

    Raises:
        ValueError: `port` does not start with `serve:`.
    """
    if not port.startswith(SERVE_PREFIX):
        raise ValueError(f"not a served printer: {port!r} (expected serve:NAME)")
    rest = port[len(SERVE_PREFIX) :]
    name, at, path = rest.partition("@")
    return (name or None), (Path(path) if at else default_socket_path())


class _Rpc:
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


class ServedPrinter(Printer):
    """A printer owned by `marlin-temp serve`, reached through its socket: `Printer("serve:NAME")` makes one.

    The arguments are `Printer`'s; those about the serial link (`baudrate`, `handshake`, `numbered`, the window,
    `password`) are the service's business and are ignored here. The heater limits still apply: a target over them
    is refused before anything is sent (and the service checks against its own).
    """

    _rpc: _Rpc | None = None

    def __init__(self, port: str, **options: Any) -> None:
        super().__init__(port, **options)
        self.name, self.socket_path = parse_served_port(port)
        self._lost: MarlinError | None = None
        self._served_print: ServedPrintHandle | None = None
        self._link_up = False
        self._loop: asyncio.AbstractEventLoop | None = None

    # ------------------------------------------------------------------------------------------- lifecycle

    async def open(self) -> None:
        """Connect to the service and to its printer.

        Raises:
            RuntimeError: already open.
            PortNotFoundError: no service listens at the socket, or it has no such printer.
            PortPermissionError: the socket belongs to another user.
            ConnectError: the service's printer is not connected now (it is reconnecting).
        """
        if self._rpc is not None and self._rpc.closed is None:
            raise RuntimeError(f"the printer {self.port} is already open")
        where = str(self.socket_path)
        try:
            reader, writer = await asyncio.open_unix_connection(where, limit=MAX_MESSAGE_BYTES)
        except (FileNotFoundError, ConnectionRefusedError):
            raise PortNotFoundError(
                f"no marlin-temp serve is listening at {where} (start one with `marlin-temp serve`)"
            ) from None
        except PermissionError:
            raise PortPermissionError(
                f"not allowed to reach the service at {where}: it belongs to another user"
            ) from None
        except OSError as exc:
            raise ConnectError(f"cannot reach the service at {where}: {exc.strerror or exc}") from None
        self._loop = asyncio.get_running_loop()
        self._lost = None
        self._served_print = None
        self._feed = type(self._feed)()  # readings of an earlier connection are not this one's
        self._rpc = _Rpc(reader, writer, self._notified, self._service_closed, where)
        try:
            hello = await self._rpc.call("hello", {"printer": self.name, "subscribe": ["readings", "link", "progress"]})
            self._take_hello(hello)
        except BaseException:
            await self.close()
            raise
        _log.info("connected to %s through the service at %s", self.name, where)
        self._link_event(
            LinkEvent(
                "connected", f"{self.port} (served: {self.firmware.name if self.firmware else 'firmware unknown'})"
            )
        )

    def _take_hello(self, hello: Any) -> None:
        if not isinstance(hello, dict) or not isinstance(hello.get("printer"), dict):
            raise ConnectError(f"the service at {self.socket_path} answered hello with {str(hello)[:200]}")
        info = hello["printer"]
        self.name = str(info["name"])
        firmware = info.get("firmware")
        if isinstance(firmware, dict):
            self.firmware = FirmwareInfo(str(firmware.get("name", "")), dict(firmware.get("fields", {})))
        self.capabilities = dict(info.get("capabilities") or {})
        self._link_up = bool(info.get("link_up"))
        latest = info.get("latest")
        if latest is not None:
            assert self._loop is not None
            self._feed.publish(reading_from_json(latest, self._loop.time()))
        if not self._link_up:
            reason = info.get("last_error") or "it is not connected"
            raise ConnectError(
                f"the service's printer {self.name} is not connected now ({reason}); it reconnects by itself"
            )

    async def close(self) -> None:
        """Leave the service (the printer stays connected there, and a print started from here goes on)."""
        rpc, self._rpc = self._rpc, None
        if rpc is not None:
            await rpc.aclose()

    @property
    def reset_on_open(self) -> bool:
        """Always False: whether the board reset when the service opened its port is the service's news."""
        return False

    # ------------------------------------------------------------------------------------------- notifications

    def _notified(self, method: str, params: dict[str, Any]) -> None:
        if params.get("printer") != self.name:
            return
        if method == "reading":
            assert self._loop is not None
            with contextlib.suppress(RpcError):
                self._feed.publish(reading_from_json(params.get("reading"), self._loop.time()))
        elif method == "link":
            kind = params.get("kind")
            message = str(params.get("message", ""))
            if kind == "reset":
                self._link_event(LinkEvent("reset", message))
            elif kind in ("connection_lost", "halted", "thermal_runaway"):
                error_type = PrinterHaltedError if kind != "connection_lost" else ConnectionLostError
                self._printer_failed(error_type(f"{self.name} (served): {message}"))
        elif method == "progress" and self._served_print is not None:
            self._served_print.update(params)

    def _printer_failed(self, error: MarlinError) -> None:
        if self._lost is not None:
            return
        self._lost = error
        self._link_up = False
        self._failed(error)  # readers, failure waiters, the link event: as a lost port tells them

    def _service_closed(self, error: MarlinError) -> None:
        if self._served_print is not None:
            self._served_print.orphaned(error)
        self._printer_failed(error)

    def _link_event(self, event: LinkEvent) -> None:
        if self._link_listeners and self._loop is not None:
            self._loop.call_soon(self._tell_link_listeners, event)

    def _call(self, method: str, **params: Any) -> Any:
        rpc = self._rpc
        if rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open")
        if self._lost is not None:
            raise self._lost
        return rpc.call(method, {"printer": self.name, **params})

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float | None = None, numbered: bool | None = None) -> Reply:
        """Send one command through the service and return its reply (see `Printer.send`; `numbered` is the
        service's choice). Commands of all clients go out in the order the service received them.

        Raises:
            ValueError: the command is malformed or over the limits (checked here first, nothing sent).
            MarlinError: as `Printer.send`, raised by the service; ConnectionLostError if the service went away.
        """
        from marlin_aio.protocol.commands import validate_command
        from marlin_aio.protocol.heaters import check_gcode_targets

        text = validate_command(command)
        check_gcode_targets(text, self._heater_limits)
        timeout = self.timeout_s if timeout_s is None else timeout_s
        return reply_from_json(await self._call("send", command=text, timeout_s=timeout))

    def emergency_stop(self) -> None:
        """Have the service write M112 at once, ahead of anything queued (see `Printer.emergency_stop`).

        Raises:
            ConnectionLostError: the service is gone, so the stop cannot reach the printer (cut its power).
        """
        if self._rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open: M112 cannot reach it (cut its power)")
        self._rpc.call_soon("emergency_stop", {"printer": self.name})
        _log.warning("emergency stop (M112) asked of the service for %s", self.name)

    def interrupt_wait(self) -> bool:
        """Have the service end a heater wait with M108, where the firmware can (see `Printer.interrupt_wait`)."""
        if not self.capabilities.get("EMERGENCY_PARSER", False):
            return False
        if self._rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open")
        self._rpc.call_soon("interrupt_wait", {"printer": self.name})
        return True

    # ------------------------------------------------------------------------------------------- temperatures

    async def read_temperatures(self) -> TemperatureReading:
        """Have the service ask the printer (M105) once and return the reading.

        Raises:
            MarlinError: as `send`.
        """
        assert self._loop is not None or self._rpc is None
        value = await self._call("read_temperatures")
        loop = asyncio.get_running_loop()
        return reading_from_json(value, loop.time())

    def temperature_readings(self) -> AsyncGenerator[TemperatureReading, None]:
        """Every reading the service takes from now on (see `Printer.temperature_readings`)."""
        return self._feed.readings(self._lost if self._rpc is not None else ConnectionLostError("not open"))

    @contextlib.asynccontextmanager
    async def poll_temperatures(self, interval_s: float = 0.01, *, auto_report: bool = True) -> AsyncIterator[None]:
        """The service polls the printer at its own rate for every client at once: this asks for nothing more.

        Raises:
            ValueError: `interval_s` is not positive.
        """
        if not interval_s > 0:
            raise ValueError(f"interval_s must be positive, got {interval_s}")
        yield

    def _polled(self) -> bool:
        return True  # the service's own poller runs while it is connected

    # ------------------------------------------------------------------------------------------- printing

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool = False,
        window_bytes: int | None = None,
        check: bool = True,
        timeout_s: float | None = None,
    ) -> PrintHandle:
        """Have the service print `source` (a file it can read, or a list of lines); the print runs there and
        goes on if this client leaves. See `Printer.start_print`.

        Raises:
            ValueError: a line is not a valid command or is over the limits (nothing is sent).
            OSError: the service cannot read the file.
            RuntimeError: a print is already running on that printer (whoever started it).
            MarlinError: as `send`.
        """
        params: dict[str, Any] = {"send_ahead": send_ahead, "check": check}
        if window_bytes is not None:
            params["window_bytes"] = window_bytes
        if timeout_s is not None:
            params["timeout_s"] = timeout_s
        if isinstance(source, str | Path):
            params["path"] = _absolute(source)  # the service's working folder is not this one
        elif isinstance(source, Sequence):
            params["lines"] = [str(line) for line in source]
        else:
            raise ValueError("a served printer prints a file or a list of lines, not an iterator")
        value = await self._call("start_print", **params)
        assert self._loop is not None
        handle = ServedPrintHandle(self, progress_from_json(value.get("progress")), str(value.get("file", "")))
        self._served_print = handle
        return handle

    # ------------------------------------------------------------------------------------------- state

    @property
    def state(self) -> LinkState:
        """READY while the service's printer is connected and this client is attached; else LOST."""
        return LinkState.READY if self.is_connected else LinkState.LOST

    @property
    def is_connected(self) -> bool:
        """True while attached to the service and its printer is connected."""
        return self._rpc is not None and self._rpc.closed is None and self._lost is None and self._link_up

    async def wait_for_failure(self) -> MarlinError:
        """Wait until the service loses the printer or this client loses the service; return why."""
        if self._lost is not None:
            return self._lost
        assert self._loop is not None, "open the printer first"
        waiter: asyncio.Future[MarlinError] = self._loop.create_future()
        self._failure_waiters.append(waiter)
        try:
            return await waiter
        finally:
            if waiter in self._failure_waiters:
                self._failure_waiters.remove(waiter)

    @property
    def heater_limits(self) -> HeaterLimits:
        """The limits this client checks targets against before the service checks its own."""
        return self._heater_limits


class ServedPrintHandle(PrintHandle):
    """A print running inside the service, as its starter follows it: progress from the service's notifications,
    `pause`, `resume` and `cancel` as requests. Leaving (closing the printer) does not stop the print."""

    def __init__(self, printer: ServedPrinter, progress: PrintProgress, file: str) -> None:
        # Not PrintHandle's link-bound state: the job and its link live in the service.
        self._printer = printer
        self._progress = progress
        self.file = file
        loop = asyncio.get_running_loop()
        self._done: asyncio.Future[PrintProgress] = loop.create_future()
        self._progress_s = time.monotonic()

    @property
    def progress(self) -> PrintProgress:
        """The progress the service last told (it tells every half second while the print runs, and at once on
        a change of state)."""
        return self._progress

    @property
    def finished(self) -> bool:
        """True once the service said the print ended."""
        return self._done.done()

    def update(self, params: dict[str, Any]) -> None:
        """Take a progress notification from the service."""
        with contextlib.suppress(RpcError):
            self._progress = progress_from_json(params.get("progress"))
        if self._done.done():
            return
        if self._progress.state is PrintState.FAILED:
            self._done.set_exception(error_from_json(params.get("error") or {"message": "the print failed"}))
            self._done.exception()  # a print nobody awaits must not log "exception never retrieved"
        elif self._progress.state in (PrintState.DONE, PrintState.CANCELLED):
            self._done.set_result(self._progress)

    def orphaned(self, error: MarlinError) -> None:
        """The connection to the service ended: the print goes on there, but this handle can follow it no more."""
        if not self._done.done():
            self._done.set_exception(
                ConnectionLostError(f"{error} (the print goes on in the service: `marlin-temp serve` shows it)")
            )
            self._done.exception()

    def pause(self) -> None:
        """Ask the service to stop feeding lines (what is in flight completes)."""
        self._ask("pause")

    def resume(self) -> None:
        """Ask the service to feed lines again."""
        self._ask("resume")

    def _ask(self, method: str) -> None:
        rpc = self._printer._rpc
        if rpc is None:
            raise ConnectionLostError(f"the printer {self._printer.port} is not open")
        rpc.call_soon(method, {"printer": self._printer.name})

    async def cancel(self, script: list[str] | tuple[str, ...] = ()) -> PrintProgress:
        """Have the service stop the print, wait for it to end, then send `script` (see `PrintHandle.cancel`).

        Raises:
            MarlinError: the print failed before it could be cancelled, or the script failed.
        """
        await self._printer._call("cancel", script=list(script))
        return await self.wait()

    async def wait(self) -> PrintProgress:
        """Wait for the print to end in the service; return its final progress.

        Raises:
            MarlinError: as `PrintHandle.wait`; ConnectionLostError if the service went away meanwhile.
        """
        return await asyncio.shield(self._done)

    def __await__(self) -> Generator[object, None, PrintProgress]:
        return self.wait().__await__()

    def check(self) -> None:
        """Nothing to do: the service tells when the print ends."""


def service_holding(port: str, socket_path: Path | None = None) -> str | None:
    """The `serve:NAME` URL of the printer that a running service holds on `port`, or None.

    Reads the service's registry (`serve.json` beside its socket) without connecting; a registry left by a
    service that is gone (its socket refuses) is not believed by whoever then connects.
    """
    import json

    path = (socket_path or default_socket_path()).with_name("serve.json")
    try:
        registry = json.loads(path.read_text())
        printers = registry["printers"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(printers, dict):
        return None
    wanted = os.path.realpath(port) if port.startswith("/") else port
    for name, held in printers.items():
        if isinstance(held, str) and (held == port or (held.startswith("/") and os.path.realpath(held) == wanted)):
            suffix = "" if socket_path is None else f"@{socket_path}"
            return f"{SERVE_PREFIX}{name}{suffix}"
    return None


def _absolute(path: str | Path) -> str:
    """`path` made absolute against this process's working folder (no file is touched)."""
    return os.path.abspath(path)
