"""What every resource of the OctoPrint door shares: the printer it speaks for, the verbs it calls, and the shapes
of its answers and refusals."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aiohttp import web

import marlin_aio
from marlin_aio.farm.job import JobState
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.protocol.rpc import RpcError
from marlin_aio.service import verbs
from marlin_aio.service.uploads import Uploads
from marlin_aio.service.verbs import Caller, Owner

__all__ = ["Door", "error", "json_body", "motion", "resource"]

#: OctoPrint's words for the states of a job that holds the printer.
_STATES = {
    JobState.STARTING: "Starting",
    JobState.PRINTING: "Printing",
    JobState.PAUSED: "Paused",
    JobState.CANCELLING: "Cancelling",
}


class Door:
    """The HTTP door of one printer: the service behind it, the printer, its uploads and the file selected.

    Args:
        owner: the service, whose table of verbs every action calls (so a print is everyone's).
        farm_printer: the printer it speaks for.
        uploads: where uploaded files are kept.
    """

    def __init__(self, owner: Owner, farm_printer: FarmPrinter, uploads: Uploads) -> None:
        self.owner = owner
        self.farm_printer = farm_printer
        self.uploads = uploads
        self.selected: Path | None = None
        """The file `select` chose (OctoPrint's job is its selected file until a print runs)."""
        # A stable id per service and printer (Home Assistant's device id): from where the service listens.
        self.uuid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"marlin-temp:{owner.socket_path}:{farm_printer.name}"))

    def operational(self) -> marlin_aio.Printer:
        """The printer, if its link is up.

        Raises:
            web.HTTPConflict: it is not (OctoPrint's 409 "Printer is not operational").
        """
        printer = self.farm_printer.printer
        if printer is None or not self.farm_printer.link_up:
            raise web.HTTPConflict(text="Printer is not operational")
        return printer

    def state_text(self) -> str:
        """OctoPrint's name for where the printer stands: Offline, Operational, Printing, Paused, ..."""
        if not self.farm_printer.link_up:
            return "Offline" if self.farm_printer.last_error is None else "Offline after error"
        job = self.farm_printer.job
        if job is not None and job.active:
            return _STATES[job.state]
        return "Operational"

    def check_idle(self, what: str) -> None:
        """Refuse (409) `what` while a print holds the printer."""
        job = self.farm_printer.job
        if job is not None and job.active:
            raise web.HTTPConflict(text=f"cannot {what} while printing: {job.describe()}")

    def check_can_start(self) -> None:
        """Refuse (409) a print that cannot start, before anything is kept for it."""
        job = self.farm_printer.job
        if job is not None and job.active:
            raise web.HTTPConflict(text=f"a print is already running: {job.describe()}; cancel it first")
        self.operational()

    async def verb(self, name: str, **params: Any) -> Any:
        """Call the service's verb `name` on this printer, as the HTTP door: its refusals as OctoPrint's statuses
        (a bad argument 400, a state that does not allow it 409)."""
        caller = Caller("http", "octoprint")
        try:
            return await verbs.call(self.owner, name, {"printer": self.farm_printer.name, **params}, caller)
        except (RpcError, ValueError) as exc:
            raise web.HTTPBadRequest(text=str(exc)) from None
        except (RuntimeError, FileNotFoundError, PermissionError, marlin_aio.MarlinError) as exc:
            raise web.HTTPConflict(text=str(exc)) from None

    async def send_all(self, commands: list[str]) -> None:
        """Send each command in turn through the `send` verb (the limits every door checks; the first refused
        stops the rest)."""
        for command in commands:
            await self.verb("send", command=command)


async def json_body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object (400 if it is not one)."""
    try:
        body = await request.json()
    except ValueError:
        raise web.HTTPBadRequest(text="the body is not JSON") from None
    if not isinstance(body, dict):
        raise web.HTTPBadRequest(text="the body is a JSON object")
    return body


def error(status: int, message: str) -> web.Response:
    """A refusal in OctoPrint's shape: `{"error": message}` with `status`."""
    return web.json_response({"error": message}, status=status)


def resource(request: web.Request, path: str) -> str:
    """The absolute URL of `path` as the client reached the service (OctoPrint's refs are absolute)."""
    return str(request.url.with_path(path).with_query(None))


def motion(build: Callable[[], list[str]]) -> list[str]:
    """The commands `build` makes, its ValueError (a distance or speed out of bounds) as a 400."""
    try:
        return build()
    except (TypeError, ValueError) as exc:
        raise web.HTTPBadRequest(text=str(exc)) from None
