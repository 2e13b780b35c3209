"""The farm view and the print view at 120, 80, 60, 40 and 30 columns: what matters most is never cut.

The farm's key line keeps `q` (it shortens: "1-9 ↑↓ Enter: details  q quits", "1-9 details  q quit", "q quit"); its
table keeps each printer's number, heaters and state, cutting a long name and folding the link and the print
progress into the state before anything else. The print view keeps its percent and its ETA (or what the print
waits for): the rate, the word "lines", the counts and the bar give way first.

Rendered pure into a recording Console at each width, and live in a real terminal (tmux) 40 columns wide.
"""

from __future__ import annotations

import io
import re
import sys
from pathlib import Path

import pytest
from rich.console import Console
from test_cli_farm_view import LOST, model_with, printer, rows_of_a_farm
from tmux_screen import Tmux, needs_tmux

from marlin_temp.common.connect import Exit
from marlin_temp.farm.view import DETAIL_KEYS_HELP, FARM_KEYS_HELP, detail_view, farm_row, farm_view
from marlin_temp.printing.view import KEYS_HELP, PrintStatus, print_view

WIDTHS = (120, 80, 60, 40, 30)


def recorded(renderable: object, width: int) -> list[str]:
    console = Console(record=True, width=width, file=io.StringIO(), color_system=None)
    console.print(renderable)
    lines = console.export_text().rstrip("\n").split("\n")
    assert all(len(line.rstrip()) <= width for line in lines), lines
    return lines


# ------------------------------------------------------------------------------------------- the farm view


@pytest.mark.parametrize("width", WIDTHS)
def test_the_farm_key_line_keeps_q_at_every_width(width: int) -> None:
    lines = recorded(farm_view(rows_of_a_farm(), width, selected=0, events=["12:00:01 ender: " + LOST]), width)
    keys = lines[-1]
    assert keys in FARM_KEYS_HELP  # one of the forms, whole: never cut in the middle
    assert re.search(r"\bq quits?$", keys)
    if width >= 60:
        assert keys == "1-9 or ↑/↓ and Enter: one printer's details   q quits"
    elif width >= 30:
        assert keys == "1-9 ↑↓ Enter: details  q quits"


def test_the_farm_key_line_shortens_to_q_quit_last() -> None:
    assert recorded(farm_view(rows_of_a_farm(), 22), 22)[-1] == "1-9 details  q quit"
    assert recorded(farm_view(rows_of_a_farm(), 12), 12)[-1] == "q quit"


@pytest.mark.parametrize("width", WIDTHS)
def test_the_farm_table_keeps_number_heaters_and_state_whole(width: int) -> None:
    lines = recorded(farm_view(rows_of_a_farm(), width), width)
    table = lines[1:5]
    header, first, second, third = table
    assert header.startswith("#") and "state" in header
    temperatures = r"204\.6/210\s+60\.0/60" if width >= 80 else r"205/210\s+60/60"
    assert re.match(rf"1\s+prusa-\S*\s+{temperatures}\s", first), table
    assert re.match(r"2\s+ender\s+-\s+-\s", second), table
    assert re.match(r"3\s+voron\s+25(\.0)?/off\s+25(\.1)?/\?\s+idle\b", third), table
    if width >= 60:
        assert "prusa-mk3s-1" in first and "link" in header and "print" in header.replace("printer", "")
    if width == 40:
        # The link column went: the printer that is down says so in its state; the print keeps its column.
        assert "link" not in header and re.search(r"\bdown\b", second) and re.search(r"printing\s+42%$", first)
    if width == 30:
        # The print column went too: the printing printer's state is its percent.
        assert re.search(r"\s42%$", first.rstrip()) and "printing" not in first


@pytest.mark.parametrize("width", WIDTHS)
def test_the_detail_key_line_keeps_q_at_every_width(width: int) -> None:
    model = model_with("T:150.00 /210.00 B:50.00 /60.00 @:127 B@:127", "T:180.00 /210.00 B:58.00 /60.00 @:127 B@:90")
    farm_printer = printer("sim2")
    lines = recorded(detail_view(farm_row(2, farm_printer, model), model, farm_printer, width, height=40), width)
    assert lines[-1] in DETAIL_KEYS_HELP and re.search(r"\bq quits?$", lines[-1])
    assert ("Esc" in lines[-1]) is (width >= 16)


# ------------------------------------------------------------------------------------------- the print view


PRINTING = PrintStatus(
    "benchy_0.2mm_PLA.gcode",
    12_345,
    98_765,
    lines_per_s=150.0,
    temperatures="hotend 210.0/210 °C   bed 60.0/60 °C",
    keys=KEYS_HELP,
)


@pytest.mark.parametrize("width", WIDTHS)
def test_the_print_view_keeps_the_percent_and_the_eta(width: int) -> None:
    lines = recorded(print_view(PRINTING), width)
    bar = lines[0]
    assert re.search(r"\b12\.5% .*ETA 0:09:36$", bar), lines
    assert bar.startswith("benchy_0.2m")  # the name, cut when it must be
    if width >= 80:
        assert "12345/98765 lines 150 lines/s  ETA 0:09:36" in bar
    if width <= 40:
        assert "lines/s" not in bar  # the rate went first
    # The temperatures stay on one line; narrow, in whole degrees.
    assert re.search(r"hotend 210(\.0)?/210 .*bed 60(\.0)?/60", lines[1]), lines
    # The keys: all of them, in fewer words at 60 columns and less; wrapped rather than lost at 30.
    keys = " ".join(lines[2:])
    assert all(key in keys for key in ("p pause", "r resume", "! ", "cancel")), lines


@pytest.mark.parametrize("width", WIDTHS)
def test_the_print_view_keeps_what_it_waits_for(width: int) -> None:
    waiting = PrintStatus(
        "part.gcode",
        500,
        1_000,
        state="heating",
        heating="heating hotend 187/200 C",
        temperatures="hotend 187.0/200 °C   bed 60.0/60 °C",
    )
    bar = recorded(print_view(waiting), width)[0]
    assert re.search(r"50\.0% .*heating hotend 187/200 C$", bar), bar
    assert "ETA" not in bar and "lines/s" not in bar


def test_the_print_view_laid_out_for_a_width_is_the_one_drawn_at_that_width() -> None:
    # Without a width the view is laid out when drawn (a live terminal can be resized): the same as given one.
    assert recorded(print_view(PRINTING), 40) == recorded(print_view(PRINTING, 40), 40)


# ------------------------------------------------------------------------------------------- a real terminal


@needs_tmux
def test_the_farm_view_in_a_40_column_terminal_keeps_q_and_q_quits(tmux: Tmux) -> None:
    command = (
        f"stty cols 40 rows 30; {sys.executable} -m marlin_temp watch --sims 3 --sim-speed 20 --refresh 0.3; "
        "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit status
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "40", "-y", "30", command)
    rows = r"^\d\s+sim\d\s+\d+/off\s+\d+/off\s+idle\s+up\s*$"
    screen = tmux.wait_for(lambda s: len(re.findall(rows, s, re.MULTILINE)) == 3, "three rows with readings")
    assert "1-9 ↑↓ Enter: details  q quits" in screen, screen

    tmux.run("send-keys", "-t", "w", "2")
    detail = tmux.wait_for(lambda s: "sim2 (2)" in s and "polls/s" in s, "sim2's detail")
    assert "Esc" in detail and re.search(r"q quits?\s*$", detail.rstrip()), detail

    tmux.run("send-keys", "-t", "w", "q")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
    assert "MARLIN-EXIT=0" in after


@needs_tmux
def test_the_print_view_in_a_40_column_terminal_keeps_the_percent_and_the_eta(tmux: Tmux, tmp_path: Path) -> None:
    gcode = tmp_path / "a_long_file_name_for_a_narrow_terminal.gcode"
    gcode.write_text("G4 P5\n" * 30_000)  # dwells pace the print: it still runs when the screen is read
    command = (
        f"stty cols 40 rows 20; {sys.executable} -m marlin_temp print {gcode} --sim; echo MARLIN-EXIT=$?; sleep 600"
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "40", "-y", "20", command)
    bar = r"^a_long_file\S*…\s.*\d+\.\d% ETA \d+:\d\d:\d\d\s*$"
    screen = tmux.wait_for(lambda s: re.search(bar, s, re.MULTILINE) is not None, "the percent and the ETA")
    assert re.search(r"^\s*hotend \d+\.\d/off °C\s+bed \d+\.\d/off °C\s*$", screen, re.MULTILINE), screen
    assert "p pause  r resume  ! stop  ^C cancel" in screen

    tmux.run("send-keys", "-t", "w", "C-c")
    tmux.wait_for(lambda s: "cancel the print?" in s, "the question")
    tmux.run("send-keys", "-t", "w", "y")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "print to exit")
    assert f"MARLIN-EXIT={int(Exit.INTERRUPTED)}" in after, after
