"""`marlin-temp serve`: one process owns the printers, and any number of local clients share them.

Moonraker's shape, at this project's size. The farm's supervisor (`marlin_aio.farm.supervisor.Farm`) keeps each
printer connected, polls it and runs its prints as tasks of its own, so a print outlives the client that started
it. Clients reach the service on a Unix socket (owner-only: the folder 0700, the socket 0600) speaking JSON-RPC
2.0, one message per line (`marlin_aio.protocol.rpc`): requests, each answered by its own response, and
notifications for what a client subscribed to (readings, console lines, print progress, link events, the
firmware's requests: prompts, pause, resume and cancel, waits for the user).

Why a client can never slow the printer or another client: the serial side never awaits a client. Each client has
one bounded queue of outgoing messages and one writer task; a notification that finds the queue full is dropped
and counted (`dropped` in `status`), and a client whose unread responses pass the bound is disconnected. Requests
are handled in tasks of their client's own, at most `MAX_REQUESTS_IN_FLIGHT` at once; beyond that a request is
refused as busy. Commands of all clients meet in the printer's one FIFO (the library's), so each reply goes to the
request that sent its command. Nothing a client sent is replayed when the service restarts: requests live only in
the process that took them.

A client's reader, writer and queue are `session.Session`. Over 400 lines because the methods are one table: each
is a few lines over the farm, and spread over modules they would hide which requests exist.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import stat
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import marlin_aio
from marlin_aio.aio.servicepaths import default_socket_path
from marlin_aio.farm.supervisor import Farm, FarmEvent, FarmPrinter, PrinterSpec
from marlin_aio.protocol import redact
from marlin_aio.protocol.rpc import (
    INVALID_PARAMS,
    MAX_MESSAGE_BYTES,
    RpcError,
    encode_message,
    error_to_json,
    notification,
    progress_to_json,
    reading_to_json,
    reply_to_json,
    requests_to_json,
)
from marlin_aio.service.history import History
from marlin_aio.service.session import Handler, Session, param
from marlin_aio.service.uploads import Uploads

__all__ = ["TOPICS", "OctoPrintSettings", "Service", "ServiceRunningError", "TcpSettings", "check_private_folder"]

_log = logging.getLogger("marlin_aio.service")

#: What a client can subscribe to.
TOPICS = frozenset({"readings", "console", "progress", "link", "requests"})
#: The most readings one `history` answer carries (evenly thinned past this): well inside a message's limit.
MAX_HISTORY_READINGS = 3_000
#: The name of a print a client sent as lines (a number is added to keep each), and how many of them are kept.
CLIENT_UPLOAD_NAME = "sent.gcode"
KEEP_CLIENT_UPLOADS = 10
#: TCP clients at once (the Unix socket's are the owner's own: not bounded).
MAX_TCP_CLIENTS = 64
#: The longest timeout a request may give a command (a G28 of a large printer takes minutes, not days).
MAX_TIMEOUT_S = 24 * 3600.0
#: How often a running print's progress is told to its subscribers.
PROGRESS_INTERVAL_S = 0.5


@dataclass(frozen=True)
class OctoPrintSettings:
    """Where the OctoPrint-shaped HTTP API listens, for which printer, and the key it wants."""

    port: int
    api_key: str = field(repr=False)
    host: str = "127.0.0.1"
    printer: str | None = None
    """The printer it speaks for (OctoPrint has one); None: the service's first."""


@dataclass(frozen=True)
class TcpSettings:
    """The socket's API on TCP too, for clients on other machines: where, and the token each must give first."""

    port: int
    token: str = field(repr=False)
    host: str = "127.0.0.1"


class ServiceRunningError(RuntimeError):
    """Another `marlin-temp serve` already listens at the socket."""


def check_private_folder(folder: Path) -> None:
    """Make `folder` (owner-only) if need be, and make sure it is this user's alone: a folder someone else made
    first (in /tmp, where anyone may) could hand the service a token or a socket of theirs.

    Raises:
        PermissionError: it is a link, not this user's, or others may enter or write it.
    """
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    info = folder.lstat()
    if stat.S_ISLNK(info.st_mode) or not stat.S_ISDIR(info.st_mode):
        raise PermissionError(f"{folder} is not a folder of its own (a link?): refusing to use it")
    if info.st_uid != os.getuid() or info.st_mode & 0o077:
        raise PermissionError(
            f"{folder} belongs to another user or others may enter it (mode {stat.S_IMODE(info.st_mode):o}): "
            "refusing to use it; remove it, or give --socket in a folder of your own"
        )


def _prepare_folder(path: Path) -> bool:
    """Check the socket's folder; say whether a socket is at the socket's path already.

    Raises:
        PermissionError: the folder is not this user's alone.
        FileExistsError: something other than a socket is at the path (never removed: it is not ours).
    """
    check_private_folder(path.parent)
    if not os.path.lexists(path):
        return False
    if not stat.S_ISSOCK(path.lstat().st_mode):
        raise FileExistsError(f"{path} exists and is not a socket: refusing to replace it")
    return True


def _remove(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()


class Service:
    """The printers of `specs`, kept connected and shared on the socket at `socket_path` until cancelled.

    Args:
        specs: the printers (names unique), as for the farm.
        socket_path: where to listen (default: `default_socket_path()`).
        uploads_dir: where prints sent as lines are written before they run (default: beside the socket).
        on_event: also called with every `FarmEvent` (the serve command prints them).
        history_recent_s: how far back every reading is kept for late joiners.
        history_long_s: how far back one reading a second is kept.
        octoprint: serve the OctoPrint API too (needs aiohttp: the `[serve]` extra).
        tcp: listen on TCP too; each client there must first send `auth` with the token.

    Raises:
        ValueError: printer names not unique, or `octoprint` names a printer the service does not have.
    """

    def __init__(
        self,
        specs: list[PrinterSpec],
        socket_path: Path | None = None,
        *,
        uploads_dir: Path | None = None,
        on_event: Callable[[FarmEvent], None] | None = None,
        history_recent_s: float = 300.0,
        history_long_s: float = 6 * 3600.0,
        octoprint: OctoPrintSettings | None = None,
        tcp: TcpSettings | None = None,
    ) -> None:
        self.socket_path = socket_path or default_socket_path()
        self.uploads = Uploads(uploads_dir or self.socket_path.parent / "uploads")
        self.farm = Farm(specs, self._on_farm_event)
        self._on_event = on_event
        self.histories = {
            name: History(recent_s=history_recent_s, long_s=history_long_s) for name in self.farm.printers
        }
        for name, farm_printer in self.farm.printers.items():
            farm_printer.reading_listeners.append(self._reader_of(name))
            farm_printer.request_listeners.append(self._requester_of(farm_printer))
        self.octoprint = octoprint
        if tcp is not None and len(tcp.token) < 16:
            raise ValueError("the TCP token must be at least 16 characters")
        self.tcp = tcp
        if octoprint is not None and octoprint.printer is not None and octoprint.printer not in self.farm.printers:
            raise ValueError(f"--octoprint-printer {octoprint.printer!r}: no such printer here")
        self.sessions: set[Session] = set()
        self._numbers = 0
        self.ready = asyncio.Event()
        self._announced: dict[str, object] = {}  # the last progress told per printer, not to repeat it
        self._requests_told: dict[str, object] = {}  # the last state of the firmware's requests told per printer
        self._cancels: dict[str, asyncio.Future[marlin_aio.PrintProgress]] = {}  # a cancel under way per printer
        self.methods: dict[str, Handler] = {
            "hello": self._hello,
            "printers": self._printers,
            "status": self._status,
            "subscribe": self._subscribe,
            "unsubscribe": self._unsubscribe,
            "history": self._history,
            "send": self._send,
            "read_temperatures": self._read_temperatures,
            "set_temperatures": self._set_temperatures,
            "upload": self._upload,
            "start_print": self._start_print,
            "pause": self._pause,
            "resume": self._resume,
            "cancel": self._cancel,
            "emergency_stop": self._emergency_stop,
            "interrupt_wait": self._interrupt_wait,
            "answer_prompt": self._answer_prompt,
            "link_stats": self._link_stats,  # issue 33 (backend seam): see `_link_stats` at the end of the class
        }

    # ------------------------------------------------------------------------------------------- running

    async def run(self) -> None:
        """Listen and supervise until cancelled; the socket and the registry are removed on the way out.

        Raises:
            ServiceRunningError: another service listens at the socket.
            OSError: the socket's folder cannot be made or the socket bound.
        """
        path = self.socket_path
        await self._claim(path)
        self.uploads.sweep()
        mask = os.umask(0o077)  # the socket is the owner's from the moment it exists, not from the chmod
        try:
            server = await asyncio.start_unix_server(self._client, str(path), limit=MAX_MESSAGE_BYTES)
        finally:
            os.umask(mask)
        http = None
        tcp = None
        try:
            os.chmod(path, 0o600)
            if self.octoprint is not None:
                http = await self._serve_octoprint(self.octoprint)
            if self.tcp is not None:
                token = self.tcp.token
                tcp = await asyncio.start_server(
                    lambda r, w: self._tcp_client(r, w, token), self.tcp.host, self.tcp.port, limit=MAX_MESSAGE_BYTES
                )
            self._write_registry()
            self.ready.set()
            _log.info("serving %s at %s", ", ".join(self.farm.printers), path)
            async with asyncio.TaskGroup() as group:
                group.create_task(self.farm.run(), name="farm")
                group.create_task(self._tell_progress(), name="progress")
        finally:
            server.close()
            if tcp is not None:
                tcp.close()
            if http is not None:
                await http.cleanup()
            for session in list(self.sessions):
                session.close()
            with contextlib.suppress(OSError):
                path.unlink()
            with contextlib.suppress(OSError):
                self.registry_path.unlink()

    async def _serve_octoprint(self, settings: OctoPrintSettings) -> Any:
        from marlin_aio.service.octoprint import OctoPrintApi  # aiohttp only when asked for

        name = settings.printer or next(iter(self.farm.printers))
        api = OctoPrintApi(self.farm.printers[name], self.farm.start_print, self.uploads, settings.api_key)
        runner = await api.serve(settings.host, settings.port)
        _log.info("OctoPrint API for %s on http://%s:%d", name, settings.host, settings.port)
        return runner

    @property
    def registry_path(self) -> Path:
        """`serve.json` beside the socket: which port each printer is on, so a command asked for a port the
        service holds uses the service instead (`marlin_aio.aio.served.service_holding`)."""
        return self.socket_path.with_name("serve.json")

    async def check_socket(self) -> None:
        """Make sure the socket can be this service's: its folder made, a socket left by a dead service removed.

        Raises:
            ServiceRunningError: another service listens there.
        """
        await self._claim(self.socket_path)

    async def _claim(self, path: Path) -> None:
        if _prepare_folder(path):
            try:
                _, writer = await asyncio.open_unix_connection(str(path))
            except OSError:
                _remove(path)  # left by a service that is gone
            else:
                writer.close()
                raise ServiceRunningError(f"a marlin-temp serve is already running at {path}")

    def _write_registry(self) -> None:
        printers = {name: fp.spec.port for name, fp in self.farm.printers.items() if fp.spec.port}
        data = json.dumps({"pid": os.getpid(), "socket": str(self.socket_path), "printers": printers})
        fd, temporary = tempfile.mkstemp(dir=self.registry_path.parent, prefix=".serve.", suffix=".json")
        with os.fdopen(fd, "w") as handle:
            handle.write(data)
        os.replace(temporary, self.registry_path)

    async def _tcp_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, token: str) -> None:
        if sum(session.remote for session in self.sessions) >= MAX_TCP_CLIENTS:
            writer.transport.abort()  # a flood of connections: the ones over the bound are not even read
            return
        await self._client(reader, writer, token)

    async def _client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, token: str | None = None
    ) -> None:
        self._numbers += 1
        session = Session(self, reader, writer, self._numbers, token)
        self.sessions.add(session)
        try:
            await session.run()
        finally:
            self.sessions.discard(session)
            for upload_id in session.uploads:
                self.uploads.discard(upload_id)  # abandoned half-way: nobody can finish it now

    # ------------------------------------------------------------------------------------------- notifications

    def _broadcast(
        self, printer: str, topic: str, method: str, params: dict[str, Any] | Callable[[], dict[str, Any]]
    ) -> None:
        """Tell every client subscribed to `topic` of `printer`; the message is made once for all of them, and
        only if one is subscribed (`params` may be a function, for what costs to make: a reading)."""
        data: bytes | None = None
        for session in self.sessions:
            if session.subscribed(printer, topic):
                if data is None:
                    made = params() if callable(params) else params
                    data = encode_message(notification(method, {"printer": printer, **made}))
                session.push(data)

    def _reader_of(self, name: str) -> Callable[[marlin_aio.TemperatureReading], None]:
        history = self.histories[name]

        def on_reading(reading: marlin_aio.TemperatureReading) -> None:
            history.add(reading)
            self._broadcast(name, "readings", "reading", lambda: {"reading": reading_to_json(reading)})

        return on_reading

    def _requester_of(self, farm_printer: FarmPrinter) -> Callable[[marlin_aio.HostRequest], None]:
        def on_request(request: marlin_aio.HostRequest) -> None:
            self._tell_requests(farm_printer, request)
            if farm_printer.print_handle is not None:
                self._progress_of(farm_printer)  # a pause, resume or cancel of the print shows at once

        return on_request

    def _requests_of(self, farm_printer: FarmPrinter, request: marlin_aio.HostRequest | None) -> dict[str, Any]:
        printer = farm_printer.printer
        last = printer.last_host_request if printer is not None else None
        return requests_to_json(request, farm_printer.prompt, farm_printer.waiting_for_user, last)

    def _tell_requests(self, farm_printer: FarmPrinter, request: marlin_aio.HostRequest | None) -> None:
        """Tell the `requests` subscribers of `request` with the state after it; with None, of the state alone
        and only if it changed since last told."""
        params = self._requests_of(farm_printer, request)
        state = {key: value for key, value in params.items() if key != "request"}
        if request is None and self._requests_told.get(farm_printer.name) == state:
            return
        self._requests_told[farm_printer.name] = state
        self._broadcast(farm_printer.name, "requests", "request", params)

    def _note(self, printer: str, direction: str, text: str) -> None:
        text = redact(text)
        self.histories[printer].note(direction, text)
        self._broadcast(printer, "console", "console", {"direction": direction, "text": text})

    def _on_farm_event(self, event: FarmEvent) -> None:
        self._note(event.printer, "!", f"{event.kind}: {event.message}")
        self._broadcast(
            event.printer, "link", "link", {"kind": event.kind, "message": event.message, "time_s": event.time_s}
        )
        if event.kind.startswith("print_"):
            self._progress_of(self.farm.printers[event.printer], final=True)
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception:  # the serve command's printing must not stop a supervisor
                _log.exception("event listener failed")

    async def _tell_progress(self) -> None:
        alive = encode_message(notification("alive", {}))
        ticks = 0
        while True:
            await asyncio.sleep(PROGRESS_INTERVAL_S)  # a ticker: progress is told at this rate, not synchronised
            ticks += 1
            if ticks % 2 == 0:
                # Once a second to every client: a client that hears nothing for long knows the service is stuck
                # (stopped, swapping), and fails its waits instead of waiting for ever.
                for session in self.sessions:
                    session.push(alive)
            for farm_printer in self.farm.printers.values():
                handle = farm_printer.print_handle
                if handle is not None and not handle.finished:
                    self._progress_of(farm_printer)
                # A wait for the user ends with an ok, and a prompt closes when answered: no request says so.
                self._tell_requests(farm_printer, None)

    def _progress_of(self, farm_printer: FarmPrinter, *, final: bool = False) -> None:
        handle = farm_printer.print_handle
        if handle is None:
            return
        progress = handle.progress
        params: dict[str, Any] = {"file": farm_printer.print_file, "progress": progress_to_json(progress)}
        if progress.state is marlin_aio.PrintState.FAILED and handle.job.error is not None:
            params["error"] = error_to_json(handle.job.error)
        if not final and self._announced.get(farm_printer.name) == params:
            return
        self._announced[farm_printer.name] = params
        self._broadcast(farm_printer.name, "progress", "progress", params)

    # ------------------------------------------------------------------------------------------- methods

    def _printer_of(self, params: dict[str, Any]) -> FarmPrinter:
        name = param(params, "printer", str, None)
        printers = self.farm.printers
        if name is None:
            if len(printers) == 1:
                return next(iter(printers.values()))
            raise RpcError(INVALID_PARAMS, f"which printer? this service has {', '.join(printers)}")
        if name not in printers:
            raise marlin_aio.PortNotFoundError(
                f"no printer named {name[:60]!r} in the service at {self.socket_path} (it has: {', '.join(printers)})"
            )
        return printers[name]

    def _connected(self, farm_printer: FarmPrinter) -> marlin_aio.Printer:
        printer = farm_printer.printer
        if printer is None or not farm_printer.link_up:
            reason = farm_printer.last_error or "connecting"
            raise marlin_aio.ConnectionLostError(f"printer {farm_printer.name} is not connected now ({reason})")
        return printer

    def _info(self, farm_printer: FarmPrinter) -> dict[str, Any]:
        printer = farm_printer.printer
        firmware = printer.firmware if printer is not None else None
        latest = farm_printer.latest
        return {
            "name": farm_printer.name,
            "port": farm_printer.spec.port or "sim",
            "link_up": farm_printer.link_up,
            "firmware": None if firmware is None else {"name": firmware.name, "fields": firmware.fields},
            "capabilities": dict(printer.capabilities) if printer is not None else {},
            "last_error": farm_printer.last_error,
            "latest": None if latest is None else reading_to_json(latest),
            "print": farm_printer.print_status(),
            # The open prompt, the wait for the user, the last pause/resume/cancel/disconnect request.
            **{key: value for key, value in self._requests_of(farm_printer, None).items() if key != "request"},
        }

    def _subscribe_to(self, session: Session, farm_printer: FarmPrinter, topics: object) -> list[str]:
        if not isinstance(topics, list) or not all(isinstance(t, str) for t in topics):
            raise RpcError(INVALID_PARAMS, f"topics are a list of names: {', '.join(sorted(TOPICS))}")
        unknown = set(topics) - TOPICS
        if unknown:
            raise RpcError(
                INVALID_PARAMS, f"no topic {sorted(unknown)[0][:40]!r}; there are {', '.join(sorted(TOPICS))}"
            )
        session.subscriptions.setdefault(farm_printer.name, set()).update(topics)
        return sorted(session.subscriptions[farm_printer.name])

    async def _hello(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        topics = params.get("subscribe", [])
        subscribed = self._subscribe_to(session, farm_printer, topics) if topics else []
        return {
            "service": {"version": marlin_aio.__version__, "printers": list(self.farm.printers)},
            "printer": self._info(farm_printer),
            "subscribed": subscribed,
        }

    async def _printers(self, session: Session, params: dict[str, Any]) -> object:
        return [self._info(farm_printer) for farm_printer in self.farm.printers.values()]

    async def _status(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        info = self._info(farm_printer)
        info["clients"] = len(self.sessions)
        info["dropped"] = session.dropped
        return info

    async def _subscribe(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        subscribed = self._subscribe_to(session, farm_printer, params.get("topics"))
        return {"subscribed": subscribed}

    async def _unsubscribe(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        topics = params.get("topics")
        if topics is None:
            session.subscriptions.pop(farm_printer.name, None)
        elif isinstance(topics, list):
            session.subscriptions.get(farm_printer.name, set()).difference_update(str(t) for t in topics)
        return {"subscribed": sorted(session.subscriptions.get(farm_printer.name, ()))}

    async def _history(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        seconds = float(param(params, "seconds", (int, float), 300.0))
        history = self.histories[farm_printer.name]
        readings = history.readings(seconds)
        if len(readings) > MAX_HISTORY_READINGS:
            # Evenly thinned, so any span fits one message (an hour at 10 Hz would not).
            step = len(readings) / MAX_HISTORY_READINGS
            readings = [readings[int(index * step)] for index in range(MAX_HISTORY_READINGS)]
        return {
            "readings": [reading_to_json(r) for r in readings],
            "console": [{"direction": c.direction, "text": c.text, "time_s": c.time_s} for c in history.console],
        }

    async def _send(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        command = param(params, "command", str)
        timeout_s = param(params, "timeout_s", (int, float), None)
        if timeout_s is not None and not 0 < timeout_s <= MAX_TIMEOUT_S:
            raise RpcError(INVALID_PARAMS, f"timeout_s must be above 0 and at most {MAX_TIMEOUT_S:g} s")
        printer = self._connected(farm_printer)
        reply = await printer.send(command, timeout_s=timeout_s)
        self._note(farm_printer.name, ">", command)
        for line in reply.lines:
            self._note(farm_printer.name, "<", line)
        self._note(farm_printer.name, "<", f"ok {reply.ok.payload}".rstrip())
        return reply_to_json(reply)

    async def _read_temperatures(self, session: Session, params: dict[str, Any]) -> object:
        printer = self._connected(self._printer_of(params))
        return reading_to_json(await printer.read_temperatures())

    async def _set_temperatures(self, session: Session, params: dict[str, Any]) -> object:
        printer = self._connected(self._printer_of(params))
        targets = {name: param(params, name, (int, float), None) for name in ("hotend", "bed", "chamber")}
        await printer.set_temperatures(**targets, tool=param(params, "tool", int, None))
        return None

    async def _upload(self, session: Session, params: dict[str, Any]) -> object:
        upload_id = param(params, "upload_id", str, None)
        lines = param(params, "lines", list, [])
        if not all(isinstance(line, str) for line in lines):
            raise RpcError(INVALID_PARAMS, "lines are strings, one line of the file each")
        if upload_id is None:
            upload_id = self.uploads.begin()
            session.uploads.add(upload_id)
        self.uploads.append(upload_id, lines)
        if not params.get("done"):
            return {"upload_id": upload_id}
        session.uploads.discard(upload_id)
        path = self.uploads.finish(upload_id, CLIENT_UPLOAD_NAME)
        # Prints sent as lines are the service's to clean up: the newest few stay (to print again), older go.
        printing = {fp.print_file for fp in self.farm.printers.values() if fp.print_handle and fp.print_file}
        self.uploads.prune(CLIENT_UPLOAD_NAME.removesuffix(".gcode"), KEEP_CLIENT_UPLOADS, printing | {path.name})
        return {"path": str(path)}

    async def _start_print(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        self._connected(farm_printer)
        path_text = param(params, "path", str)
        path = Path(path_text)
        if not path.is_absolute():
            raise RpcError(INVALID_PARAMS, f"the service needs an absolute path, got {path_text[:200]!r}")
        if session.remote and path.parent != self.uploads.folder:
            # A path means a file on this machine: a client elsewhere prints what it uploaded, nothing else.
            raise PermissionError("over TCP a print is a file uploaded first (the client's start_print does that)")
        timeout_s = param(params, "timeout_s", (int, float), None)
        if timeout_s is not None and not 0 < timeout_s <= MAX_TIMEOUT_S:
            raise RpcError(INVALID_PARAMS, f"timeout_s must be above 0 and at most {MAX_TIMEOUT_S:g} s")
        options = {"send_ahead": bool(params.get("send_ahead", False)), "timeout_s": timeout_s}
        # In a task of the service's, not the client's: a client that leaves while its print is starting leaves
        # the start to finish (or fail) whole, never half-done.
        start = asyncio.ensure_future(self.farm.start_print(farm_printer, path, **options))
        handle = await asyncio.shield(start)
        return {"file": farm_printer.print_file, "progress": progress_to_json(handle.progress)}

    def _running(self, farm_printer: FarmPrinter) -> marlin_aio.PrintHandle:
        handle = farm_printer.print_handle
        if handle is None or handle.finished:
            raise RuntimeError(f"no print is running on {farm_printer.name}")
        return handle

    async def _pause(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        self._running(farm_printer).pause()
        self._progress_of(farm_printer)
        return None

    async def _resume(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        self._running(farm_printer).resume()
        self._progress_of(farm_printer)
        return None

    async def _cancel(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        script = param(params, "script", list, [])
        if not all(isinstance(command, str) for command in script):
            raise RpcError(INVALID_PARAMS, "script is a list of commands")
        # One cancel per print, in a task of the service's: a second cancel (another client, a double press) waits
        # for the first instead of running its script again, and a client that leaves mid-cancel does not stop
        # the script (the heaters off) from running.
        cancelling = self._cancels.get(farm_printer.name)
        if cancelling is None or cancelling.done():
            handle = self._running(farm_printer)
            cancelling = asyncio.ensure_future(handle.cancel(tuple(script)))
            self._cancels[farm_printer.name] = cancelling
        progress = await asyncio.shield(cancelling)
        return progress_to_json(progress)

    async def _emergency_stop(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        self._connected(farm_printer).emergency_stop()
        self._note(farm_printer.name, ">", "M112 (emergency stop)")
        return None

    async def _interrupt_wait(self, session: Session, params: dict[str, Any]) -> object:
        return self._connected(self._printer_of(params)).interrupt_wait()

    async def _answer_prompt(self, session: Session, params: dict[str, Any]) -> object:
        farm_printer = self._printer_of(params)
        index = param(params, "index", int)
        self._connected(farm_printer)
        # The printer checks the index against the prompt open now (ValueError, nothing written).
        await self.farm.answer_prompt(farm_printer, index)
        self._tell_requests(farm_printer, None)  # closed here at once: every client hears it now, not at a tick
        return None

    # ------------------------------------------------------------------------------------------- link_stats
    # (issue 33, the served printer as a backend: one handler, for `Printer.stats` and `round_trips` of a served
    # printer; the served client fetches it once a second.)

    async def _link_stats(self, session: Session, params: dict[str, Any]) -> object:
        from dataclasses import asdict

        printer = self._connected(self._printer_of(params))
        round_trips = list(printer.round_trips)[-256:]  # the latest (asked once a second)
        return {
            "stats": asdict(printer.stats),
            "round_trips": [[answered_s, latency_s] for answered_s, latency_s in round_trips],
            "now_s": asyncio.get_running_loop().time(),  # the clock of `answered_s`, for a client to shift to its own
        }
