"""Commands to the farm's printers over MQTT: each payload checked as the CLI checks its arguments, then run.

A command is a JSON object published to `PREFIX/NAME/command`; its answer goes to `PREFIX/NAME/response` as
`{"id": <the command's id>, "ok": true, "result": ...}` or `{"id": ..., "ok": false, "error": "..."}`:

    {"id": 1, "action": "set_temperatures", "hotend": 200, "bed": 60}
    {"id": 2, "action": "set_target", "heater": "hotend", "celsius": 210}    (Home Assistant's number entities)
    {"id": 3, "action": "gcode", "command": "G28"}                            (or "commands": ["G28", "M114"])
    {"id": 4, "action": "print", "path": "benchy.gcode"}                      (inside --allowed-dir only)
    {"id": 5, "action": "pause"} / "resume" / "cancel"
    {"id": 6, "action": "emergency_stop"}

Everything is checked before anything is written: bad JSON, an unknown printer or action, a target of 900 or
`abc`, a newline inside a G-code command, a G-code command setting a target above the printer's limit however it
is spelt (`M104S280`, `m0104 s280`, `M104 B1000`: the library's `check_gcode_targets`, which reads it as Marlin
does), a path outside the allowed directory each get an error answer and write nothing to any printer.
`parse_command` does the checking (no I/O but the path's), `run_command` the running.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import marlin_aio

from .farm import FarmPrinter

__all__ = ["ACTIONS", "CommandError", "FarmCommand", "parse_command", "run_command"]

ACTIONS = ("set_temperatures", "set_target", "gcode", "print", "pause", "resume", "cancel", "emergency_stop")
MAX_PAYLOAD_BYTES = 65_536
MAX_GCODE_COMMANDS = 100


class CommandError(ValueError):
    """A command refused before anything was written; the message says why, for the response topic."""


@dataclass(frozen=True)
class FarmCommand:
    """A checked command for one printer."""

    printer: str
    action: str
    id: str | int | None = None
    targets: dict[str, float | int] = field(default_factory=dict)
    """For set_temperatures: hotend, bed, chamber (degrees C) and tool."""
    gcode: tuple[str, ...] = ()
    path: Path | None = None


def _targets(values: dict[str, Any], farm_printer: FarmPrinter) -> dict[str, float | int]:
    spec = farm_printer.spec
    limits = {"hotend": spec.max_hotend_celsius, "bed": spec.max_bed_celsius, "chamber": spec.max_chamber_celsius}
    targets: dict[str, float | int] = {}
    for heater, limit in limits.items():
        if heater in values:
            try:
                targets[heater] = marlin_aio.check_target(heater, values[heater], limit)
            except ValueError as exc:
                raise CommandError(str(exc)) from None
    if "tool" in values:
        tool = values["tool"]
        if isinstance(tool, bool) or not isinstance(tool, int) or tool < 0:
            raise CommandError(f"tool must be a hotend number (0, 1, ...), got {tool!r}")
        targets["tool"] = tool
    if not targets.keys() - {"tool"}:
        raise CommandError("set_temperatures needs at least one of hotend, bed, chamber")
    return targets


def parse_command(
    printer: str, payload: bytes, printers: dict[str, FarmPrinter], allowed_dir: Path | None
) -> FarmCommand:
    """Check one command payload for `printer`.

    Raises:
        CommandError: anything wrong with it (the message is the answer to publish).
    """
    if printer not in printers:
        raise CommandError(f"no printer named {printer!r} (printers: {', '.join(printers)})")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise CommandError(f"command payload too large ({len(payload)} bytes, at most {MAX_PAYLOAD_BYTES})")
    try:
        body = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CommandError(f"not JSON: {exc}") from None
    if not isinstance(body, dict):
        raise CommandError('a command is a JSON object such as {"action": "gcode", "command": "M105"}')
    command_id = body.get("id")
    if command_id is not None and (isinstance(command_id, bool) or not isinstance(command_id, str | int)):
        raise CommandError("id must be a string or a number")
    action = body.get("action")
    if action not in ACTIONS:
        raise CommandError(f"unknown action {action!r} (actions: {', '.join(ACTIONS)})")
    extra = set(body) - {"id", "action"} - _FIELDS[action]
    if extra:
        takes = ", ".join(sorted(_FIELDS[action])) or "nothing"
        raise CommandError(f"{action} takes no {sorted(extra)[0]!r} (it takes: {takes})")
    farm_printer = printers[printer]
    if action == "set_temperatures":
        return FarmCommand(printer, action, command_id, targets=_targets(body, farm_printer))
    if action == "set_target":
        heater = body.get("heater")
        tool: int | None = None
        if isinstance(heater, str):
            heater = heater.replace("_", " ")  # "hotend_1", as Home Assistant's entity ids spell it
        if isinstance(heater, str) and heater.startswith("hotend ") and heater[7:].isdigit():
            heater, tool = "hotend", int(heater[7:])
        if heater not in ("hotend", "bed", "chamber"):
            raise CommandError(f"heater must be hotend, 'hotend N', bed or chamber, got {heater!r}")
        values: dict[str, Any] = {heater: body.get("celsius")}
        if tool is not None:
            values["tool"] = tool
        # The same command as set_temperatures, with one heater.
        return FarmCommand(printer, "set_temperatures", command_id, targets=_targets(values, farm_printer))
    if action == "gcode":
        commands = body.get("commands", [body["command"]] if "command" in body else None)
        if not isinstance(commands, list) or not commands or not all(isinstance(c, str) for c in commands):
            raise CommandError('gcode needs "command": "G28" or "commands": ["G28", "M114"]')
        if len(commands) > MAX_GCODE_COMMANDS:
            raise CommandError(f"at most {MAX_GCODE_COMMANDS} commands at once, got {len(commands)}")
        checked = []
        spec = farm_printer.spec
        limits = marlin_aio.HeaterLimits(spec.max_hotend_celsius, spec.max_bed_celsius, spec.max_chamber_celsius)
        for text in commands:
            try:
                checked.append(marlin_aio.validate_command(text))
                # Printer.send refuses such a target too (the library's own check, reading the command as Marlin's
                # parser does), but only when its turn comes: checked here, a list with one bad target writes
                # nothing at all.
                marlin_aio.check_gcode_targets(text, limits)
            except ValueError as exc:
                raise CommandError(_one_line(exc)) from None
        return FarmCommand(printer, action, command_id, gcode=tuple(checked))
    if action == "print":
        return FarmCommand(printer, action, command_id, path=_allowed_path(body.get("path"), allowed_dir))
    return FarmCommand(printer, action, command_id)


_FIELDS: dict[str, set[str]] = {
    "set_temperatures": {"hotend", "bed", "chamber", "tool"},
    "set_target": {"heater", "celsius"},
    "gcode": {"command", "commands"},
    "print": {"path"},
    "pause": set(),
    "resume": set(),
    "cancel": set(),
    "emergency_stop": set(),
}


def _one_line(exc: Exception) -> str:
    """An error's message as one line, for an answer (the first line says what was wrong)."""
    lines = str(exc).splitlines()
    return lines[0] if lines else type(exc).__name__


def _allowed_path(value: object, allowed_dir: Path | None) -> Path:
    if allowed_dir is None:
        raise CommandError("prints over MQTT are off: start the bridge with --allowed-dir DIR")
    if not isinstance(value, str) or not value:
        raise CommandError('print needs "path": a G-code file inside the allowed directory')
    root = allowed_dir.resolve()
    path = (root / value).resolve()
    if not path.is_relative_to(root):
        raise CommandError(f"{value!r} is outside the allowed directory")
    if not path.is_file():
        raise CommandError(f"{value!r}: no such file in the allowed directory")
    return path


def _check_heaters(targets: dict[str, float | int], farm_printer: FarmPrinter) -> None:
    """Refuse a target for a heater the printer does not report, as `marlin-temp set` does: nothing is sent."""
    reading = farm_printer.latest
    if reading is None:
        raise CommandError(f"printer {farm_printer.name!r} has not reported its heaters yet; try again")
    keys = set(reading.temperatures.heaters)
    hotends = sorted(int(key[1:]) for key in keys if key[:1] == "T" and key[1:].isdigit()) or (
        [0] if "T" in keys else []
    )
    has = [f"{len(hotends)} hotend{'s' if len(hotends) != 1 else ''}"] + [
        name for key, name in (("B", "bed"), ("C", "chamber")) if key in keys
    ]
    tool = targets.get("tool")
    missing = []
    if "hotend" in targets and (not hotends or (tool is not None and int(tool) not in hotends)):
        missing.append("hotend" if tool is None else f"hotend {tool}")
    missing += [name for key, name in (("B", "bed"), ("C", "chamber")) if name in targets and key not in keys]
    if missing:
        raise CommandError(f"printer {farm_printer.name!r} has no {', '.join(missing)} (it has {', '.join(has)})")


async def run_command(command: FarmCommand, farm_printer: FarmPrinter) -> Any:
    """Run a checked command on its printer; return the result to answer with.

    Raises:
        CommandError: the printer is not connected, or no print is running to pause, resume or cancel.
        ValueError: the file has a line that is not a valid command, or a G-code command sets a target above the
            limits (the library checks every command it is given; nothing of it is sent).
        MarlinError: as the library raises it.
    """
    printer = farm_printer.printer
    if printer is None or not farm_printer.link_up:
        raise CommandError(f"printer {farm_printer.name!r} is not connected")
    match command.action:
        case "set_temperatures":
            _check_heaters(command.targets, farm_printer)
            targets = dict(command.targets)
            tool = targets.pop("tool", None)
            await printer.set_temperatures(
                hotend=targets.get("hotend"),
                bed=targets.get("bed"),
                chamber=targets.get("chamber"),
                tool=None if tool is None else int(tool),
            )
            return {"targets": command.targets}
        case "gcode":
            replies = []
            for text in command.gcode:
                reply = await printer.send(text)
                replies.append({"command": text, "lines": list(reply.lines)})
            return {"replies": replies}
        case "emergency_stop":
            printer.emergency_stop()
            return {"sent": "M112"}
        case "print":
            assert command.path is not None
            handle = farm_printer.print_handle
            if handle is not None and not handle.finished:
                raise CommandError("a print is already running: cancel it first")
            farm_printer.print_handle = await printer.start_print(command.path)
            farm_printer.print_file = command.path.name
            return {"started": command.path.name}
        case _:
            handle = farm_printer.print_handle
            if handle is None or handle.finished:
                raise CommandError(f"no print to {command.action}")
            if command.action == "pause":
                handle.pause()
            elif command.action == "resume":
                handle.resume()
            else:
                progress = await handle.cancel(marlin_aio.COOL_DOWN)
                return {"cancelled_at_line": progress.last_source_line}
            return {"state": handle.progress.state.value}
