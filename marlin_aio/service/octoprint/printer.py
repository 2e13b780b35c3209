"""The printer's resources: its state and temperatures (with their history), heater targets, the print head, the
tool, and G-code commands; each action through the service's verbs, so with the limits every door checks."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from aiohttp import web

from marlin_aio.farm.job import JobState
from marlin_aio.protocol.motion import extrude_commands, home_command, move_commands
from marlin_aio.service.octoprint.common import Door, json_body, motion

__all__ = ["PrinterRoutes"]

#: Commands one `POST /api/printer/command` may carry (each goes in turn with every other caller's).
MAX_COMMANDS = 100
#: Readings a temperature history answers by default, and how far back it looks (OctoPrint keeps 300).
HISTORY_READINGS = 300
HISTORY_SECONDS = 600.0
#: Feed and flow rate factors accepted (OctoPrint's own checks once were 50..200 %).
MIN_FACTOR_PERCENT = 10
MAX_FACTOR_PERCENT = 500
#: An extrusion's speed when the request gives none (mm/min).
EXTRUDE_MM_MIN = 300.0

_OFFSETS = "temperature offsets other than 0 are not supported: set the target you want"


class PrinterRoutes:
    """The printer's resources of one door."""

    def __init__(self, door: Door) -> None:
        self.door = door

    def routes(self) -> list[web.RouteDef]:
        """Its routes."""
        return [
            web.get("/api/printer", self.printer),
            web.get("/api/printer/tool", self.tools),
            web.post("/api/printer/tool", self.tool),
            web.get("/api/printer/bed", self.bed_state),
            web.post("/api/printer/bed", self.bed),
            web.get("/api/printer/chamber", self.chamber_state),
            web.post("/api/printer/chamber", self.chamber),
            web.post("/api/printer/printhead", self.printhead),
            web.post("/api/printer/command", self.printer_command),
        ]

    async def printer(self, request: web.Request) -> web.Response:
        """`GET /api/printer[?exclude=temperature,sd,state&history=true&limit=N]`: temperatures (with their history
        if asked) and state flags (409 while the printer is not connected)."""
        self.door.operational()
        exclude = {part.strip() for part in request.query.get("exclude", "").split(",")}
        info = await self.door.verb("status")
        answer: dict[str, Any] = {}
        if "temperature" not in exclude:
            answer["temperature"] = await self._temperatures(request, info, lambda name: True)
        if "state" not in exclude:
            job = info["job"]
            state = JobState(job["state"]) if job is not None and job["active"] else None
            flags = {
                "operational": True,
                "printing": state in (JobState.STARTING, JobState.PRINTING),
                "paused": state is JobState.PAUSED,
                "pausing": False,
                "resuming": False,
                "cancelling": state is JobState.CANCELLING,
                "finishing": False,
                "closedOrError": False,
                "error": False,
                "ready": state is None,
                "sdReady": False,
            }
            answer["state"] = {"text": self.door.state_text(), "error": "", "flags": flags}
        return web.json_response(answer)

    async def tools(self, request: web.Request) -> web.Response:
        """`GET /api/printer/tool[?history=true&limit=N]`: the hotends' temperatures."""
        self.door.operational()
        info = await self.door.verb("status")
        return web.json_response(await self._temperatures(request, info, lambda name: name.startswith("tool")))

    async def bed_state(self, request: web.Request) -> web.Response:
        """`GET /api/printer/bed[?history=true&limit=N]`: the bed's temperature (409 if the printer reports none)."""
        return await self._one_heater(request, "bed")

    async def chamber_state(self, request: web.Request) -> web.Response:
        """`GET /api/printer/chamber[?history=true&limit=N]`: the chamber's temperature (409 if the printer
        reports none, as OctoPrint answers without a heated chamber)."""
        return await self._one_heater(request, "chamber")

    async def _one_heater(self, request: web.Request, heater: str) -> web.Response:
        self.door.operational()
        info = await self.door.verb("status")
        answer = await self._temperatures(request, info, lambda name: name == heater)
        if heater not in answer:
            raise web.HTTPConflict(text=f"the printer reports no heated {heater}")
        return web.json_response(answer)

    async def _temperatures(
        self, request: web.Request, info: dict[str, Any], wanted: Callable[[str], bool]
    ) -> dict[str, Any]:
        """OctoPrint's temperature block of the heaters `wanted` keeps, with their `history` if the query asks
        (`history=true`, the last `limit` readings, default 300; `limit=0` all, as OctoPrint reads it)."""
        latest = info["latest"]
        answer: dict[str, Any] = {
            name: {"actual": actual, "target": target, "offset": 0}
            for name, (actual, target) in _heaters(latest["heaters"] if latest else {}).items()
            if wanted(name)
        }
        if request.query.get("history", "").lower() in ("true", "yes", "y", "1"):
            text = request.query.get("limit", "")
            limit = int(text) if text.isdigit() else HISTORY_READINGS
            kept = await self.door.verb("history", seconds=HISTORY_SECONDS)
            readings = json.loads(kept.json)["readings"]
            entries = [
                {"time": int(reading["time_s"])}
                | {
                    name: {"actual": actual, "target": target}
                    for name, (actual, target) in _heaters(reading["heaters"]).items()
                    if wanted(name)
                }
                for reading in readings
            ]
            answer["history"] = entries[-limit:] if limit else entries
        return answer

    async def tool(self, request: web.Request) -> web.Response:
        """`POST /api/printer/tool`: `target` (`{"targets": {"tool0": 200}}`), `offset` (`{"offsets": {"tool0":
        0}}`: only 0, none is applied), `select` (`{"tool": "tool1"}`), `extrude` (`{"amount": 5, "speed"?}`, 409
        while printing), `flowrate` (`{"factor": 90}`); each through the `send` or `set_temperatures` verb, so with
        the limits every door checks. Unknown tools are refused (400)."""
        body = await json_body(request)
        command = body.get("command")
        self.door.operational()
        if command == "target":
            targets = body.get("targets")
            if not isinstance(targets, dict) or not targets:
                raise web.HTTPBadRequest(text='target needs "targets": {"tool0": celsius, ...}')
            for name, target in targets.items():
                await self.door.verb("set_temperatures", hotend=target, tool=_tool_index(name))
        elif command == "offset":
            offsets = body.get("offsets")
            if not isinstance(offsets, dict) or not offsets:
                raise web.HTTPBadRequest(text='offset needs "offsets": {"tool0": celsius, ...}')
            for name, offset in offsets.items():
                _tool_index(name)
                _no_offset(offset)
        elif command == "select":
            await self.door.send_all([f"T{_tool_index(body.get('tool'))}"])
        elif command == "extrude":
            self.door.check_idle("extrude")
            speed = body.get("speed", EXTRUDE_MM_MIN)
            amount: Any = body.get("amount")  # checked by extrude_commands (a 400 if it is no distance)
            await self.door.send_all(motion(lambda: extrude_commands(amount, feedrate_mm_min=speed)))
        elif command == "flowrate":
            await self.door.send_all([f"M221 S{_percent(body.get('factor'))}"])
        else:
            raise web.HTTPBadRequest(text=f"unknown tool command {str(command)[:20]!r}")
        return web.Response(status=204)

    async def bed(self, request: web.Request) -> web.Response:
        """`POST /api/printer/bed` `{"command": "target", "target": 60}` (or `offset` 0; 409 while offline)."""
        body = await json_body(request)
        self.door.operational()
        await self._heater_command(body, "bed")
        return web.Response(status=204)

    async def chamber(self, request: web.Request) -> web.Response:
        """`POST /api/printer/chamber` `{"command": "target", "target": 40}` (409 without a heated chamber)."""
        body = await json_body(request)
        self.door.operational()
        latest = self.door.farm_printer.latest
        if latest is None or latest.temperatures.chamber is None:
            raise web.HTTPConflict(text="the printer reports no heated chamber")
        await self._heater_command(body, "chamber")
        return web.Response(status=204)

    async def _heater_command(self, body: dict[str, Any], heater: str) -> None:
        """The bed's or the chamber's `target` (through `set_temperatures`) or `offset` (0 only)."""
        command = body.get("command")
        if command == "target":
            await self.door.verb("set_temperatures", **{heater: body.get("target")})
        elif command == "offset":
            _no_offset(body.get("offset"))
        else:
            raise web.HTTPBadRequest(text=f"unknown {heater} command {str(command)[:20]!r}")

    async def printhead(self, request: web.Request) -> web.Response:
        """`POST /api/printer/printhead`: `jog` (`{"x"?, "y"?, "z"?, "absolute"?, "speed"?}` mm and mm/min),
        `home` (`{"axes": ["x", "y"]}`), `feedrate` (`{"factor": 100}` percent, or 1.0); within the moves' limits
        (`marlin_aio.protocol.motion`), each command through the `send` verb. 409 while printing, but feedrate."""
        body = await json_body(request)
        command = body.get("command")
        self.door.operational()
        if command == "jog":
            self.door.check_idle("jog")
            axes = {axis: body[axis] for axis in ("x", "y", "z") if body.get(axis) not in (None, 0)}
            if axes:
                relative = not body.get("absolute", False)
                speed = body.get("speed")
                await self.door.send_all(
                    motion(lambda: move_commands(**axes, feedrate_mm_min=speed or None, relative=relative))
                )
        elif command == "home":
            self.door.check_idle("home")
            homed = body.get("axes")
            if not isinstance(homed, list) or not homed:
                raise web.HTTPBadRequest(text='home needs "axes": a list of x, y, z')
            await self.door.send_all(motion(lambda: [home_command(homed)]))
        elif command == "feedrate":
            await self.door.send_all([f"M220 S{_percent(body.get('factor'))}"])
        else:
            raise web.HTTPBadRequest(text=f"unknown printhead command {str(command)[:20]!r}")
        return web.Response(status=204)

    async def printer_command(self, request: web.Request) -> web.Response:
        """`POST /api/printer/command` `{"command": "G28"}` or `{"commands": [...]}`: each sent in turn, through the
        same checks as every door's `send` (a target over the limits is refused, 400, and nothing after it goes)."""
        body = await json_body(request)
        one, many = body.get("command"), body.get("commands")
        if (one is None) == (many is None):
            raise web.HTTPBadRequest(text='give "command" (a string) or "commands" (a list of strings)')
        commands = [one] if many is None else many
        if not isinstance(commands, list) or not all(isinstance(c, str) for c in commands):
            raise web.HTTPBadRequest(text='"commands" is a list of strings')
        if len(commands) > MAX_COMMANDS:
            raise web.HTTPBadRequest(text=f"at most {MAX_COMMANDS} commands at once")
        self.door.operational()
        for command in commands:
            await self.door.verb("send", command=command)
        return web.Response(status=204)


def _heaters(heaters: dict[str, list[float | None]]) -> dict[str, tuple[float | None, float | None]]:
    """The service's heaters (`T`, `T1`, `B`, `C`: `[actual, target, power]`) by OctoPrint's names (`tool0`,
    `tool1`, `bed`, `chamber`); others (a probe, the board) are not OctoPrint's."""
    named: dict[str, tuple[float | None, float | None]] = {}
    for key, (actual, target, *_power) in heaters.items():
        name = {"T": "tool0", "B": "bed", "C": "chamber"}.get(key)
        if name is None and key.startswith("T") and key[1:].isdigit():
            name = f"tool{key[1:]}"
        if name is not None and name not in named:
            named[name] = (actual, target)
    return named


def _tool_index(name: object) -> int:
    """The number of OctoPrint's `toolN` (400 for anything else)."""
    if not (isinstance(name, str) and name.startswith("tool") and name[4:].isdigit() and len(name) <= 6):
        raise web.HTTPBadRequest(text=f"unknown tool {str(name)[:20]!r}: tools are tool0, tool1, ...")
    return int(name[4:])


def _no_offset(offset: object) -> None:
    """Take an offset of 0 (what every heater has: nothing to do); refuse another (400), which would be applied to
    every target the print sets, a rewrite of the print the service does not make."""
    if isinstance(offset, bool) or not isinstance(offset, int | float):
        raise web.HTTPBadRequest(text="an offset is a number of degrees")
    if offset != 0:
        raise web.HTTPBadRequest(text=_OFFSETS)


def _percent(factor: object) -> int:
    """OctoPrint's factor as a percentage: an integer is one, a float is a fraction (1.0 is 100); 400 outside
    `MIN_FACTOR_PERCENT`..`MAX_FACTOR_PERCENT`."""
    if isinstance(factor, bool) or not isinstance(factor, int | float):
        raise web.HTTPBadRequest(text='"factor" is a number: a percentage, or a fraction as 1.0')
    percent = round(factor * 100) if isinstance(factor, float) else factor
    if not MIN_FACTOR_PERCENT <= percent <= MAX_FACTOR_PERCENT:
        raise web.HTTPBadRequest(text=f"factor {percent} % is outside {MIN_FACTOR_PERCENT}..{MAX_FACTOR_PERCENT} %")
    return percent
