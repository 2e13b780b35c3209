"""Commands to the farm's printers over MQTT: each payload checked as the CLI checks its arguments, then run.

A command is a JSON object published to `PREFIX/NAME/command`; its answer goes to `PREFIX/NAME/response` as
`{"id": <the command's id>, "ok": true, "result": ...}` or `{"id": ..., "ok": false, "error": "..."}`:

    {"id": 1, "action": "set_temperatures", "hotend": 200, "bed": 60}
    {"id": 2, "action": "set_target", "heater": "hotend", "celsius": 210}    (Home Assistant's number entities)
    {"id": 7, "action": "preset", "name": "PLA"}                             (the bridge's presets, any case)
    {"id": 3, "action": "gcode", "command": "G28"}                            (or "commands": ["G28", "M114"])
    {"id": 4, "action": "print", "path": "benchy.gcode"}                      (inside --allowed-dir only;
                                                                              "stop_on_unknown": true stops at a
                                                                              command the firmware lacks)
    {"id": 5, "action": "pause"} / "resume" / "cancel" / "restart"         (restart: a paused print from line 1)
    {"id": 6, "action": "emergency_stop"}
    {"id": 8, "action": "answer_prompt", "index": 0}                        (button 0 of the printer's open prompt)

Every action may also carry `"time": <epoch seconds>`, when it was sent: given the bridge's clock, a command sent
more than `MAX_COMMAND_AGE_S` before it (a queued "set the bed to 100" delivered an hour late, a replayed message)
or as far after it (a wrong clock) is refused. `"id"` is a string of at most 128 characters or a 64-bit integer.
Retained messages are never taken as commands: the bridge refuses them (one answer for each of its own printers at
each connection; nothing for a name it does not have), since a retained "print" would run again at every reconnect.

Everything is checked before anything is written: bad JSON, an unknown printer or action, a target of 900 or
`abc`, a newline inside a G-code command, a G-code command setting a target above the printer's limit however it
is spelt (`M104S280`, `m0104 s280`, `M104 B1000`: the library's `check_gcode_targets`, which reads it as Marlin
does), a path outside the allowed directory each get an error answer and write nothing to any printer.
`parse_command` does the checking (no I/O but stat calls on the path), `run_command` the running: it calls the
service's table of verbs (`marlin_aio.service.verbs`), as every other door does.

One message must not knock the farm over: whatever the topic and bytes, `parse_command` returns a `FarmCommand` or
raises `CommandError` whose message is one printable line of at most `MAX_ERROR_CHARS` (values from the payload are
shown with repr, cut at `SHOWN_VALUE_CHARS`). Hence the limits, each refused with its own message: the payload's
size (`MAX_PAYLOAD_BYTES`), UTF-8, the JSON nesting (`MAX_JSON_DEPTH`, scanned before the JSON is parsed: 50 KB of
`[` would otherwise blow the parser's recursion), NaN, Infinity and numbers that overflow to them, integers longer
than `MAX_INTEGER_DIGITS`, repeated fields, control characters (C0, DEL, C1) and lone surrogates in any string, a
G-code command longer than `MAX_GCODE_CHARS` or not printable ASCII, a path longer than `MAX_PATH_CHARS` or one the
file system cannot resolve (a symlink loop, a name too long).

Over 400 lines because every check a command passes before it reaches a printer is here, one per field kind and
action: one place to read what a message from the network can and cannot make a printer do.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import marlin_aio
import marlin_aio.protocol
from marlin_aio.service.verbs import VERBS, Caller, Owner, Queue, call

from .presets import DEFAULT_PRESETS, Preset
from .supervisor import FarmPrinter

__all__ = [
    "ACTIONS",
    "ACTION_VERBS",
    "MAX_COMMAND_AGE_S",
    "MAX_PROMPT_BUTTON",
    "UNQUEUED_ACTIONS",
    "CommandError",
    "FarmCommand",
    "command_id_of",
    "parse_command",
    "run_command",
]

ACTIONS = (
    "set_temperatures",
    "set_target",
    "preset",
    "gcode",
    "print",
    "pause",
    "resume",
    "restart",
    "cancel",
    "emergency_stop",
    "answer_prompt",
)
"""What a command can ask for (its "action")."""
MAX_PROMPT_BUTTON = 99
"""The highest button index an answer_prompt may name (a prompt has a handful; whether it has this one is the
printer's check, when the command runs)."""
MAX_PAYLOAD_BYTES = 65_536
"""The largest payload read (a list of 100 commands of 96 characters is about 10 KB)."""
MAX_GCODE_COMMANDS = 100
"""G-code commands in one `commands` list."""
MAX_JSON_DEPTH = 4
"""Containers inside containers: a command object holding a list of strings is depth 2."""
MAX_INTEGER_DIGITS = 30
"""Python refuses to convert more than 4300 digits (with a ValueError from inside json.loads); no field needs 30."""
MAX_ID_CHARS = 128
"""The longest string id (it is echoed in the answer)."""
MAX_GCODE_CHARS = 96
"""Marlin's MAX_CMD_SIZE: a longer line is cut short by the printer's serial buffer."""
MAX_PATH_CHARS = 255
"""The longest print path (a file name's limit on most file systems)."""
MAX_COMMAND_AGE_S = 5.0
"""A command whose "time" is further than this from the bridge's clock (either way) is refused."""
MAX_ERROR_CHARS = 200
"""The longest refusal message (answers and log lines stay one short line)."""
SHOWN_VALUE_CHARS = 60
"""How much of a value from the payload a refusal shows."""

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_SURROGATE = re.compile(r"[\ud800-\udfff]")
# A JSON string (to the end of the text if it is not closed, so the match cannot fail and backtrack) or a bracket.
# The depth scan reads only the brackets outside strings.
_JSON_TOKEN = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"?|[\[\]{}]', re.DOTALL)
_HOTEND_N = re.compile(r"hotend ([0-9]{1,3})")


class CommandError(ValueError):
    """A command refused before anything was written; the message says why, for the response topic.

    `command_id` is the refused command's id when it got as far as having a valid one (to answer with), else None.
    """

    def __init__(self, message: str, command_id: str | int | None = None) -> None:
        super().__init__(message)
        self.command_id = command_id


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
    preset: str | None = None
    """For a preset command (run as set_temperatures): the preset's name, as its file spells it."""
    index: int | None = None
    """For answer_prompt: the button (0 the first), as `M876 S<index>` counts."""
    stop_on_unknown: bool = False
    """For print: stop at a command the firmware does not know, instead of warning and going on."""


def _show(value: object) -> str:
    """A value from the payload for an error message: its repr (so printable and one line), cut short, with an M511
    password redacted (the answer goes to every subscriber of the response topic)."""
    text = repr(marlin_aio.redact(value) if isinstance(value, str) else value)
    return text if len(text) <= SHOWN_VALUE_CHARS else text[: SHOWN_VALUE_CHARS - 3] + "..."


def _one_line(exc: Exception) -> str:
    """An error's message as one line, for an answer (the first line says what was wrong)."""
    lines = str(exc).splitlines()
    return lines[0] if lines else type(exc).__name__


def _clip(message: str) -> str:
    """`message` as the contract promises it: one printable line of at most MAX_ERROR_CHARS.

    Messages built here already are; this holds for the library's messages too (which show whole values).
    """
    if not message.isprintable():
        message = repr(message)[1:-1]
    return message if len(message) <= MAX_ERROR_CHARS else message[: MAX_ERROR_CHARS - 3] + "..."


def _targets(values: dict[str, Any], farm_printer: FarmPrinter) -> dict[str, float | int]:
    limits = farm_printer.spec.limits
    targets: dict[str, float | int] = {}
    for heater in ("hotend", "bed", "chamber"):
        if heater in values:
            try:
                targets[heater] = marlin_aio.protocol.check_target(heater, values[heater], limits.of(heater))
            except ValueError as exc:
                raise CommandError(_one_line(exc)) from None
    if "tool" in values:
        tool = values["tool"]
        if isinstance(tool, bool) or not isinstance(tool, int) or tool < 0:
            raise CommandError(f"tool must be a hotend number (0, 1, ...), got {_show(tool)}")
        targets["tool"] = tool
    if not targets.keys() - {"tool"}:
        raise CommandError("set_temperatures needs at least one of hotend, bed, chamber")
    return targets


def parse_command(
    printer: str,
    payload: bytes,
    printers: Mapping[str, FarmPrinter],
    allowed_dir: Path | None,
    *,
    now_s: float | None = None,
    max_age_s: float = MAX_COMMAND_AGE_S,
    presets: Sequence[Preset] = DEFAULT_PRESETS,
) -> FarmCommand:
    """Check one command payload for `printer` (a topic level: any text).

    `now_s` is the bridge's clock (`time.time()`); given it, a command whose "time" is more than `max_age_s` from
    it either way is refused. Nothing is written or opened: a print's path is only resolved and stat'ed. A
    "preset" command names one of `presets` and becomes the set_temperatures of its targets.

    Raises:
        CommandError: anything wrong with it, and nothing else whatever the bytes; the message is one printable
            line of at most MAX_ERROR_CHARS characters, the answer to publish.
    """
    try:
        return _parse(printer, payload, printers, allowed_dir, now_s, max_age_s, presets)
    except CommandError as exc:
        raise CommandError(_clip(str(exc)), exc.command_id) from None


def _parse(
    printer: str,
    payload: bytes,
    printers: Mapping[str, FarmPrinter],
    allowed_dir: Path | None,
    now_s: float | None,
    max_age_s: float,
    presets: Sequence[Preset],
) -> FarmCommand:
    if printer not in printers:
        raise CommandError(f"no printer named {_show(printer)} (printers: {', '.join(printers)})")
    body = _decode(payload)
    command_id = _command_id(body)
    try:
        return _check(printer, body, command_id, printers[printer], allowed_dir, now_s, max_age_s, presets)
    except CommandError as exc:
        exc.command_id = command_id
        raise


def _decode(payload: bytes) -> dict[str, Any]:
    """The payload's JSON object, within the limits."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise CommandError(f"command payload too large ({len(payload)} bytes, at most {MAX_PAYLOAD_BYTES})")
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CommandError(f"not JSON: not UTF-8 text (byte 0x{payload[exc.start]:02x} at {exc.start})") from None
    depth = _json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise CommandError(f"not a command: JSON nested too deep (more than {MAX_JSON_DEPTH} levels)")
    try:
        body = json.loads(
            text,
            parse_constant=_refuse_constant,
            parse_int=_parse_int,
            parse_float=_parse_float,
            object_pairs_hook=_unique_fields,
        )
    except CommandError:
        raise
    except RecursionError:
        # Cannot happen past the depth scan; kept so that a scan missing some nesting still cannot end the farm.
        raise CommandError("not a command: JSON nested too deep") from None
    except ValueError as exc:
        raise CommandError(f"not JSON: {_one_line(exc)}") from None
    if not isinstance(body, dict):
        raise CommandError('a command is a JSON object such as {"action": "gcode", "command": "M105"}')
    return body


def _json_depth(text: str) -> int:
    """How deep the text's brackets nest, strings skipped: cheap enough to run before json.loads, whose recursion it
    bounds. Not a validation: mismatched brackets are json.loads's to refuse."""
    depth = deepest = 0
    for match in _JSON_TOKEN.finditer(text):
        token = match.group()
        if token in ("[", "{"):
            depth += 1
            if depth > MAX_JSON_DEPTH:
                return depth  # no need to read the rest of a 50 KB run of brackets
            deepest = max(deepest, depth)
        elif token in ("]", "}"):
            depth = max(depth - 1, 0)
    return deepest


def _refuse_constant(name: str) -> float:
    raise CommandError(f"not JSON: {name} is not a number JSON allows")


def _parse_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INTEGER_DIGITS:
        raise CommandError(f"a number in the command is too long ({digits} digits, at most {MAX_INTEGER_DIGITS})")
    return int(text)


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise CommandError(f"a number in the command is out of range: {_show(text)}")
    return value


def _unique_fields(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    # Parsers disagree on which of two equal keys wins; a command whose meaning depends on that is refused.
    body = dict(pairs)
    if len(body) < len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise CommandError(f"the field {_show(key)} appears twice")
            seen.add(key)
    return body


def command_id_of(payload: bytes) -> str | int | None:
    """The id of a command payload, for the answer to a command refused before it was read (a retained one, an
    unknown printer): the id if the payload is a JSON object within the limits and its id is valid, else None.
    Never raises."""
    try:
        return _command_id(_decode(payload))
    except CommandError:
        return None


def _command_id(body: dict[str, Any]) -> str | int | None:
    command_id = body.get("id")
    if command_id is None:
        return None
    if isinstance(command_id, str) and len(command_id) <= MAX_ID_CHARS:
        _check_text("id", command_id)
        return command_id
    if isinstance(command_id, int) and not isinstance(command_id, bool) and abs(command_id) < 2**63:
        return command_id  # within 64 bits, which any client's JSON reads back as the integer it sent
    raise CommandError(
        f"id must be a string of at most {MAX_ID_CHARS} characters or a 64-bit integer, got {_show(command_id)}"
    )


def _check_text(name: str, text: str) -> None:
    """Refuse a string value with a control character or a lone surrogate (which could not even be encoded back)."""
    control = _CONTROL.search(text)
    if control is not None:
        char = control.group()
        what = "a line break" if char in "\r\n" else "a control character"
        raise CommandError(f"{name} contains {what} ({char!r}): {_show(text)}")
    if _SURROGATE.search(text) is not None:
        raise CommandError(f"{name} is not valid Unicode (a lone surrogate): {_show(text)}")


def _check_strings(name: str, value: object) -> None:
    """Every string in a field's value (however nested, within MAX_JSON_DEPTH) through `_check_text`."""
    if isinstance(value, str):
        _check_text(name, value)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _check_strings(f"{name}[{index}]", item)
    elif isinstance(value, dict):
        for key, item in value.items():
            _check_strings(f"{name}[{_show(key)}]", item)


def _check_time(sent: object, now_s: float | None, max_age_s: float) -> None:
    if isinstance(sent, bool) or not isinstance(sent, int | float) or not math.isfinite(sent):
        raise CommandError(f"time must be the epoch seconds when the command was sent, got {_show(sent)}")
    if now_s is None:
        return
    age_s = now_s - sent
    if age_s > max_age_s:
        raise CommandError(f"stale: sent {_seconds(age_s)} s ago, commands older than {max_age_s:g} s are refused")
    if -age_s > max_age_s:
        raise CommandError(f"sent {_seconds(-age_s)} s in the future: are the clocks set?")


def _seconds(value: float) -> str:
    return f"{value:.1f}" if value < 1e9 else f"{value:.3g}"


def _check(
    printer: str,
    body: dict[str, Any],
    command_id: str | int | None,
    farm_printer: FarmPrinter,
    allowed_dir: Path | None,
    now_s: float | None,
    max_age_s: float,
    presets: Sequence[Preset],
) -> FarmCommand:
    action = body.get("action")
    if not isinstance(action, str) or action not in ACTIONS:
        raise CommandError(f"unknown action {_show(action)} (actions: {', '.join(ACTIONS)})")
    if "time" in body:
        _check_time(body["time"], now_s, max_age_s)  # a stale command goes no further
    extra = set(body) - _COMMON_FIELDS - _FIELDS[action]
    if extra:
        takes = ", ".join([*sorted(_FIELDS[action]), *sorted(_COMMON_FIELDS - {"action"})])
        raise CommandError(f"{action} takes no {_show(min(extra))} (it takes: {takes})")
    for name, value in body.items():
        _check_strings(name, value)
    if action == "set_temperatures":
        return FarmCommand(printer, action, command_id, targets=_targets(body, farm_printer))
    if action == "set_target":
        heater = body.get("heater")
        tool: int | None = None
        if isinstance(heater, str):
            heater = heater.replace("_", " ")  # "hotend_1", as Home Assistant's entity ids spell it
            numbered = _HOTEND_N.fullmatch(heater)
            if numbered is not None:
                heater, tool = "hotend", int(numbered.group(1))
        if heater not in ("hotend", "bed", "chamber"):
            raise CommandError(f"heater must be hotend, 'hotend N', bed or chamber, got {_show(heater)}")
        values: dict[str, Any] = {heater: body.get("celsius")}
        if tool is not None:
            values["tool"] = tool
        # The same command as set_temperatures, with one heater.
        return FarmCommand(printer, "set_temperatures", command_id, targets=_targets(values, farm_printer))
    if action == "preset":
        preset = _preset(body.get("name"), presets)
        try:
            targets = _targets(dict(preset.targets()), farm_printer)
        except CommandError as exc:
            raise CommandError(f"preset {preset.name!r}: {exc}") from None
        return FarmCommand(printer, "set_temperatures", command_id, targets=targets, preset=preset.name)
    if action == "gcode":
        return FarmCommand(printer, action, command_id, gcode=_gcode(body, farm_printer))
    if action == "print":
        stop = body.get("stop_on_unknown", False)
        if not isinstance(stop, bool):
            raise CommandError(f'"stop_on_unknown" must be true or false, got {_show(stop)}')
        path = _allowed_path(body.get("path"), allowed_dir)
        return FarmCommand(printer, action, command_id, path=path, stop_on_unknown=stop)
    if action == "answer_prompt":
        index = body.get("index")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index <= MAX_PROMPT_BUTTON:
            raise CommandError(
                f'answer_prompt needs "index": a button of the prompt (0 the first, at most {MAX_PROMPT_BUTTON}), '
                f"got {_show(index)}"
            )
        return FarmCommand(printer, action, command_id, index=index)
    return FarmCommand(printer, action, command_id)


_COMMON_FIELDS = {"id", "action", "time"}
_FIELDS: dict[str, set[str]] = {
    "set_temperatures": {"hotend", "bed", "chamber", "tool"},
    "set_target": {"heater", "celsius"},
    "preset": {"name"},
    "gcode": {"command", "commands"},
    "print": {"path", "stop_on_unknown"},
    "pause": set(),
    "resume": set(),
    "restart": set(),
    "cancel": set(),
    "emergency_stop": set(),
    "answer_prompt": {"index"},
}


def _preset(name: object, presets: Sequence[Preset]) -> Preset:
    names = ", ".join(preset.name for preset in presets) or "none"
    if not isinstance(name, str) or not name:
        raise CommandError(f'preset needs "name": one of the presets ({names})')
    for preset in presets:
        if preset.name.casefold() == name.casefold():
            return preset
    raise CommandError(f"no preset named {_show(name)} (presets: {names})")


def _gcode(body: dict[str, Any], farm_printer: FarmPrinter) -> tuple[str, ...]:
    commands = body.get("commands", [body["command"]] if "command" in body else None)
    if not isinstance(commands, list) or not commands or not all(isinstance(c, str) for c in commands):
        raise CommandError('gcode needs "command": "G28" or "commands": ["G28", "M114"]')
    if len(commands) > MAX_GCODE_COMMANDS:
        raise CommandError(f"at most {MAX_GCODE_COMMANDS} commands at once, got {len(commands)}")
    checked = []
    limits = farm_printer.spec.limits
    for text in commands:
        if len(text) > MAX_GCODE_CHARS:
            # Not shown: it may carry a password (M511), which only the library's own messages redact.
            raise CommandError(f"a G-code command is {len(text)} characters long, at most {MAX_GCODE_CHARS}")
        try:
            checked.append(marlin_aio.protocol.validate_command(text))
            # Printer.send refuses such a target too (the library's own check, reading the command as Marlin's
            # parser does), but only when its turn comes: checked here, a list with one bad target writes
            # nothing at all.
            marlin_aio.protocol.check_gcode_targets(text, limits)
        except ValueError as exc:
            raise CommandError(_one_line(exc)) from None
    return tuple(checked)


def _allowed_path(value: object, allowed_dir: Path | None) -> Path:
    if allowed_dir is None:
        raise CommandError("prints over MQTT are off: start the bridge with --allowed-dir DIR")
    if not isinstance(value, str) or not value:
        raise CommandError('print needs "path": a G-code file inside the allowed directory')
    if len(value) > MAX_PATH_CHARS:
        raise CommandError(f"path is {len(value)} characters long, at most {MAX_PATH_CHARS}: {_show(value)}")
    try:
        root = allowed_dir.resolve()
        path = (root / value).resolve()
        inside = path.is_relative_to(root)
        found = inside and path.is_file()
    except RuntimeError:  # 3.11's resolve() on a symlink loop
        raise CommandError(f"{_show(value)}: a symlink loop in the allowed directory") from None
    except OSError as exc:  # a name too long, a directory we may not search...
        reason = exc.strerror or type(exc).__name__
        raise CommandError(f"{_show(value)}: cannot be looked up in the allowed directory ({reason})") from None
    except ValueError:  # a NUL or a surrogate reaching the OS (the string checks refuse both first)
        raise CommandError(f"{_show(value)}: not a valid file name") from None
    if not inside:
        raise CommandError(f"{_show(value)} is outside the allowed directory")
    if not found:
        raise CommandError(f"{_show(value)}: no such file in the allowed directory")
    return path


#: The verb of the service's table each action calls (`marlin_aio.service.verbs`): set_target and preset are
#: set_temperatures and apply_preset in another shape, gcode is send for each command.
ACTION_VERBS = {
    "set_temperatures": "set_temperatures",
    "preset": "apply_preset",
    "gcode": "send",
    "print": "start_print",
    "pause": "pause",
    "resume": "resume",
    "restart": "restart",
    "cancel": "cancel",
    "emergency_stop": "emergency_stop",
    "answer_prompt": "answer_prompt",
}


async def run_command(command: FarmCommand, owner: Owner) -> Any:
    """Run a checked command through the service's table of verbs, as MQTT's door: the same verb, with the same
    checks and effects, as the socket's and the OctoPrint API's; return the result in MQTT's answer shape.

    Raises:
        CommandError: the printer is not connected.
        ValueError, RuntimeError, OSError, MarlinError: as the verb raised them (a heater the printer lacks, no
            print to pause, ...): nothing was done.
    """
    farm_printer = owner.farm.printers[command.printer]
    if farm_printer.printer is None or not farm_printer.link_up:
        raise CommandError(f"printer {farm_printer.name!r} is not connected")
    caller = Caller("mqtt", "mqtt")  # a print's path was checked against --allowed-dir by parse_command

    async def run(verb_name: str, **params: Any) -> Any:
        return await call(owner, verb_name, {"printer": command.printer, **params}, caller)

    match command.action:
        case "set_temperatures" if command.preset is not None:
            return await run("apply_preset", name=command.preset)
        case "set_temperatures":
            await run("set_temperatures", **command.targets)
            return {"targets": command.targets}
        case "gcode":
            replies = []
            for text in command.gcode:
                reply = await run("send", command=text)
                replies.append({"command": text, "lines": reply["lines"]})
            return {"replies": replies}
        case "print":
            assert command.path is not None
            job = await run("start_print", path=str(command.path), stop_on_unknown=command.stop_on_unknown)
            return {"started": job["file"]}
        case "emergency_stop":
            await run("emergency_stop")
            return {"sent": "M112"}
        case "answer_prompt":
            return await run("answer_prompt", index=command.index)
        case "cancel":
            job = (await run("cancel"))["job"]
            return {"cancelled_at_line": job["surely_run_line"], "job": job}
        case _:
            job = await run(command.action)
            return {"state": job["progress"]["state"], "job": job}


UNQUEUED_ACTIONS = frozenset(action for action, name in ACTION_VERBS.items() if VERBS[name].queue is Queue.URGENT)
"""Actions whose verb is urgent (`Queue.URGENT`): never refused for being too many waiting (a flood of slow
commands must not keep the emergency stop out, nor the answer that ends an M600 they wait behind)."""
