"""The state of the link to a printer, as one value instead of loose flags and message text.

`LinkState` and its transition table live in `states`, with each line's state; this module keeps the
name importable where it always was.
"""

from __future__ import annotations

from marlin_aio.protocol.states import LinkState

__all__ = ["LinkState"]
