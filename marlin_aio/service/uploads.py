"""Prints that reach the service as content, not as a path: sent in pieces over the socket (a client printing a
list of lines, or the CLI's plan of a file), or uploaded whole (the OctoPrint API's `POST /api/files/local`).

Each is written to the service's uploads folder (owner-only) under a name made safe (a base name of letters,
digits, `.`, `-` and `_`, ending `.gcode`), never over another file, and within a size bound; a piece-by-piece
upload lives as a hidden `.part` file until its last piece, and one its client abandons is removed.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path

__all__ = ["MAX_UPLOAD_BYTES", "UploadError", "Uploads", "safe_name"]

#: The largest print the service takes as content: far past any slicer's output for a hobby printer.
MAX_UPLOAD_BYTES = 512 * 1024 * 1024

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_GCODE_SUFFIXES = (".gcode", ".gco", ".g")


class UploadError(ValueError):
    """An upload the service refuses: too large, not text, an unknown upload id; the message says which."""


def safe_name(name: str) -> str:
    """`name` as a file name that cannot leave the uploads folder or hide: its last path part, unsafe characters
    as `_`, no leading dot, at most 100 characters, ending in a G-code suffix."""
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    base = _UNSAFE.sub("_", base).lstrip(".")[:100] or "upload"
    return base if base.lower().endswith(_GCODE_SUFFIXES) else f"{base}.gcode"


class Uploads:
    """The uploads folder: pieces in, finished files out.

    Args:
        folder: where uploads are kept (made owner-only on first use).
        max_bytes: the largest upload taken.
    """

    def __init__(self, folder: Path, max_bytes: int = MAX_UPLOAD_BYTES) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self._parts: dict[str, tuple[Path, int]] = {}

    def _folder(self) -> Path:
        self.folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        return self.folder

    def begin(self) -> str:
        """Start a piece-by-piece upload; return its id."""
        upload_id = secrets.token_hex(8)
        path = self._folder() / f".{upload_id}.part"
        path.touch(mode=0o600)
        self._parts[upload_id] = (path, 0)
        return upload_id

    def append(self, upload_id: str, lines: list[str]) -> None:
        """Add `lines` (each one line of the file, its newline optional) to the upload `upload_id`.

        Raises:
            UploadError: no such upload, a line holds a line break inside it, or the upload grew past the bound.
        """
        if upload_id not in self._parts:
            raise UploadError(f"no upload {upload_id[:40]!r} in progress")
        path, size = self._parts[upload_id]
        text = "".join(line.removesuffix("\n").removesuffix("\r") + "\n" for line in lines)
        if text.count("\n") != len(lines) or "\r" in text:
            raise UploadError("a line of an upload holds a line break inside it")
        data = text.encode("utf-8", errors="strict")
        if size + len(data) > self.max_bytes:
            self.discard(upload_id)
            raise UploadError(f"the upload is over the limit of {self.max_bytes // (1024 * 1024)} MiB")
        with path.open("ab") as handle:
            handle.write(data)
        self._parts[upload_id] = (path, size + len(data))

    def finish(self, upload_id: str, name: str) -> Path:
        """End the upload `upload_id` as a file named after `name` (made safe, never over another); return its path.

        Raises:
            UploadError: no such upload.
        """
        if upload_id not in self._parts:
            raise UploadError(f"no upload {upload_id[:40]!r} in progress")
        path, _ = self._parts.pop(upload_id)
        final = self._free(safe_name(name))
        os.replace(path, final)
        return final

    def store(self, name: str, data: bytes) -> Path:
        """Keep `data` whole as a file named after `name` (made safe, never over another); return its path.

        Raises:
            UploadError: it is over the bound, or not text (a NUL byte, or not UTF-8).
        """
        if len(data) > self.max_bytes:
            raise UploadError(f"the upload is over the limit of {self.max_bytes // (1024 * 1024)} MiB")
        if b"\0" in data:
            raise UploadError("not a text G-code file (a NUL byte)")
        try:
            data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise UploadError(f"not a text G-code file (not UTF-8 at byte {exc.start})") from None
        final = self._free(safe_name(name))
        fd = os.open(final, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        return final

    def discard(self, upload_id: str) -> None:
        """Drop an unfinished upload (its client left, or it failed)."""
        entry = self._parts.pop(upload_id, None)
        if entry is not None:
            with contextlib.suppress(FileNotFoundError):
                entry[0].unlink()

    def _free(self, name: str) -> Path:
        folder = self._folder()
        path = folder / name
        stem, dot, suffix = name.rpartition(".")
        number = 1
        while path.exists():
            number += 1
            path = folder / f"{stem}-{number}{dot}{suffix}"
        return path
