"""A wire log: every line sent to and read from a printer, with its wall-clock time, in a text file (what
OctoPrint's serial.log and Printrun's "debug communications" give).

    2026-11-28T04:10:00.100 # /dev/ttyUSB0 at 250000 baud: opening (local time, UTC+01:00)
    2026-11-28T04:10:00.412 > N1 M110 N0*125
    2026-11-28T04:10:00.431 < ok
    2026-11-28T04:10:09.870 # /dev/ttyUSB0: closed (the connection to /dev/ttyUSB0 was closed)

`Printer(port, wire_log=WireLog("wire.log"))` writes one. The lines come from the connection's trace
(`Trace.tap`), so they are redacted as it is (an `M511 P<password>` line reads `M511 ****`) and cover every line of
the link: the handshake, the poller's fast path, print streaming, emergency commands. A printer without a wire log
pays one test against None per line for it.

One `WireLog` can serve several connections at once and one after another (reconnects, a farm): `named(name)` gives
a view of the same file whose lines start with the printer's name. The file is opened for appending (a day's
sessions stay in one file) when the first connection starts, and closed when the last one ends. It is its owner's
alone: made 0600, and an existing file others could read is made 0600 too (with a warning on `marlin_aio`'s
logger). A port that could not be opened is logged too (`# ...: not opened (...)`), as is a handshake that failed:
the log says why a connection never came. Lines go through a buffer (a 100 Hz poll is 200 lines a second) flushed
at least once a second and when the last connection ends, so a crash loses little. A write that fails (a full
disk) stops the log, never the link: `error` says why.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from typing import IO, Literal

__all__ = ["WireLog", "WireSession"]

_log = logging.getLogger("marlin_aio")

#: At most this long between a line written and the same line on disk.
FLUSH_EVERY_S = 1.0


class _WireFile:
    """The file several `WireLog` views share: opened by the first connection, closed after the last one."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self.file: IO[str] | None = None
        self.users = 0
        self.error: OSError | None = None
        self.error_told = False
        self._flush_timer: asyncio.TimerHandle | None = None
        # The time of day down to the second is formatted once a second, not once a line.
        self._second = -1
        self._stamp = ""

    def stamp(self) -> str:
        """Now, local time, to the millisecond: 2026-11-28T04:10:00.123."""
        now = time.time()
        second = int(now)
        if second != self._second:
            self._second = second
            self._stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(second))
        return f"{self._stamp}.{min(int((now - second) * 1000), 999):03d}"

    def acquire(self) -> None:
        self.users += 1
        if self.file is None and self.error is None:
            try:
                fd = _open_private(self.path)
                # Line-buffered would be a write per line: a block buffer, flushed by the timer below.
                self.file = open(fd, "a", encoding="utf-8", errors="replace", newline="\n")  # noqa: SIM115
            except OSError as exc:
                self._failed(exc)

    def release(self) -> None:
        self.users = max(0, self.users - 1)
        if self.users == 0:
            self.close()

    def write(self, text: str) -> None:
        file = self.file
        if file is None:
            return
        try:
            file.write(text)
        except OSError as exc:
            self._failed(exc)
            return
        if self._flush_timer is None:
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:  # written from outside a loop: nothing would flush it later
                self.flush()
            else:
                self._flush_timer = loop.call_later(FLUSH_EVERY_S, self.flush)

    def flush(self) -> None:
        self._flush_timer = None
        if self.file is not None:
            try:
                self.file.flush()
            except OSError as exc:
                self._failed(exc)

    def close(self) -> None:
        if self._flush_timer is not None:
            self._flush_timer.cancel()
        self.flush()
        file, self.file = self.file, None
        if file is not None:
            try:
                file.close()
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        # The link must go on: the read handler calls `write`, and an error there would leave the link hung.
        if self.error is None:
            self.error = exc
            _log.warning("the wire log %s stopped: %s", self.path, exc.strerror or exc)
        file, self.file = self.file, None
        if file is not None:
            # Its buffer cannot be written either: the error above says so.
            with contextlib.suppress(OSError):
                file.close()


def _open_private(path: str) -> int:
    """Open `path` for appending, readable and writable by its owner only: made 0600 if it is new (a wire log holds
    every line of a print farm's printers), tightened to 0600 (and said so) if others could read it.

    Raises:
        OSError: it cannot be opened.
    """
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o600)
    mode = os.fstat(fd).st_mode & 0o777
    if mode & 0o077:
        try:
            os.fchmod(fd, 0o600)  # the open file, not the path: no window for a swapped file
        except PermissionError as exc:  # another user's file that we may write to: theirs to share
            _log.warning("the wire log %s is readable by others (%o) and not ours to change: %s", path, mode, exc)
        else:
            _log.warning("the wire log %s was readable by others (%o): made it owner-only (600)", path, mode)
    return fd


class WireSession:
    """One connection's part of a wire log: `line` is its trace's tap, `end` writes the closing line."""

    __slots__ = ("_ended", "_file", "_port", "_prefix")

    def __init__(self, file: _WireFile, port: str, baudrate: int, name: str | None) -> None:
        self._file = file
        self._port = port
        self._prefix = "" if name is None else f"{name} "
        self._ended = False
        file.acquire()
        offset = time.strftime("%z")
        utc = f"UTC{offset[:3]}:{offset[3:]}" if len(offset) == 5 else "local time"
        file.write(f"{file.stamp()} {self._prefix}# {port} at {baudrate} baud: opening (local time, {utc})\n")

    def line(self, time_s: float, direction: Literal["sent", "received"], text: str) -> None:
        """Write one line of the wire (`>` sent, `<` received); `time_s` (the link's clock) is not used: the log
        tells wall-clock time."""
        file = self._file
        if not self._ended:
            file.write(f"{file.stamp()} {self._prefix}{'>' if direction == 'sent' else '<'} {text}\n")

    def end(self, reason: str) -> None:
        """Write the closing line and let go of the file (it is closed after its last connection). Safe to call
        twice."""
        if self._ended:
            return
        self._ended = True
        file = self._file
        file.write(f"{file.stamp()} {self._prefix}# {self._port}: {reason}\n")
        file.release()


class WireLog:
    """Every line on the wire of the printers given it (`Printer(..., wire_log=...)`), with times, appended to the
    file at `path` (see the module's docstring for the format and when it is written).

    Args:
        path: the file; its folder must exist (the file is made when the first connection starts).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self._file = _WireFile(path)
        self._name: str | None = None

    @property
    def path(self) -> str:
        """The file's path, as given."""
        return self._file.path

    @property
    def error(self) -> OSError | None:
        """Why the log stopped (the file could not be opened or written), or None while it is written."""
        return self._file.error

    def take_error(self) -> OSError | None:
        """`error` the first time it is asked for after the log stopped, then None: for saying so once."""
        if self._file.error is None or self._file.error_told:
            return None
        self._file.error_told = True
        return self._file.error

    def named(self, name: str) -> WireLog:
        """A view of the same file whose lines start with `name` (a farm's printer name), for several printers in
        one file."""
        view = WireLog.__new__(WireLog)
        view._file = self._file
        view._name = name
        return view

    def connection(self, port: str, baudrate: int) -> WireSession:
        """Start a connection's part of the log, with a line naming the port and baud rate; `Printer` calls this
        as it opens the port, and `end` on the session as it closes."""
        return WireSession(self._file, port, baudrate, self._name)

    def flush(self) -> None:
        """Write what the buffer holds now, without waiting for the second to pass."""
        self._file.flush()
