"""Keeping the printer's password (Marlin's PASSWORD_FEATURE, `M511 P<password>`) out of everything the library
writes for people: error messages, log lines, the trace of the last lines on the wire, and whatever a caller
publishes from those (the farm's MQTT topics, some of them retained and readable by any later subscriber).

Only the text is redacted: the bytes written to the port keep the password, or the printer would stay locked.

`redact` blanks everything after an M511 command word to the end of its line, so the checksum goes too (a line's
checksum and number are enough to recover a short numeric password by trying them all). It finds every spelling
that Marlin's parser (parser.cpp) reads as M511: either letter case, leading zeros in the code (`M0511`), blanks
between the letter and the number (`M 511`), a line number before it (`N12 M511`, `N12M511`), and no blank before
the parameter (`M511P1234`). It looks anywhere in a line, not only at its start, since the same text is quoted
inside messages (`no 'ok' for 'M511 P1234' after 2.0 s`) and echoed by firmware without the feature
(`echo:Unknown command: "M511 P1234"`). Quote each command through `redact` before building a message around it:
redacting a whole message also blanks whatever the message says after the command.

Three texts are left alone because they never carry a password: Marlin's own lock message
(`Printer locked! (Unlock with M511 or LCD)`), this library's hint `M511 P<password>`, and text already redacted
(`M511 ****`), so that redacting is idempotent and a message built from redacted pieces can be redacted again
whole (as the farm does before publishing) without losing what it says after the command.
"""

from __future__ import annotations

import re

__all__ = ["REDACTED", "redact"]

#: What replaces the rest of a line after an M511 (or M512: set a new password, old and new) command word.
REDACTED = " ****"

# The command word: not glued to a letter before it (`XM511` is no command word; after the digits of a line
# number, or a quote, it is), the code number with any leading zeros and not followed by another digit (M5110 is
# another command). Marlin skips only spaces between the letter and the number; tabs are redacted as well, since
# blanking too much is harmless here.
_M511 = re.compile(
    r"(?<![A-Za-z])([Mm][ \t]*0*51[12])(?![0-9])"
    r"(?![ \t]*(?:or LCD\)|P<password>(?=[\s,;)'\"]|$)|\*\*\*\*(?=[\r\n,;)'\"]|\Z)))"
    r"[^\r\n]*"
)


def redact(text: str) -> str:
    """`text` with everything after each M511 command word replaced by ` ****`, line by line.

    `M511 P1234` gives `M511 ****`, `N12 M511 P1234*87` gives `N12 M511 ****`; any other text comes back
    unchanged (the same object). A line without `511` costs one substring test: the trace redacts every line sent
    and received, a hundred times a second on a Raspberry Pi, and almost none of them is an M511.
    """
    if "511" not in text and "512" not in text:
        return text
    return _M511.sub(_keep_word, text)


def _keep_word(match: re.Match[str]) -> str:
    return match.group(1) + REDACTED
