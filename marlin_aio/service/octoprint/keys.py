"""OctoPrint's app-key flow (its bundled appkeys plugin), how Home Assistant and Cura get a key: probe, request,
poll for the decision. The owner of the service decides (`marlin-temp keys approve TOKEN` on its Unix socket);
nothing is handed out without that. Open without a key, as OctoPrint's plugin is: it is how an app gets one."""

from __future__ import annotations

import html
import logging

from aiohttp import web

from marlin_aio.service.appkeys import AppKeyError, TooManyRequestsError
from marlin_aio.service.octoprint.common import Door, error, json_body, resource

__all__ = ["PREFIX", "AppKeyRoutes"]

#: Where the flow's routes live: the auth middleware lets them through without a key.
PREFIX = "/plugin/appkeys/"

_log = logging.getLogger("marlin_aio.service.octoprint")


class AppKeyRoutes:
    """The app-key flow of one door."""

    def __init__(self, door: Door) -> None:
        self.door = door

    def routes(self) -> list[web.RouteDef]:
        """Its routes."""
        return [
            web.get(f"{PREFIX}probe", self.probe),
            web.post(f"{PREFIX}request", self.ask),
            web.get(PREFIX + "request/{token}", self.poll),
            web.get(PREFIX + "auth/{token}", self.dialog),
        ]

    async def probe(self, request: web.Request) -> web.Response:
        """`GET /plugin/appkeys/probe`: 204, the app-key flow is on."""
        return web.Response(status=204)

    async def ask(self, request: web.Request) -> web.Response:
        """`POST /plugin/appkeys/request` `{"app", "user"?}`: 201 and where to poll; the owner is told how to decide."""
        body = await json_body(request)
        try:
            asked = self.door.owner.app_keys.request(body.get("app"), body.get("user"))
        except TooManyRequestsError as exc:
            return error(429, str(exc))
        except AppKeyError as exc:
            return error(400, str(exc))
        _log.warning(
            "%r%s asks for an API key for the OctoPrint API: approve with `marlin-temp keys approve %s` "
            "(or deny with `marlin-temp keys deny %s`)",
            asked.app,
            f" (user {asked.user!r})" if asked.user else "",
            asked.token,
            asked.token,
        )
        where = resource(request, f"{PREFIX}request/{asked.token}")
        dialog = resource(request, f"{PREFIX}auth/{asked.token}")
        return web.json_response(
            {"app_token": asked.token, "auth_dialog": dialog}, status=201, headers={"Location": where}
        )

    async def dialog(self, request: web.Request) -> web.Response:
        """`GET /plugin/appkeys/auth/<token>`: the page an app opens for its user (Cura does): how the owner
        approves the request. It decides nothing: only the owner's socket does."""
        token = request.match_info["token"]
        # Read from the list waiting, never through `poll`: that hands a granted key out once, to the app.
        pending = any(asked.token == token for asked in self.door.owner.app_keys.pending())
        shown = html.escape(token[:64]) if pending else "TOKEN"
        text = (
            f"<p>An app asks for a key to this printer ({html.escape(self.door.farm_printer.name)}).</p>"
            f"<p>On the machine running <code>marlin-temp serve</code>, as its owner:</p>"
            f"<pre>marlin-temp keys approve {shown}\nmarlin-temp keys deny {shown}</pre>"
            f"<p>(<code>marlin-temp keys</code> lists the requests waiting.)</p>"
        )
        page = f"<!doctype html><title>marlin-temp: approve an app key</title>{text}"
        return web.Response(text=page, content_type="text/html")

    async def poll(self, request: web.Request) -> web.Response:
        """`GET /plugin/appkeys/request/<token>`: 202 while the owner decides, 200 with the key once, else 404."""
        decision, key = self.door.owner.app_keys.poll(request.match_info["token"])
        if decision == "pending":
            return web.json_response({"message": "Awaiting decision"}, status=202)
        if decision == "granted":
            return web.json_response({"api_key": key})
        return error(404, "No such request, or it was denied")
