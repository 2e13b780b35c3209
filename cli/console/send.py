"""`marlin-temp send "G28" "M503"`: run G-code commands one after another and print each reply.

Every command is checked before the port is opened, so a bad one among several sends none of them. The checks
are the library's (`validate_command`, and `check_gcode_targets` for a target above the limits: `M104S280` exits 2
with nothing connected), plus a length that fits whatever line number the client gives it. M112 is not queued
behind the others: it goes out at once as the emergency stop (`Printer.emergency_stop`).

What the printer says is printed verbatim: `Cap:REPEAT:0` must not become an emoji, nor `echo:[bold]` a style, so
every line is printed with markup and emoji codes off, whatever Console it is given.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rich.console import Console

import marlin_aio
from marlin_aio import HeaterLimits
from marlin_aio.protocol import DEFAULT_LIMITS, command_code, command_timeout_s, validate_command

from ..common.connect import ConnectOptions, Exit, UsageProblem, open_printer

__all__ = [
    "check_command",
    "check_commands",
    "emergency_stop_notes",
    "reply_lines",
    "send_commands",
    "unknown_command",
]


def emergency_stop_notes(capabilities: Mapping[str, bool]) -> list[str]:
    """What to tell the user once M112 is written; a board that said (M115) it has no EMERGENCY_PARSER reads it
    only when its turn comes, after the commands it already has, so the user must know to cut the power."""
    notes = ["emergency stop sent (M112): the printer halts; reset it (or power it off and on) to go on"]
    if capabilities.get("EMERGENCY_PARSER") is False:
        notes.append(
            "this firmware has no EMERGENCY_PARSER: it acts on M112 only after the commands it already holds; "
            "if it must stop now, cut its power"
        )
    return notes


def check_command(text: str, *, limits: HeaterLimits = DEFAULT_LIMITS) -> str:
    """The command as it will be sent (comment and surrounding blanks removed).

    Raises:
        ValueError: a line break, non-ASCII, `*` or nothing in it, too long for Marlin once numbered, or a target
            that is not a number, negative or above `limits` (by default the library's).
    """
    command = validate_command(text)
    # The client refuses it too, but only once connected: checked here, a bad command opens nothing.
    marlin_aio.protocol.check_command(command, limits)
    return command


def check_commands(texts: Sequence[str], *, limits: HeaterLimits = DEFAULT_LIMITS) -> list[str]:
    """Every command checked (see `check_command`, with `limits`), before any is sent.

    Raises:
        UsageProblem: none given, or one is bad (the message says which and why).
    """
    if not texts:
        raise UsageProblem('no command given: marlin-temp send "G28" "M114"')
    commands = []
    for index, text in enumerate(texts, 1):
        try:
            commands.append(check_command(text, limits=limits))
        except ValueError as exc:
            which = f"command {index} of {len(texts)}" if len(texts) > 1 else "the command"
            # The library speaks to callers of `send()`; here each command is an argument of its own.
            reason = str(exc).replace("send one command per call", "give each command as an argument of its own")
            raise UsageProblem(f"{which} was refused, nothing was sent: {reason}") from None
    return commands


def reply_lines(reply: marlin_aio.Reply) -> list[str]:
    """The lines to show for a reply: what the printer said, then its `ok` (with what rode on it, e.g. M105's)."""
    lines = list(reply.lines)
    if reply.lines_dropped:
        lines.insert(0, f"({reply.lines_dropped} earlier lines not kept)")
    lines.append(f"ok {reply.ok.payload}".rstrip())
    return lines


def unknown_command(reply: marlin_aio.Reply) -> bool:
    """Did the printer say it does not know the command (and so ran nothing)?"""
    return any(line.startswith("echo:Unknown command") for line in reply.lines)


async def send_commands(options: ConnectOptions, commands: Sequence[str], console: Console, errors: Console) -> Exit:
    """Send `commands` (already checked) in order, printing each reply; return the exit code.

    The first failure (a timeout, a halt, the link lost) ends the run: the commands after it are not sent. A
    command the printer does not know is reported, the others still run, and the exit code is 1.

    Raises:
        MarlinError: opening the printer or a command failed.
    """
    code = Exit.OK
    async with open_printer(options, errors) as (printer, _label):
        for command in commands:
            if len(commands) > 1:
                console.print(f"> {command}", style="bold", markup=False, emoji=False)
            if command_code(command) == "M112":
                printer.emergency_stop()
                for note in emergency_stop_notes(printer.capabilities):
                    console.print(note, style="bold red", markup=False, emoji=False)
                continue
            reply = await printer.send(command, timeout_s=command_timeout_s(command, options.timeout_s))
            for line in reply_lines(reply):
                console.print(line, markup=False, emoji=False)
            if unknown_command(reply):
                errors.print(
                    f"error: the printer does not know {command_code(command)}", style="red", markup=False, emoji=False
                )
                code = Exit.ERROR
    return code
