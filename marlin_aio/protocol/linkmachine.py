"""The link's state machine: its state and every fact a move of it reads or writes, in one owner.

h11's `ConnectionState` holds each side's state and the few facts its transitions depend on, and nothing else
writes them. The link's state (`states.LinkState`) moves the same way: only through `LinkMachine`, whose moves
follow `states.LINK_TRANSITIONS`, and the facts that go with it live here too, so no part of the core keeps a
copy of its own or writes one behind the machine's back:

- `halt`: why the link is HALTED or STOPPED, raised to every new command (set by a halt, cleared by a reset or
  by M999's answer; a thermal runaway's message is never replaced by a plainer one);
- `thermal_message`: the firmware's thermal error, which explains the halt line that follows it;
- `requires_numbers`: the firmware refused an unnumbered command (`Missing checksum`).

The parts of `Connection` call its verbs (`halted`, `reset`, `resumed`, `locked`, ...) and read its fields.
Nothing here imports anything but the core's errors and tables.
"""

from __future__ import annotations

import logging

from marlin_aio.errors import PrinterHaltedError, ThermalRunawayError
from marlin_aio.protocol.states import LINK_TRANSITIONS, LinkEvent, LinkState, next_link_state

__all__ = ["LinkMachine"]

_log = logging.getLogger("marlin_aio")


class LinkMachine:
    """The link's state (`LinkState`), moved only by the table, and the facts its moves read."""

    __slots__ = ("halt", "requires_numbers", "state", "thermal_message")

    def __init__(self, *, connecting: bool = False) -> None:
        self.state = LinkState.CONNECTING if connecting else LinkState.READY
        self.halt: PrinterHaltedError | None = None
        self.thermal_message: str | None = None
        self.requires_numbers = False

    def move(self, event: LinkEvent, *, remote: bool = False) -> None:
        """Move the state by the table.

        A move the table lacks is a bug when the core itself asks for it (it raises `ImpossibleTransitionError`);
        when the printer's words ask for it (`remote`: "locked" on a halted board, say) it is logged and ignored,
        as no byte from the printer may break the link.
        """
        if remote and event not in LINK_TRANSITIONS[self.state]:
            _log.warning("ignored: the printer said %s while the link was %s", event.value, self.state.value)
            return
        self.state = next_link_state(self.state, event)

    def refuse(self, code: str) -> None:
        """Raise why the link takes no command now (halted or stopped), unless `code` is the M999 that resumes it.

        Raises:
            PrinterHaltedError: the printer halted or stopped.
        """
        if self.halt is not None and code != "M999":
            raise self.halt

    def halted(self, error: PrinterHaltedError, *, stopped: bool) -> PrinterHaltedError:
        """The printer halted (`stopped`: a stop() that M999 clears; otherwise it needs a reset). Returns the
        error every command on its way fails with."""
        if self.halt is None or isinstance(error, ThermalRunawayError):
            self.halt = error
        # A second line about the same halt: a kill() after a stop() is final, and a stop() never softens a kill()
        # (the table: HALTED stays HALTED on a stop).
        self.move(LinkEvent.STOPPED if stopped else LinkEvent.HALTED, remote=True)
        return self.halt

    def emergency_stopped(self) -> PrinterHaltedError:
        """The host sent M112: the printer is halted (it needs a reset). Returns the error commands fail with."""
        self.halt = PrinterHaltedError("emergency stop (M112) sent; reset the printer to go on")
        self.move(LinkEvent.HALTED)
        return self.halt

    def thermal_error(self, message: str) -> None:
        """The firmware's thermal protection spoke: the halt line that follows is explained by it."""
        self.thermal_message = message

    def resumed(self) -> None:
        """M999 was answered on a STOPPED printer: it runs commands again."""
        self.halt = None
        self.move(LinkEvent.RESUMED, remote=True)

    def reset(self) -> None:
        """The board rebooted: a halt, a lock and a thermal error are all forgotten."""
        self.halt = None
        self.thermal_message = None
        self.move(LinkEvent.RESET, remote=True)

    def handshake_done(self) -> None:
        """The client's handshake ended: a link still CONNECTING is READY (a locked, stopped or halted one stays
        so; a lost one stays lost)."""
        if self.state is LinkState.CONNECTING:
            self.move(LinkEvent.HANDSHAKE_DONE)

    def port_lost(self) -> None:
        """The port closed or went away: nothing moves the link again."""
        if self.state is not LinkState.LOST:
            self.move(LinkEvent.PORT_LOST)

    def checksums_required(self) -> None:
        """The firmware refused an unnumbered command: every command is numbered from now on."""
        self.requires_numbers = True

    def print_moved(self, streaming: bool, on_wire: bool) -> None:
        """Move PRINTING and STOPPING on as a print ends (`streaming` False) and its last lines on the wire
        (`on_wire`) are answered."""
        state = self.state
        if state is LinkState.PRINTING and not streaming:
            self.move(LinkEvent.PRINT_STOPPED if on_wire else LinkEvent.PRINT_ENDED)
        elif state is LinkState.STOPPING and not on_wire:
            self.move(LinkEvent.WIRE_CLEAR)
