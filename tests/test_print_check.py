"""One check for every line of a print: the library's `scan_gcode` and the CLI's `plan_print` refuse the same lines
with the same words (`marlin_aio.protocol.check_command`), the CLI adding only the option that raises a limit."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from marlin_aio.aio import scan_gcode
from marlin_aio.protocol import DEFAULT_MAX_BED_CELSIUS, DEFAULT_MAX_HOTEND_CELSIUS, HeaterLimits, check_command
from marlin_temp.printing.plan import plan_print

LIMITS = HeaterLimits(DEFAULT_MAX_HOTEND_CELSIUS, DEFAULT_MAX_BED_CELSIUS, 60.0)


@pytest.mark.parametrize(
    ("bad", "words"),
    [
        ("M104S280", "hotend target 280 C is above the limit of 260 C"),
        ("m0140 s200", "bed target 200 C is above the limit of 140 C"),
        ("M104 B1000", "hotend target 1000 C is above the limit of 260 C"),
        ("M104 Sabc", "hotend target must be a number"),
        ("G1 X1*2", "'*'"),
        ("M117 " + "x" * 100, "longer than Marlin's"),
    ],
)
def test_the_library_and_the_cli_refuse_the_same_line_alike(tmp_path: Path, bad: str, words: str) -> None:
    path = tmp_path / "part.gcode"
    path.write_text(f"G28\n; a comment\n{bad} ; the bad line\nG1 X1\n")
    with pytest.raises(ValueError, match=re.escape(words)) as library:
        scan_gcode(path, LIMITS)
    with pytest.raises(ValueError, match=re.escape(words)) as cli:
        plan_print(path, limits=LIMITS)
    assert str(library.value).startswith(f"{path}: line 3: ")
    # The same message, the CLI naming the option that raises a limit it is over.
    assert str(cli.value).removesuffix(" (--max-hotend)").removesuffix(" (--max-bed)") == str(library.value)


def test_check_command_is_the_rule() -> None:
    check_command("M104 S200", LIMITS)
    check_command("M104 S280")  # no limits: only whether Marlin can take it
    with pytest.raises(ValueError, match="above the limit"):
        check_command("M104 S280", LIMITS)
    with pytest.raises(ValueError, match="non-ASCII"):
        check_command("M117 caf\u00e9")


def test_display_text_is_checked_as_it_is_sent(tmp_path: Path) -> None:
    # The CLI sends `M117 café` as `M117 cafe`: what it checks is what it sends, so the file prints.
    path = tmp_path / "part.gcode"
    path.write_text("G28\nM117 caf\u00e9\nG1 X1\n", encoding="utf-8")
    with pytest.raises(ValueError, match="line 2: command contains non-ASCII"):
        scan_gcode(path)
    plan = plan_print(path)
    assert plan.commands == 3 and list(plan.lines())[1] == "M117 cafe\n"
