"""The verbs of the print job: a file sent in pieces, the job started, paused, resumed, cancelled, and read.

There is one job per printer (`marlin_aio.farm.job.Job`), held by the farm and changed only through these verbs,
whichever door calls them: a print started with `marlin-temp print --port serve:NAME` is the same job `/api/job`,
MQTT's state and `watch --port serve:NAME` show, and a cancel from any of them runs the job's one cancel script.
"""

from __future__ import annotations

import asyncio
import os
import stat
from pathlib import Path
from typing import Any

from marlin_aio.farm.job import Job
from marlin_aio.farm.supervisor import FarmPrinter
from marlin_aio.protocol.rpc import INVALID_PARAMS, RpcError, progress_to_json
from marlin_aio.service.verbs.printer import MAX_TIMEOUT_S, connected
from marlin_aio.service.verbs.table import REQUIRED, SOCKETS, SOCKETS_AND_HTTP, Access, Arg, Context, Owner, Queue, verb

__all__ = ["check_printable", "start_job"]


def _job_json(job: Job | None) -> dict[str, Any] | None:
    return None if job is None else job.to_json()


def _refuse_if_busy(farm_printer: FarmPrinter) -> None:
    job = farm_printer.job
    if job is not None and job.active:
        raise RuntimeError(f"a print is already running: {job.describe()}; cancel it first")


def check_printable(owner: Owner, path: Path, files: str) -> None:
    """Refuse what a print cannot be read from: not an absolute path, not a regular file (a FIFO would block the
    service's reader for ever, `/dev/zero` would fill its memory), or for a caller on another machine anything but
    a finished upload of the service's.

    Raises:
        RpcError: INVALID_PARAMS for a relative path.
        PermissionError: a caller that may print only uploads named another file.
        FileNotFoundError, ValueError: no such file, or not a regular file.
    """
    if not path.is_absolute():
        raise RpcError(INVALID_PARAMS, f"the service needs an absolute path, got {str(path)[:200]!r}")
    if files == "uploads" and not owner.uploads.is_finished(path):
        # A path means a file on this machine: a client elsewhere prints a finished upload (never a `.part`).
        raise PermissionError("over TCP a print is a file uploaded first (the client's start_print does that)")
    try:
        info = os.stat(path)  # stat, not open: opening a FIFO would wait for a writer
    except FileNotFoundError:
        raise FileNotFoundError(f"no such file: {path}") from None
    except ValueError:  # a NUL in the path
        raise ValueError("not a file name (it holds a NUL)") from None
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"{path} is not a regular file (a FIFO, a device or a folder): the service prints files")


async def start_job(
    context: Context, path: Path, name: str | None, options: dict[str, Any], *, keep_file: bool = True
) -> Job:
    """Start the job of `path` on the context's printer for its caller: the one way every door starts a print.

    Raises:
        RuntimeError: a job is running there already (named), or the printer is not connected.
        ValueError, OSError, MarlinError: as `Farm.start_print`.
    """
    farm_printer = context.farm_printer
    owner = context.owner
    check_printable(owner, path, context.caller.files)
    connected(farm_printer)  # the farm refuses a busy printer (naming its job) before its first await
    given = owner.sent_files.get(path)
    start = owner.farm.start_print(
        farm_printer,
        path,
        name=name or given or path.name,
        started_by=context.caller.who,
        remove_file=given is not None and not keep_file,
        **options,
    )
    # In a task of the service's, not the caller's: a client that leaves while its print is starting leaves the
    # start to finish (or fail) whole, never half-done.
    job = await asyncio.shield(asyncio.ensure_future(start))
    owner.sent_files.pop(path, None)
    owner.tell_progress(farm_printer)
    return job


@verb(
    "upload",
    Arg("lines", list, [], "lines of the file (a piece)"),
    Arg("upload_id", str, None, "the upload to add to (none: a new one)"),
    Arg("done", bool, False, "the last piece: the file is made"),
    Arg("name", str, "upload.gcode", "the file's name as the client knows it"),
    Arg("printer", str, None, "the printer it is for: refused at once while a print runs there"),
    access=Access.CONTROL,
    doors=SOCKETS,
    result="{upload_id} or {path}",
    on_printer=False,
)
async def upload(context: Context, args: dict[str, Any]) -> object:
    """Send a print as lines, in pieces; the last piece makes the file, removed once its print ends unless kept."""
    owner = context.owner
    if args["printer"] is not None:
        from marlin_aio.service.verbs.table import printer_of

        _refuse_if_busy(printer_of(owner, args["printer"]))  # before a byte is stored: a refused print costs nothing
    upload_id = args["upload_id"]
    subscriber = context.caller.subscriber
    if upload_id is None:
        upload_id = owner.uploads.begin()
        if subscriber is not None:
            subscriber.uploads.add(upload_id)  # dropped if the client leaves before its last piece
    owner.uploads.append(upload_id, args["lines"])
    if not args["done"]:
        return {"upload_id": upload_id}
    if subscriber is not None:
        subscriber.uploads.discard(upload_id)
    path = owner.uploads.finish(upload_id, args["name"])
    owner.sent_files[path] = args["name"]
    return {"path": str(path)}


@verb(
    "start_print",
    Arg("path", str, REQUIRED, "the file, an absolute path on the service's machine (or an upload's)"),
    Arg("name", str, None, "the file's name for people (default: the upload's, or the path's)"),
    Arg("send_ahead", bool, False, "several lines in flight"),
    Arg("window_bytes", int, None, "unanswered bytes at most with send_ahead"),
    Arg("timeout_s", float, None, "how long a line may wait for its ok"),
    Arg("stop_on_unknown", bool, False, "stop at a command the firmware does not know (default: warn and go on)"),
    Arg("check", bool, True, "ignored: the service always checks the whole file before the first line"),
    Arg("keep_file", bool, False, "keep an uploaded copy once the job ends"),
    Arg("cancel_script", list, None, "commands a cancel runs (default: every heater and the fan off)"),
    Arg("end_script", list, None, "commands run after the print ended by itself (default: none)"),
    access=Access.CONTROL,
    result="{file, progress, job}",
)
async def start_print(context: Context, args: dict[str, Any]) -> object:
    """Start the printer's print job from a file; it runs in the service, whoever started it and whatever door."""
    timeout_s = args["timeout_s"]
    if timeout_s is not None and not 0 < timeout_s <= MAX_TIMEOUT_S:
        raise RpcError(INVALID_PARAMS, f"timeout_s must be above 0 and at most {MAX_TIMEOUT_S:g} s")
    options: dict[str, Any] = {
        "send_ahead": args["send_ahead"],
        "timeout_s": timeout_s,
        "stop_on_unknown": args["stop_on_unknown"],
    }
    if args["window_bytes"] is not None:
        options["window_bytes"] = args["window_bytes"]
    for script in ("cancel_script", "end_script"):
        if args[script] is not None:
            options[script] = tuple(args[script])
    job = await start_job(context, Path(args["path"]), args["name"], options, keep_file=args["keep_file"])
    assert job.handle is not None
    return {"file": job.file, "progress": progress_to_json(job.handle.progress), "job": job.to_json()}


@verb("job", access=Access.READ, doors=SOCKETS_AND_HTTP, result="job or null")
async def job(context: Context, args: dict[str, Any]) -> object:
    """The printer's job: the one running, or the last one, with its state, progress and resume line."""
    return _job_json(context.farm_printer.job)


@verb("pause", access=Access.CONTROL, queue=Queue.URGENT, result="job")
async def pause(context: Context, args: dict[str, Any]) -> object:
    """Stop feeding the job's lines (what is in flight completes; heaters stay as they are)."""
    job = context.owner.farm.pause_print(context.farm_printer)
    context.owner.tell_progress(context.farm_printer)
    return job.to_json()


@verb("resume", access=Access.CONTROL, queue=Queue.URGENT, result="job")
async def resume(context: Context, args: dict[str, Any]) -> object:
    """Feed the job's lines again."""
    job = context.owner.farm.resume_print(context.farm_printer)
    context.owner.tell_progress(context.farm_printer)
    return job.to_json()


@verb("restart", access=Access.CONTROL, result="job (the new one)")
async def restart(context: Context, args: dict[str, Any]) -> object:
    """Print a paused job's file again from its first line: the paused job ends without its cancel script (the
    heaters stay on) and a new one starts with the same file and options."""
    restart = context.owner.farm.restart_print(context.farm_printer, context.caller.who)
    # In a task of the service's, as `start_job`: a client that leaves mid-restart never leaves it half-done.
    job = await asyncio.shield(asyncio.ensure_future(restart))
    context.owner.tell_progress(context.farm_printer)
    return job.to_json()


@verb(
    "cancel",
    Arg("script", list, None, "commands to run instead of the job's cancel script ([]: none)"),
    access=Access.CONTROL,
    queue=Queue.URGENT,
    result="job (ended)",
)
async def cancel(context: Context, args: dict[str, Any]) -> object:
    """Cancel the job: stop feeding, wait for what is in flight, run its cancel script once (by default every
    heater and the fan off, from every door), and return it ended."""
    farm_printer = context.farm_printer
    script = args["script"]
    running = farm_printer.job
    if script is not None and running is not None and running.active and running.cancel_task is None:
        running.cancel_script = tuple(script)
    job = await context.owner.farm.cancel_print(farm_printer, context.caller.who)
    context.owner.tell_progress(farm_printer)
    value = job.to_json()
    # The shape older clients read (`PrintProgress`'s fields at the top) beside the job's.
    return (value["progress"] or {}) | {"job": value}
