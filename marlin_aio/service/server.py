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

What a request can do is the service's table of verbs (`marlin_aio.service.verbs`), which every door calls: this
module is the owner the verbs act on (the farm, the uploads, the histories, the clients to tell) and the socket's
door (`methods`: each verb the socket offers, called with the session as the caller). A client's reader, writer
and queue are `session.Session`. Over 400 lines because it is the service's life (listening, the registry) and
every notification it sends, read together.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import stat
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import marlin_aio
from marlin_aio.aio.servicepaths import SOCKET_ENV, default_socket_path
from marlin_aio.farm.presets import DEFAULT_PRESETS, Preset
from marlin_aio.farm.supervisor import Farm, FarmEvent, FarmPrinter, PrinterSpec
from marlin_aio.protocol import redact
from marlin_aio.protocol.rpc import (
    MAX_MESSAGE_BYTES,
    encode_message,
    error_to_json,
    notification,
    progress_to_json,
    reading_to_json,
    requests_to_json,
)
from marlin_aio.service import verbs
from marlin_aio.service.appkeys import AppKeys
from marlin_aio.service.history import History
from marlin_aio.service.session import MAX_AUTHENTICATING, MAX_TCP_CLIENTS, Handler, Session, tcp_clients
from marlin_aio.service.uploads import Uploads
from marlin_aio.service.verbs import Caller, Door
from marlin_aio.service.verbs.feeds import TOPICS

__all__ = ["TOPICS", "OctoPrintSettings", "Service", "ServiceRunningError", "TcpSettings", "check_private_folder"]

_log = logging.getLogger("marlin_aio.service")

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
        # Anyone may make a folder in /tmp first: say whose it is and how to get out of the way, in one line.
        whose = "another user" if info.st_uid == os.getuid() else f"user {_user_name(info.st_uid)}"
        raise PermissionError(
            f"{folder} belongs to {whose} or others may enter it (mode {stat.S_IMODE(info.st_mode):o}): refusing "
            f"to use it; remove it, or give --socket (or ${SOCKET_ENV}) in a folder of your own, such as under "
            "$XDG_RUNTIME_DIR"
        )


def _user_name(uid: int) -> str:
    import pwd

    try:
        return f"{pwd.getpwuid(uid).pw_name} (uid {uid})"
    except KeyError:
        return f"uid {uid}"


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
        presets: the named targets the `apply_preset` verb sets.

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
        presets: Sequence[Preset] = DEFAULT_PRESETS,
    ) -> None:
        self.socket_path = socket_path or default_socket_path()
        self.uploads = Uploads(uploads_dir or self.socket_path.parent / "uploads")
        # The OctoPrint API's app keys, kept beside its API key in the service's private folder.
        self.app_keys = AppKeys(self.socket_path.parent / "app-keys.json" if octoprint is not None else None)
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
        self.presets = tuple(presets)
        self.sent_files: dict[Path, str] = {}  # prints sent as lines: removed when their job ends
        # Prints an earlier service did not see to their end, by printer (`marlin_aio.service.lifecycle`).
        self.interrupted_jobs: dict[str, dict[str, object]] = {}
        # The socket's door: every verb of the table it is offered on, called with the session as the caller.
        self.methods: dict[str, Handler] = {
            name: self._door(name) for name, entry in verbs.VERBS.items() if entry.doors & {"socket", "tcp"}
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
        api = OctoPrintApi(self, self.farm.printers[name], self.uploads, settings.api_key)
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
        if tcp_clients(self.sessions) >= MAX_TCP_CLIENTS:
            writer.transport.abort()  # a flood of connections: the ones over the bound are not even read
            return
        waiting = [session for session in self.sessions if session.authenticating]
        if len(waiting) >= MAX_AUTHENTICATING:
            # The one waiting longest makes room: a client with the token authenticates with its first line, so
            # only clients without it are ever old here, however many of them connect.
            oldest = min(waiting, key=lambda session: session.number)
            _log.warning("client %d: %d clients wait to authenticate: disconnected", oldest.number, len(waiting))
            oldest.close(abort=True)
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
                job = farm_printer.job
                if job is not None and job.active:
                    self._progress_of(farm_printer)
                # A wait for the user ends with an ok, and a prompt closes when answered: no request says so.
                self._tell_requests(farm_printer, None)

    def _progress_of(self, farm_printer: FarmPrinter, *, final: bool = False) -> None:
        job = farm_printer.job
        if job is None or job.handle is None:
            return
        handle = job.handle
        progress = handle.progress
        params: dict[str, Any] = {"file": job.file, "progress": progress_to_json(progress), "job": job.to_json()}
        if progress.state is marlin_aio.PrintState.FAILED and handle.job.error is not None:
            params["error"] = error_to_json(handle.job.error)
        if not final and self._announced.get(farm_printer.name) == params:
            return
        self._announced[farm_printer.name] = params
        self._broadcast(farm_printer.name, "progress", "progress", params)

    # ------------------------------------------------------------------------------------------- the owner of verbs

    @property
    def clients(self) -> int:
        """Socket clients connected now."""
        return len(self.sessions)

    def note(self, printer: str, direction: str, text: str) -> None:
        """Keep a console line (redacted) and tell the console's subscribers."""
        self._note(printer, direction, text)

    def tell_progress(self, farm_printer: FarmPrinter) -> None:
        """Tell the progress subscribers of the printer's job now."""
        self._progress_of(farm_printer)

    def tell_requests(self, farm_printer: FarmPrinter) -> None:
        """Tell the requests subscribers the state of the printer's prompts now."""
        self._tell_requests(farm_printer, None)

    def _door(self, name: str) -> Handler:
        """The socket's handler of the verb `name`: the session's client as the caller, the table does the rest."""

        async def handle(session: Session, params: dict[str, Any]) -> object:
            door: Door = "tcp" if session.remote else "socket"
            caller = Caller(
                door,
                f"{door} client {session.number}",
                files="uploads" if session.remote else "any",
                subscriber=session,
            )
            return await verbs.call(self, name, params, caller)

        return handle
