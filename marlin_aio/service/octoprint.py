"""The part of OctoPrint's REST API that slicers and Home Assistant use, served by `marlin-temp serve --octoprint`.

PrusaSlicer, OrcaSlicer and Cura's "OctoPrint" host type upload a file and start it (`GET /api/version`, then
`POST /api/files/local` with `print=true`); Home Assistant's OctoPrint integration reads `/api/printer` and
`/api/job` and sends `POST /api/job` (pause, resume, cancel) and heater targets. Each request is answered from the
service's own state (its farm's printer: the latest reading, the print running) and acts through the same calls as
the socket's clients, so a print started here is the same print `marlin-temp serve` shows everywhere.

Served by aiohttp (a well-kept server, not a hand-written one), on 127.0.0.1 unless told otherwise. Every request,
`GET /api/version` too, needs the API key (`X-Api-Key` header, or `apikey` in the query), compared in constant time;
without it the answer is 403, as OctoPrint's, so a slicer's "test connection" fails on a wrong key.

Every part of a request is bounded (`httpbounds`): its headers, a JSON body, an upload's fields, its file (a
size bound and a quota for the folder, checked before a byte is written when the length is told, and as it
streams), and a bad request is one short log line with no secret. An upload with `print=true` is refused (409)
before anything is kept when the print cannot start (another one running, the printer offline); a handler's
unexpected exception is a 500 and one line.

Over 400 lines because it is the HTTP door whole: each route translates OctoPrint's shapes to and from the
service's verbs (`marlin_aio.service.verbs`), read in one place.
"""

from __future__ import annotations

import hmac
import json
import logging
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aiohttp import web

import marlin_aio
from marlin_aio.farm.job import JobState
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.protocol.motion import extrude_commands, home_command, move_commands
from marlin_aio.protocol.rpc import RpcError, progress_from_json
from marlin_aio.service import verbs
from marlin_aio.service.appkeys import AppKeyError, TooManyRequestsError
from marlin_aio.service.httpbounds import (
    MAX_JSON_BYTES,
    bounded_runner,
    check_length,
    one_line,
    read_upload_form,
    upload_errors,
)
from marlin_aio.service.uploads import Uploads, check_name
from marlin_aio.service.verbs import Caller, Owner

__all__ = ["OCTOPRINT_VERSION", "OctoPrintApi"]

_log = logging.getLogger("marlin_aio.service.octoprint")

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

#: The OctoPrint release whose API this imitates (clients check it is at least 1.x).
OCTOPRINT_VERSION = "1.10.0"
_API_VERSION = "0.1"

#: OctoPrint's words for the states of a job that holds the printer.
_STATES = {
    JobState.STARTING: "Starting",
    JobState.PRINTING: "Printing",
    JobState.PAUSED: "Paused",
    JobState.CANCELLING: "Cancelling",
}


class OctoPrintApi:
    """The OctoPrint-shaped HTTP API of one printer of a service.

    Args:
        owner: the service, whose table of verbs every action calls (so a print is everyone's).
        farm_printer: the printer it speaks for.
        uploads: where uploaded files are kept.
        api_key: the key every request must carry.

    Raises:
        ValueError: the key is shorter than 16 characters.
    """

    def __init__(self, owner: Owner, farm_printer: FarmPrinter, uploads: Uploads, api_key: str) -> None:
        if len(api_key) < 16:
            raise ValueError("the API key must be at least 16 characters")
        self.farm_printer = farm_printer
        # The service whose table of verbs every action here calls (as the socket's and MQTT's doors do).
        self.owner = owner
        self.uploads = uploads
        self._key = api_key.encode()
        self.selected: Path | None = None
        # A stable id per service and printer (Home Assistant's device id): from where the service listens.
        self._uuid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"marlin-temp:{owner.socket_path}:{farm_printer.name}"))
        # `//api/...` (a base URL with a trailing slash, as pyoctoprintapi builds some) is redirected, method kept.
        slashes = web.normalize_path_middleware(
            append_slash=False, merge_slashes=True, redirect_class=web.HTTPPermanentRedirect
        )
        # client_max_size bounds the JSON bodies; an upload is streamed part by part, each with its own bound.
        self.app = web.Application(middlewares=[slashes, self._auth], client_max_size=MAX_JSON_BYTES)
        self.app.add_routes(
            [
                web.get("/api/version", self.version),
                web.get("/api/server", self.server),
                web.get("/api/connection", self.connection),
                web.post("/api/connection", self.connection_command),
                web.get("/api/settings", self.settings),
                web.get("/api/printerprofiles", self.profiles),
                web.get("/api/printerprofiles/{profile}", self.profile),
                web.get("/api/printer", self.printer),
                web.post("/api/printer/tool", self.tool),
                web.post("/api/printer/bed", self.bed),
                web.get("/api/printer/tool", self.tools),
                web.post("/api/printer/printhead", self.printhead),
                web.get("/api/printer/chamber", self.chamber_state),
                web.post("/api/printer/chamber", self.chamber),
                web.get("/api/printer/command/custom", self.custom_controls),
                web.get("/api/languages", self.languages),
                web.get("/api/timelapse", self.timelapses),
                web.get("/api/slicing", self.slicers),
                web.get("/api/system/commands", self.system_commands),
                web.get("/api/system/commands/{source}", self.system_commands),
                web.post("/api/system/commands/{source}/{action}", self.system_command),
                web.get("/api/printer/bed", self.bed_state),
                web.get("/api/job", self.job),
                web.post("/api/job", self.job_command),
                web.get("/api/files", self.files),
                web.get("/api/files/local", self.files),
                web.post("/api/files/local", self.upload),
                web.post("/api/files/local/{name}", self.file_command),
                web.get("/api/files/local/{name}", self.file_info),
                web.delete("/api/files/local/{name}", self.file_delete),
                web.post("/api/printer/command", self.printer_command),
                web.get("/plugin/appkeys/probe", self.appkeys_probe),
                web.post("/plugin/appkeys/request", self.appkeys_request),
                web.get("/plugin/appkeys/request/{token}", self.appkeys_poll),
            ]
        )

    # ------------------------------------------------------------------------------------------- plumbing

    @web.middleware
    async def _auth(self, request: web.Request, handler: Any) -> web.StreamResponse:
        given = (request.headers.get("X-Api-Key") or request.query.get("apikey") or "").encode(errors="surrogatepass")
        # The app-key flow is how an app without a key gets one: open, as OctoPrint's plugin is.
        if not request.path.startswith("/plugin/appkeys/"):
            own = hmac.compare_digest(given, self._key)
            if not (own | self.owner.app_keys.valid(given)):  # both compared, whichever matches
                return _error(403, "Invalid API key")
        try:
            response: web.StreamResponse = await handler(request)
        except marlin_aio.MarlinError as exc:
            return _error(409, str(exc))
        except web.HTTPException:
            raise
        except Exception as exc:  # a bug of ours: the client gets a 500, the log one line, never a traceback
            _log.error("%s %s failed: %s", request.method, request.path[:200], one_line(exc, self._key.decode()))
            return _error(500, "Internal error")
        return response

    async def serve(self, host: str, port: int) -> web.AppRunner:
        """Start listening on `host`:`port`; return the runner (its `cleanup()` stops it).

        Raises:
            OSError: the address is in use or not allowed.
        """
        runner = bounded_runner(self.app, _log, self._key.decode())
        await runner.setup()
        site = web.TCPSite(runner, host, port)
        try:
            await site.start()
        except BaseException:
            await runner.cleanup()
            raise
        return runner

    def _operational(self) -> marlin_aio.Printer:
        printer = self.farm_printer.printer
        if printer is None or not self.farm_printer.link_up:
            raise web.HTTPConflict(text="Printer is not operational")
        return printer

    def _handle(self) -> marlin_aio.PrintHandle | None:
        return self.farm_printer.print_handle

    def _state_text(self) -> str:
        if not self.farm_printer.link_up:
            return "Offline" if self.farm_printer.last_error is None else "Offline after error"
        job = self.farm_printer.job
        if job is not None and job.active:
            return _STATES[job.state]
        return "Operational"

    def _check_can_start(self) -> None:
        """Refuse (409) a print that cannot start, before anything is kept for it."""
        job = self.farm_printer.job
        if job is not None and job.active:
            raise web.HTTPConflict(text=f"a print is already running: {job.describe()}; cancel it first")
        self._operational()

    # ------------------------------------------------------------------------------------------- read

    async def version(self, request: web.Request) -> web.Response:
        """`GET /api/version`: who answers (a slicer's "test connection": with a wrong key, 403)."""
        return web.json_response(
            {
                "api": _API_VERSION,
                "server": OCTOPRINT_VERSION,
                "text": f"OctoPrint (marlin_aio {marlin_aio.__version__})",
            }
        )

    async def server(self, request: web.Request) -> web.Response:
        """`GET /api/server`."""
        return web.json_response({"version": OCTOPRINT_VERSION, "safemode": None})

    async def connection(self, request: web.Request) -> web.Response:
        """`GET /api/connection`: the port the service holds, and whether it is up."""
        spec = self.farm_printer.spec
        current = {
            "state": self._state_text(),
            "port": spec.port or "sim",
            "baudrate": spec.baud,
            "printerProfile": "_default",
        }
        options = {
            "ports": [current["port"]],
            "baudrates": [spec.baud],
            "printerProfiles": [{"id": "_default", "name": self.farm_printer.name}],
        }
        return web.json_response({"current": current, "options": options})

    async def connection_command(self, request: web.Request) -> web.Response:
        """`POST /api/connection` `{"command": "connect" | "disconnect" | "fake_ack"}`: open or close the port the
        service holds (a `port` or `baudrate` other than its own is refused, 400; a disconnect while printing, 409)."""
        body = await _json(request)
        command = body.get("command")
        spec = self.farm_printer.spec
        if command == "connect":
            port, baud = body.get("port"), body.get("baudrate")
            if port not in (None, "AUTO", spec.port or "sim") or baud not in (None, 0, spec.baud):
                raise web.HTTPBadRequest(text=f"this printer is on {spec.port or 'sim'} at {spec.baud} baud")
            await self._verb("connect")
        elif command == "disconnect":
            await self._verb("disconnect")
        elif command != "fake_ack":  # nothing to acknowledge: the library never waits for an ok it lost
            raise web.HTTPBadRequest(text=f"unknown connection command {str(command)[:20]!r}")
        return web.Response(status=204)

    async def settings(self, request: web.Request) -> web.Response:
        """`GET /api/settings`: what clients read of OctoPrint's settings. Home Assistant takes
        `plugins.discovery.upnpUuid` as the device's id (stable: the same service and printer give the same one
        after a restart); every webcam field is there, with no webcam."""
        webcam = {
            "webcamEnabled": False,
            "streamUrl": "",
            "snapshotUrl": "",
            "flipH": False,
            "flipV": False,
            "rotate90": False,
            "bitrate": "",
            "snapshotSslValidation": True,
        }
        discovery = {
            "upnpUuid": self._uuid,
            "publicHost": None,
            "publicPort": None,
            "pathPrefix": None,
            "httpUsername": None,
            "httpPassword": None,
            "model": {"name": "marlin_aio", "vendor": "marlin_aio", "number": marlin_aio.__version__},
        }
        return web.json_response(
            {
                "api": {"enabled": True},
                "appearance": {"name": self.farm_printer.name},
                "feature": {"sdSupport": False},
                "webcam": webcam,
                "plugins": {"discovery": discovery},
            }
        )

    async def profiles(self, request: web.Request) -> web.Response:
        """`GET /api/printerprofiles`: one profile, with a heated bed if the printer reports one."""
        return web.json_response({"profiles": {"_default": self._profile(request)}})

    def _profile(self, request: web.Request) -> dict[str, Any]:
        """The one printer profile: the printer's name, its heaters as it reports them, its axes."""
        latest = self.farm_printer.latest
        bed = latest is not None and latest.bed is not None
        axis = {"speed": 6000, "inverted": False}
        return {
            "id": "_default",
            "name": self.farm_printer.name,
            "model": self.farm_printer.name,
            "color": "default",
            "current": True,
            "default": True,
            "resource": str(request.url.with_path("/api/printerprofiles/_default").with_query(None)),
            "heatedBed": bed,
            "heatedChamber": latest is not None and latest.temperatures.chamber is not None,
            "volume": {"formFactor": "rectangular", "origin": "lowerleft", "width": 200, "depth": 200, "height": 200},
            "axes": {
                "x": axis,
                "y": axis,
                "z": {"speed": 200, "inverted": False},
                "e": {"speed": 300, "inverted": False},
            },
            "extruder": {"count": 1, "offsets": [[0.0, 0.0]], "nozzleDiameter": 0.4, "sharedNozzle": False},
        }

    async def profile(self, request: web.Request) -> web.Response:
        """`GET /api/printerprofiles/_default` (the one there is)."""
        if request.match_info["profile"] != "_default":
            raise web.HTTPNotFound(text="the one printer profile is _default")
        return web.json_response(self._profile(request))

    async def printer(self, request: web.Request) -> web.Response:
        """`GET /api/printer[?exclude=temperature,sd,state&history=true&limit=N]`: temperatures (with their history
        if asked) and state flags (409 while the printer is not connected)."""
        self._operational()
        exclude = {part.strip() for part in request.query.get("exclude", "").split(",")}
        info = await self._verb("status")
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
            answer["state"] = {"text": self._state_text(), "error": "", "flags": flags}
        return web.json_response(answer)

    async def tools(self, request: web.Request) -> web.Response:
        """`GET /api/printer/tool[?history=true&limit=N]`: the hotends' temperatures."""
        self._operational()
        info = await self._verb("status")
        return web.json_response(await self._temperatures(request, info, lambda name: name.startswith("tool")))

    async def bed_state(self, request: web.Request) -> web.Response:
        """`GET /api/printer/bed[?history=true&limit=N]`: the bed's temperature (409 if the printer reports none)."""
        return await self._one_heater(request, "bed")

    async def chamber_state(self, request: web.Request) -> web.Response:
        """`GET /api/printer/chamber[?history=true&limit=N]`: the chamber's temperature (409 if the printer
        reports none, as OctoPrint answers without a heated chamber)."""
        return await self._one_heater(request, "chamber")

    async def _one_heater(self, request: web.Request, heater: str) -> web.Response:
        self._operational()
        info = await self._verb("status")
        answer = await self._temperatures(request, info, lambda name: name == heater)
        if heater not in answer:
            raise web.HTTPConflict(text=f"the printer reports no heated {heater}")
        return web.json_response(answer)

    async def chamber(self, request: web.Request) -> web.Response:
        """`POST /api/printer/chamber` `{"command": "target", "target": 40}` (409 without a heated chamber)."""
        body = await _json(request)
        if body.get("command") != "target":
            raise web.HTTPBadRequest(text="temperature offsets are not supported: set the target you want")
        self._operational()
        latest = self.farm_printer.latest
        if latest is None or latest.temperatures.chamber is None:
            raise web.HTTPConflict(text="the printer reports no heated chamber")
        await self._verb("set_temperatures", chamber=body.get("target"))
        return web.Response(status=204)

    async def custom_controls(self, request: web.Request) -> web.Response:
        """`GET /api/printer/command/custom`: no custom controls are configured."""
        return web.json_response({"controls": []})

    async def languages(self, request: web.Request) -> web.Response:
        """`GET /api/languages`: no language pack is installed (the API speaks no UI)."""
        return web.json_response(
            {"language_packs": {"_core": {"identifier": "_core", "display": "Core", "languages": []}}}
        )

    async def timelapses(self, request: web.Request) -> web.Response:
        """`GET /api/timelapse`: timelapses are off (the service has no camera)."""
        return web.json_response({"config": {"type": "off"}, "enabled": False, "files": [], "unrendered": []})

    async def slicers(self, request: web.Request) -> web.Response:
        """`GET /api/slicing`: no slicer is installed (slicers upload G-code)."""
        return web.json_response({})

    async def system_commands(self, request: web.Request) -> web.Response:
        """`GET /api/system/commands[/SOURCE]`: none (the service runs no shell command for a client)."""
        source = request.match_info.get("source")
        if source is None:
            return web.json_response({"core": [], "plugin": [], "custom": []})
        if source not in ("core", "plugin", "custom"):
            raise web.HTTPNotFound(text=f"no source {source[:20]!r}")
        return web.json_response([])

    async def system_command(self, request: web.Request) -> web.Response:
        """`POST /api/system/commands/SOURCE/ACTION`: 404, as OctoPrint answers an action it does not have (the
        service never restarts or shuts down its machine for a client)."""
        raise web.HTTPNotFound(text="no such system command: the service runs none for its clients")

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
            kept = await self._verb("history", seconds=HISTORY_SECONDS)
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

    async def job(self, request: web.Request) -> web.Response:
        """`GET /api/job`: the printer's job (running or last run; or the file selected), and its progress."""
        job = await self._verb("job")
        # The file selected names the job until a print runs (OctoPrint's job is its selected file); a print
        # running names it, whoever started it.
        selected = None if self.selected is None else self.selected.name
        if job is not None and (job["active"] or selected is None or job["file"] == selected):
            name = job["file"]
        else:
            name = selected
            job = None  # a file selected since the last print: its progress is not that print's
        file: dict[str, Any] = {"name": name, "path": name, "origin": "local" if name else None}
        progress: dict[str, Any] = {"completion": None, "filepos": None, "printTime": None, "printTimeLeft": None}
        snapshot = None if job is None or job["progress"] is None else progress_from_json(job["progress"])
        if snapshot is not None:
            file["size"] = snapshot.source_bytes_total
            fraction = snapshot.fraction
            progress = {
                "completion": None if fraction is None else round(100 * fraction, 2),
                "filepos": snapshot.source_bytes_acked,
                "printTime": round(snapshot.elapsed_s),
                "printTimeLeft": None if snapshot.eta_s is None else round(snapshot.eta_s),
            }
        value = {"file": file, "estimatedPrintTime": None, "lastPrintTime": None, "filament": None}
        return web.json_response({"job": value, "progress": progress, "state": self._state_text()})

    async def files(self, request: web.Request) -> web.Response:
        """`GET /api/files`: the uploaded files."""
        folder = self.uploads.folder
        entries = sorted(folder.glob("*.gcode")) if folder.is_dir() else []
        files = [_file_ref(request, path) for path in entries]
        usage = shutil.disk_usage(folder if folder.is_dir() else folder.parent)
        return web.json_response({"files": files, "free": usage.free, "total": usage.total})

    def _uploaded(self, request: web.Request) -> Path:
        """The uploaded file `/api/files/local/NAME` names (404 if there is none)."""
        name = request.match_info["name"]
        with upload_errors(self.uploads, request):
            check_name(name)
        path = self.uploads.folder / name
        if not self.uploads.is_finished(path):
            raise web.HTTPNotFound(text=f"no uploaded file {name[:100]!r}")
        return path

    async def file_info(self, request: web.Request) -> web.Response:
        """`GET /api/files/local/NAME`: one uploaded file (404 if there is none)."""
        return web.json_response(_file_ref(request, self._uploaded(request)))

    async def file_delete(self, request: web.Request) -> web.Response:
        """`DELETE /api/files/local/NAME`: remove an uploaded file (409 while it is being printed)."""
        path = self._uploaded(request)
        job = self.farm_printer.job
        if job is not None and job.active and self.selected == path:
            raise web.HTTPConflict(text=f"{path.name} is being printed")
        path.unlink(missing_ok=True)
        if self.selected == path:
            self.selected = None
        return web.Response(status=204)

    # ------------------------------------------------------------------------------------------- act

    async def tool(self, request: web.Request) -> web.Response:
        """`POST /api/printer/tool`: `target` (`{"targets": {"tool0": 200}}`), `select` (`{"tool": "tool1"}`),
        `extrude` (`{"amount": 5, "speed"?}`, 409 while printing), `flowrate` (`{"factor": 90}`); each through the
        `send` or `set_temperatures` verb, so with the limits every door checks. Unknown tools are refused (400)."""
        body = await _json(request)
        command = body.get("command")
        self._operational()
        if command == "target":
            targets = body.get("targets")
            if not isinstance(targets, dict) or not targets:
                raise web.HTTPBadRequest(text='target needs "targets": {"tool0": celsius, ...}')
            for name, target in targets.items():
                await self._verb("set_temperatures", hotend=target, tool=_tool_index(name))
        elif command == "select":
            await self._send_all([f"T{_tool_index(body.get('tool'))}"])
        elif command == "extrude":
            self._check_idle("extrude")
            speed = body.get("speed", EXTRUDE_MM_MIN)
            amount: Any = body.get("amount")  # checked by extrude_commands (a 400 if it is no distance)
            await self._send_all(_motion(lambda: extrude_commands(amount, feedrate_mm_min=speed)))
        elif command == "flowrate":
            await self._send_all([f"M221 S{_percent(body.get('factor'))}"])
        elif command == "offset":
            raise web.HTTPBadRequest(text="temperature offsets are not supported: set the target you want")
        else:
            raise web.HTTPBadRequest(text=f"unknown tool command {str(command)[:20]!r}")
        return web.Response(status=204)

    async def bed(self, request: web.Request) -> web.Response:
        """`POST /api/printer/bed` `{"command": "target", "target": 60}` (409 without a heated bed)."""
        body = await _json(request)
        command = body.get("command")
        if command == "offset":
            raise web.HTTPBadRequest(text="temperature offsets are not supported: set the target you want")
        if command != "target":
            raise web.HTTPBadRequest(text=f"unknown bed command {str(command)[:20]!r}")
        self._operational()
        await self._verb("set_temperatures", bed=body.get("target"))
        return web.Response(status=204)

    async def printhead(self, request: web.Request) -> web.Response:
        """`POST /api/printer/printhead`: `jog` (`{"x"?, "y"?, "z"?, "absolute"?, "speed"?}` mm and mm/min),
        `home` (`{"axes": ["x", "y"]}`), `feedrate` (`{"factor": 100}` percent, or 1.0); within the moves' limits
        (`marlin_aio.protocol.motion`), each command through the `send` verb. 409 while printing, but feedrate."""
        body = await _json(request)
        command = body.get("command")
        self._operational()
        if command == "jog":
            self._check_idle("jog")
            axes = {axis: body[axis] for axis in ("x", "y", "z") if body.get(axis) not in (None, 0)}
            if axes:
                relative = not body.get("absolute", False)
                speed = body.get("speed")
                await self._send_all(
                    _motion(lambda: move_commands(**axes, feedrate_mm_min=speed or None, relative=relative))
                )
        elif command == "home":
            self._check_idle("home")
            homed = body.get("axes")
            if not isinstance(homed, list) or not homed:
                raise web.HTTPBadRequest(text='home needs "axes": a list of x, y, z')
            await self._send_all(_motion(lambda: [home_command(homed)]))
        elif command == "feedrate":
            await self._send_all([f"M220 S{_percent(body.get('factor'))}"])
        else:
            raise web.HTTPBadRequest(text=f"unknown printhead command {str(command)[:20]!r}")
        return web.Response(status=204)

    def _check_idle(self, what: str) -> None:
        job = self.farm_printer.job
        if job is not None and job.active:
            raise web.HTTPConflict(text=f"cannot {what} while printing: {job.describe()}")

    async def _send_all(self, commands: list[str]) -> None:
        for command in commands:
            await self._verb("send", command=command)

    async def job_command(self, request: web.Request) -> web.Response:
        """`POST /api/job`: start (the selected file), cancel, pause (`action` pause, resume or toggle), restart."""
        body = await _json(request)
        command = body.get("command")
        handle = self._handle()
        if command in ("start", "restart"):
            if self.selected is None:
                raise web.HTTPConflict(text="no file is selected")
            await self._start(self.selected)
        elif command == "cancel":
            # The job's one cancel script (heaters and fan off by default), as from every door.
            await self._verb("cancel")
        elif command == "pause":
            action = body.get("action", "toggle")
            paused = handle is not None and handle.progress.state is marlin_aio.PrintState.PAUSED
            if action == "pause" or (action == "toggle" and not paused):
                await self._verb("pause")
            elif action in ("resume", "toggle"):
                await self._verb("resume")
            else:
                raise web.HTTPBadRequest(text=f"unknown pause action {str(action)[:20]!r}")
        else:
            raise web.HTTPBadRequest(text=f"unknown job command {str(command)[:20]!r}")
        return web.Response(status=204)

    async def printer_command(self, request: web.Request) -> web.Response:
        """`POST /api/printer/command` `{"command": "G28"}` or `{"commands": [...]}`: each sent in turn, through the
        same checks as every door's `send` (a target over the limits is refused, 400, and nothing after it goes)."""
        body = await _json(request)
        one, many = body.get("command"), body.get("commands")
        if (one is None) == (many is None):
            raise web.HTTPBadRequest(text='give "command" (a string) or "commands" (a list of strings)')
        commands = [one] if many is None else many
        if not isinstance(commands, list) or not all(isinstance(c, str) for c in commands):
            raise web.HTTPBadRequest(text='"commands" is a list of strings')
        if len(commands) > MAX_COMMANDS:
            raise web.HTTPBadRequest(text=f"at most {MAX_COMMANDS} commands at once")
        self._operational()
        for command in commands:
            await self._verb("send", command=command)
        return web.Response(status=204)

    async def _start(self, path: Path) -> None:
        await self._verb("start_print", path=str(path))

    async def _verb(self, name: str, **params: Any) -> Any:
        """Call the service's verb `name` on this printer, as the HTTP door: its refusals as OctoPrint's statuses
        (a bad argument 400, a state that does not allow it 409)."""
        caller = Caller("http", "octoprint")
        try:
            return await verbs.call(self.owner, name, {"printer": self.farm_printer.name, **params}, caller)
        except (RpcError, ValueError) as exc:
            raise web.HTTPBadRequest(text=str(exc)) from None
        except (RuntimeError, FileNotFoundError, PermissionError, marlin_aio.MarlinError) as exc:
            raise web.HTTPConflict(text=str(exc)) from None

    async def upload(self, request: web.Request) -> web.Response:
        """`POST /api/files/local` (multipart: `file`, and `select`/`print` as `true`): keep the file and, with
        print, start it at once, as slicers' "upload and print" does. Nothing is kept when the upload is refused:
        over a bound (413), not text or not a well-formed form (400), or its print cannot start (409)."""
        if not request.content_type.startswith("multipart/"):
            raise web.HTTPBadRequest(text="upload a file as multipart/form-data")
        check_length(request, self.uploads)

        def before_file(fields: dict[str, str]) -> None:
            if fields.get("print", "").lower() == "true":
                self._check_can_start()  # before a byte of the file is written

        upload_id: str | None = None
        try:
            with upload_errors(self.uploads, request):
                form = await read_upload_form(request, self.uploads, ("select", "print"), before_file)
                upload_id = form.upload_id
                select = form.fields.get("select", "false").lower() == "true"
                start = form.fields.get("print", "false").lower() == "true"
                if start:
                    self._check_can_start()  # again: the file may have come before the print field
                stored = self.uploads.finish(upload_id, form.name)
        finally:
            if upload_id is not None:
                self.uploads.discard(upload_id)  # nothing if finished
        if select or start:
            self.selected = stored
        if start:
            try:
                await self._start(stored)
            except (web.HTTPException, marlin_aio.MarlinError):
                stored.unlink(missing_ok=True)  # another print won the race: refused, so nothing kept
                if self.selected == stored:
                    self.selected = None
                raise
        files = {"local": _file_ref(request, stored)}
        answer = {"files": files, "done": True, "effectiveSelect": select, "effectivePrint": start}
        return web.json_response(answer, status=201, headers={"Location": _resource(request, stored)})

    async def file_command(self, request: web.Request) -> web.Response:
        """`POST /api/files/local/NAME` `{"command": "select", "print": true}`: select an uploaded file, and print."""
        body = await _json(request)
        if body.get("command") != "select":
            raise web.HTTPBadRequest(text="only the select command is supported")
        path = self._uploaded(request)
        if body.get("print"):
            self._check_can_start()
        self.selected = path
        if body.get("print"):
            await self._start(path)
        return web.Response(status=204)

    # ------------------------------------------------------------------------------------------- app keys

    async def appkeys_probe(self, request: web.Request) -> web.Response:
        """`GET /plugin/appkeys/probe`: 204, the app-key flow is on."""
        return web.Response(status=204)

    async def appkeys_request(self, request: web.Request) -> web.Response:
        """`POST /plugin/appkeys/request` `{"app", "user"?}`: 201 and where to poll; the owner is told how to decide."""
        body = await _json(request)
        try:
            asked = self.owner.app_keys.request(body.get("app"), body.get("user"))
        except TooManyRequestsError as exc:
            return _error(429, str(exc))
        except AppKeyError as exc:
            return _error(400, str(exc))
        _log.warning(
            "%r%s asks for an API key for the OctoPrint API: approve with `marlin-temp keys approve %s` "
            "(or deny with `marlin-temp keys deny %s`)",
            asked.app,
            f" (user {asked.user!r})" if asked.user else "",
            asked.token,
            asked.token,
        )
        where = str(request.url.with_path(f"/plugin/appkeys/request/{asked.token}").with_query(None))
        dialog = str(request.url.with_path(f"/plugin/appkeys/auth/{asked.token}").with_query(None))
        return web.json_response(
            {"app_token": asked.token, "auth_dialog": dialog}, status=201, headers={"Location": where}
        )

    async def appkeys_poll(self, request: web.Request) -> web.Response:
        """`GET /plugin/appkeys/request/<token>`: 202 while the owner decides, 200 with the key once, else 404."""
        decision, key = self.owner.app_keys.poll(request.match_info["token"])
        if decision == "pending":
            return web.json_response({"message": "Awaiting decision"}, status=202)
        if decision == "granted":
            return web.json_response({"api_key": key})
        return _error(404, "No such request, or it was denied")


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


def _percent(factor: object) -> int:
    """OctoPrint's factor as a percentage: an integer is one, a float is a fraction (1.0 is 100); 400 outside
    `MIN_FACTOR_PERCENT`..`MAX_FACTOR_PERCENT`."""
    if isinstance(factor, bool) or not isinstance(factor, int | float):
        raise web.HTTPBadRequest(text='"factor" is a number: a percentage, or a fraction as 1.0')
    percent = round(factor * 100) if isinstance(factor, float) else factor
    if not MIN_FACTOR_PERCENT <= percent <= MAX_FACTOR_PERCENT:
        raise web.HTTPBadRequest(text=f"factor {percent} % is outside {MIN_FACTOR_PERCENT}..{MAX_FACTOR_PERCENT} %")
    return percent


def _motion(build: Callable[[], list[str]]) -> list[str]:
    """The commands `build` makes, its ValueError (a distance or speed out of bounds) as a 400."""
    try:
        return build()
    except (TypeError, ValueError) as exc:
        raise web.HTTPBadRequest(text=str(exc)) from None


async def _json(request: web.Request) -> dict[str, Any]:
    try:
        body = await request.json()
    except ValueError:
        raise web.HTTPBadRequest(text="the body is not JSON") from None
    if not isinstance(body, dict):
        raise web.HTTPBadRequest(text="the body is a JSON object")
    return body


def _resource(request: web.Request, path: Path) -> str:
    """The absolute URL of an uploaded file, as the client reached the service (OctoPrint's refs are absolute, and
    Cura reads the upload's `Location` and splits it at `api/`)."""
    return str(request.url.with_path(f"/api/files/local/{path.name}").with_query(None))


def _file_ref(request: web.Request, path: Path) -> dict[str, Any]:
    """An uploaded file as OctoPrint's API names one: its name, origin, type, size, date and absolute URLs."""
    stat = path.stat()
    return {
        "name": path.name,
        "display": path.name,
        "path": path.name,
        "origin": "local",
        "type": "machinecode",
        "typePath": ["machinecode", "gcode"],
        "size": stat.st_size,
        "date": int(stat.st_mtime),
        "refs": {
            "resource": _resource(request, path),
            "download": str(request.url.with_path(f"/downloads/files/local/{path.name}").with_query(None)),
        },
    }


def _error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)
