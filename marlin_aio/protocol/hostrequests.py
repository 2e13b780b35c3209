"""The firmware's own requests: `//action:` lines and `paused for user` keepalives, tracked without I/O.

Marlin with HOST_ACTION_COMMANDS asks the host to act: `//action:pause` (the host should pause its print),
`//action:paused <reason>` (the printer paused itself, as a filament runout does: `paused filament_runout 0`),
`//action:resume` / `//action:resumed`, `//action:cancel`, `//action:disconnect`. With HOST_PROMPT_SUPPORT it opens
prompts for a person (`host_actions.cpp`): `prompt_end` (any earlier one), `prompt_begin <message>`, one
`prompt_button <label>` per button (`prompt_choice` in older versions), then `prompt_show`; the host answers with
`M876 S<index>` (0-based). While M600 (or M0/M1) waits for a person, its keepalive reads `busy: paused for user`.

`HostRequests.receive(event)` follows all of this from the parsed events and returns a `HostRequest` for each
thing a host should show or act on; `prompt` and `waiting_for_user` are the state at any time.
"""

from __future__ import annotations

from dataclasses import dataclass

from marlin_aio.protocol.events import BusyKeepalive, Event, HostAction, Ok

__all__ = ["PRINT_CANCELS", "PRINT_PAUSES", "PRINT_RESUMES", "HostRequest", "HostRequests", "Prompt"]

#: Actions that mean a running print must stop feeding lines: the host is asked to pause, or the printer paused.
PRINT_PAUSES = frozenset({"pause", "paused"})
#: Actions that mean the print goes on: the host is asked to resume, or the printer resumed.
PRINT_RESUMES = frozenset({"resume", "resumed"})
#: Actions that mean the print must end (its cancel path: nothing more is fed).
PRINT_CANCELS = frozenset({"cancel"})

#: Keepalive reasons of a command that waits for a person (M600, M0/M1): `echo:busy: paused for user`.
_USER_WAITS = frozenset({"paused for user", "paused for input"})


@dataclass(frozen=True, slots=True)
class Prompt:
    """A prompt the firmware opened for a person: its message and its buttons, in order.

    Answer it with `M876 S<index>` (`Printer.answer_prompt(index)`), 0 being the first button. `shown` is False
    while it is still being built (between `prompt_begin` and `prompt_show`).
    """

    message: str
    buttons: tuple[str, ...] = ()
    shown: bool = False


@dataclass(frozen=True, slots=True)
class HostRequest:
    """One thing the firmware asked of the host, or told it.

    `action` is the `//action:` word (`pause`, `paused`, `resume`, `resumed`, `cancel`, `disconnect`,
    `notification`, `out_of_filament`, ...), or `prompt` (a prompt was shown: see `prompt`), `prompt_closed`
    (`prompt_end` closed an open prompt) or `paused_for_user` (a command began waiting for a person). `argument`
    is the rest of the line (`filament_runout 0`); `prompt` is the prompt shown, for `prompt`.
    """

    action: str
    argument: str = ""
    prompt: Prompt | None = None

    @property
    def reason(self) -> str:
        """The request in words for a person: `printer asked: filament_runout 0`."""
        if self.action == "prompt" and self.prompt is not None:
            return f"printer asks: {self.prompt.message}"
        if self.action == "paused_for_user":
            return "printer waits for the user"
        return f"printer asked: {self.argument or self.action}"


class HostRequests:
    """The state of the firmware's requests, fed every received event (`receive`)."""

    __slots__ = ("_building", "last", "prompt", "waiting_for_user")

    def __init__(self) -> None:
        self.prompt: Prompt | None = None
        """The prompt shown and not yet closed (or answered), or None."""
        self.last: HostRequest | None = None
        """The last pause, paused, resume, resumed, cancel or disconnect request."""
        self.waiting_for_user = False
        """True while a command waits for a person (`busy: paused for user`), until its ok or another keepalive."""
        self._building: Prompt | None = None

    def receive(self, event: Event) -> HostRequest | None:
        """Follow one received event; return the request it makes, or None (most events make none)."""
        if type(event) is Ok:
            # The command that waited for the user has finished (any ok proves the printer moved on).
            self.waiting_for_user = False
            return None
        if isinstance(event, BusyKeepalive):
            waiting = event.reason in _USER_WAITS
            started = waiting and not self.waiting_for_user
            self.waiting_for_user = waiting
            return HostRequest("paused_for_user", event.reason) if started else None
        if isinstance(event, HostAction):
            return self._action(event.action, event.argument)
        return None

    def answered(self) -> None:
        """The host answered the open prompt (M876): it is closed on the host's side at once."""
        self.prompt = None
        self._building = None

    def clear(self) -> None:
        """Forget everything (the board reset: its prompts and waits are gone)."""
        self.prompt = None
        self._building = None
        self.waiting_for_user = False

    def _action(self, action: str, argument: str) -> HostRequest | None:
        match action:
            case "prompt_begin":
                self.prompt = None
                self._building = Prompt(argument)
                return None
            case "prompt_button" | "prompt_choice":
                if self._building is not None:
                    begun = self._building
                    self._building = Prompt(begun.message, (*begun.buttons, argument))
                return None
            case "prompt_show":
                shown = self._building if self._building is not None else self.prompt
                if shown is None:
                    return None
                self._building = None
                self.prompt = Prompt(shown.message, shown.buttons, shown=True)
                return HostRequest("prompt", shown.message, self.prompt)
            case "prompt_end":
                was_open = self.prompt is not None
                self.prompt = None
                self._building = None
                return HostRequest("prompt_closed") if was_open else None
        request = HostRequest(action, argument)
        if action in PRINT_PAUSES | PRINT_RESUMES | PRINT_CANCELS or action == "disconnect":
            self.last = request
        return request
