"""`marlin-temp serve` at work: the service runs until --duration, SIGTERM (systemd's stop) or Ctrl-C; every
printer's events are printed as they happen, one line each.

SIGTERM and Ctrl-C end the prints first (`marlin_aio.service.lifecycle`: stop feeding, the cancel script, the record,
the clients told), within a bound; a second one leaves at once. --duration and a failure of the service itself end
without that (the prints then fail as their link closes, and their record says where a restart should resume).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import secrets
import signal
import time
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.text import Text

from marlin_aio.aio import WireLog
from marlin_aio.farm.supervisor import FarmEvent, PrinterSpec
from marlin_aio.service import (
    TOKEN_ENV,
    Lifecycle,
    OctoPrintSettings,
    Service,
    ServiceRunningError,
    TcpSettings,
    check_private_folder,
    default_socket_path,
)

from ..common.connect import Exit, UsageProblem
from .logs import ServeLogs

__all__ = ["API_KEY_ENV", "ServeOptions", "default_log_dir", "run_serve", "secret", "stop_prints"]


#: Where the OctoPrint API key can come from when no file is named.
API_KEY_ENV = "MARLIN_SERVE_API_KEY"


def secret(named: Path | None, env: str, made: Path, what: str) -> tuple[str, str]:
    """A secret (the OctoPrint API key, the TCP token) and where it came from: the file `named`, else `$env`, else
    the file `made` (beside the socket; a random one written owner-only the first time).

    Raises:
        UsageProblem: the secret is shorter than 16 characters.
        OSError: the file cannot be read or made.
    """
    if named is not None:
        value, source = named.read_text().strip(), str(named)
    elif os.environ.get(env):
        value, source = os.environ[env].strip(), f"${env}"
    else:
        check_private_folder(made.parent)  # a folder someone else made could hand us their secret
        if not made.exists():
            fd = os.open(made, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w") as handle:
                handle.write(secrets.token_hex(16) + "\n")
        value, source = made.read_text().strip(), str(made)
    if len(value) < 16:
        raise UsageProblem(f"the {what} from {source} is shorter than 16 characters")
    return value, source


@dataclass(frozen=True)
class ServeOptions:
    """What `marlin-temp serve` does besides the socket: the OctoPrint API (`http`: host and port), the logs."""

    http: tuple[str, int] | None = None
    http_printer: str | None = None
    key_file: Path | None = None
    tcp: tuple[str, int] | None = None
    token_file: Path | None = None
    log_dir: Path | None = None
    log_interval_s: float = 1.0
    wire_log: WireLog | None = None
    """Every printer's serial lines, each with the printer's name (--wire-log), or None."""
    leave_heaters: bool = False
    """After a restart, leave a printer that heats with no print as it is (--leave-heaters-after-restart)."""


def default_log_dir() -> Path:
    """`$XDG_STATE_HOME/marlin-temp/logs`, else `~/.local/state/marlin-temp/logs`."""
    state = os.environ.get("XDG_STATE_HOME")
    return (Path(state) if state else Path.home() / ".local" / "state") / "marlin-temp" / "logs"


async def run_serve(
    specs: list[PrinterSpec],
    socket: Path | None,
    duration_s: float | None,
    errors: Console,
    options: ServeOptions | None = None,
) -> None:
    """Serve `specs` at `socket` until `duration_s` passed, SIGTERM, or the task is cancelled; with `http`, the
    OctoPrint API on that host and port too. The service's warnings (a client let go, a malformed HTTP request,
    each one line with no secret) are printed on `errors` meanwhile.

    Raises:
        UsageProblem: another service already listens at the socket (exit 2: it is the user's to stop), or the
            OctoPrint options do not fit.
        OSError: the socket cannot be made, or the HTTP port is in use.
    """
    handler = _ConsoleHandler(errors)
    logger = logging.getLogger("marlin_aio.service")
    logger.addHandler(handler)
    try:
        await _run_serve(specs, socket, duration_s, errors, options)
    finally:
        logger.removeHandler(handler)


class _ConsoleHandler(logging.Handler):
    """The service's warnings as one dim line each on the serve command's stderr (the messages are the service's
    own, made one line and redacted where they are made)."""

    def __init__(self, errors: Console) -> None:
        super().__init__(logging.WARNING)
        self._errors = errors

    def emit(self, record: logging.LogRecord) -> None:
        try:
            line = record.getMessage().splitlines()[0] if record.getMessage() else record.levelname
            self._errors.print(Text(f"serve: {line}"), style="dim", soft_wrap=True)
        except Exception:  # logging must never end the service
            self.handleError(record)


async def _run_serve(
    specs: list[PrinterSpec],
    socket: Path | None,
    duration_s: float | None,
    errors: Console,
    options: ServeOptions | None,
) -> None:

    def show(event: FarmEvent) -> None:
        stamp = time.strftime("%H:%M:%S", time.localtime(event.time_s))
        errors.print(f"{stamp} {escape(event.printer)}: {escape(event.kind)}: {escape(event.message)}")
        if lifecycle is not None:
            lifecycle.on_event(event)

    lifecycle: Lifecycle | None = None

    options = options or ServeOptions()
    octoprint = None
    socket_path = socket or default_socket_path()
    if options.http is not None:
        key, key_source = secret(options.key_file, API_KEY_ENV, socket_path.parent / "api-key", "OctoPrint API key")
        octoprint = OctoPrintSettings(
            port=options.http[1], api_key=key, host=options.http[0], printer=options.http_printer
        )
    tcp = None
    if options.tcp is not None:
        token, token_source = secret(options.token_file, TOKEN_ENV, socket_path.parent / "token", "TCP token")
        tcp = TcpSettings(port=options.tcp[1], token=token, host=options.tcp[0])
    try:
        service = Service(specs, socket_path, on_event=show, octoprint=octoprint, tcp=tcp)
    except ValueError as exc:
        raise UsageProblem(str(exc)) from None
    service.farm.wire_log = options.wire_log
    try:
        # The socket first: a record of a print is an earlier service's only when no service runs here now.
        await service.check_socket()
    except ServiceRunningError as exc:
        raise UsageProblem(str(exc), Exit.USAGE) from None
    lifecycle = Lifecycle(service, leave_heaters=options.leave_heaters)
    lifecycle.install()
    stopped = asyncio.Event()
    signals: list[str] = []  # the signals received, in order
    leave_now: list[asyncio.Task[None]] = []  # the stop of the prints, cancelled by a second signal

    def on_signal(name: str) -> None:
        signals.append(name)
        stopped.set()
        if len(signals) > 1:
            for task in leave_now:
                task.cancel()

    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):  # not the main thread, or no signals
        for number in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(number, on_signal, number.name)
    started = time.monotonic()

    async def announce() -> None:
        await service.ready.wait()
        names = ", ".join(specs_names(specs))
        errors.print(
            f"serving {escape(names)} at {escape(str(service.socket_path))}; reach it as --port serve:NAME; "
            "Ctrl-C stops",
            style="dim",
        )
        if options.log_dir is not None:
            errors.print(f"logging temperatures to {escape(str(options.log_dir))}", style="dim")
        if tcp is not None:
            errors.print(
                f"also on tcp://{escape(tcp.host)}:{tcp.port} (clients give the token in {escape(token_source)} as "
                "$MARLIN_SERVE_TOKEN)",
                style="dim",
            )
        if octoprint is not None:
            errors.print(
                f"OctoPrint API on http://{escape(octoprint.host)}:{octoprint.port} (API key in {escape(key_source)})",
                style="dim",
            )

    running = asyncio.create_task(service.run(), name="service")
    waiters = [asyncio.create_task(stopped.wait(), name="SIGTERM"), asyncio.create_task(announce(), name="announce")]
    if options.log_dir is not None:
        logs = ServeLogs(service, options.log_dir, options.log_interval_s, errors)
        waiters.append(asyncio.create_task(logs.run(), name="logs"))
    try:
        async with asyncio.timeout(duration_s):
            await asyncio.wait([running, waiters[0]], return_when=asyncio.FIRST_COMPLETED)
        if signals and not running.done():
            await stop_prints(lifecycle, signals[0], errors, leave_now)
    except TimeoutError:
        pass  # --duration is up
    finally:
        # Ctrl-C (this task cancelled), SIGTERM, --duration or the service's own end: every printer is closed on
        # the way out and the socket removed before this returns.
        for task in (running, *waiters):
            task.cancel()
        outcome = (await asyncio.gather(running, *waiters, return_exceptions=True))[0]
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            for number in (signal.SIGTERM, signal.SIGINT):
                loop.remove_signal_handler(number)
    if isinstance(outcome, ServiceRunningError):
        raise UsageProblem(str(outcome), Exit.USAGE)
    if isinstance(outcome, OSError) and outcome.errno in (98, 13) and (octoprint or tcp):  # EADDRINUSE, EACCES
        listeners = [f"{octoprint.host}:{octoprint.port}" for octoprint in [octoprint] if octoprint]
        listeners += [f"tcp {tcp.host}:{tcp.port}" for tcp in [tcp] if tcp]
        raise UsageProblem(f"cannot listen on {' or '.join(listeners)}: {outcome.strerror}", Exit.USAGE)
    if isinstance(outcome, Exception):
        raise outcome
    errors.print(f"serve: stopped after {time.monotonic() - started:.0f} s", style="dim")
    if signals and signals[0] == "SIGINT":
        raise KeyboardInterrupt  # Ctrl-C ends as everywhere else: "interrupted", exit code 130


async def stop_prints(lifecycle: Lifecycle, why: str, errors: Console, leave_now: list[asyncio.Task[None]]) -> None:
    """End the running prints as the service stops (see `Lifecycle.stop`); a second signal leaves at once."""
    farm = lifecycle.service.farm
    printing = [fp.name for fp in farm.printers.values() if fp.print_handle and not fp.print_handle.finished]
    if printing:
        errors.print(
            f"serve: {why}: stopping the print on {escape(', '.join(printing))} (cancel script, then exit; at most "
            f"{lifecycle.stop_timeout_s:g} s; {why} again to leave at once)",
            style="dim",
        )
    stop = asyncio.create_task(lifecycle.stop(why, lambda line: errors.print(f"serve: {escape(line)}")), name="stop")
    leave_now.append(stop)
    await asyncio.wait([stop])
    if stop.cancelled():
        errors.print("serve: left at once: the prints were not stopped; their heaters may be on", style="bold red")
    elif stop.exception() is not None:
        raise stop.exception()  # type: ignore[misc]


def specs_names(specs: list[PrinterSpec]) -> list[str]:
    """The printers' names, in order."""
    return [spec.name for spec in specs]
