"""The terminal as an input: Ctrl-C and SIGTERM as events (not exceptions mid-line), and single key presses.

Keys come as they are typed; `raw=True` keeps their case and hands an escape sequence (an arrow key, F1) over
whole, so a program that reads typed text (watch's G-code line) can ignore it instead of seeing `[A`.
"""

from __future__ import annotations

import codecs
import contextlib
import contextvars
import os
import signal
import sys
import termios
import tty
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import asyncio

__all__ = ["PASTE", "STOP_SIGNALLED", "key_presses", "on_stop_signals", "split_keys"]

#: Set by SIGINT or SIGTERM while `on_stop_signals` handles them in this task (None outside): what must end at once
#: on a signal rather than at the command's next look at its own stop (opening the printer: `connect.open_printer`)
#: waits on it.
STOP_SIGNALLED: contextvars.ContextVar[asyncio.Event | None] = contextvars.ContextVar("stop_signalled", default=None)

#: With `key_presses(raw=True)`, a paste (more than two keys in one read) arrives as PASTE followed by the text.
PASTE = "\x00paste:"

_ESCAPE = "\x1b"


@contextlib.contextmanager
def on_stop_signals(callback: Callable[[], None]) -> Iterator[None]:
    """Call `callback` on SIGINT or SIGTERM while active (and set `STOP_SIGNALLED`); restore the defaults afterwards.

    Signal handlers can only be installed from the main thread; elsewhere (a test running the command in a worker
    thread) nothing is installed, and the command runs until it ends by itself.
    """
    import asyncio  # here, not at the top: `--help` loads no event loop

    loop = asyncio.get_running_loop()
    signalled = asyncio.Event()

    def on_signal() -> None:
        signalled.set()
        callback()

    installed = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(signum, on_signal)
        except (RuntimeError, ValueError):
            continue
        installed.append(signum)
    token = STOP_SIGNALLED.set(signalled if installed else None)
    try:
        yield
    finally:
        STOP_SIGNALLED.reset(token)
        for signum in installed:
            loop.remove_signal_handler(signum)


def split_keys(text: str) -> list[str]:
    """Split what one read of the terminal gave into keys: one character each, an escape sequence whole.

    CSI sequences (`ESC [` parameters, then a final letter or `~`) and SS3 ones (`ESC O` and one character) are
    one key; an ESC followed by anything else, or by nothing, is the Esc key on its own.
    """
    keys: list[str] = []
    index = 0
    while index < len(text):
        char = text[index]
        if char == _ESCAPE and index + 1 < len(text) and text[index + 1] in "[O":
            end = index + 2
            if text[index + 1] == "[":
                # parameters and intermediates are 0x20-0x3F; the final byte is 0x40-0x7E
                while end < len(text) and "\x20" <= text[end] <= "\x3f":
                    end += 1
            end = min(end + 1, len(text))
            keys.append(text[index:end])
            index = end
            continue
        keys.append(char)
        index += 1
    return keys


@contextlib.contextmanager
def key_presses(callback: Callable[[str], None], *, raw: bool = False, discard_unread: bool = False) -> Iterator[bool]:
    """While active, call `callback` with each key pressed; yield whether stdin is a terminal at all.

    Keys are lower case, one character each; with `raw`, as typed (case kept, escape sequences whole, see
    `split_keys`), and a paste arrives whole, as `PASTE` followed by its text. The terminal is put in cbreak mode
    (keys arrive one at a time, unechoed; Ctrl-C still raises SIGINT) and its mode is restored afterwards, however
    the block ends. With `discard_unread`, keys typed but not yet read when the block ends are thrown away
    rather than left for the shell (a second `y` typed while a print was ending must not become a command).
    """
    if not sys.stdin.isatty():
        yield False
        return
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    import asyncio  # here, not at the top: `--help` loads no event loop

    loop = asyncio.get_running_loop()
    # A character of several bytes may be split between two reads: decode incrementally.
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")

    def on_readable() -> None:
        with contextlib.suppress(OSError):
            text = decoder.decode(os.read(fd, 64))
            keys = split_keys(text) if raw else list(text.lower())
            if raw and len(keys) > 2:
                # More keys than a person types between two reads: a paste. It is handed over whole, so pasted
                # text is never taken for key commands (an `o` in it turning the heaters off).
                callback(PASTE + text)
                return
            for key in keys:
                callback(key)

    try:
        tty.setcbreak(fd)
        loop.add_reader(fd, on_readable)
        yield True
    finally:
        loop.remove_reader(fd)
        termios.tcsetattr(fd, termios.TCSAFLUSH if discard_unread else termios.TCSADRAIN, saved)
