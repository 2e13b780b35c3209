"""Choosing and opening the printer for a CLI command, and turning failures into one line and an exit code."""

from __future__ import annotations

import contextlib
import contextvars
import getpass
import os
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console

import marlin_aio
from marlin_aio.protocol import DEFAULT_LIMITS

if TYPE_CHECKING:
    import asyncio

    from marlin_aio.aio import Retry, WireLog

from .keys import STOP_SIGNALLED

__all__ = [
    "EXIT_CODES_HELP",
    "OPENED_PORT",
    "PASSWORD_ENV",
    "ConnectOptions",
    "Exit",
    "UsageProblem",
    "exit_code_for",
    "open_printer",
    "printer_password",
    "run_sessions",
]

#: The port the latest `open_printer` of this task opened (as a path or URL, without a note): `--on-done` tells it.
OPENED_PORT: contextvars.ContextVar[str] = contextvars.ContextVar("opened_port", default="")

#: The environment variable a locked printer's password (M511) is read from.
PASSWORD_ENV = "MARLIN_PASSWORD"


class Exit(IntEnum):
    """The exit codes of every marlin-temp command (also listed in `--help`)."""

    OK = 0
    ERROR = 1
    USAGE = 2
    NO_PORT = 3
    PORT_BUSY = 4
    PERMISSION = 5
    NO_ANSWER = 6
    HALTED = 7
    LOST = 8
    TIMEOUT = 9
    INTERRUPTED = 130


EXIT_CODES_HELP = (
    "Exit codes: 0 done; 1 other error; 2 bad arguments or targets; 3 port not found; 4 port busy; "
    "5 permission denied; 6 no answer (wrong port or baud rate); 7 printer halted or thermal runaway; "
    "8 connection lost; 9 timed out; 130 interrupted."
)


class UsageProblem(Exception):
    """A problem with the user's arguments or environment, reported with exit code 2 (or `code`)."""

    def __init__(self, message: str, code: Exit = Exit.USAGE) -> None:
        super().__init__(message)
        self.code = code


def printer_password(on_argv: str | None, password_file: Path | None, *, ask: bool) -> str | None:
    """A locked printer's password (Marlin's PASSWORD_FEATURE): asked on the terminal with `ask`, else read from
    `password_file` (its first line), else from $MARLIN_PASSWORD; None when none is given.

    Never from the command line: every user of the machine sees a process's arguments (`ps`), so a password given
    there (`on_argv`) is refused with the ways that keep it private.

    Raises:
        UsageProblem: a password on the command line, more than one source, or a file that cannot be read.
    """
    if on_argv is not None:
        raise UsageProblem(
            f"--password on the command line is visible to every user of this machine (ps): put it in ${PASSWORD_ENV}, "
            "in a file given with --password-file, or type it with --ask-password"
        )
    if ask and password_file is not None:
        raise UsageProblem("--ask-password and --password-file are two sources of one password: give one")
    if ask:
        try:
            return getpass.getpass("printer password (M511): ") or None
        except (EOFError, KeyboardInterrupt):
            raise UsageProblem("no password typed for --ask-password", Exit.INTERRUPTED) from None
    if password_file is not None:
        try:
            lines = password_file.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise UsageProblem(f"--password-file {password_file}: {reason}") from None
        if not lines or not lines[0].strip():
            raise UsageProblem(f"--password-file {password_file} is empty: its first line should be the password")
        return lines[0].strip()
    return os.environ.get(PASSWORD_ENV) or None


def exit_code_for(exc: marlin_aio.MarlinError) -> Exit:
    """The exit code for a library error."""
    if isinstance(exc, marlin_aio.PortNotFoundError):
        return Exit.NO_PORT
    if isinstance(exc, marlin_aio.PortBusyError):
        return Exit.PORT_BUSY
    if isinstance(exc, marlin_aio.PortPermissionError):
        return Exit.PERMISSION
    if isinstance(exc, marlin_aio.HandshakeError):
        return Exit.NO_ANSWER
    if isinstance(exc, marlin_aio.PrinterHaltedError):
        return Exit.HALTED
    if isinstance(exc, marlin_aio.ConnectionLostError):
        return Exit.LOST
    if isinstance(exc, TimeoutError):
        return Exit.TIMEOUT
    return Exit.ERROR


@dataclass(frozen=True)
class ConnectOptions:
    """The options every command that talks to a printer shares (`options.connect_options` makes them from the
    command line)."""

    port: str | None = None
    baud: int | None = None
    sim: bool = False
    sim_speed: float = 1.0
    timeout_s: float = 10.0
    limits: marlin_aio.HeaterLimits = DEFAULT_LIMITS
    """The highest targets any command may set (--max-hotend, --max-bed, --max-chamber)."""
    password: str | None = None
    wire_log: WireLog | None = None
    """Where every line on the wire goes (--wire-log), or None."""

    def printer(self, port: str, baud: int) -> marlin_aio.Printer:
        """A client for `port` with these options."""
        return marlin_aio.connect(
            port,
            baudrate=baud,
            timeout_s=self.timeout_s,
            max_hotend_celsius=self.limits.hotend,
            max_bed_celsius=self.limits.bed,
            max_chamber_celsius=self.limits.chamber,
            password=self.password,
            wire_log=self.wire_log,
        )


def _choose_port(console: Console) -> str:
    ports = marlin_aio.list_ports()
    likely = [p for p in ports if p.likely_printer]
    if len(likely) == 1:
        console.print(f"using {likely[0].device} ({likely[0].bridge})", style="dim")
        return likely[0].device
    if not likely:
        seen = ", ".join(p.device for p in ports) or "none"
        raise UsageProblem(
            f"no printer port found (serial ports: {seen}): give --port DEVICE, or --sim for the simulated printer"
        )
    names = ", ".join(f"{p.device} ({p.bridge})" for p in likely)
    raise UsageProblem(f"several printer ports found ({names}): choose one with --port")


@contextlib.asynccontextmanager
async def open_printer(options: ConnectOptions, console: Console) -> AsyncIterator[tuple[marlin_aio.Printer, str]]:
    """Open the printer the options name; yield it with a label for the footer (the port).

    With `--sim` the simulated printer runs in this process on a real pty. Without `--port`, a single likely
    printer port is used, trying 250000 baud then 115200 unless `--baud` was given.

    Raises:
        UsageProblem: no port given and none (or several) found.
        MarlinError: opening or the handshake failed.
    """
    if options.sim:
        # Imported here: a command on a real printer (and every --help) need not load the simulator.
        from marlin_aio.simulator import SimulatorConfig, serve_pty

        async with (
            serve_pty(SimulatorConfig(), time_scale=options.sim_speed) as server,
            options.printer(server.url, options.baud or marlin_aio.DEFAULT_BAUDRATE) as printer,
        ):
            OPENED_PORT.set(server.url)
            yield printer, f"{server.url} (simulated)"
        _say_wire_log_error(options, console)
        return
    if options.port is not None and not options.port.strip():
        raise UsageProblem("--port is empty: give a device path or URL, or leave --port out to find the printer")
    port = options.port or _choose_port(console)
    if not port.startswith("serve:"):
        from marlin_aio.service import service_holding

        served = service_holding(port)
        if served is not None:
            # The service owns the port (opening it would fail as busy): go through it instead, and say so.
            console.print(f"{port} is held by marlin-temp serve: using it ({served})", style="dim")
            port = served
    served_port = port.startswith("serve:")
    if served_port and options.wire_log is not None:
        # The client speaks to the service, not to the printer: the serial lines are the service's to log.
        console.print(
            f"--wire-log: {port}'s wire belongs to marlin-temp serve, nothing is written here "
            "(give serve --wire-log instead)",
            style="yellow",
            markup=False,
        )
    rates = (
        [options.baud or marlin_aio.DEFAULT_BAUDRATE] if served_port or options.baud else list(marlin_aio.BAUD_RATES)
    )
    for index, baud in enumerate(rates):
        try:
            printer = options.printer(port, baud)
            await _open_unless_signalled(printer)
        except marlin_aio.HandshakeError as exc:
            if index + 1 < len(rates):
                console.print(f"no answer at {baud} baud, trying {rates[index + 1]}", style="dim")
                continue
            if len(rates) > 1:
                # The library's hint names the other common rate, which was tried already.
                tried = " and ".join(str(rate) for rate in rates)
                raise marlin_aio.HandshakeError(
                    f"no answer from {port} at {tried} baud (is it the printer's port, and is the printer on?); "
                    f"at {baud}: {exc}",
                    step=exc.step,
                ) from exc
            raise
        OPENED_PORT.set(port)
        if served_port:
            port = f"{port} (served)"
        elif printer.reset_on_open:
            # Boards reset by DTR on the first open after plugging in; a user who set targets before must know.
            console.print(
                "note: the board reset when the port was opened; targets set earlier were cleared", style="yellow"
            )
        try:
            yield printer, port
        finally:
            await printer.close()
            _say_wire_log_error(options, console)
        return


async def _open_unless_signalled(printer: marlin_aio.Printer) -> None:
    """Open `printer`; a stop signal (Ctrl-C, SIGTERM) while it opens ends the opening at once, port closed.

    A command that handles its stop signals (`keys.on_stop_signals`) only looks at its stop once connected, and a
    handshake may take several timeouts (and the baud fallback a second handshake): without this, Ctrl-C waited
    for all of it.

    Raises:
        KeyboardInterrupt: a stop signal came first (the command ends with exit code 130).
        MarlinError: opening or the handshake failed.
    """
    signalled = STOP_SIGNALLED.get()
    if signalled is None:
        await printer.open()
        return
    if signalled.is_set():
        raise KeyboardInterrupt
    import asyncio  # here, not at the top: `--help` loads no event loop

    opening = asyncio.create_task(printer.open(), name=f"open {printer.port}")
    stopping = asyncio.create_task(signalled.wait(), name="stop signal")
    try:
        await asyncio.wait({opening, stopping}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        stopping.cancel()
        if not opening.done():
            # Cancelling the handshake closes the port (`Printer.open` closes it on any failure).
            opening.cancel()
            await asyncio.gather(opening, return_exceptions=True)
    if opening.cancelled():
        raise KeyboardInterrupt
    opening.result()  # opened (the command sees its stop as it always did), or why not


def _say_wire_log_error(options: ConnectOptions, console: Console) -> None:
    """Say once that the wire log stopped (a full disk, a file that cannot be opened): it never stops the command."""
    error = options.wire_log.take_error() if options.wire_log is not None else None
    if error is not None and options.wire_log is not None:
        console.print(
            f"warning: --wire-log {options.wire_log.path} stopped: {error.strerror or error}",
            style="yellow",
            markup=False,
        )


async def run_sessions(
    options: ConnectOptions,
    errors: Console,
    session: Callable[[marlin_aio.Printer, str], Awaitable[None]],
    *,
    reconnect: bool,
    retried: tuple[type[marlin_aio.MarlinError], ...],
    goal: str,
    stop: asyncio.Event,
    deadline: float | None,
    before_wait: Callable[[], None] | None = None,
) -> None:
    """Run `session(printer, label)` on the printer `options` name (`open_printer`); with `reconnect`, again after
    each failure of a `retried` kind, through the library's `keep_connected` (waits of 1 s doubling to 30 s, from
    1 s again once connected; a stop or the deadline ends a wait at once). `before_wait` runs before each wait.

    Raises:
        MarlinError: a failure not in `retried`, or any failure without `reconnect` or after a stop; a lost link
            then says "unplugged? use --reconnect to `goal`".
    """
    label = ""

    @contextlib.asynccontextmanager
    async def connect() -> AsyncIterator[marlin_aio.Printer]:
        nonlocal label
        async with open_printer(options, errors) as (printer, label):
            yield printer

    async def run(printer: marlin_aio.Printer) -> None:
        await session(printer, label)

    def on_retry(retry: Retry) -> None:
        exc = retry.error
        # keep_connected retries every MarlinError; a command retries only its `retried` kinds. The others (a
        # halted printer, a timeout, ...) end the run as they always did, with their exit codes.
        if not isinstance(exc, retried):
            raise exc
        if not reconnect or stop.is_set():
            if isinstance(exc, marlin_aio.ConnectionLostError):
                raise marlin_aio.ConnectionLostError(f"{exc} (unplugged? use --reconnect to {goal})") from exc
            raise exc
        if before_wait is not None:
            before_wait()
        errors.print(f"{exc}; reconnecting in {retry.delay_s:g} s (Ctrl-C stops)", style="yellow", markup=False)

    from marlin_aio.aio import Backoff, keep_connected  # the client, when a command runs (not for --help)

    await keep_connected(connect, run, backoff=Backoff(1.0, 30.0), on_retry=on_retry, stop=stop, deadline=deadline)
