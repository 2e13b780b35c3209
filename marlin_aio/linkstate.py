"""The state of the link to a printer, as one value instead of loose flags and message text."""

from __future__ import annotations

from enum import Enum

__all__ = ["LinkState"]


class LinkState(Enum):
    """Where the link to the printer stands; `Printer.state` and `Connection.state` report it.

    The protocol core knows READY, LOCKED, STOPPED and HALTED; the client adds CONNECTING (the handshake) and
    LOST (the port closed or went away). A board that resets (prints `start`) goes back to READY: commands in
    flight fail with `PrinterResetError`, and nothing is replayed.
    """

    CONNECTING = "connecting"
    """The port is open and the handshake (banner, sync, M115) is under way."""
    READY = "ready"
    """Commands go out and are answered."""
    LOCKED = "locked"
    """The printer refuses every command until unlocked (`M511 P<password>` or its screen)."""
    STOPPED = "stopped"
    """The printer stopped after an error (`Printer stopped due to errors`); `M999` resumes it."""
    HALTED = "halted"
    """The printer halted (kill(), thermal protection, M112): it answers nothing until it is reset."""
    LOST = "lost"
    """The port was closed or went away."""
