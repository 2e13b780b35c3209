"""The OctoPrint door of one printer put together: its resources' routes behind the key check.

Served by aiohttp (a well-kept server, not a hand-written one), on 127.0.0.1 unless told otherwise. Every request,
`GET /api/version` too, needs an API key (`X-Api-Key` header, or `apikey` in the query): the service's own, or one
its owner approved through the app-key flow; compared in constant time. Without one the answer is 403, as
OctoPrint's, so a slicer's "test connection" fails on a wrong key. A bad request is one short log line with no
secret; a handler's unexpected exception is a 500 and one line.
"""

from __future__ import annotations

import hmac
import logging
from typing import Any

from aiohttp import web

import marlin_aio
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.service.httpbounds import MAX_JSON_BYTES, bounded_runner, one_line
from marlin_aio.service.octoprint.common import Door, error
from marlin_aio.service.octoprint.files import FileRoutes
from marlin_aio.service.octoprint.keys import PREFIX, AppKeyRoutes
from marlin_aio.service.octoprint.printer import PrinterRoutes
from marlin_aio.service.octoprint.server import ServerRoutes
from marlin_aio.service.uploads import Uploads
from marlin_aio.service.verbs import Owner

__all__ = ["OctoPrintApi"]

_log = logging.getLogger("marlin_aio.service.octoprint")


class OctoPrintApi(Door):
    """The OctoPrint-shaped HTTP API of one printer of a service.

    Args:
        owner: the service, whose table of verbs every action calls (so a print is everyone's).
        farm_printer: the printer it speaks for.
        uploads: where uploaded files are kept.
        api_key: the key every request must carry (or one the owner approved).

    Raises:
        ValueError: the key is shorter than 16 characters.
    """

    def __init__(self, owner: Owner, farm_printer: FarmPrinter, uploads: Uploads, api_key: str) -> None:
        if len(api_key) < 16:
            raise ValueError("the API key must be at least 16 characters")
        super().__init__(owner, farm_printer, uploads)
        self._key = api_key.encode()
        # `//api/...` (a base URL with a trailing slash, as pyoctoprintapi builds some) is redirected, method kept.
        slashes = web.normalize_path_middleware(
            append_slash=False, merge_slashes=True, redirect_class=web.HTTPPermanentRedirect
        )
        # client_max_size bounds the JSON bodies; an upload is streamed part by part, each with its own bound.
        self.app = web.Application(middlewares=[slashes, self._auth], client_max_size=MAX_JSON_BYTES)
        for part in (ServerRoutes(self), PrinterRoutes(self), FileRoutes(self), AppKeyRoutes(self)):
            self.app.add_routes(part.routes())

    @web.middleware
    async def _auth(self, request: web.Request, handler: Any) -> web.StreamResponse:
        given = (request.headers.get("X-Api-Key") or request.query.get("apikey") or "").encode(errors="surrogatepass")
        # The app-key flow is how an app without a key gets one: open, as OctoPrint's plugin is.
        if not request.path.startswith(PREFIX):
            own = hmac.compare_digest(given, self._key)
            if not (own | self.owner.app_keys.valid(given)):  # both compared, whichever matches
                return error(403, "Invalid API key")
        try:
            response: web.StreamResponse = await handler(request)
        except marlin_aio.MarlinError as exc:
            return error(409, str(exc))
        except web.HTTPException:
            raise
        except Exception as exc:  # a bug of ours: the client gets a 500, the log one line, never a traceback
            _log.error("%s %s failed: %s", request.method, request.path[:200], one_line(exc, self._key.decode()))
            return error(500, "Internal error")
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
