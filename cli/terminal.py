"""The terminal as an input: Ctrl-C and SIGTERM as events (not exceptions mid-line), and single key presses."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import termios
import tty
from collections.abc import Callable, Iterator

__all__ = ["key_presses", "on_stop_signals"]


@contextlib.contextmanager
def on_stop_signals(callback: Callable[[], None]) -> Iterator[None]:
    """Call `callback` on SIGINT or SIGTERM while active; restore the defaults afterwards.

    Signal handlers can only be installed from the main thread; elsewhere (a test running the command in a worker
    thread) nothing is installed, and the command runs until it ends by itself.
    """
    loop = asyncio.get_running_loop()
    installed = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(signum, callback)
        except (RuntimeError, ValueError):
            continue
        installed.append(signum)
    try:
        yield
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)


@contextlib.contextmanager
def key_presses(callback: Callable[[str], None]) -> Iterator[bool]:
    """While active, call `callback` with each key pressed (lower case); yield whether stdin is a terminal at all.

    The terminal is put in cbreak mode (keys arrive one at a time, unechoed; Ctrl-C still raises SIGINT) and its
    mode is restored afterwards, however the block ends.
    """
    if not sys.stdin.isatty():
        yield False
        return
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    loop = asyncio.get_running_loop()

    def on_readable() -> None:
        with contextlib.suppress(OSError):
            for key in os.read(fd, 64).decode(errors="replace").lower():
                callback(key)

    try:
        tty.setcbreak(fd)
        loop.add_reader(fd, on_readable)
        yield True
    finally:
        loop.remove_reader(fd)
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
