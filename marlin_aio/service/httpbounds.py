"""The bounds of the service's HTTP door (the OctoPrint-shaped API): how much of a request it reads, what it keeps of
an upload that breaks a bound, and how a bad request is logged.

- A request line and each header at most 8 KiB, 64 headers (aiohttp's parser, its limits set here on purpose); a
  JSON body at most 64 KiB.
- An upload is a multipart form read part by part: a small field at most 4 KiB (read in one bounded piece, never
  whole), 16 parts, one file streamed into `Uploads` (its size bound and the folder's quota checked as it comes).
  A body whose Content-Length shows it is over a bound is refused (413) before a byte is written; one that grows
  past it while streaming is refused with its partial file removed. A name with a control character is a 400.
- aiohttp logs each malformed request with a traceback and the header it could not parse, which may hold the API
  key; here each is one short line with no secret, at most 10 every 10 s, then one line for those left out.
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import unquote

from aiohttp import BodyPartReader, web
from aiohttp.http_exceptions import HttpProcessingError

from marlin_aio.service.uploads import UploadError, Uploads, UploadTooLargeError, check_name

__all__ = [
    "FORM_SLACK_BYTES",
    "MAX_FIELD_BYTES",
    "MAX_FORM_FIELD_BYTES",
    "MAX_FORM_PARTS",
    "MAX_HEADERS",
    "MAX_JSON_BYTES",
    "MAX_LINE_BYTES",
    "UploadForm",
    "bounded_runner",
    "check_length",
    "one_line",
    "read_upload_form",
    "upload_errors",
]

#: The request line (path and query) and one header: aiohttp's own defaults, written down as a choice.
MAX_LINE_BYTES = 8190
MAX_FIELD_BYTES = 8190
MAX_HEADERS = 64
#: A JSON body (heater targets, job commands) is tens of bytes.
MAX_JSON_BYTES = 64 * 1024
#: A form field beside the file (`select`, `print`, `path`) is a word; the parts of a form a handful.
MAX_FORM_FIELD_BYTES = 4096
MAX_FORM_PARTS = 16
#: What an upload's body may hold besides its file (boundaries, part headers, the small fields): a body longer than
#: the upload bound by more than this is refused before it is read.
FORM_SLACK_BYTES = 64 * 1024
#: At most this many malformed-request lines a window: a client sending garbage in a loop cannot fill the log.
_LOG_BURST = 10
_LOG_WINDOW_S = 10.0


def bounded_runner(app: web.Application, logger: logging.Logger, secret: str) -> web.AppRunner:
    """A runner for `app` with the header bounds set and its bad requests logged by `OneLineLog` (never `secret`)."""
    return web.AppRunner(
        app,
        access_log=None,
        logger=_OneLineLog(logger, secret),
        max_line_size=MAX_LINE_BYTES,
        max_field_size=MAX_FIELD_BYTES,
        max_headers=MAX_HEADERS,
    )


def check_length(request: web.Request, uploads: Uploads) -> None:
    """Refuse an upload whose Content-Length shows it is over the bound or past the quota, before reading it.

    Raises:
        web.HTTPRequestEntityTooLarge: it is.
    """
    if request.content_length is not None:
        with upload_errors(uploads, request):
            uploads.check_room(max(0, request.content_length - FORM_SLACK_BYTES))


@contextlib.contextmanager
def upload_errors(uploads: Uploads, request: web.Request) -> Iterator[None]:
    """An upload's refusals as HTTP answers: over a bound 413; not text, a bad name or a malformed form 400.

    Raises:
        web.HTTPRequestEntityTooLarge: over a bound.
        web.HTTPBadRequest: not text, a bad name, or not a well-formed multipart form.
    """
    try:
        yield
    except UploadTooLargeError as exc:
        actual = request.content_length or 0
        raise web.HTTPRequestEntityTooLarge(max_size=uploads.max_bytes, actual_size=actual, text=str(exc)) from None
    except UploadError as exc:
        raise web.HTTPBadRequest(text=str(exc)) from None
    except (HttpProcessingError, ValueError) as exc:  # aiohttp's multipart reader: not the form it claims to be
        raise web.HTTPBadRequest(text=f"not a well-formed multipart form ({one_line(exc, '')})") from None


@dataclass(frozen=True)
class UploadForm:
    """An upload's form as read: its small fields wanted, its file as an upload under way, the file's name as given."""

    fields: dict[str, str]
    upload_id: str
    name: str


async def read_upload_form(
    request: web.Request, uploads: Uploads, wanted: tuple[str, ...], before_file: Callable[[dict[str, str]], None]
) -> UploadForm:
    """Read an upload's multipart form within its bounds: the `wanted` small fields (others read, bounded, and
    dropped) and one `file`, streamed into `uploads`; `before_file` sees the fields read so far and may refuse
    before a byte of the file is written. The caller finishes or discards the upload.

    Raises:
        web.HTTPBadRequest: no file, two, a nested form, too many parts, or a field over its bound.
        UploadError: the file's name holds a control character, or the file is not text or over a bound (its
            partial file removed); ValueError or HttpProcessingError: a malformed form (see `upload_errors`).
    """
    reader = await request.multipart()
    fields: dict[str, str] = {}
    file: tuple[str, str] | None = None
    try:
        for _ in range(MAX_FORM_PARTS):
            part = await reader.next()
            if part is None:
                break
            if not isinstance(part, BodyPartReader):
                raise web.HTTPBadRequest(text="a form inside the form is not taken")
            if part.name == "file":
                if file is not None:
                    raise web.HTTPBadRequest(text="one file per upload")
                # Some clients percent-encode the name (RFC 5987 style): decoded, then made safe all the same.
                name = check_name(unquote(part.filename or "upload.gcode"))
                before_file(fields)
                file = (await _receive(part, uploads), name)
            else:
                value = await _read_field(part)
                if part.name in wanted:
                    fields[part.name] = value
        else:
            if await reader.next() is not None:
                raise web.HTTPBadRequest(text=f"a form of more than {MAX_FORM_PARTS} parts")
    except BaseException:
        if file is not None:
            uploads.discard(file[0])
        raise
    if file is None:
        raise web.HTTPBadRequest(text="no file in the upload")
    return UploadForm(fields, *file)


async def _receive(part: BodyPartReader, uploads: Uploads) -> str:
    upload_id = uploads.begin()
    try:
        while chunk := await part.read_chunk(65536):
            uploads.append_bytes(upload_id, chunk)
    except BaseException:
        uploads.discard(upload_id)
        raise
    return upload_id


async def _read_field(part: BodyPartReader) -> str:
    """A small form field's text, read in one bounded piece: a huge field is refused, never held whole."""
    data = bytearray()
    while len(data) <= MAX_FORM_FIELD_BYTES and (chunk := await part.read_chunk(MAX_FORM_FIELD_BYTES + 1)):
        data += chunk
    if len(data) > MAX_FORM_FIELD_BYTES:
        raise web.HTTPBadRequest(text=f"the form field {str(part.name)[:40]!r} is over {MAX_FORM_FIELD_BYTES} bytes")
    return data.decode("utf-8", errors="replace")


_UNPRINTABLE = re.compile(r"[^\x20-\x7e]+")


def one_line(exc: BaseException, secret: str) -> str:
    """`exc` as one short printable line without `secret`: its kind and the first line of its message (aiohttp's
    parser errors go on to quote the offending request bytes, which may hold the API key)."""
    message = exc.message if isinstance(exc, HttpProcessingError) else str(exc)
    first = _printable(str(message).strip().split("\n", 1)[0].strip().rstrip(":"), secret)
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def _printable(text: str, secret: str) -> str:
    """`text` without `secret`, control characters or anything past 100 characters."""
    if secret:
        text = text.replace(secret, "<key>")
    return _UNPRINTABLE.sub("?", text)[:100]


class _OneLineLog(logging.LoggerAdapter):  # type: ignore[type-arg]  # generic only in typeshed, not at run time
    """aiohttp's server log as the service wants it: each bad request one short line with no secret, at most
    `_LOG_BURST` lines a `_LOG_WINDOW_S`, then one line for what was left out."""

    def __init__(self, logger: logging.Logger, secret: str) -> None:
        super().__init__(logger, {})
        self._secret = secret
        self._window_start_s = -math.inf
        self._in_window = 0
        self._left_out = 0

    def log(self, level: int, msg: object, *args: object, **kwargs: Any) -> None:
        """Log one line for what aiohttp reports (its traceback dropped), within the window's share."""
        if not self.isEnabledFor(level):
            return
        text = str(msg)
        with contextlib.suppress(TypeError, ValueError):
            text = text % args
        text = _printable(text, self._secret)
        exc = kwargs.get("exc_info")
        if isinstance(exc, BaseException):
            text = f"{text}: {one_line(exc, self._secret)}"
        now = time.monotonic()
        if now - self._window_start_s >= _LOG_WINDOW_S:
            if self._left_out:
                self.logger.warning("OctoPrint API: %d more bad requests were not logged", self._left_out)
            self._window_start_s, self._in_window, self._left_out = now, 0, 0
        self._in_window += 1
        if self._in_window <= _LOG_BURST:
            # A client's bad request is a warning, not the service's error.
            self.logger.log(min(level, logging.WARNING), "OctoPrint API: %s", text[:200])
        else:
            self._left_out += 1

    def process(self, msg: Any, kwargs: Any) -> tuple[Any, Any]:
        """As given: `log` does the work."""
        return msg, kwargs
