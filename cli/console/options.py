"""The command lines of `marlin-temp send` and `marlin-temp terminal`: their options and help, checked before
`send` or `terminal` opens the printer."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions, Exit, UsageProblem
from ..common.options import error_console, fail, run, with_connect_options

__all__ = ["SEND_HELP", "TERMINAL_HELP", "send", "terminal"]

# Typer keeps single line breaks in help paragraphs, so each paragraph is one string.
SEND_HELP = "\n\n".join(
    (
        "Send G-code commands in order and print each reply (its lines, then ok).",
        "Every command is checked first: a line break, non-ASCII, an empty command, one too long for Marlin, or a "
        "heater target above --max-hotend or --max-bed however it is spelt (M104S280, m0104 s280, M104 B1000) exits "
        "with code 2 and nothing is sent. The first failure (timeout, halt, lost link) ends the run with its exit "
        "code; a command the printer does not know exits 1 after the others ran.",
        "Homing and probing (G28, G29, ...) get at least 3 minutes. M112 is the emergency stop: sent at once, the "
        "printer halts.",
    )
)


@with_connect_options("hotend", "bed")
def send(
    commands: Annotated[
        list[str] | None,
        typer.Argument(help='G-code commands, one per argument: send "G28" "G1 X10 F3000".', show_default=False),
    ] = None,
    *,
    options: ConnectOptions,
) -> None:
    """Send G-code commands in order and print each reply (the help text is `SEND_HELP`)."""
    from .send import check_commands, send_commands

    try:
        checked = check_commands(commands or [], limits=options.limits)
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    code = run(send_commands(options, checked, Console(highlight=False, emoji=False, soft_wrap=True), error_console()))
    raise typer.Exit(int(code))


TERMINAL_HELP = "\n\n".join(
    (
        "Interactive G-code console: type commands, read replies; temperatures in the bottom bar.",
        "Tab completes the common G and M codes (with what each does); Up/Down and Ctrl-R reach the history of "
        "earlier sessions. Replies are printed as they come, and you can type on while a long command runs. Ctrl-C "
        "clears the line, Ctrl-D quits.",
        "F12 sends the emergency stop at once, ahead of anything queued: the printer halts and needs a reset (the "
        "exit code is then 7). M112 (or !) and Enter asks first. M112 is never completed or kept in the history.",
        "Every command is read as Marlin reads it and checked against --max-hotend and --max-bed (M104S280, "
        "m0104 s280 and M104 B1000 are all heater targets); one refused, or a malformed one, is one error line and "
        "nothing is sent.",
        "Needs a terminal: from scripts use send.",
    )
)


@with_connect_options("hotend", "bed")
def terminal(
    *,
    options: ConnectOptions,
    interval: Annotated[
        float, typer.Option("--interval", help="Seconds between the (hidden) M105 temperature polls.", min=0.05)
    ] = 1.0,
    temperatures_every: Annotated[
        float,
        typer.Option(
            "--temperatures-every",
            help="Add a temperature line to the scrollback at most this often, when they changed (0: never).",
            min=0,
        ),
    ] = 30.0,
    history: Annotated[
        Path | None,
        typer.Option(
            "--history",
            help="History file. Default: $XDG_STATE_HOME/marlin-temp/history (~/.local/state/marlin-temp/history).",
            show_default=False,
        ),
    ] = None,
    no_history: Annotated[bool, typer.Option("--no-history", help="Keep no history after this session.")] = False,
) -> None:
    """The interactive G-code console (the help text is `TERMINAL_HELP`)."""
    from .terminal import ConsoleSettings, default_history_path, run_console

    if not (sys.stdin.isatty() and sys.stdout.isatty()):
        fail('terminal needs an interactive terminal; from a script use: marlin-temp send "G28" "M114"', Exit.USAGE)
    settings = ConsoleSettings(
        poll_interval_s=interval,
        temperature_every_s=temperatures_every,
        history_path=None if no_history else history or default_history_path(),
    )
    code = run(run_console(options, settings, error_console()))
    raise typer.Exit(int(code))
