"""A printer that `marlin-temp serve` owns: `Printer`'s backend for `serve:NAME` (`marlin_aio.connect("serve:NAME")`).

The service holds the serial port and keeps the printer connected; any number of clients share it through its
Unix socket (JSON-RPC 2.0, one message per line: `marlin_aio.protocol.rpc`). `ServedBackend` turns each of
`Printer`'s calls into a request instead of G-code lines, so a program written for a port runs against a served
printer unchanged: `send`, `set_temperatures`, `wait_for_temperatures`, `temperature_readings`, `on_reading`,
`start_print` and the rest, each request answered by its own reply. What differs, and why:

- Readings come from the service's own polling (`marlin-temp serve --interval`): `poll_temperatures()` asks for
  nothing more, so ten clients watching one printer put no more M105s on its wire than one.
- A print runs inside the service: it goes on when the client that started it exits. Its `PrintHandle` follows
  the service's progress notifications, and `pause`, `resume` and `cancel` are requests.
- The firmware's requests (`prompt`, `waiting_for_user`, `last_host_request`, `on_host_request`,
  `host_requests()`) are the service's: it tells each as its printer makes it, and `answer_prompt` is a request
  (the service checks the index against the prompt open there, and writes M876).
- The link's figures are the service's link's: `stats` and `round_trips` are a copy of them fetched once a
  second (`link_stats`), every client's commands and the service's polls included. The wire itself (`trace`), its
  window (`sending_ahead`, `send_ahead_window_bytes`) and the pace of polls during prints
  (`print_poll_interval_s`) are the service's to set: those raise `NotSupportedError`, saying where to look.
- When the service loses the printer, this printer fails as a lost port would (`wait_for_failure()` returns,
  readers of temperatures end, commands fail with the service's error); open it again once the service has
  reconnected (`keep_connected` does that).

Where: `serve:NAME@tcp://HOST:PORT` reaches a service's TCP listener (its token in `$MARLIN_SERVE_TOKEN`);
`serve:NAME` is printer NAME at the default socket (`default_socket_path()`), `serve:NAME@/path/to.sock`
at that socket, and `serve:` alone the service's only printer.

Over 400 lines because it is `Printer`'s backend member by member (commands, temperatures, prints, the firmware's
requests, the link's figures) over one connection: spread over modules, a reader would no longer see in one place
how a served printer answers each of `Printer`'s members.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import os
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

from marlin_aio.aio.listeners import LinkEvent, Listeners
from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.aio.rpcclient import RpcClient
from marlin_aio.aio.servedprint import ServedPrintHandle, absolute, check_file, file_lines, upload
from marlin_aio.aio.servicepaths import TCP_PREFIX, TOKEN_ENV, parse_served_port
from marlin_aio.errors import (
    ConnectError,
    ConnectionLostError,
    MarlinError,
    NotSupportedError,
    PortNotFoundError,
    PortPermissionError,
    PrinterHaltedError,
    RemoteProtocolError,
)
from marlin_aio.protocol.commands import validate_command
from marlin_aio.protocol.events import FirmwareInfo
from marlin_aio.protocol.heaters import HeaterLimits, check_gcode_targets
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
from marlin_aio.protocol.stats import LinkStats
from marlin_aio.protocol.temperatures import TemperatureReading
from marlin_aio.protocol.wire import Trace

__all__ = ["LINK_STATS_INTERVAL_S", "ServedBackend"]

_log = logging.getLogger("marlin_aio")

#: How often the copy of the service's link figures (`stats`, `round_trips`) is fetched while open.
LINK_STATS_INTERVAL_S = 1.0

_STAT_FIELDS = tuple(field.name for field in dataclasses.fields(LinkStats))
_NO_STATS = LinkStats(**dict.fromkeys(_STAT_FIELDS, 0))


class ServedBackend:
    """A printer owned by `marlin-temp serve`, reached through its socket (see the module's docstring).

    Of `Printer`'s arguments only the port, `timeout_s` and the heater limits mean something here: a target over
    them is refused before anything is sent (and the service checks against its own).
    """

    def __init__(self, port: str, listeners: Listeners, *, timeout_s: float, limits: HeaterLimits) -> None:
        self.port = port
        self.timeout_s = timeout_s
        self._limits = limits
        self._listeners = listeners
        self._feed = listeners.feed
        self.name, self.socket_path = parse_served_port(port)
        self._remote = self.socket_path.startswith(TCP_PREFIX)
        self.firmware: FirmwareInfo | None = None
        self.capabilities: dict[str, bool] = {}
        self._rpc: RpcClient | None = None
        self._lost: MarlinError | None = None
        self._served_print: ServedPrintHandle | None = None
        self._link_up = False
        self._loop: asyncio.AbstractEventLoop | None = None
        # The firmware's requests as the service last told them (its printer tracks them: see `_take_requests`).
        self._prompt: Prompt | None = None
        self._waiting_for_user = False
        self._last_request: HostRequest | None = None
        # The service's link figures as last fetched (`link_stats`), round trips on this process's clock.
        self._stats = _NO_STATS
        self._round_trips: deque[tuple[float, float]] = deque(maxlen=8192)
        self._round_trips_until_s = float("-inf")  # the newest round trip copied, on the service's clock
        self._no_link_stats: str | None = None  # why the service tells none (it is older than this client)
        self._refresher: asyncio.Task[None] | None = None

    def set_limits(self, limits: HeaterLimits) -> None:
        """Check every command and print line against `limits` from now on (before it is sent)."""
        self._limits = limits

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
        self._loop = self._listeners.loop = asyncio.get_running_loop()
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
            await self._fetch_link_stats(first=True)
        except BaseException:
            await self.close()
            raise
        if self._no_link_stats is None:
            self._refresher = self._loop.create_task(self._refresh_link_stats(), name=f"link stats of {self.port}")
        _log.info("connected to %s through the service at %s", self.name, where)
        firmware = self.firmware.name if self.firmware else "firmware unknown"
        self._listeners.link_event(LinkEvent("connected", f"{self.port} (served: {firmware})"))

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
        refresher, self._refresher = self._refresher, None
        if refresher is not None:
            refresher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await refresher
        rpc, self._rpc = self._rpc, None
        if rpc is not None:
            await rpc.aclose()

    @property
    def reset_on_open(self) -> bool:
        """Always False: this connection opens no port, so it cannot reset the board (the service's can: its
        news)."""
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
                self._listeners.link_event(LinkEvent("reset", message))
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
            if request is not None:
                self._listeners.host_request(request)

    def _take_requests(self, params: dict[str, Any]) -> None:
        """The state of the firmware's requests from a `request` notification or a printer's info.

        Raises:
            RpcError: a field is not of its shape (nothing taken).
        """
        prompt = prompt_from_json(params.get("prompt"))
        last = host_request_from_json(params.get("last_host_request"))
        self._prompt, self._last_request = prompt, last
        self._waiting_for_user = bool(params.get("waiting_for_user"))

    def _printer_failed(self, error: MarlinError) -> None:
        if self._lost is not None:
            return
        self._lost = error
        self._link_up = False
        self._listeners.failed(error)  # readers, failure waiters, the link event: as a lost port tells them

    def _service_closed(self, error: MarlinError) -> None:
        if self._served_print is not None:
            self._served_print.orphaned(error)
        self._printer_failed(error)

    # ------------------------------------------------------------------------------------------- requests

    async def call(self, method: str, **params: Any) -> Any:
        """Send the service a request about this printer and return its result (see `ServedPrinter.call`).

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

    def _call(self, method: str, *, on_result: Callable[[Any], None] | None = None, **params: Any) -> Any:
        rpc = self._rpc
        if rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open")
        if self._lost is not None:
            raise self._lost
        return rpc.call(method, {"printer": self.name, **params}, on_result=on_result)

    # ------------------------------------------------------------------------------------------- commands

    async def send(self, command: str, *, timeout_s: float, numbered: bool | None) -> Reply:
        """Send one command through the service and return its reply (`numbered` is the service's choice).
        Commands of all clients go out in the order the service received them.

        Raises:
            ValueError: the command is malformed or over the limits (checked here first, nothing sent).
            MarlinError: as `Printer.send`, raised by the service; ConnectionLostError if the service went away.
        """
        text = validate_command(command)
        check_gcode_targets(text, self._limits)
        return reply_from_json(await self._call("send", command=text, timeout_s=timeout_s))

    def emergency_stop(self) -> None:
        """Have the service write M112 at once, ahead of anything queued.

        Raises:
            ConnectionLostError: the service is gone, so the stop cannot reach the printer (cut its power).
        """
        if self._rpc is None:
            raise ConnectionLostError(f"the printer {self.port} is not open: M112 cannot reach it (cut its power)")
        self._rpc.call_soon("emergency_stop", {"printer": self.name})
        _log.warning("emergency stop (M112) asked of the service for %s", self.name)

    def interrupt_wait(self) -> bool:
        """Have the service end a heater wait with M108, where the firmware can.

        Raises:
            ConnectionLostError: the service is gone.
        """
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
        value = await self._call("read_temperatures")
        return reading_from_json(value, asyncio.get_running_loop().time())

    def readings_ended(self) -> MarlinError | None:
        """Why a new reader gets no readings: not open, or the service or its printer went away."""
        return self._lost if self._rpc is not None else ConnectionLostError(f"the printer {self.port} is not open")

    @contextlib.asynccontextmanager
    async def poll_temperatures(self, interval_s: float, auto_report: bool) -> AsyncIterator[None]:
        """The service polls the printer at its own rate for every client at once: this asks for nothing more."""
        yield

    def polled(self) -> bool:
        """True: the service's own poller runs while it is connected."""
        return True

    @property
    def print_poll_interval_s(self) -> float:
        """Not here: the service sets its own pace of polls.

        Raises:
            NotSupportedError: always.
        """
        raise self._unsupported("print_poll_interval_s", "the service polls its printer at its own rate")

    @print_poll_interval_s.setter
    def print_poll_interval_s(self, interval_s: float) -> None:
        raise self._unsupported("print_poll_interval_s", "the service polls its printer at its own rate")

    # ------------------------------------------------------------------------------------------- printing

    async def start_print(
        self,
        source: str | Path | Iterable[str],
        *,
        send_ahead: bool,
        window_bytes: int | None,
        check: bool,
        timeout_s: float | None,
        name: str | None = None,
        stop_on_unknown: bool = False,
    ) -> PrintHandle:
        """Have the service print `source` (a file it can read, or a list of lines); the print runs there and
        goes on if this client leaves.

        Raises:
            ValueError: a line is not a valid command or is over the limits (nothing is sent).
            OSError: the service cannot read the file.
            RuntimeError: a print is already running on that printer (whoever started it).
            MarlinError: as `send`.
        """
        params: dict[str, Any] = {"send_ahead": send_ahead, "check": check}
        if stop_on_unknown:
            params["stop_on_unknown"] = True  # only when asked: a service from before it still takes the rest
        if window_bytes is not None:
            params["window_bytes"] = window_bytes
        if timeout_s is not None:
            params["timeout_s"] = timeout_s
        limits = self._limits
        if isinstance(source, str | Path):
            path = absolute(source)
            if check:
                # Against this client's limits (the service checks its own), before anything is sent; in a thread,
                # as a file of millions of lines takes a while.
                await asyncio.to_thread(check_file, path, limits)
            # Over TCP the service is another machine: the file goes with the request, not its path.
            if self._remote:
                params["path"] = await upload(self, file_lines(path), name or Path(path).name)
            else:
                params["path"] = path
            if name is not None:
                params["name"] = name
        else:
            if check and isinstance(source, Sequence):
                for _ in gcode_commands(source, limits):  # a list over the limits is refused whole, as a file is
                    pass
            # The job is called by its name everywhere (the service log, /api/job), not by the service's copy's.
            params["path"] = await upload(self, source, name or "upload.gcode")

        def started(value: Any) -> None:
            # In the read loop, as the answer arrives: a short print's progress (its end, even) may be the very next
            # message, and must find its handle.
            progress = progress_from_json(value.get("progress"))
            self._served_print = ServedPrintHandle(self, progress, str(value.get("file", "")))

        await self._call("start_print", on_result=started, **params)
        assert self._served_print is not None
        return self._served_print

    # ------------------------------------------------------------------------------------------- state

    @property
    def state(self) -> LinkState:
        """READY while the service's printer is connected and this client is attached; else LOST."""
        return LinkState.READY if self.is_connected else LinkState.LOST

    @property
    def is_connected(self) -> bool:
        """True while attached to the service and its printer is connected."""
        return self._rpc is not None and self._rpc.closed is None and self._lost is None and self._link_up

    def failure(self) -> MarlinError | None:
        """Why the printer can take no more commands: the service lost it, or this client lost the service."""
        return self._lost

    # ------------------------------------------------------------------------------------------- the link's figures

    @property
    def stats(self) -> LinkStats:
        """The service's link counters, as last fetched (at most `LINK_STATS_INTERVAL_S` old while open).

        Raises:
            NotSupportedError: the service tells none (it is older than this client).
        """
        if self._no_link_stats is not None:
            raise self._unsupported("stats", self._no_link_stats)
        return self._stats

    @property
    def round_trips(self) -> deque[tuple[float, float]]:
        """The service's round trips (every client's commands and its polls), on this process's loop clock.

        Raises:
            NotSupportedError: the service tells none (it is older than this client).
        """
        if self._no_link_stats is not None:
            raise self._unsupported("round_trips", self._no_link_stats)
        return self._round_trips

    @property
    def trace(self) -> Trace:
        """Not here: the wire is the service's.

        Raises:
            NotSupportedError: always.
        """
        raise self._unsupported(
            "trace", "the wire of a served printer is the service's; use `marlin-temp serve --wire-log`"
        )

    @property
    def send_ahead_window_bytes(self) -> int:
        """Not here: the service sets the window of the prints it runs.

        Raises:
            NotSupportedError: always.
        """
        raise self._unsupported(
            "send_ahead_window_bytes", "the service sets the window of the prints it runs (start_print's window_bytes)"
        )

    def sending_ahead(self, max_in_flight: int) -> AbstractContextManager[None]:
        """Not here: the service's wire carries every client's commands, one window for all.

        Raises:
            NotSupportedError: always.
        """
        raise self._unsupported("sending_ahead", "the service's wire carries every client's commands in its window")

    def _unsupported(self, member: str, why: str) -> NotSupportedError:
        return NotSupportedError(member, f"{why} ({self.port} is a printer of marlin-temp serve)")

    async def _fetch_link_stats(self, *, first: bool = False) -> None:
        """Copy the service's link figures (`link_stats`); the first time, learn whether it tells them.

        Raises:
            MarlinError: the service or its printer went away.
        """
        try:
            value = await self._call("link_stats")
        except RemoteProtocolError as exc:
            if not first:
                raise
            self._no_link_stats = f"the service does not tell its link's figures ({exc}); upgrade it"
            return
        try:
            stats = value["stats"]
            self._stats = LinkStats(**{name: int(stats[name]) for name in _STAT_FIELDS})
            # Its loop's clock is not this one's (another process, maybe another machine): shifted by the difference
            # now, so round trips line up with this process's readings (off by the answer's way here, a millisecond).
            assert self._loop is not None
            shift_s = self._loop.time() - float(value.get("now_s", self._loop.time()))
            for answered_s, latency_s in value["round_trips"]:
                if answered_s > self._round_trips_until_s:
                    self._round_trips.append((float(answered_s) + shift_s, float(latency_s)))
                    self._round_trips_until_s = answered_s
        except (KeyError, TypeError, ValueError) as exc:
            _log.warning("the service answered link_stats with what it should not (%r): %s", exc, str(value)[:200])

    async def _refresh_link_stats(self) -> None:
        while True:
            await asyncio.sleep(LINK_STATS_INTERVAL_S)  # a pace, not a wait for something: figures this fresh
            try:
                await self._fetch_link_stats()
            except (MarlinError, ValueError):
                return  # the service or its printer went away: the figures stay as last fetched
