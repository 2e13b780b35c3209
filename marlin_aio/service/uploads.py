"""Prints that reach the service as content, not as a path: sent in pieces over the socket (a client printing a
list of lines, or the CLI's plan of a file), or uploaded whole (the OctoPrint API's `POST /api/files/local`).

Each is written to the service's uploads folder (owner-only) under a name made safe (a base name of letters,
digits, `.`, `-` and `_`, ending `.gcode`), never over another file, and within two bounds checked as the bytes
arrive: one upload's size, and the folder's quota (its finished files and the uploads under way, together). A
piece-by-piece upload lives as a hidden `.part` file until its last piece, and one its client abandons or that
breaks a bound is removed. Only a finished upload is printed (`is_finished`), never another client's `.part`.

The bounds default to 512 MiB an upload and 2 GiB in all; `$MARLIN_SERVE_UPLOAD_LIMIT_MIB` and
`$MARLIN_SERVE_UPLOAD_QUOTA_MIB` change them for a service (a farm with big prints, or a test that must not send
512 MiB to see the bound hold).
"""

from __future__ import annotations

import codecs
import contextlib
import os
import re
import secrets
import shutil
import stat
from pathlib import Path

__all__ = [
    "LIMIT_ENV",
    "MAX_UPLOAD_BYTES",
    "QUOTA_BYTES",
    "QUOTA_ENV",
    "UploadError",
    "UploadTooLargeError",
    "UploadTypeError",
    "Uploads",
    "check_name",
    "safe_name",
]

#: The largest print the service takes as content: far past any slicer's output for a hobby printer.
MAX_UPLOAD_BYTES = 512 * 1024 * 1024
#: All the uploads folder may hold, finished files and uploads under way together.
QUOTA_BYTES = 2 * 1024 * 1024 * 1024
#: Environment variables that change the two bounds, in MiB.
LIMIT_ENV = "MARLIN_SERVE_UPLOAD_LIMIT_MIB"
QUOTA_ENV = "MARLIN_SERVE_UPLOAD_QUOTA_MIB"
_MIB = 1024 * 1024

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_GCODE_SUFFIXES = (".gcode", ".gco", ".g")


class UploadError(ValueError):
    """An upload the service refuses: too large, not text, an unknown upload id; the message says which."""


class UploadTooLargeError(UploadError):
    """An upload over its size bound, or one the uploads folder's quota has no room for."""


class UploadTypeError(UploadError):
    """A file name the uploads folder does not keep: not a G-code file's (OctoPrint's "invalid type", 415)."""


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def check_name(name: str) -> str:
    """`name` as given for an upload, if it holds no control character (a NUL, a line break, ...).

    Raises:
        UploadError: it holds one (nothing a slicer sends; a NUL would also end the name at the OS).
    """
    found = _CONTROL.search(name)
    if found is not None:
        raise UploadError(f"the file name holds a control character ({found.group()!r} at {found.start()})")
    return name


def _mib(size: int) -> str:
    return f"{size / _MIB:.1f}".removesuffix(".0") + " MiB"


def _bound_from_env(variable: str, default: int) -> int:
    text = os.environ.get(variable, "").strip()
    if not text:
        return default
    try:
        mib = int(text)
    except ValueError:
        mib = 0
    if mib <= 0:
        raise ValueError(f"${variable} must be a whole number of MiB above 0, got {text[:40]!r}")
    return mib * _MIB


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
        max_bytes: the largest upload taken (default: `$MARLIN_SERVE_UPLOAD_LIMIT_MIB`, else `MAX_UPLOAD_BYTES`).
        quota_bytes: all the folder may hold (default: `$MARLIN_SERVE_UPLOAD_QUOTA_MIB`, else `QUOTA_BYTES`).

    Raises:
        ValueError: a bound is not above 0 (or its environment variable not a whole number of MiB).
    """

    def __init__(self, folder: Path, max_bytes: int | None = None, quota_bytes: int | None = None) -> None:
        self.folder = folder
        self.max_bytes = _bound_from_env(LIMIT_ENV, MAX_UPLOAD_BYTES) if max_bytes is None else max_bytes
        self.quota_bytes = _bound_from_env(QUOTA_ENV, QUOTA_BYTES) if quota_bytes is None else quota_bytes
        if self.max_bytes <= 0 or self.quota_bytes <= 0:
            raise ValueError("the upload bounds must be above 0 bytes")
        self._parts: dict[str, _Part] = {}
        # The finished files' bytes, counted when an upload begins or ends, not at every piece: between those,
        # a file removed only makes the count too high (a refusal a moment early), never too low.
        self._finished_bytes = 0

    def is_finished(self, path: Path) -> bool:
        """Whether `path` is a finished upload: a regular file (not a link) right inside the folder, neither
        hidden nor a `.part` of an upload under way."""
        if path.parent != self.folder or path.name.startswith(".") or path.name.endswith(".part"):
            return False
        try:
            return stat.S_ISREG(os.lstat(path).st_mode)
        except (OSError, ValueError):  # ValueError: a NUL in the path
            return False

    def used_bytes(self) -> int:
        """What the folder holds towards the quota: its finished uploads and the uploads under way."""
        self._finished_bytes = self._count_finished()
        return self._finished_bytes + sum(part.size for part in self._parts.values())

    def check_room(self, size: int) -> None:
        """Refuse an upload of `size` bytes before it is written, if it is over the bound or cannot fit.

        Raises:
            UploadTooLargeError: it is over the bound of one upload, or past what the quota has left.
        """
        if size > self.max_bytes:
            raise UploadTooLargeError(f"the upload is {_mib(size)}, over the limit of {_mib(self.max_bytes)}")
        used = self.used_bytes()
        if used + size > self.quota_bytes:
            raise UploadTooLargeError(self._full(used))

    def _full(self, used: int) -> str:
        return (
            f"the uploads folder is full ({_mib(used)} of its {_mib(self.quota_bytes)} quota used): "
            f"remove files from {self.folder}"
        )

    def _count_finished(self) -> int:
        total = 0
        with contextlib.suppress(FileNotFoundError), os.scandir(self.folder) as entries:
            for entry in entries:
                if not entry.name.startswith(".") and entry.is_file(follow_symlinks=False):
                    with contextlib.suppress(FileNotFoundError):
                        total += entry.stat(follow_symlinks=False).st_size
        return total

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
        self._finished_bytes = self._count_finished()
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
            UploadError: no such upload, or not text (a NUL byte, not UTF-8); the upload is dropped.
            UploadTooLargeError: past the bound of one upload, or past the quota; the upload is dropped.
        """
        part = self._parts.get(upload_id)
        if part is None:
            raise UploadError(f"no upload {upload_id[:40]!r} in progress")
        try:
            if part.size + len(data) > self.max_bytes:
                raise UploadTooLargeError(f"the upload is over the limit of {_mib(self.max_bytes)}")
            used = self._finished_bytes + sum(other.size for other in self._parts.values())
            if used + len(data) > self.quota_bytes:
                raise UploadTooLargeError(self._full(used))
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
        self._finished_bytes += part.size
        return final

    def store(self, name: str, data: bytes) -> Path:
        """Keep `data` whole as a file named after `name` (see `append_bytes` and `finish`); return its path.

        Raises:
            UploadError: not text.
            UploadTooLargeError: over the bound, or past the quota.
        """
        upload_id = self.begin()
        self.append_bytes(upload_id, data)
        return self.finish(upload_id, name)

    def copy(self, source: Path, name: str) -> Path:
        """Copy the finished upload `source` to a new file `name` in the folder, within the quota; return it.

        Raises:
            FileNotFoundError: `source` is not a finished upload.
            UploadTypeError: `name` is not a G-code file's name.
            UploadError: `name` is not a plain file name of the folder (a path, a hidden or unsafe name).
            FileExistsError: a file `name` exists (never overwritten).
            UploadTooLargeError: the copy would go past the quota (nothing is written).
        """
        target = self._destination(source, name)
        size = source.stat().st_size
        self.check_room(size)
        upload_id = self.begin()
        part = self._parts[upload_id]
        try:
            with source.open("rb") as reading, part.path.open("ab") as writing:
                shutil.copyfileobj(reading, writing)
            os.link(part.path, target)  # never over a file that appeared meanwhile: FileExistsError
        finally:
            self.discard(upload_id)
        self._finished_bytes += size
        return target

    def move(self, source: Path, name: str) -> Path:
        """Rename the finished upload `source` to `name` in the folder; return the new path.

        Raises:
            FileNotFoundError, UploadTypeError, UploadError, FileExistsError: as `copy`.
        """
        target = self._destination(source, name)
        os.link(source, target)  # a rename that never replaces: FileExistsError if `name` is taken
        source.unlink()
        return target

    def _destination(self, source: Path, name: str) -> Path:
        if not self.is_finished(source):
            raise FileNotFoundError(f"no uploaded file {source.name[:100]!r}")
        check_name(name)
        if not name.lower().endswith(_GCODE_SUFFIXES):
            raise UploadTypeError(f"{name[:100]!r} is not a G-code file's name (.gcode, .gco or .g)")
        if safe_name(name) != name:
            raise UploadError(
                f"{name[:100]!r} is not a file name the uploads keep (one folder; letters, digits, . - _)"
            )
        target = self.folder / name
        if target.exists():
            raise FileExistsError(f"{name} exists already")
        return target

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
