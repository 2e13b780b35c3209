"""The files and the job: uploads (with `select` and `print`, as slicers send them), the file commands (select,
copy, move), a file's info and removal, and the job read and steered (start, pause, resume, restart, cancel).

Every part of an upload is bounded (`httpbounds`): its headers, its fields, its file (a size bound and the uploads
folder's quota, checked before a byte is written when the length is told, and as it streams). An upload with
`print=true` is refused (409) before anything is kept when the print cannot start (another one running, the
printer offline). A copy is held to the same quota.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from aiohttp import web

import marlin_aio
from marlin_aio.protocol.rpc import progress_from_json
from marlin_aio.service.httpbounds import check_length, read_upload_form, upload_errors
from marlin_aio.service.octoprint.common import Door, json_body, resource
from marlin_aio.service.uploads import UploadTypeError, check_name

__all__ = ["FileRoutes"]


class FileRoutes:
    """The files and the job of one door."""

    def __init__(self, door: Door) -> None:
        self.door = door

    def routes(self) -> list[web.RouteDef]:
        """Its routes."""
        return [
            web.get("/api/files", self.files),
            web.get("/api/files/local", self.files),
            web.post("/api/files/local", self.upload),
            web.post("/api/files/local/{name}", self.file_command),
            web.get("/api/files/local/{name}", self.file_info),
            web.delete("/api/files/local/{name}", self.file_delete),
            web.get("/api/job", self.job),
            web.post("/api/job", self.job_command),
        ]

    # ------------------------------------------------------------------------------------------- files

    async def files(self, request: web.Request) -> web.Response:
        """`GET /api/files`: the uploaded files, and the disk's free and total bytes."""
        folder = self.door.uploads.folder
        entries = sorted(folder.glob("*.gcode")) if folder.is_dir() else []
        files = [_file_ref(request, path) for path in entries]
        usage = shutil.disk_usage(folder if folder.is_dir() else folder.parent)
        return web.json_response({"files": files, "free": usage.free, "total": usage.total})

    def _uploaded(self, request: web.Request) -> Path:
        """The uploaded file `/api/files/local/NAME` names (404 if there is none)."""
        name = request.match_info["name"]
        uploads = self.door.uploads
        with upload_errors(uploads, request):
            check_name(name)
        path = uploads.folder / name
        if not uploads.is_finished(path):
            raise web.HTTPNotFound(text=f"no uploaded file {name[:100]!r}")
        return path

    def _printing(self, path: Path) -> bool:
        job = self.door.farm_printer.job
        return job is not None and job.active and job.path == path

    async def file_info(self, request: web.Request) -> web.Response:
        """`GET /api/files/local/NAME`: one uploaded file (404 if there is none)."""
        return web.json_response(_file_ref(request, self._uploaded(request)))

    async def file_delete(self, request: web.Request) -> web.Response:
        """`DELETE /api/files/local/NAME`: remove an uploaded file (409 while it is being printed)."""
        path = self._uploaded(request)
        if self._printing(path):
            raise web.HTTPConflict(text=f"{path.name} is being printed")
        path.unlink(missing_ok=True)
        if self.door.selected == path:
            self.door.selected = None
        return web.Response(status=204)

    async def upload(self, request: web.Request) -> web.Response:
        """`POST /api/files/local` (multipart: `file`, and `select`/`print` as `true`): keep the file and, with
        print, start it at once, as slicers' "upload and print" does. Nothing is kept when the upload is refused:
        over a bound (413), not text or not a well-formed form (400), or its print cannot start (409)."""
        if not request.content_type.startswith("multipart/"):
            raise web.HTTPBadRequest(text="upload a file as multipart/form-data")
        door = self.door
        check_length(request, door.uploads)

        def before_file(fields: dict[str, str]) -> None:
            if fields.get("print", "").lower() == "true":
                door.check_can_start()  # before a byte of the file is written

        upload_id: str | None = None
        try:
            with upload_errors(door.uploads, request):
                form = await read_upload_form(request, door.uploads, ("select", "print"), before_file)
                upload_id = form.upload_id
                select = form.fields.get("select", "false").lower() == "true"
                start = form.fields.get("print", "false").lower() == "true"
                if start:
                    door.check_can_start()  # again: the file may have come before the print field
                stored = door.uploads.finish(upload_id, form.name)
        finally:
            if upload_id is not None:
                door.uploads.discard(upload_id)  # nothing if finished
        if select or start:
            door.selected = stored
        if start:
            try:
                await door.verb("start_print", path=str(stored))
            except (web.HTTPException, marlin_aio.MarlinError):
                stored.unlink(missing_ok=True)  # another print won the race: refused, so nothing kept
                if door.selected == stored:
                    door.selected = None
                raise
        files = {"local": _file_ref(request, stored)}
        answer = {"files": files, "done": True, "effectiveSelect": select, "effectivePrint": start}
        return web.json_response(answer, status=201, headers={"Location": _resource(request, stored)})

    async def file_command(self, request: web.Request) -> web.Response:
        """`POST /api/files/local/NAME`: `select` (`"print": true` starts it; 409 while a print runs), `copy` and
        `move` (`"destination": "other.gcode"`: 201; 409 if it exists, 415 if it is no G-code file's name; a copy
        within the uploads' quota, 413; a file being printed is not moved, 409), `slice` (404: no slicer)."""
        body = await json_body(request)
        command = body.get("command")
        if command == "slice":
            raise web.HTTPNotFound(text="no slicer: the service slices nothing (slice, then upload the G-code)")
        path = self._uploaded(request)
        if command == "select":
            self.door.check_idle("select a file")  # OctoPrint's 409: the job is the print running
            if body.get("print"):
                self.door.check_can_start()
            self.door.selected = path
            if body.get("print"):
                await self.door.verb("start_print", path=str(path))
            return web.Response(status=204)
        if command in ("copy", "move"):
            return await self._copy_or_move(request, path, command, body.get("destination"))
        raise web.HTTPBadRequest(text=f"unknown file command {str(command)[:20]!r}: select, copy or move")

    async def _copy_or_move(self, request: web.Request, path: Path, command: str, destination: object) -> web.Response:
        if not isinstance(destination, str) or not destination:
            raise web.HTTPBadRequest(text=f'{command} needs "destination": a file name')
        if command == "move" and self._printing(path):
            raise web.HTTPConflict(text=f"{path.name} is being printed")
        uploads = self.door.uploads
        try:
            with upload_errors(uploads, request):  # a copy past the quota 413, a name that is no file's 400
                try:
                    made = uploads.copy(path, destination) if command == "copy" else uploads.move(path, destination)
                except UploadTypeError as exc:  # OctoPrint's "invalid type" (before it is read as an UploadError)
                    raise web.HTTPUnsupportedMediaType(text=str(exc)) from None
        except FileExistsError as exc:
            raise web.HTTPConflict(text=str(exc)) from None
        except FileNotFoundError as exc:
            raise web.HTTPNotFound(text=str(exc)) from None
        if command == "move" and self.door.selected == path:
            self.door.selected = made
        ref = _file_ref(request, made)
        return web.json_response(ref, status=201, headers={"Location": ref["refs"]["resource"]})

    # ------------------------------------------------------------------------------------------- the job

    async def job(self, request: web.Request) -> web.Response:
        """`GET /api/job`: the printer's job (running or last run; or the file selected), and its progress."""
        door = self.door
        job = await door.verb("job")
        # The file selected names the job until a print runs (OctoPrint's job is its selected file); a print
        # running names it, whoever started it.
        selected = None if door.selected is None else door.selected.name
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
        return web.json_response({"job": value, "progress": progress, "state": door.state_text()})

    async def job_command(self, request: web.Request) -> web.Response:
        """`POST /api/job`: start (the selected file), cancel, pause (`action` pause, resume or toggle), restart (a
        paused print from its first line); each the service's verb of that name, as from every door."""
        door = self.door
        body = await json_body(request)
        command = body.get("command")
        handle = door.farm_printer.print_handle
        if command == "start":
            if door.selected is None:
                raise web.HTTPConflict(text="no file is selected")
            await door.verb("start_print", path=str(door.selected))
        elif command == "restart":
            await door.verb("restart")
        elif command == "cancel":
            # The job's one cancel script (heaters and fan off by default), as from every door.
            await door.verb("cancel")
        elif command == "pause":
            action = body.get("action", "toggle")
            paused = handle is not None and handle.progress.state is marlin_aio.PrintState.PAUSED
            if action == "pause" or (action == "toggle" and not paused):
                await door.verb("pause")
            elif action in ("resume", "toggle"):
                await door.verb("resume")
            else:
                raise web.HTTPBadRequest(text=f"unknown pause action {str(action)[:20]!r}")
        else:
            raise web.HTTPBadRequest(text=f"unknown job command {str(command)[:20]!r}")
        return web.Response(status=204)


def _resource(request: web.Request, path: Path) -> str:
    """The absolute URL of an uploaded file, as the client reached the service (Cura reads the upload's
    `Location` and splits it at `api/`)."""
    return resource(request, f"/api/files/local/{path.name}")


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
            "download": resource(request, f"/downloads/files/local/{path.name}"),
        },
    }
