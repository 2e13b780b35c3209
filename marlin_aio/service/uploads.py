"""Prints that reach the service as content, not as a path: sent in pieces over the socket (a client printing a
list of lines, or the CLI's plan of a file), or uploaded whole (the OctoPrint API's `POST /api/files/local`).

Each is written to the service's uploads folder (owner-only) under a name made safe (a base name of letters,
digits, `.`, `-` and `_`, ending `.gcode`), never over another file, and within a size bound; a piece-by-piece
upload lives as a hidden `.part` file until its last piece, and one its client abandons is removed.
"""

from __future__ import annotations

import codecs
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


class _Part:
    """An upload under way: its hidden file, its size so far, and the check that it is UTF-8 across pieces."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = 0
        self.decoder = codecs.getincrementaldecoder("utf-8")()


class Uploads:
    """The uploads folder: pieces in, finished files out.

    Args:
        folder: where uploads are kept (made owner-only on first use).
        max_bytes: the largest upload taken.
    """

    def __init__(self, folder: Path, max_bytes: int = MAX_UPLOAD_BYTES) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self._parts: dict[str, _Part] = {}

    def _folder(self) -> Path:
        self.folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        return self.folder

    def sweep(self) -> None:
        """Remove the `.part` files a service that died left behind (at start-up: none is under way yet)."""
        if self.folder.is_dir():
            for part in self.folder.glob(".*.part"):
                with contextlib.suppress(FileNotFoundError):
                    part.unlink()

    def prune(self, prefix: str, keep: int, busy: set[str]) -> None:
        """Keep the `keep` newest finished uploads whose names start with `prefix` (what clients sent as lines,
        not what people uploaded by name), never one named in `busy` (printing)."""
        made = sorted(self.folder.glob(f"{prefix}*.gcode"), key=lambda path: path.stat().st_mtime, reverse=True)
        for path in made[keep:]:
            if path.name not in busy:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()

    def begin(self) -> str:
        """Start an upload in pieces; return its id."""
        upload_id = secrets.token_hex(8)
        path = self._folder() / f".{upload_id}.part"
        path.touch(mode=0o600)
        self._parts[upload_id] = _Part(path)
        return upload_id

    def append(self, upload_id: str, lines: list[str]) -> None:
        """Add `lines` (each one line of the file, its newline optional) to the upload `upload_id`.

        Raises:
            UploadError: no such upload, a line holds a line break inside it, or the upload grew past the bound.
        """
        text = "".join(line.removesuffix("\n").removesuffix("\r") + "\n" for line in lines)
        if text.count("\n") != len(lines) or "\r" in text:
            self.discard(upload_id)
            raise UploadError("a line of an upload holds a line break inside it")
        self.append_bytes(upload_id, text.encode("utf-8", errors="surrogateescape"))

    def append_bytes(self, upload_id: str, data: bytes) -> None:
        """Add `data` (any piece of the file's bytes) to the upload `upload_id`, checking it is text as it comes.

        Raises:
            UploadError: no such upload, not text (a NUL byte, not UTF-8), or past the bound; the upload is dropped.
        """
        part = self._parts.get(upload_id)
        if part is None:
            raise UploadError(f"no upload {upload_id[:40]!r} in progress")
        try:
            if part.size + len(data) > self.max_bytes:
                raise UploadError(f"the upload is over the limit of {self.max_bytes // (1024 * 1024)} MiB")
            if b"\0" in data:
                raise UploadError(f"not a text G-code file (a NUL byte near byte {part.size + data.index(0)})")
            try:
                part.decoder.decode(data)
            except UnicodeDecodeError:
                raise UploadError(f"not a text G-code file (not UTF-8 near byte {part.size})") from None
        except UploadError:
            self.discard(upload_id)
            raise
        with part.path.open("ab") as handle:
            handle.write(data)
        part.size += len(data)

    def finish(self, upload_id: str, name: str) -> Path:
        """End the upload `upload_id` as a file named after `name` (made safe, never over another); return its path.

        Raises:
            UploadError: no such upload, or it ends inside a UTF-8 character.
        """
        part = self._parts.get(upload_id)
        if part is None:
            raise UploadError(f"no upload {upload_id[:40]!r} in progress")
        try:
            part.decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            self.discard(upload_id)
            raise UploadError("not a text G-code file (it ends inside a UTF-8 character)") from None
        del self._parts[upload_id]
        final = self._free(safe_name(name))
        os.replace(part.path, final)
        return final

    def store(self, name: str, data: bytes) -> Path:
        """Keep `data` whole as a file named after `name` (see `append_bytes` and `finish`); return its path.

        Raises:
            UploadError: over the bound, or not text.
        """
        upload_id = self.begin()
        self.append_bytes(upload_id, data)
        return self.finish(upload_id, name)

    def discard(self, upload_id: str) -> None:
        """Drop an unfinished upload (its client left, or it failed)."""
        part = self._parts.pop(upload_id, None)
        if part is not None:
            with contextlib.suppress(FileNotFoundError):
                part.path.unlink()

    def _free(self, name: str) -> Path:
        folder = self._folder()
        path = folder / name
        stem, dot, suffix = name.rpartition(".")
        number = 1
        while path.exists():
            number += 1
            path = folder / f"{stem}-{number}{dot}{suffix}"
        return path
