"""The firmware's prompts and requests as the views show them, and the digit keys that answer a prompt.

Pure functions of the library's state (`Printer.prompt`, `Printer.waiting_for_user`), shared by `print`, `watch`
and `terminal`: one wording everywhere. Buttons are numbered from 1 for the keys (`1 Continue  2 PurgeMore`); the
printer's own answer (`M876 S<n>`) counts from 0, which `answer_index` translates.
"""

from __future__ import annotations

from marlin_aio.protocol import Prompt

__all__ = ["answer_index", "buttons_text", "prompt_text", "request_text"]


def buttons_text(prompt: Prompt) -> str:
    """The buttons with their keys: `1 Continue  2 PurgeMore`."""
    return "  ".join(f"{number} {label}" for number, label in enumerate(prompt.buttons, 1))


def prompt_text(prompt: Prompt | None, waiting_for_user: bool, press: str = "press") -> str | None:
    """What the view says about the printer's prompt or its wait for the user; None when there is neither.

    A filament change (M600, or a runout) reads `filament change: load filament, then press 1 Continue`; `press`
    is how the user answers (`type answer` in the terminal).
    """
    if prompt is None:
        return "the printer waits for the user (on its screen, or M108)" if waiting_for_user else None
    if not prompt.buttons:
        return f"printer: {prompt.message}"
    keys = buttons_text(prompt)
    if waiting_for_user and "filament" in prompt.message.lower():
        return f"filament change: {prompt.message.lower()}, then {press} {keys}"
    return f"printer asks: {prompt.message}  {press} {keys}"


def answer_index(key: str, prompt: Prompt | None) -> int | None:
    """The button a key answers (0-based, as M876 counts), or None if the key is not one of its digits."""
    if prompt is None or len(key) != 1 or not "1" <= key <= "9":
        return None
    index = int(key) - 1
    return index if index < len(prompt.buttons) else None


def request_text(action: str, argument: str) -> str | None:
    """One line for a request of the printer that the user should hear of (`printer asked to pause:
    filament_runout 0`), or None for those the views show otherwise (prompts) or that need no word."""
    match action:
        case "pause" | "paused":
            return f"printer paused the print: {argument}" if argument else "printer paused the print"
        case "resume" | "resumed":
            return "printer resumed the print"
        case "cancel":
            return "printer asked to cancel the print"
        case "disconnect":
            return "printer asked the host to disconnect"
        case "notification":
            return f"printer: {argument}" if argument else None
    return None
