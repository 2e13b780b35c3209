"""The verbs on a printer itself: what it is and how it is, commands, temperatures and presets, prompts, and the
emergency stop. Each is declared once (`marlin_aio.service.verbs`) and reached the same way from every door."""

from __future__ import annotations

import asyncio
import dataclasses
from typing import Any

import marlin_aio
from marlin_aio.farm.presets import find_preset, preset_targets
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.protocol import check_gcode_targets, check_target, validate_command
from marlin_aio.protocol.rpc import INVALID_PARAMS, RpcError, reading_to_json, reply_to_json, requests_to_json
from marlin_aio.service.verbs.table import (
    DOORS,
    NOT_HTTP,
    REQUIRED,
    SOCKETS,
    SOCKETS_AND_HTTP,
    Access,
    Arg,
    Context,
    Owner,
    Queue,
    verb,
)

__all__ = ["MAX_TIMEOUT_S", "check_heaters", "connected", "info"]

#: The longest timeout a request may give a command (a G28 of a large printer takes minutes, not days).
MAX_TIMEOUT_S = 24 * 3600.0


def connected(farm_printer: FarmPrinter) -> marlin_aio.Printer:
    """The printer's open connection.

    Raises:
        ConnectionLostError: it is not connected now (the message says why, and that it reconnects by itself).
    """
    printer = farm_printer.printer
    if printer is None or not farm_printer.link_up:
        reason = farm_printer.last_error or "connecting"
        raise marlin_aio.ConnectionLostError(f"printer {farm_printer.name} is not connected now ({reason})")
    return printer


def info(owner: Owner, farm_printer: FarmPrinter) -> dict[str, Any]:
    """What the service knows of a printer, as every door reads it (`status`, `printers`, `hello`)."""
    printer = farm_printer.printer
    firmware = printer.firmware if printer is not None else None
    latest = farm_printer.latest
    last = printer.last_host_request if printer is not None else None
    requests = requests_to_json(None, farm_printer.prompt, farm_printer.waiting_for_user, last)
    job = farm_printer.job
    return {
        "name": farm_printer.name,
        "port": farm_printer.spec.port or "sim",
        "link_up": farm_printer.link_up,
        "firmware": None if firmware is None else {"name": firmware.name, "fields": firmware.fields},
        "capabilities": dict(printer.capabilities) if printer is not None else {},
        "last_error": farm_printer.last_error,
        "latest": None if latest is None else reading_to_json(latest),
        "print": farm_printer.print_status(),
        "job": None if job is None else job.to_json(),
        # A print the service before this one was running when it was killed or stopped, from its own record.
        "interrupted_job": owner.interrupted_jobs.get(farm_printer.name),
        # The open prompt, the wait for the user, the last pause/resume/cancel/disconnect request.
        **{key: value for key, value in requests.items() if key != "request"},
    }


def check_heaters(farm_printer: FarmPrinter, targets: dict[str, float | None], tool: int | None) -> None:
    """Refuse a target for a heater the printer does not report (`tool9` of a one-hotend printer, a bed it lacks):
    nothing is sent, from any door.

    Raises:
        ValueError: the printer has no such heater, or has not reported its heaters yet.
    """
    reading = farm_printer.latest
    if reading is None:
        raise ValueError(f"printer {farm_printer.name!r} has not reported its heaters yet; try again")
    keys = set(reading.temperatures.heaters)
    hotends = sorted(int(key[1:]) for key in keys if key[:1] == "T" and key[1:].isdigit()) or (
        [0] if "T" in keys else []
    )
    has = [f"{len(hotends)} hotend{'s' if len(hotends) != 1 else ''}"] + [
        name for key, name in (("B", "bed"), ("C", "chamber")) if key in keys
    ]
    missing = []
    if targets.get("hotend") is not None and (not hotends or (tool is not None and tool not in hotends)):
        missing.append("hotend" if tool is None else f"hotend {tool}")
    missing += [
        name for key, name in (("B", "bed"), ("C", "chamber")) if targets.get(name) is not None and key not in keys
    ]
    if missing:
        raise ValueError(f"printer {farm_printer.name!r} has no {', '.join(missing)} (it has {', '.join(has)})")


def _timeout(value: float | None) -> float | None:
    if value is not None and not 0 < value <= MAX_TIMEOUT_S:
        raise RpcError(INVALID_PARAMS, f"timeout_s must be above 0 and at most {MAX_TIMEOUT_S:g} s")
    return value


# ------------------------------------------------------------------------------------------- what and how


@verb("printers", access=Access.READ, doors=SOCKETS, result="[printer info]", on_printer=False)
async def printers(context: Context, args: dict[str, Any]) -> object:
    """Every printer of the service: its link, firmware, latest reading, job and prompt."""
    return [info(context.owner, farm_printer) for farm_printer in context.owner.farm.printers.values()]


@verb("status", access=Access.READ, doors=SOCKETS_AND_HTTP, result="printer info, clients, dropped")
async def status(context: Context, args: dict[str, Any]) -> object:
    """One printer's info, with how many clients the service has and how many notifications this one missed."""
    value = info(context.owner, context.farm_printer)
    value["clients"] = context.owner.clients
    subscriber = context.caller.subscriber
    value["dropped"] = 0 if subscriber is None else subscriber.dropped
    return value


@verb("link_stats", access=Access.READ, doors=SOCKETS, result="{stats, round_trips}")
async def link_stats(context: Context, args: dict[str, Any]) -> object:
    """The service's link counters for the printer and its latest round trips, `[answered_s, round_trip_s]`."""
    printer = connected(context.farm_printer)
    round_trips = list(printer.round_trips)[-256:]  # the latest (a served printer asks once a second)
    return {
        "stats": dataclasses.asdict(printer.stats),
        "round_trips": [[answered_s, latency_s] for answered_s, latency_s in round_trips],
        "now_s": asyncio.get_running_loop().time(),  # the clock of `answered_s`, for a client to shift to its own
    }


# ------------------------------------------------------------------------------------------- commands


@verb(
    "send",
    Arg("command", str, REQUIRED, "one G-code command"),
    Arg("timeout_s", float, None, "how long to wait for its ok (default: the printer's)"),
    access=Access.CONTROL,
    doors=DOORS,
    result="reply",
)
async def send(context: Context, args: dict[str, Any]) -> object:
    """Send one command in turn with every other caller's and return its reply (its lines and ok)."""
    farm_printer = context.farm_printer
    command = args["command"]
    timeout_s = _timeout(args["timeout_s"])
    # Checked before it waits for the link: a bad command is refused the same way whatever the printer's state.
    check_gcode_targets(validate_command(command), farm_printer.spec.limits)
    reply = await connected(farm_printer).send(command, timeout_s=timeout_s)
    owner = context.owner
    owner.note(farm_printer.name, ">", command)
    for line in reply.lines:
        owner.note(farm_printer.name, "<", line)
    owner.note(farm_printer.name, "<", f"ok {reply.ok.payload}".rstrip())
    return reply_to_json(reply)


@verb("emergency_stop", access=Access.CONTROL, queue=Queue.URGENT, doors=NOT_HTTP, result="null")
async def emergency_stop(context: Context, args: dict[str, Any]) -> object:
    """Write M112 at once, ahead of anything queued: the printer halts and needs a reset."""
    farm_printer = context.farm_printer
    connected(farm_printer).emergency_stop()
    context.owner.note(farm_printer.name, ">", f"M112 (emergency stop by {context.caller.who})")
    return None


@verb("interrupt_wait", access=Access.CONTROL, queue=Queue.URGENT, doors=SOCKETS, result="bool: M108 written")
async def interrupt_wait(context: Context, args: dict[str, Any]) -> object:
    """End a heater wait or M0/M1 pause now with M108, where the firmware's emergency parser reads it."""
    return connected(context.farm_printer).interrupt_wait()


@verb(
    "answer_prompt",
    Arg("index", int, REQUIRED, "the button, 0 the first"),
    access=Access.CONTROL,
    queue=Queue.URGENT,
    doors=NOT_HTTP,
    result="{answered, button}",
)
async def answer_prompt(context: Context, args: dict[str, Any]) -> object:
    """Answer the printer's open prompt with a button (`M876 S<index>`); the printer checks it has that button."""
    farm_printer = context.farm_printer
    index = args["index"]
    connected(farm_printer)
    prompt = farm_printer.prompt
    await context.owner.farm.answer_prompt(farm_printer, index)
    context.owner.tell_requests(farm_printer)  # closed here at once: every client hears it now, not at a tick
    label = prompt.buttons[index] if prompt is not None and index < len(prompt.buttons) else None
    return {"answered": index, "button": label}


# ------------------------------------------------------------------------------------------- temperatures


@verb("read_temperatures", access=Access.READ, doors=SOCKETS, result="reading")
async def read_temperatures(context: Context, args: dict[str, Any]) -> object:
    """Ask the printer for its temperatures now (M105) and return the reading."""
    return reading_to_json(await connected(context.farm_printer).read_temperatures())


@verb(
    "set_temperatures",
    Arg("hotend", float, None, "degrees C (0 off)"),
    Arg("bed", float, None, "degrees C (0 off)"),
    Arg("chamber", float, None, "degrees C (0 off)"),
    Arg("tool", int, None, "which hotend (default: the active one)"),
    access=Access.CONTROL,
    result="{targets}",
)
async def set_temperatures(context: Context, args: dict[str, Any]) -> object:
    """Set heater targets without waiting, each checked against the printer's limits and heaters first."""
    farm_printer = context.farm_printer
    targets = {name: args[name] for name in ("hotend", "bed", "chamber") if args[name] is not None}
    if not targets:
        raise ValueError("set_temperatures needs at least one of hotend, bed, chamber")
    tool = args["tool"]
    if tool is not None and tool < 0:
        raise ValueError(f"tool must be a hotend number (0, 1, ...), got {tool}")
    limits = farm_printer.spec.limits
    for name, value in targets.items():  # every target checked before anything is sent
        check_target(name, value, limits.of(name))
    check_heaters(farm_printer, dict(targets), tool)
    await connected(farm_printer).set_temperatures(**targets, tool=tool)
    return {"targets": targets | ({"tool": tool} if tool is not None else {})}


@verb("presets", access=Access.READ, doors=SOCKETS, result="[{name, hotend, bed}]", on_printer=False)
async def presets(context: Context, args: dict[str, Any]) -> object:
    """The service's presets (named targets), in their file's order."""
    return [{"name": p.name, "hotend": p.hotend_celsius, "bed": p.bed_celsius} for p in context.owner.presets]


@verb(
    "apply_preset",
    Arg("name", str, REQUIRED, "a preset's name, any case"),
    access=Access.CONTROL,
    doors=NOT_HTTP,
    result="{targets, preset}",
)
async def apply_preset(context: Context, args: dict[str, Any]) -> object:
    """Set the targets of a preset (its limits checked when used: one file serves printers with other limits)."""
    farm_printer = context.farm_printer
    preset = find_preset(context.owner.presets, args["name"])
    targets = preset_targets(preset, farm_printer.spec.limits)
    check_heaters(farm_printer, dict(targets), None)
    await connected(farm_printer).set_temperatures(hotend=targets.get("hotend"), bed=targets.get("bed"))
    return {"targets": dict(targets), "preset": preset.name}


@verb("connect", access=Access.CONTROL, doors=SOCKETS_AND_HTTP, result="{connected: bool}")
async def connect(context: Context, args: dict[str, Any]) -> object:
    """Open the printer's port again after a `disconnect`, and keep it open (reopened whenever it is lost)."""
    farm_printer = context.farm_printer
    context.owner.farm.connect(farm_printer)
    return {"connected": farm_printer.link_up}


@verb("disconnect", access=Access.CONTROL, doors=SOCKETS_AND_HTTP, result="{disconnected: true}")
async def disconnect(context: Context, args: dict[str, Any]) -> object:
    """Close the printer's port and keep it closed until `connect` (refused while a print runs; heaters are left
    as they are)."""
    await context.owner.farm.disconnect(context.farm_printer)
    return {"disconnected": True}
