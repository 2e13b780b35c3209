"""What every command's typer function shares: the options that say which printer and how (`--port`, `--baud`,
`--sim`, `--timeout`, the password's, `--max-hotend` ...), the one function that makes them a `ConnectOptions`,
and the way a command fails (`fail`) and runs its async body (`run`).

Typer has no option groups, so a command that talks to one printer declares a keyword-only
`options: ConnectOptions` and `with_connect_options` puts the shared options in its place: `--help` lists them
where `options` stands, and the function gets them already made into one `ConnectOptions` by `connect_options`.
`watch` declares them itself (its `--port` is repeatable, and its own options come between them) and calls
`connect_options`.
"""

from __future__ import annotations

import functools
import inspect
import os
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer
from rich.console import Console
from rich.markup import escape

import marlin_aio
from marlin_aio.protocol import DEFAULT_LIMITS, check_target

if TYPE_CHECKING:
    from marlin_aio.aio import WireLog

from .connect import PASSWORD_ENV, ConnectOptions, Exit, UsageProblem, exit_code_for, printer_password

__all__ = [
    "AskPasswordOption",
    "BaudOption",
    "FarmWireLogOption",
    "MaxBedOption",
    "MaxChamberOption",
    "MaxHotendOption",
    "PasswordFileOption",
    "PasswordOption",
    "PortOption",
    "SimOption",
    "SimSpeedOption",
    "TimeoutOption",
    "WireLogOption",
    "checked_log_path",
    "checked_target",
    "checked_wire_log",
    "connect_options",
    "error_console",
    "fail",
    "run",
    "with_connect_options",
]

_T = TypeVar("_T")


def error_console() -> Console:
    """The console for errors and notes: stderr, without markup surprises (no highlighting, no emoji)."""
    return Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)


def fail(message: str, code: int = Exit.ERROR) -> NoReturn:
    """Print `error: message` as one line on stderr and exit with `code`."""
    error_console().print(f"[bold red]error:[/] {escape(message)}", markup=True)
    raise typer.Exit(int(code))


def run(main: Coroutine[Any, Any, _T]) -> _T:
    """Run an async command body; map errors to one line and an exit code, Ctrl-C to 130."""
    import asyncio  # here, not at the top: `--help` loads no event loop

    try:
        return asyncio.run(main)
    except BrokenPipeError:
        # The reader went away (`marlin-temp watch | head`): not an error. Point stdout at /dev/null so the flush at
        # exit does not fail on the closed pipe again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        raise typer.Exit(int(Exit.OK)) from None
    except KeyboardInterrupt:
        error_console().print("interrupted", style="dim")
        raise typer.Exit(int(Exit.INTERRUPTED)) from None
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    except marlin_aio.MarlinError as exc:
        fail(str(exc), exit_code_for(exc))
    except ValueError as exc:
        # Our own checks raise ValueError for bad input found late (e.g. a log file with other columns).
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))


def checked_log_path(path: Path, flag: str) -> Path:
    """A log file the user named (`log --output`, `watch --log`), checked before anything connects: its folder must
    exist and it must not be a folder itself, else one line naming what is wrong and exit code 2 (before this, the
    open failed after the connect, with exit code 1 and only the file's name)."""
    folder = path.parent
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        fail(f"{flag} {path}: its folder {what}: {folder.resolve()} (create it first)", Exit.USAGE)
    if path.is_dir():
        fail(f"{flag} {path} is a folder: give a file name in it", Exit.USAGE)
    return path


def checked_target(name: str, raw: str | None, limit: float) -> float | None:
    """A target given on the command line (`--hotend`, `--bed`, `--chamber`) as a number, None if not given; one
    that is not a number, negative or above `limit` fails with exit code 2, saying which --max-* raises it."""
    if raw is None:
        return None
    try:
        return check_target(name, raw, limit)
    except ValueError as exc:
        hint = f" (raise the limit with --max-{name})" if "above the limit" in str(exc) else ""
        fail(f"{exc}{hint}", Exit.USAGE)


# ------------------------------------------------------------------------------------------- shared options

PortOption = Annotated[
    str | None,
    typer.Option(
        "--port",
        "-p",
        help="Device path (/dev/ttyUSB0) or pyserial URL (socket://host:port). Default: the one printer-like port.",
        show_default=False,
    ),
]


def _check_baud(value: int | None) -> int | None:
    if value is not None and value <= 0:
        raise typer.BadParameter(f"must be a positive number of bits per second, such as 250000 or 115200, got {value}")
    return value


BaudOption = Annotated[
    int | None,
    typer.Option(
        "--baud",
        "-b",
        help="Baud rate. Default 250000, falling back to 115200 when auto-detecting.",
        callback=_check_baud,
    ),
]
SimOption = Annotated[bool, typer.Option("--sim", help="Use the built-in simulated printer (no hardware needed).")]
SimSpeedOption = Annotated[
    float, typer.Option("--sim-speed", help="With --sim: simulated seconds per real second.", min=0.01)
]
TimeoutOption = Annotated[
    float, typer.Option("--timeout", help="Seconds to wait for each answer from the printer.", min=0.1)
]
# The printer's password (Marlin's PASSWORD_FEATURE, M511) never comes from the command line, where `ps` shows it
# to every user of the machine: `--password VALUE` is refused with a line that says where to put it instead.
PasswordOption = Annotated[str | None, typer.Option("--password", hidden=True, show_default=False)]
PasswordFileOption = Annotated[
    Path | None,
    typer.Option(
        "--password-file",
        help=f"Unlock a printer with Marlin's PASSWORD_FEATURE (M511) when it connects, with the password in this "
        f"file (or in ${PASSWORD_ENV}).",
        show_default=False,
    ),
]
AskPasswordOption = Annotated[
    bool, typer.Option("--ask-password", help="Ask for the printer's password (M511) on the terminal.")
]
MaxHotendOption = Annotated[
    float, typer.Option("--max-hotend", help="Highest hotend target allowed (C).", min=1, max=1000)
]
MaxBedOption = Annotated[float, typer.Option("--max-bed", help="Highest bed target allowed (C).", min=1, max=1000)]
MaxChamberOption = Annotated[
    float, typer.Option("--max-chamber", help="Highest chamber target allowed (C).", min=1, max=1000)
]
WireLogOption = Annotated[
    Path | None,
    typer.Option(
        "--wire-log",
        help="Append every line sent to and received from the printer, with times, to this file (passwords "
        "redacted). Default: no wire log.",
        show_default=False,
    ),
]

#: `--wire-log` of the commands that run several printers (serve, farm): one file, each line with the printer's name.
FarmWireLogOption = Annotated[
    Path | None,
    typer.Option(
        "--wire-log",
        help="Append every line sent to and received from the printers, with times and each printer's name, to "
        "this file (passwords redacted). Default: no wire log.",
        show_default=False,
    ),
]


def checked_wire_log(path: Path | None) -> WireLog | None:
    """The wire log `--wire-log` names, checked before anything connects as `checked_log_path` checks a log (and
    that it can be written): exit code 2 with one line otherwise. The file itself is made by the first connection."""
    if path is None:
        return None
    checked_log_path(path, "--wire-log")
    target = path if path.exists() else path.parent
    if not os.access(target, os.W_OK):
        fail(f"--wire-log {path}: cannot write to {target.resolve()} (permission denied)", Exit.USAGE)
    # (issue 33) The wire log makes an existing file that others could read owner-only as it opens it: said here,
    # where the user sees it (the library says it on its logger).
    mode = path.stat().st_mode & 0o777 if path.exists() else 0
    if mode & 0o077 and path.stat().st_uid == os.getuid():
        error_console().print(
            f"--wire-log {path} is readable by others ({mode:o}): it is made owner-only (600)",
            style="dim",
            markup=False,
        )
    from marlin_aio.aio import WireLog  # the client's parts load when a command runs, not for --help

    return WireLog(path)


def connect_options(
    port: PortOption = None,
    baud: BaudOption = None,
    sim: SimOption = False,
    sim_speed: SimSpeedOption = 1.0,
    timeout: TimeoutOption = 10.0,
    password: PasswordOption = None,
    password_file: PasswordFileOption = None,
    ask_password: AskPasswordOption = False,
    max_hotend: MaxHotendOption = DEFAULT_LIMITS.hotend,
    max_bed: MaxBedOption = DEFAULT_LIMITS.bed,
    max_chamber: MaxChamberOption = DEFAULT_LIMITS.chamber,
    wire_log: WireLogOption = None,
) -> ConnectOptions:
    """The `ConnectOptions` of the shared options, with the printer's password read as `printer_password` says:
    a `--password` on the command line, two sources, or an unreadable file fails with one line (exit code 2).

    Its parameters are also the shared options' declaration: `with_connect_options` gives them to a command.
    """
    try:
        secret = printer_password(password, password_file, ask=ask_password)
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    return ConnectOptions(
        port=port,
        baud=baud,
        sim=sim,
        sim_speed=sim_speed,
        timeout_s=timeout,
        limits=marlin_aio.HeaterLimits(max_hotend, max_bed, max_chamber),
        password=secret,
        wire_log=checked_wire_log(wire_log),
    )


_SHARED = inspect.signature(connect_options, eval_str=True).parameters
_LIMIT_OPTIONS = {"hotend": "max_hotend", "bed": "max_bed", "chamber": "max_chamber"}


def with_connect_options(*heaters: str) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Give a command the shared options in place of its keyword-only `options: ConnectOptions` parameter, with
    `--max-<heater>` for each of `heaters` ("hotend", "bed", "chamber"; a heater left out keeps the library's
    limit); the command is called with them made into one `ConnectOptions` (`connect_options`).

    Typer reads a command's options from its signature, so the one it is given is the command's own with the
    shared parameters spliced in where `options` was: `--help` lists them in that place.

    Raises:
        ValueError: a heater other than those three.
    """
    unknown = set(heaters) - _LIMIT_OPTIONS.keys()
    if unknown:
        raise ValueError(f"no --max-* option for {sorted(unknown)}: the heaters are {', '.join(_LIMIT_OPTIONS)}")
    left_out = {_LIMIT_OPTIONS[heater] for heater in _LIMIT_OPTIONS.keys() - set(heaters)}
    shared = [parameter for name, parameter in _SHARED.items() if name not in left_out]

    def decorate(command: Callable[..., None]) -> Callable[..., None]:
        own = inspect.signature(command, eval_str=True)
        parameters = []
        for parameter in own.parameters.values():
            parameters.extend(shared if parameter.name == "options" else [parameter])

        @functools.wraps(command)
        def with_options(**values: Any) -> None:
            options = connect_options(**{parameter.name: values.pop(parameter.name) for parameter in shared})
            command(**values, options=options)

        # Keyword-only, as typer passes them: the spliced list need not follow Python's order of defaults.
        spliced = [parameter.replace(kind=inspect.Parameter.KEYWORD_ONLY) for parameter in parameters]
        with_options.__signature__ = own.replace(parameters=spliced)  # type: ignore[attr-defined]
        with_options.__annotations__ = {parameter.name: parameter.annotation for parameter in spliced}
        return with_options

    return decorate
