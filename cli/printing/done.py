"""What `print --on-done CMD` is told when the print ends (`common.hooks` runs it): done, cancelled, halted (the
emergency stop), or failed and how, from the exit code `print_gcode` returns or the error it raised."""

from __future__ import annotations

from pathlib import Path

from ..common.connect import OPENED_PORT, Exit
from ..common.hooks import Done, outcome_of_error

__all__ = ["print_done"]

#: The outcome of each exit code a print returns (rather than raises); any other code is a failure.
_OUTCOMES: dict[int, str] = {Exit.OK: "done", Exit.INTERRUPTED: "cancelled", Exit.HALTED: "halted", Exit.LOST: "lost"}


def print_done(path: Path, code: Exit | None, error: BaseException | None, elapsed_s: float) -> Done:
    """The end of a print of `path`: `code` when `print_gcode` returned, `error` when it raised."""
    port = OPENED_PORT.get()
    where = f"print of {path.name} on {port or 'the printer'}"
    if error is not None:
        outcome, exit_code = outcome_of_error(error)
        message = f"{where}: {outcome}" + (f": {error}" if str(error) else "")
    else:
        exit_code = int(code if code is not None else Exit.ERROR)
        outcome = _OUTCOMES.get(exit_code, "failed")
        message = f"{where}: {outcome} after {_duration(elapsed_s)}"
        if outcome == "failed":
            message += f" (exit code {exit_code})"
    return Done("print", outcome, exit_code, message, port=port, file=str(path.resolve()), elapsed_s=elapsed_s)


def _duration(seconds: float) -> str:
    """2 h 05 min, 3 min 07 s, 12 s."""
    whole = round(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    if minutes:
        return f"{minutes} min {secs:02d} s"
    return f"{secs} s"
