"""A print that runs inside `marlin-temp serve`, as the client that started it follows it (`ServedPrintHandle`)."""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Generator, Iterable, Iterator
from pathlib import Path
from typing import Any, Protocol

from marlin_aio.aio.printhandle import PrintHandle
from marlin_aio.errors import ConnectionLostError, MarlinError
from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.protocol.printjob import PrintProgress, PrintState, gcode_commands
from marlin_aio.protocol.rpc import RpcError, error_from_json, progress_from_json

__all__ = [
    "UPLOAD_PIECE_BYTES",
    "ServedPrintHandle",
    "ServedPrinterLike",
    "absolute",
    "check_file",
    "file_lines",
    "upload",
]

#: How much of a print sent as lines goes in one request (well inside the message limit).
UPLOAD_PIECE_BYTES = 256 * 1024


class ServedPrinterLike(Protocol):
    """What a served print needs of its printer: a request for its printer, awaited or written at once."""

    async def call(self, method: str, **params: Any) -> Any:
        """Send `method` for this printer and return its result."""

    def call_soon(self, method: str) -> None:
        """Write `method` for this printer now, not waiting for its answer."""


class ServedPrintHandle(PrintHandle):
    """A print running inside the service, as its starter follows it: progress from the service's notifications,
    `pause`, `resume` and `cancel` as requests. Leaving (closing the printer) does not stop the print."""

    def __init__(self, printer: ServedPrinterLike, progress: PrintProgress, file: str) -> None:
        # Not PrintHandle's link-bound state: the job and its link live in the service.
        self._printer = printer
        self._progress = progress
        self.file = file
        loop = asyncio.get_running_loop()
        self._done: asyncio.Future[PrintProgress] = loop.create_future()

    @property
    def progress(self) -> PrintProgress:
        """The progress the service last told (it tells every half second while the print runs, and at once on
        a change of state)."""
        return self._progress

    @property
    def finished(self) -> bool:
        """True once the service said the print ended."""
        return self._done.done()

    def update(self, params: dict[str, Any]) -> None:
        """Take a progress notification from the service."""
        with contextlib.suppress(RpcError):
            self._progress = progress_from_json(params.get("progress"))
        if self._done.done():
            return
        if self._progress.state is PrintState.FAILED:
            self._done.set_exception(error_from_json(params.get("error") or {"message": "the print failed"}))
            self._done.exception()  # a print nobody awaits must not log "exception never retrieved"
        elif self._progress.state in (PrintState.DONE, PrintState.CANCELLED):
            self._done.set_result(self._progress)

    def orphaned(self, error: MarlinError) -> None:
        """The connection to the service ended. Closed by this client, the print goes on there; else the service
        went away (stopped, killed, or stuck), and with it, most likely, the print: the error says how far it may
        have run, from the last bound the service told (it sends no line past it before telling the next one)."""
        if self._done.done():
            return
        if str(error).endswith(" was closed"):  # this client's own close (`RpcClient.aclose`)
            message = f"{error} (the print goes on in the service: `marlin-temp serve` shows it)"
        else:
            progress = self._progress
            surely = progress.last_source_line
            may = max(progress.may_have_run_through or 0, surely)
            message = f"{error}: the service went away during the print of {self.file}; line {surely} surely ran"
            if may > surely:
                message += f", lines up to {may} may have run"
            message += f": resume from line {may + 1}"
        self._done.set_exception(ConnectionLostError(message))
        self._done.exception()

    def pause(self) -> None:
        """Ask the service to stop feeding lines (what is in flight completes)."""
        self._ask("pause")

    def resume(self) -> None:
        """Ask the service to feed lines again."""
        self._ask("resume")

    def _ask(self, method: str) -> None:
        self._printer.call_soon(method)

    async def cancel(self, script: list[str] | tuple[str, ...] | None = None) -> PrintProgress:
        """Have the service cancel the print (stop feeding, wait for the lines in flight), then run the job's cancel
        script, as every door's cancel does: by default every heater and the fan off. `script` replaces it for this
        cancel (`()`: none, the heaters left as they are).

        Raises:
            MarlinError: the print failed before it could be cancelled, or the script failed.
        """
        await self._printer.call("cancel", **({} if script is None else {"script": list(script)}))
        return await self.wait()

    async def wait(self) -> PrintProgress:
        """Wait for the print to end in the service; return its final progress.

        Raises:
            MarlinError: as `PrintHandle.wait`; ConnectionLostError if the service went away meanwhile.
        """
        return await asyncio.shield(self._done)

    def __await__(self) -> Generator[object, None, PrintProgress]:
        return self.wait().__await__()

    def check(self) -> None:
        """Nothing to do: the service tells when the print ends."""


async def upload(printer: ServedPrinterLike, lines: Iterable[str], name: str = "upload.gcode") -> str:
    """Send `lines` to the service in pieces of at most `UPLOAD_PIECE_BYTES`; return the file it made of them.
    (A list or an iterator of any length: the service keeps the print, so it must have all of it.)"""
    upload_id: str | None = None
    piece: list[str] = []
    size = 0

    async def send(done: bool) -> Any:
        nonlocal upload_id, piece, size
        params: dict[str, Any] = {"lines": piece, "done": done, "name": name}
        if upload_id is not None:
            params["upload_id"] = upload_id
        result = await printer.call("upload", **params)
        piece, size = [], 0
        upload_id = result.get("upload_id", upload_id)
        return result

    for line in lines:
        piece.append(str(line))
        size += len(line) + 8
        if size >= UPLOAD_PIECE_BYTES:
            await send(False)
    return str((await send(True))["path"])


def check_file(path: str, limits: HeaterLimits) -> None:
    """Check every command of the file as a print checks it.

    Raises:
        ValueError: a line is not a valid command or is over `limits` (the message names it).
        OSError: the file cannot be read.
    """
    for _ in gcode_commands(file_lines(path), limits):
        pass


def file_lines(path: str) -> Iterator[str]:
    """The lines of the file at `path`, read as they are asked for (so a file of any size uploads in pieces)."""
    with open(path, encoding="utf-8", errors="surrogateescape") as handle:
        for line in handle:
            yield line.rstrip("\r\n")


def absolute(path: str | Path) -> str:
    """`path` made absolute against this process's working folder (no file is touched)."""
    return os.path.abspath(path)
