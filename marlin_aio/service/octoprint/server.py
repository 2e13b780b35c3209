"""The server's resources: version, server, connection, settings, printer profiles, and what the service has none
of (timelapses, slicers, custom controls) or keeps for its owner (administration).

A key of the service has the rights of OctoPrint's default "Operator" group: it prints, controls, uploads and
reads the settings, and may not administer the server. So every administrative call (users, settings saved,
printer profiles changed, system commands, logs, language packs, slicer profiles, the utility tests) answers 403
as OctoPrint answers an operator's key; the service is administered on its host, with `marlin-temp`.
"""

from __future__ import annotations

from typing import Any

from aiohttp import web

import marlin_aio
from marlin_aio.service.octoprint.common import Door, error, json_body, resource

__all__ = ["ADMIN_ONLY", "OCTOPRINT_VERSION", "ServerRoutes"]

#: The OctoPrint release whose API this imitates (clients check it is at least 1.x).
OCTOPRINT_VERSION = "1.10.0"
_API_VERSION = "0.1"

#: (method, path) OctoPrint keeps for administrators: 403 for every key of the service, as for an operator's.
ADMIN_ONLY: tuple[tuple[str, str], ...] = (
    ("POST", "/api/settings"),
    ("POST", "/api/settings/apikey"),
    ("GET", "/api/settings/templates"),
    ("POST", "/api/printerprofiles"),
    ("PATCH", "/api/printerprofiles/{profile}"),
    ("DELETE", "/api/printerprofiles/{profile}"),
    ("*", "/api/system/commands"),
    ("*", "/api/system/commands/{source}"),
    ("*", "/api/system/commands/{source}/{action}"),
    ("*", "/api/languages"),
    ("*", "/api/languages/{locale}/{pack}"),
    ("PUT", "/api/slicing/{slicer}/profiles/{name}"),
    ("DELETE", "/api/slicing/{slicer}/profiles/{name}"),
    ("*", "/plugin/logging/{tail:.*}"),
    ("*", "/api/logs{tail:.*}"),
    ("*", "/api/users{tail:.*}"),
    ("*", "/api/access/{tail:.*}"),
    ("*", "/api/util/test"),
)

_TIMELAPSES = {"config": {"type": "off"}, "enabled": False, "files": [], "unrendered": []}


class ServerRoutes:
    """The server's resources of one door."""

    def __init__(self, door: Door) -> None:
        self.door = door

    def routes(self) -> list[web.RouteDef]:
        """Its routes, the administrative refusals with them."""
        return [
            web.get("/api/version", self.version),
            web.get("/api/server", self.server),
            web.get("/api/connection", self.connection),
            web.post("/api/connection", self.connection_command),
            web.get("/api/settings", self.settings),
            web.get("/api/printerprofiles", self.profiles),
            web.get("/api/printerprofiles/{profile}", self.profile),
            web.get("/api/printer/command/custom", self.custom_controls),
            web.get("/api/timelapse", self.timelapses),
            web.post("/api/timelapse", self.timelapse_config),
            web.delete("/api/timelapse/{name}", self.timelapse_delete),
            web.delete("/api/timelapse/unrendered/{name}", self.nothing_to_do),
            web.post("/api/timelapse/unrendered/{name}", self.nothing_to_do),
            web.get("/api/slicing", self.slicers),
            web.get("/api/slicing/{slicer}/profiles", self.no_slicer),
            web.get("/api/slicing/{slicer}/profiles/{name}", self.no_slicer),
        ] + [web.route(method, path, self.admin_only) for method, path in ADMIN_ONLY]

    async def version(self, request: web.Request) -> web.Response:
        """`GET /api/version`: who answers (a slicer's "test connection": with a wrong key, 403)."""
        text = f"OctoPrint (marlin_aio {marlin_aio.__version__})"
        return web.json_response({"api": _API_VERSION, "server": OCTOPRINT_VERSION, "text": text})

    async def server(self, request: web.Request) -> web.Response:
        """`GET /api/server`."""
        return web.json_response({"version": OCTOPRINT_VERSION, "safemode": None})

    async def connection(self, request: web.Request) -> web.Response:
        """`GET /api/connection`: the port the service holds, and whether it is up."""
        farm_printer = self.door.farm_printer
        spec = farm_printer.spec
        current = {
            "state": self.door.state_text(),
            "port": spec.port or "sim",
            "baudrate": spec.baud,
            "printerProfile": "_default",
        }
        options = {
            "ports": [current["port"]],
            "baudrates": [spec.baud],
            "printerProfiles": [{"id": "_default", "name": farm_printer.name}],
        }
        return web.json_response({"current": current, "options": options})

    async def connection_command(self, request: web.Request) -> web.Response:
        """`POST /api/connection` `{"command": "connect" | "disconnect" | "fake_ack"}`: open or close the port the
        service holds (a `port` or `baudrate` other than its own is refused, 400; a disconnect while printing, 409)."""
        body = await json_body(request)
        command = body.get("command")
        spec = self.door.farm_printer.spec
        if command == "connect":
            port, baud = body.get("port"), body.get("baudrate")
            if port not in (None, "AUTO", spec.port or "sim") or baud not in (None, 0, spec.baud):
                raise web.HTTPBadRequest(text=f"this printer is on {spec.port or 'sim'} at {spec.baud} baud")
            await self.door.verb("connect")
        elif command == "disconnect":
            await self.door.verb("disconnect")
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
            "upnpUuid": self.door.uuid,
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
                "appearance": {"name": self.door.farm_printer.name},
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
        farm_printer = self.door.farm_printer
        latest = farm_printer.latest
        axis = {"speed": 6000, "inverted": False}
        return {
            "id": "_default",
            "name": farm_printer.name,
            "model": farm_printer.name,
            "color": "default",
            "current": True,
            "default": True,
            "resource": resource(request, "/api/printerprofiles/_default"),
            "heatedBed": latest is not None and latest.bed is not None,
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

    async def custom_controls(self, request: web.Request) -> web.Response:
        """`GET /api/printer/command/custom`: no custom controls are configured."""
        return web.json_response({"controls": []})

    async def timelapses(self, request: web.Request) -> web.Response:
        """`GET /api/timelapse`: timelapses are off (the service has no camera)."""
        return web.json_response(_TIMELAPSES)

    async def timelapse_config(self, request: web.Request) -> web.Response:
        """`POST /api/timelapse` `{"type": "off"}`: they stay off (any other type is refused, 400: no camera)."""
        kind = (await json_body(request)).get("type")
        if kind != "off":
            raise web.HTTPBadRequest(text=f"timelapse {str(kind)[:20]!r}: the service has no camera, they stay off")
        return web.json_response(_TIMELAPSES)

    async def timelapse_delete(self, request: web.Request) -> web.Response:
        """`DELETE /api/timelapse/NAME`: there are none; the listing, as OctoPrint answers a name it lacks."""
        return web.json_response(_TIMELAPSES)

    async def nothing_to_do(self, request: web.Request) -> web.Response:
        """Delete or render an unrendered timelapse: there are none (204, as OctoPrint answers)."""
        return web.Response(status=204)

    async def slicers(self, request: web.Request) -> web.Response:
        """`GET /api/slicing`: no slicer is installed (slicers upload G-code)."""
        return web.json_response({})

    async def no_slicer(self, request: web.Request) -> web.Response:
        """A slicer's profiles: 404, there is no slicer."""
        return error(404, f"no slicer {request.match_info['slicer'][:40]!r}: the service slices nothing")

    async def admin_only(self, request: web.Request) -> web.Response:
        """An administrative call: 403, as OctoPrint answers an operator's key."""
        return error(403, "Insufficient rights: the service is administered on its host (marlin-temp)")
