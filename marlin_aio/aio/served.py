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
- The firmware's requests (`prompt`, `waiting_for_user`, `last_host_request`, `on_host_request`,
  `host_requests()`) are the service's: it tells each as its printer makes it, and `answer_prompt` is a request
  (the service checks the index against the prompt open there, and writes M876).
- The link's own counters (`stats`, `trace`, `round_trips`) are the service's business: here they stay empty.
- When the service loses the printer, this printer fails as a lost port would (`wait_for_failure()` returns,
  readers of temperatures end, commands fail with the service's error); open it again once the service has
  reconnected (`keep_connected` does that).

Where: `serve:NAME@tcp://HOST:PORT` reaches a service's TCP listener (its token in `$MARLIN_SERVE_TOKEN`);
`serve:NAME` is printer NAME at the default socket (`default_socket_path()`), `serve:NAME@/path/to.sock`
at that socket, and `serve:` alone the service's only printer.

Over 400 lines because it is `Printer`'s API replaced method by method (commands, temperatures, prints, the
firmware's requests) over one connection: spread over modules, a reader would no longer see in one place which of
`Printer`'s methods a served printer answers differently.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections.abc import AsyncGenerator, AsyncIterator, Iterable, Sequence
from pathlib import Path
from typing import Any

from marlin_aio.aio.printer import LinkEvent, Printer
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.aio.rpcclient import RpcClient
from marlin_aio.aio.servedprint import ServedPrintHandle, absolute, check_file, file_lines, upload
from marlin_aio.aio.servicepaths import TCP_PREFIX, TOKEN_ENV, parse_served_port
from marlin_aio.errors import (
    ConnectError,
    ConnectionLostError,
    MarlinError,
    PortNotFoundError,
    PortPermissionError,
    PrinterHaltedError,
)
from marlin_aio.protocol.events import FirmwareInfo
from marlin_aio.protocol.hostrequests import HostRequest, Prompt
from marlin_aio.protocol.linkstate import LinkState
from marlin_aio.protocol.printjob import gcode_commands
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.rpc import (
    MAX_MESSAGE_BYTES,
    RpcError,
    host_request_from_json,
    progress_from_json,
    prompt_from_json,
    reading_from_json,
    reply_from_json,
)
from marlin_aio.protocol.temperatures import TemperatureReading

__all__ = ["ServedPrinter"]

_log = logging.getLogger("marlin_aio")


class ServedPrinter(Printer):
    """A printer owned by `marlin-temp serve`, reached through its socket: `Printer("serve:NAME")` makes one.

    The arguments are `Printer`'s; those about the serial link (`baudrate`, `handshake`, `numbered`, the window,
    `password`) are the service's business and are ignored here. The heater limits still apply: a target over them
    is refused before anything is sent (and the service checks against its own).
    """

    _rpc: RpcClient | None = None

    def __init__(self, port: str, **options: Any) -> None:
        super().__init__(port, **options)
        self.name, self.socket_path = parse_served_port(port)
        self._remote = self.socket_path.startswith(TCP_PREFIX)
        self._lost: MarlinError | None = None
        self._served_print: ServedPrintHandle | None = None
        self._link_up = False
        self._loop: asyncio.AbstractEventLoop | None = None
        # The firmware's requests as the service last told them (its printer tracks them: see `_take_requests`).
        self._prompt: Prompt | None = None
        self._waiting_for_user = False
        self._last_request: HostRequest | None = None

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
        tcp = self._remote
        token = os.environ.get(TOKEN_ENV, "")
        if tcp and not token:
            raise ConnectError(f"the service at {where} wants its token: set ${TOKEN_ENV}")
        try:
            if tcp:
                host, _, port_text = where[len(TCP_PREFIX) :].rpartition(":")
                reader, writer = await asyncio.open_connection(
                    host.strip("[]"), int(port_text), limit=MAX_MESSAGE_BYTES
                )
            else:
                reader, writer = await asyncio.open_unix_connection(where, limit=MAX_MESSAGE_BYTES)
        except (FileNotFoundError, ConnectionRefusedError):
            raise PortNotFoundError(
                f"no marlin-temp serve is listening at {where} (start one with `marlin-temp serve`)"
            ) from None
        except PermissionError:
            raise PortPermissionError(
                f"not allowed to reach the service at {where}: it belongs to another user"
            ) from None
        except (OSError, ValueError) as exc:
            raise ConnectError(
                f"cannot reach the service at {where}: {getattr(exc, 'strerror', None) or exc}"
            ) from None
        self._loop = asyncio.get_running_loop()
        self._lost = None
        self._served_print = None
        self._rpc = RpcClient(reader, writer, self._notified, self._service_closed, where)
        try:
            if tcp:
                try:
                    await self._rpc.call("auth", {"token": token})
                except ValueError as exc:  # refused: said once, then the service closes the connection
                    raise PortPermissionError(f"the service at {where} refused: {exc}") from None
            hello = await self._rpc.call(
                "hello", {"printer": self.name, "subscribe": ["readings", "link", "progress", "requests"]}
            )
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
        with contextlib.suppress(RpcError):  # a service that does not tell them: none known
            self._take_requests(info)
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
        elif method == "request":
            try:
                self._take_requests(params)
                request = host_request_from_json(params.get("request"))
            except RpcError:
                _log.warning("the service told a malformed request of the printer: %s", str(params)[:200])
                return
            if request is not None and self._request_listeners and self._loop is not None:
                self._loop.call_soon(self._tell_request_listeners, request)

    def _take_requests(self, params: dict[str, Any]) -> None:
        """The state of the firmware's requests from a `request` notification or a printer's info.

        Raises:
            RpcError: a field is not of its shape (nothing taken).
        """
        prompt = prompt_from_json(params.get("prompt"))
        last = host_request_from_json(params.get("last_host_request"))
        self._prompt, self._last_request = prompt, last
        self._waiting_for_user = bool(params.get("waiting_for_user"))

    def _failed(self, error: MarlinError) -> None:
        # `Printer._failed` tells the `host_requests()` readers on its link's loop; this printer has no link open.
        queues, self._request_queues = self._request_queues, []
        try:
            super()._failed(error)
        finally:
            self._request_queues = queues
        if self._loop is not None:
            for queue in queues:
                self._loop.call_soon(queue.put_nowait, error)

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

    async def call(self, method: str, **params: Any) -> Any:
        """Send the service a request about this printer (`method` and its parameters, as `marlin_aio.protocol.rpc`
        lists them) and return its result: for what `Printer`'s API has no name for.

        Raises:
            ConnectionLostError: not open, or the service went away.
            MarlinError, ValueError, RuntimeError, OSError: as the service raised them.
        """
        return await self._call(method, **params)

    def call_soon(self, method: str) -> None:
        """Write a request about this printer now and ignore its answer (an emergency stop, a pause).

        Raises:
            ConnectionLostError: not open, or the service went away.
        """
        if self._rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open")
        self._rpc.call_soon(method, {"printer": self.name})

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

    # ------------------------------------------------------------------------------------------- firmware requests

    @property
    def prompt(self) -> Prompt | None:
        """The prompt the service's printer shows for a person, as the service last told it, or None."""
        return self._prompt

    @property
    def waiting_for_user(self) -> bool:
        """True while a command of the service's printer waits for a person (M600), as the service last told."""
        return self._waiting_for_user

    @property
    def last_host_request(self) -> HostRequest | None:
        """The firmware's last pause, paused, resume, resumed, cancel or disconnect request, or None."""
        return self._last_request

    async def answer_prompt(self, index: int) -> None:
        """Have the service answer its printer's open prompt with button `index` (0 the first): `M876 S<index>`.

        Raises:
            ValueError: `index` is not a button number, or the service's printer has no prompt open or no button
                `index` (the service checks against the prompt open there; nothing is written).
            MarlinError: as `send`.
        """
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"a prompt's button is a number from 0, got {index!r}")
        await self._call("answer_prompt", index=index)
        self._prompt = None  # closed at once, as the service closed it (its notification may come later)

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
        limits = self._heater_limits
        if isinstance(source, str | Path):
            path = absolute(source)
            if check:
                # Against this client's limits (the service checks its own), before anything is sent; in a thread,
                # as a file of millions of lines takes a while.
                await asyncio.to_thread(check_file, path, limits)
            # Over TCP the service is another machine: the file goes with the request, not its path.
            params["path"] = await upload(self, file_lines(path)) if self._remote else path
        else:
            if check and isinstance(source, Sequence):
                for _ in gcode_commands(source, limits):  # a list over the limits is refused whole, as a file is
                    pass
            params["path"] = await upload(self, source)
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

    def _failure(self) -> MarlinError | None:
        return self._lost  # the service lost the printer, or this client lost the service
