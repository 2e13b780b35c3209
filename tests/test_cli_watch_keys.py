"""`marlin-temp watch` with keys, and on narrow terminals.

The keys' meaning is pure (`WatchControls`: key in, action or notice out) and tested without I/O; the actions are
performed against the simulated printer on a real pty; the whole live view runs under tmux, where the screen is
read back until what a key should change shows up (polled with a deadline, never a fixed sleep). Rendering is
checked at 40, 60, 80 and 120 columns with a recording Console.
"""

from __future__ import annotations

import asyncio
import io
import re
import sys
from dataclasses import replace

import pytest
from rich.console import Console
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import HeaterLimits, TemperatureReading
from marlin_aio.protocol import DEFAULT_LIMITS, ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.keys import split_keys
from marlin_temp.common.model import (
    Notice,
    Quit,
    SendCommand,
    SetFan,
    SetTargets,
    TurnOff,
    WatchControls,
    WatchModel,
)
from marlin_temp.common.render import controls_view, heater_table, watch_view
from marlin_temp.main import app
from marlin_temp.watch.command import _outcome, _perform

WIDTHS = (40, 60, 80, 120)


def reading(text: str, time_s: float) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_700_000_000 + time_s, ReadingSource.POLL)


def model_with(text: str, seconds: float = 5.0) -> WatchModel:
    model = WatchModel(window_s=60)
    for step in range(int(seconds * 10)):
        model.add(reading(text, step / 10))
    return model


def press(controls: WatchControls, keys: str | list[str], model: WatchModel | None = None) -> list[object]:
    """Press each key; return the actions that came out (None left out)."""
    model = model or model_with("T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0")
    actions = [controls.press(key, model) for key in keys]
    return [action for action in actions if action is not None]


# ------------------------------------------------------------------------------------------- keys (pure)


def test_presets_set_both_targets_at_once() -> None:
    controls = WatchControls()
    assert press(controls, "1") == [SetTargets(hotend=200.0, bed=60.0, label="PLA")]
    assert press(controls, "2") == [SetTargets(hotend=240.0, bed=80.0, label="PETG")]


def test_typing_a_target_sets_it_on_enter_and_esc_cancels() -> None:
    controls = WatchControls()
    assert press(controls, "h") == []
    assert controls.prompt == "hotend target °C"
    assert press(controls, "2x1a5") == []  # letters typed by mistake never become part of a target
    assert controls.buffer == "215"
    assert press(controls, "\x7f") == [] and controls.buffer == "21"  # backspace
    assert press(controls, "5\r") == [SetTargets(hotend=215.0)]
    assert controls.prompt is None
    assert press(controls, ["b", "6", "0", "\n"]) == [SetTargets(bed=60.0)]
    assert press(controls, ["b", "9", "\x1b"]) == []  # Esc: nothing set
    assert controls.prompt is None and controls.buffer == ""
    assert press(controls, "h\r") == []  # Enter on an empty line only closes it


@pytest.mark.parametrize(
    ("keys", "limits", "message"),
    [
        (
            "h900\r",
            DEFAULT_LIMITS,
            "hotend target 900 C is above the limit of 260 C (raise the limit with --max-hotend)",
        ),
        ("b141\r", DEFAULT_LIMITS, "above the limit of 140 C (raise the limit with --max-bed)"),
        ("h.\r", DEFAULT_LIMITS, "must be a number"),
        ("2", replace(DEFAULT_LIMITS, hotend=230), "PETG: hotend target 240 C is above the limit of 230 C"),
        ("1", replace(DEFAULT_LIMITS, bed=50), "PLA: bed target 60 C is above the limit of 50 C"),
    ],
)
def test_a_refused_target_is_a_notice_never_an_action(keys: str, limits: HeaterLimits, message: str) -> None:
    controls = WatchControls(limits)
    assert press(controls, keys) == []
    assert controls.notice is not None and controls.notice.error
    assert message in controls.notice.title and controls.notice.title.endswith("; nothing sent")
    assert controls.notice.lines == ()  # one line


def test_plus_and_minus_step_the_heater_chosen_last_from_what_was_asked() -> None:
    controls = WatchControls()
    model = model_with("T:190.00 /200.00 B:25.00 /0.00 @:60 B@:0")
    assert press(controls, "+", model) == [SetTargets(hotend=205.0)]
    # Pressed again before a reading shows 205: it steps from what was asked, not from the stale 200.
    assert press(controls, "=", model) == [SetTargets(hotend=210.0)]
    model.add(reading("T:190.00 /210.00 B:25.00 /0.00 @:60 B@:0", 10.0))
    assert press(controls, "-", model) == [SetTargets(hotend=205.0)]
    assert press(controls, "b\x1b", model) == []  # choosing the bed, even without setting it, moves +/- to it
    assert "+/- 5C bed" in controls.help_items()
    assert press(controls, "-", model) == []
    assert controls.notice == Notice("the bed is already off")
    assert press(controls, "+", model) == [SetTargets(bed=5.0)]


def test_a_failed_set_no_longer_counts_as_asked() -> None:
    controls = WatchControls()
    model = model_with("T:25.00 /200.00 B:25.00 /0.00 @:0 B@:0")
    [action] = press(controls, "+", model)
    assert action == SetTargets(hotend=205.0)
    controls.finished(action, Notice("no answer", error=True))
    assert press(controls, "+", model) == [SetTargets(hotend=205.0)]


def test_off_fan_command_and_quit() -> None:
    controls = WatchControls()
    assert press(controls, "o") == [TurnOff()]
    assert press(controls, "f50\r") == [SetFan(50.0)]
    assert press(controls, "f150\r") == []
    assert controls.notice is not None and controls.notice.error and "0 to 100 %" in controls.notice.title
    # The G-code line keeps case and takes any printable character, q included; arrow keys are ignored.
    assert press(controls, [":", *"M117 Quick", "\x1b[D", "\r"]) == [SendCommand("M117 Quick")]
    assert press(controls, "Q") == [Quit()]
    assert press(controls, "q") == [Quit()]


def test_without_keys_the_help_says_ctrl_c() -> None:
    assert WatchControls(keys_enabled=False).help_items() == ["Ctrl-C quits (keys need a terminal on stdin)"]
    items = WatchControls().help_items()
    presets = ["1 PLA", "2 PETG", "3 ABS", "4 cooldown"]  # the default presets (no presets file)
    assert items == [
        "h hotend",
        "b bed",
        "o off",
        "+/- 5C hotend",
        *presets,
        "f fan",
        ": command",
        "w window",
        "q quit",
    ]


def test_split_keys_keeps_escape_sequences_whole() -> None:
    assert split_keys("h2\r") == ["h", "2", "\r"]
    assert split_keys("\x1b[A\x1b[1;5C\x1bOPx") == ["\x1b[A", "\x1b[1;5C", "\x1bOP", "x"]
    assert split_keys("\x1b") == ["\x1b"]
    assert split_keys("\x1bq") == ["\x1b", "q"]  # Esc then q, typed quickly


# ------------------------------------------------------------------------------------------- narrow terminals


MODELS = {
    "one hotend": "T:123.80 /200.00 B:37.00 /60.00 @:127 B@:127",
    "two hotends, bed, chamber": (
        "T:123.80 /200.00 T0:123.80 /200.00 T1:99.10 /215.00 B:37.00 /60.00 C:30.00 /40.00 @:127 B@:127"
    ),
}


def heating(text: str) -> WatchModel:
    model = WatchModel(window_s=60)
    for step in range(200):
        model.add(reading(text.replace("123.80", f"{25 + step * 0.5:.2f}"), step / 10))
    model.add_latency(19.0, 0.0008)
    return model


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("name", list(MODELS))
def test_the_view_fits_every_width_without_cutting_names_or_units(width: int, name: str) -> None:
    model = heating(MODELS[name])
    controls = WatchControls()
    controls.notice = Notice("> M114", ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok"))
    console = Console(record=True, width=width)
    console.print(watch_view(model, "/dev/pts/12 (simulated)", "Marlin 2.1.2.4", width=width, controls=controls))
    text = console.export_text()
    assert "…" not in text and "..." not in text
    table = text.split("\n\n")[0]
    # Every line of the table fits as it is: nothing wrapped ("°C" alone on a line) and nothing cut.
    assert all(len(line.rstrip()) <= width for line in table.splitlines())
    for key in model.heater_keys():
        status = model.status(key)
        row = next(line for line in table.splitlines() if line.strip().startswith(status.name + " "))
        assert f"{status.actual:.1f}" in row
    assert "°C" in table
    assert "h hotend" in text and "q quit" in text and "2 PETG" in text
    assert "latency 0.8 ms median" in text  # the footer breaks between its parts, not inside one


def test_wide_terminals_keep_units_in_the_cells_and_narrow_ones_move_them_to_the_header() -> None:
    model = heating(MODELS["one hotend"])
    statuses = [model.status(key) for key in model.heater_keys()]

    def rendered(width: int) -> str:
        console = Console(record=True, width=width)
        console.print(heater_table(statuses, width))
        return console.export_text()

    assert re.search(r"hotend\s+\d+\.\d °C\s+200 °C\s+100 %\s+\+\d+\.\d\d °C/s", rendered(120))
    narrow = rendered(60)
    assert re.search(r"^\s+actual\s+target\s+power\s+rate", narrow, re.MULTILINE)
    assert re.search(r"^heater\s+°C\s+°C\s+%\s+°C/s", narrow, re.MULTILINE)
    assert re.search(r"^hotend\s+\d+\.\d\s+200\s+100\s+\+\d+\.\d\d\s+heating", narrow, re.MULTILINE)
    assert "heating" in rendered(40) and "hotend" in rendered(40)


@pytest.mark.parametrize("width", WIDTHS)
def test_the_chart_takes_the_rows_the_other_parts_leave(width: int) -> None:
    model = heating(MODELS["two hotends, bed, chamber"])
    controls = WatchControls()
    controls.notice = Notice("> M503", tuple(f"echo: line {n}" for n in range(8)))

    def rendered(height: int) -> list[str]:
        console = Console(record=True, width=width, height=height)
        console.print(watch_view(model, "/dev/pts/12", "Marlin 2.1.2.4", width=width, height=height, controls=controls))
        return console.export_text().splitlines()

    def chart_rows(lines: list[str]) -> int:
        return sum(1 for line in lines if line[5:6] in ("┤", "│"))

    assert len(rendered(40)) == 39  # one line spare, for the cursor
    tall = rendered(80)
    assert chart_rows(tall) == 30 and len(tall) < 79  # the chart stops at 30 rows
    # A short terminal: the chart gives way, and the reply's last line and how to quit stay on screen.
    short = rendered(26)
    assert len(short) <= 25
    assert any("echo: line 7" in line for line in short) and any("q quit" in line for line in short)


# ------------------------------------------------------------------------------------------- actions on a printer


async def test_actions_reach_the_printer_and_their_outcome_is_told(
    pty_sim: SimulatorServer, printer: marlin_aio.Printer
) -> None:
    model = WatchModel()
    model.add(await printer.read_temperatures())
    notice = await _perform(printer, SetTargets(hotend=200.0, bed=60.0, label="PLA"), model)
    assert notice == Notice("PLA: hotend target 200 °C, bed target 60 °C")
    reply = await _perform(printer, SendCommand("M114"), model)
    assert reply.title == "> M114" and any(line.startswith("X:") for line in reply.lines) and reply.lines[-1] == "ok"
    assert await _perform(printer, SetFan(50.0), model) == Notice("fan 50 %")
    assert await _perform(printer, TurnOff(), model) == Notice("every heater off")
    executed = list(pty_sim.printer.executed)
    for command in ("M104 S200", "M140 S60", "M114", "M106 S128", "M104 S0", "M140 S0"):
        assert command in executed


@pytest.mark.parametrize("text", ["M117 héllo", "M117 a*b", "M104 S999"])
async def test_a_command_the_library_refuses_is_never_sent(
    pty_sim: SimulatorServer, printer: marlin_aio.Printer, text: str
) -> None:
    before = pty_sim.printer.executed_count
    # M104 S999: a target typed on the : line meets the same limits as the keys' (the library's send checks it).
    with pytest.raises(ValueError, match=r"non-ASCII|'\*'|above the limit of 260"):
        await _perform(printer, SendCommand(text), WatchModel())
    await printer.send("M400")  # anything written before this would have run before it
    assert pty_sim.printer.executed_count == before + 1


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("M104 S999", "hotend target 999 C is above the limit of 260 C; nothing sent"),
        ("M104 Sabc", "hotend target must be a number"),
        ("M140 S-5", "bed target must not be negative"),
        ("M104\nS200", "line break"),
    ],
)
async def test_bad_input_on_the_colon_line_is_one_line_in_the_view_and_never_sent(
    pty_sim: SimulatorServer, printer: marlin_aio.Printer, text: str, message: str
) -> None:
    before = pty_sim.printer.executed_count
    controls = WatchControls()
    action = SendCommand(text)
    notice = await _outcome(printer, action, WatchModel())  # what the view's action task makes of it
    controls.finished(action, notice)
    assert notice.error and message in notice.title and notice.lines == ()
    console = Console(record=True, width=300, file=io.StringIO(), color_system=None)
    console.print(controls_view(controls, 300))
    shown = console.export_text().splitlines()
    assert [line for line in shown if "error:" in line] == [shown[0]] and shown[1].startswith("h hotend")
    assert not controls.heated  # refused: it set nothing
    await printer.send("M400")  # anything written before this would have run before it
    assert pty_sim.printer.executed_count == before + 1


def test_a_pasted_line_with_a_line_break_in_it_is_one_line_saying_nothing_was_sent() -> None:
    from marlin_temp.common.keys import PASTE

    controls = WatchControls()
    assert press(controls, [":", PASTE + "M104 S200\nM140 S60\n"]) == []
    assert controls.notice is not None and controls.notice.lines == ()
    assert controls.notice.title == "several lines pasted; nothing sent: one line at a time"


def test_keys_that_set_a_target_are_remembered_for_the_way_out() -> None:
    controls = WatchControls()
    controls.finished(SetTargets(hotend=0.0), Notice("hotend target off"))
    assert not controls.heated  # turning a heater off leaves nothing on to warn of
    controls.finished(SendCommand("M114"), Notice("> M114"))
    assert not controls.heated
    controls.finished(SetTargets(hotend=200.0), Notice("refused", error=True))
    assert not controls.heated
    controls.finished(SendCommand("m140 s60"), Notice("> m140 s60"))
    assert controls.heated
    other = WatchControls()
    other.finished(SetTargets(bed=60.0, label="PLA"), Notice("PLA: bed target 60 °C"))
    assert other.heated


# ------------------------------------------------------------------------------------------- a real terminal


def sized(command: str, columns: int, rows: int) -> str:
    """`command` in a terminal of this size, said to the pty itself: the first pane of a fresh tmux server can
    start with the pty at 80x24 while tmux draws it at the size asked for, and rich would lay out for 80."""
    return f"stty cols {columns} rows {rows}; {command}"


def flat(screen: str) -> str:
    """The screen's words with single spaces: a message wrapped onto two lines reads as one."""
    return " ".join(screen.split())


def table_row(screen: str, name: str) -> str:
    """The heater table's row for `name` (the chart's legend and the notices name heaters too)."""
    for line in screen.splitlines():
        if re.match(rf"^\s*{name}\s+\d+\.\d", line):
            return line
    return ""


def hotend_target_shows(target: str) -> re.Pattern[str]:
    return re.compile(rf"^\s*hotend\s+\d+\.\d( °C)?\s+{target}\b", re.MULTILINE)


@needs_tmux
def test_keys_set_targets_and_send_gcode_in_the_live_view(tmux: Tmux) -> None:
    command = (
        f"{sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.3; "
        "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit status
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", sized(command, 100, 40))
    screen = tmux.wait_for(lambda s: "polls/s" in s and "h hotend" in s, "the live view with its key help")
    assert "1 PLA" in screen and ": command" in screen and "q quit" in screen

    tmux.run("send-keys", "-t", "w", "1")  # PLA: 200 / 60
    tmux.wait_for(lambda s: "200 °C" in table_row(s, "hotend") and "60 °C" in table_row(s, "bed"), "the PLA targets")

    tmux.run("send-keys", "-t", "w", "h")
    tmux.wait_for(lambda s: "hotend target °C:" in s and "Esc cancels" in s, "the input line")
    tmux.run("send-keys", "-t", "w", "-l", "215")
    tmux.wait_for(lambda s: "hotend target °C: 215" in s, "the digits typed")
    tmux.run("send-keys", "-t", "w", "Enter")
    tmux.wait_for(lambda s: "215 °C" in table_row(s, "hotend"), "the typed hotend target")

    tmux.run("send-keys", "-t", "w", "-l", "h900")
    tmux.run("send-keys", "-t", "w", "Enter")
    screen = tmux.wait_for(lambda s: "nothing sent" in flat(s), "the refused target")
    assert "error: hotend target 900 C is above the limit of 260 C (raise the limit with --max-hotend)" in flat(screen)
    assert "215 °C" in table_row(screen, "hotend")

    tmux.run("send-keys", "-t", "w", "-l", ":M114")
    tmux.wait_for(lambda s: "G-code: M114" in s, "the G-code line")
    tmux.run("send-keys", "-t", "w", "Enter")
    screen = tmux.wait_for(lambda s: "> M114" in s and "X:" in s, "the reply under the chart")
    assert screen.index("now") < screen.index("> M114")  # under the chart

    tmux.run("send-keys", "-t", "w", "-l", ":M104 S999")
    tmux.run("send-keys", "-t", "w", "Enter")
    screen = tmux.wait_for(lambda s: "999 C" in s, "the refused G-code line")
    assert "error: hotend target 999 C is above the limit of 260 C; nothing sent" in flat(screen)
    assert "215 °C" in table_row(screen, "hotend")

    tmux.run("send-keys", "-t", "w", "q")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
    assert "MARLIN-EXIT=0" in after
    # The keys left the hotend and the bed on: the way out says so, in set's words.
    assert re.search(
        r"the heaters stay on \(hotend \d+\.\d/215 C, bed \d+\.\d/60 C\)\. Turn them off with:", flat(after)
    )
    assert "marlin-temp set --off" in flat(after)


@needs_tmux
async def test_at_40_columns_a_refused_target_is_shown_and_never_sent(tmux: Tmux) -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        command = (
            f"{sys.executable} -m marlin_temp watch --port {sim.url} --refresh 0.3; echo MARLIN-EXIT=$?; sleep 600"
        )
        # The simulator runs in this event loop: the terminal is polled from a thread so the printer keeps answering.
        await asyncio.to_thread(
            tmux.run, "new-session", "-d", "-s", "w", "-x", "40", "-y", "30", sized(command, 40, 30)
        )
        screen = await asyncio.to_thread(tmux.wait_for, lambda s: "h hotend" in s and "°C" in s, "the live view")
        assert "…" not in screen and "..." not in screen
        assert table_row(screen, "hotend") and table_row(screen, "bed")

        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "-l", "h900")
        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "Enter")
        await asyncio.to_thread(tmux.wait_for, lambda s: "limit of 260 C" in flat(s), "the refused hotend")
        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "-l", "b200")
        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "Enter")
        await asyncio.to_thread(tmux.wait_for, lambda s: "limit of 140 C" in flat(s), "the refused bed")

        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "2")  # PETG: 240 / 80
        screen = await asyncio.to_thread(
            tmux.wait_for, lambda s: bool(hotend_target_shows("240").search(s)), "the PETG hotend target"
        )
        assert "…" not in screen and "..." not in screen

        await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", "q")
        after = await asyncio.to_thread(tmux.wait_for, lambda s: "MARLIN-EXIT=" in s, "watch to exit")
        assert "MARLIN-EXIT=0" in after
        executed = list(sim.printer.executed)
    assert "M104 S240" in executed and "M140 S80" in executed
    assert not [c for c in executed if c.startswith(("M104", "M140")) and c not in ("M104 S240", "M140 S80")]


def test_watch_help_lists_the_keys() -> None:
    result = CliRunner().invoke(app, ["watch", "--help"], env={"COLUMNS": "120"})
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    for words in ("1 PLA", "2 PETG", "--max-hotend", "--max-bed", "G-code line", "40 columns"):
        assert words in text


@needs_tmux
def test_without_a_terminal_on_stdin_the_live_view_has_no_keys(tmux: Tmux) -> None:
    command = (
        f"echo h2 | {sys.executable} -m marlin_temp watch --sim --sim-speed 20 --refresh 0.3 --duration 4; "
        "echo MARLIN-EXIT=$?; sleep 600"
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", sized(command, 100, 40))
    screen = tmux.wait_for(lambda s: "polls/s" in s, "the live view")
    assert "Ctrl-C quits (keys need a terminal on stdin)" in screen and "h hotend" not in screen
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to end after --duration")
    assert "MARLIN-EXIT=0" in after


def test_a_paste_is_never_taken_for_keys() -> None:
    from marlin_temp.common.keys import PASTE

    controls = WatchControls()
    # Two lines pasted into the : line: nothing is sent, and the "o" and "1" in them turn nothing off or on.
    assert press(controls, [":", PASTE + "M117 hello\r\nM117 world 1\r\n"]) == []
    assert controls.notice is not None and controls.notice.error and "several lines" in controls.notice.title
    assert controls.prompt is None
    # Outside an input line a paste does nothing at all, unless it starts with the key of one (typed fast).
    assert press(controls, [PASTE + "o1q2"]) == []
    assert controls.notice is not None and "ignored" in controls.notice.title
    assert press(controls, [PASTE + "h215\r"]) == [SetTargets(hotend=215.0)]
    # One line pasted into the : line is taken whole, and sent with the Enter that ends it.
    assert press(controls, [":", PASTE + "M117 hi there\r"]) == [SendCommand("M117 hi there")]
