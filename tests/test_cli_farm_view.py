"""`marlin-temp watch` with several printers: the farm view.

The rows and the keys are pure and tested without I/O (the table rendered at 60, 80 and 120 columns into a
recording Console); the command runs through CliRunner with three simulated printers (piped: one line per printer
per refresh) and under tmux (rows, a digit opens a printer's detail, Esc goes back, q quits). One printer
unplugged is tested against simulators on TCP served by the test itself, so that one can be pulled and come back
while the watch polls all three.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import re
import sys
from dataclasses import replace

import pytest
from conftest import until
from rich.console import Console
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.farm.config import specs_from_options
from marlin_aio.farm.supervisor import FarmPrinter, PrinterSpec
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, serve_tcp
from marlin_temp.common.model import WatchModel
from marlin_temp.farm.view import (
    FarmKeys,
    FarmRow,
    HeaterCell,
    detail_view,
    farm_row,
    farm_table,
    farm_view,
    json_lines,
    link_text,
    plain_lines,
)
from marlin_temp.main import app
from marlin_temp.watch.command import WatchSettings, watch_farm

WIDTHS = (60, 80, 120)
LOST = "connection lost: the printer closed the link (unplugged, or the board reset?); 3 commands failed"


def reading(text: str, time_s: float) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_700_000_000 + time_s, ReadingSource.POLL)


def model_with(*texts: str, seconds: float = 5.0) -> WatchModel:
    """A model fed `texts` in turn over `seconds` (10 readings a second), so rates and states are known."""
    model = WatchModel(window_s=60)
    count = int(seconds * 10)
    for step in range(count):
        model.add(reading(texts[min(step * len(texts) // count, len(texts) - 1)], step / 10))
    return model


def printer(name: str, *, up: bool = True, error: str | None = None, connections: int = 1) -> FarmPrinter:
    farm_printer = FarmPrinter(PrinterSpec(name=name, port=f"socket://127.0.0.1:{len(name)}"))
    farm_printer.link_up = up
    farm_printer.last_error = error
    farm_printer.connections = connections
    return farm_printer


def recorded(renderable: object, width: int) -> str:
    console = Console(record=True, width=width, file=io.StringIO(), color_system=None)
    console.print(renderable)
    return console.export_text()


# ------------------------------------------------------------------------------------------- rows (pure)


def test_a_row_names_each_heater_with_actual_and_target_and_the_printer_state() -> None:
    heating = model_with("T:150.00 /210.00 B:50.00 /60.00 @:127 B@:127", "T:180.00 /210.00 B:58.00 /60.00 @:127 B@:90")
    row = farm_row(1, printer("prusa-1"), heating)
    assert row.link == "up" and row.state == "heating" and row.progress is None
    assert [(cell.name, cell.text()) for cell in row.heaters] == [("hotend", "180.0/210"), ("bed", "58.0/60")]

    idle = farm_row(2, printer("ender"), model_with("T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"))
    assert idle.state == "idle" and [cell.text() for cell in idle.heaters] == ["25.0/off", "25.0/off"]

    holding = farm_row(3, printer("mk4"), model_with("T:209.50 /210.00 B:60.00 /60.00 @:40 B@:20"))
    assert holding.state == "holding"


def test_the_link_says_up_connecting_or_down_with_when_it_reconnects_and_why() -> None:
    assert link_text(printer("a", up=False, connections=0)) == "connecting"
    down = printer("b", up=False, error=LOST)
    down.reconnect_at_s = 103.2
    # The error's explanation (in parentheses) and its second clause are left out: the row has no room for them.
    assert link_text(down, now_s=100.0) == "down, reconnecting in 4 s: connection lost: the printer closed the link"
    down.reconnect_at_s = None  # trying now
    assert link_text(down, now_s=100.0).startswith("down, reconnecting now: connection lost")
    # A down printer shows no temperatures: its last ones would read as current.
    row = farm_row(2, down, model_with("T:200.00 /210.00 B:60.00 /60.00 @:60 B@:20"))
    assert row.heaters == () and row.state == "-" and not row.link_up


def rows_of_a_farm() -> list[FarmRow]:
    return [
        FarmRow(
            1,
            "prusa-mk3s-1",
            True,
            "up",
            (HeaterCell("T", "hotend", 204.6, 210.0), HeaterCell("B", "bed", 60.0, 60.0)),
            "printing",
            "42%",
        ),
        FarmRow(2, "ender", False, "down, reconnecting in 8 s: " + LOST, (), "-", None),
        FarmRow(
            3,
            "voron",
            True,
            "up",
            (HeaterCell("T", "hotend", 25.0, 0.0), HeaterCell("B", "bed", 25.1, None)),
            "idle",
            None,
        ),
    ]


@pytest.mark.parametrize("width", WIDTHS)
def test_the_farm_table_fits_each_width_and_cuts_only_the_link(width: int) -> None:
    text = recorded(farm_table(rows_of_a_farm(), width), width)
    lines = text.rstrip("\n").split("\n")
    assert len(lines) == 4  # the header and one line per printer: nothing wraps
    assert all(len(line.rstrip()) <= width for line in lines)
    header, first, second, third = lines
    units = " °C" if width >= 80 else ""  # narrow: whole degrees, and the unit left to the title
    for column in ("#", "printer", f"hotend{units}", f"bed{units}", "state", "print", "link"):
        assert column in header
    if width >= 80:
        assert re.search(r"1\s+prusa-mk3s-1\s+204\.6/210\s+60\.0/60\s+printing\s+42%\s+up", first)
        assert re.search(r"2\s+ender\s+-\s+-\s+-\s+-\s+down, reconnecting in 8 s", second)
        # The bed's target is not reported (None): unknown, not off.
        assert re.search(r"3\s+voron\s+25\.0/off\s+25\.1/\?\s+idle\s+-\s+up", third)
    else:
        assert re.search(r"1\s+prusa-mk3s-1\s+205/210\s+60/60\s+printing\s+42%\s+up", first)
        assert re.search(r"2\s+ender\s+-\s+-\s+-\s+-\s+down, retry 8 s", second)
        assert re.search(r"3\s+voron\s+25/off\s+25/\?\s+idle\s+-\s+up", third)
    if width < 120:
        # No room for the error: when it retries stays whole.
        assert second.rstrip().endswith("down, retry 8 s" if width < 80 else "down, reconnecting in 8 s")
    else:
        assert "s: connection lost" in second and second.rstrip().endswith("…")  # the error is cut, and says so


@pytest.mark.parametrize("width", WIDTHS)
def test_the_farm_view_has_a_title_events_and_the_keys(width: int) -> None:
    view = farm_view(rows_of_a_farm(), width, selected=1, events=["12:00:01 ender: " + LOST])
    text = recorded(view, width)
    assert all(len(line.rstrip()) <= width for line in text.split("\n"))
    assert text.startswith("farm: 3 printers, 2 up")
    assert "12:00:01 ender: connection lost" in text
    assert "1-9 or ↑/↓ and Enter" in text and "q quits" in text
    without_keys = recorded(farm_view(rows_of_a_farm(), width, keys_enabled=False), width)
    assert "Ctrl-C quits (keys need a terminal on stdin)" in without_keys and "1-9" not in without_keys


@pytest.mark.parametrize("width", WIDTHS)
def test_the_detail_view_is_the_single_printer_view_under_the_printers_link(width: int) -> None:
    model = model_with("T:150.00 /210.00 B:50.00 /60.00 @:127 B@:127", "T:180.00 /210.00 B:58.00 /60.00 @:127 B@:90")
    farm_printer = printer("sim2")
    text = recorded(detail_view(farm_row(2, farm_printer, model), model, farm_printer, width, height=30), width)
    lines = text.rstrip("\n").split("\n")
    assert lines[0].startswith("sim2 (2)  up")
    assert all(len(line.rstrip()) <= width for line in lines)
    assert "hotend" in text and "now" in text and "polls/s" in text  # the table, the chart, the footer
    assert "Esc" in lines[-1] and "back to the farm" in lines[-1] and "q quits" in lines[-1]  # shorter, never cut

    down = printer("sim2", up=False, error=LOST)
    down.reconnect_at_s = 10.0
    waiting = recorded(detail_view(farm_row(2, down, WatchModel(), now_s=5.0), WatchModel(), down, width), width)
    assert "sim2 (2) down, reconnecting in 5 s: connection lost" in " ".join(waiting.split())
    assert "waiting for the first reading" in waiting


def test_no_print_column_when_no_printer_prints() -> None:
    rows = [replace(row, progress=None) for row in rows_of_a_farm()]
    header = recorded(farm_table(rows, 120), 120).split("\n")[0]
    assert "print" not in header.replace("printer", "")


def test_plain_and_json_lines_give_one_line_per_printer() -> None:
    lines = plain_lines(rows_of_a_farm(), wall_time_s=0)
    assert len(lines) == 3
    assert re.fullmatch(
        r"\d\d:\d\d:\d\d prusa-mk3s-1: up \| hotend 204\.6/210 C \| bed 60\.0/60 C \| printing \| print 42%", lines[0]
    )
    assert re.fullmatch(r"\d\d:\d\d:\d\d ender: down, reconnecting in 8 s: connection lost.*…", lines[1])
    objects = [json.loads(line) for line in json_lines(rows_of_a_farm(), wall_time_s=5.0)]
    assert [item["printer"] for item in objects] == ["prusa-mk3s-1", "ender", "voron"]
    assert objects[0]["heaters"] == {
        "hotend": {"actual": 204.6, "target": 210.0},
        "bed": {"actual": 60.0, "target": 60.0},
    }
    assert objects[0]["print"] == "42%" and objects[1]["link_up"] is False and objects[1]["heaters"] == {}


def test_keys_open_a_printer_go_back_and_quit() -> None:
    keys = FarmKeys(3)
    assert not keys.press("2") and keys.detail == 1
    assert not keys.press("\x1b") and keys.detail is None  # Esc
    assert not keys.press("\x1b[B") and keys.selected == 2 and keys.detail is None  # down from the second
    assert not keys.press("\x1b[B") and keys.selected == 2  # the last stays the last
    assert not keys.press("\r") and keys.detail == 2
    assert not keys.press("\x1b[A") and keys.detail == 1  # in a detail, up steps to the printer before
    assert not keys.press("\x7f") and keys.detail is None  # Backspace
    assert not keys.press("7") and keys.detail is None  # no seventh printer
    assert keys.press("q") and FarmKeys(1).press("Q")


# ------------------------------------------------------------------------------------------- the command


def test_watch_sims_3_piped_prints_a_line_per_printer_per_refresh() -> None:
    result = CliRunner().invoke(
        app, ["watch", "--sims", "3", "--sim-speed", "20", "--refresh", "0.5", "--duration", "5"]
    )
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stdout.splitlines() if line]
    assert lines and len(lines) % 3 == 0
    names = [re.match(r"\d\d:\d\d:\d\d (sim\d): ", line) for line in lines]
    assert all(names), lines
    assert [m.group(1) for m in names if m] == ["sim1", "sim2", "sim3"] * (len(lines) // 3)
    last = lines[-3:]
    assert all(" up | hotend " in line and " bed " in line for line in last), last
    assert "watched 3 printers" in result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--sims", "2", "--log", "x.csv"], "--log records one printer"),
        (["--port", "a=/dev/null", "--port", "a=/dev/zero"], "printer name 'a' is given twice"),
        (["--port", "a b=/dev/null", "--sim"], "printer name 'a b' must be letters"),
    ],
)
def test_bad_farm_options_are_one_line_and_exit_2(args: list[str], message: str) -> None:
    result = CliRunner().invoke(app, ["watch", *args])
    assert result.exit_code == 2
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_watch_help_explains_the_farm_view() -> None:
    result = CliRunner().invoke(app, ["watch", "--help"], env={"COLUMNS": "120"})
    text = " ".join(result.output.split())
    for words in ("--sims", "farm view", "NAME=PORT", "Esc or Backspace"):
        assert words in text


# ------------------------------------------------------------------------------------------- a real terminal


def farm_rows(screen: str) -> dict[str, str]:
    """The farm table's rows by printer name."""
    return {m.group(1): m.group(0) for m in re.finditer(r"^\s*\d\s+(sim\d)\s+.*$", screen, re.MULTILINE)}


@needs_tmux
def test_the_farm_view_opens_a_printer_on_a_digit_and_goes_back_on_esc(tmux: Tmux) -> None:
    command = (
        f"stty cols 100 rows 40; {sys.executable} -m marlin_temp watch --sims 3 --sim-speed 20 --refresh 0.3; "
        "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit status
    )
    tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", command)
    screen = tmux.wait_for(
        lambda s: (
            len(farm_rows(s)) == 3 and all(re.search(r"\d+\.\d/off .* up$", row) for row in farm_rows(s).values())
        ),
        "three rows with readings, all up",
    )
    assert "farm: 3 printers, 3 up" in screen and "hotend °C" in screen and "bed °C" in screen

    tmux.run("send-keys", "-t", "w", "2")
    screen = tmux.wait_for(lambda s: "sim2 (2)" in s and "polls/s" in s, "sim2's detail")
    assert "heater" in screen and "now" in screen  # the single-printer table and chart
    assert not farm_rows(screen)

    tmux.run("send-keys", "-t", "w", "Escape")
    tmux.wait_for(lambda s: "farm: 3 printers" in s and len(farm_rows(s)) == 3, "the farm again")

    tmux.run("send-keys", "-t", "w", "q")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
    assert "MARLIN-EXIT=0" in after


# ------------------------------------------------------------------------------------------- one unplugged


class Output:
    """What watch printed so far (pytest captures stdout), read as it grows."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self._capsys = capsys
        self.lines: list[str] = []

    def latest(self, name: str) -> str:
        self.lines += self._capsys.readouterr().out.splitlines()
        for line in reversed(self.lines):
            if f" {name}: " in line:
                return line.split(f" {name}: ", 1)[1]
        return ""


async def test_one_printer_unplugged_shows_down_while_the_others_update(capsys: pytest.CaptureFixture[str]) -> None:
    async with contextlib.AsyncExitStack() as stack:
        sims = [await stack.enter_async_context(serve_tcp(SimulatorConfig(seed=i), time_scale=20)) for i in range(3)]
        ports = [f"p{index + 1}={sim.url}" for index, sim in enumerate(sims)]
        specs = specs_from_options(ports, 0, baud=marlin_aio.DEFAULT_BAUDRATE, poll_interval_s=0.05, sim_speed=1.0)
        specs = [replace(spec, timeout_s=2.0) for spec in specs]
        errors = io.StringIO()
        watching = asyncio.create_task(
            watch_farm(specs, WatchSettings(refresh_s=0.2), Console(file=io.StringIO()), Console(file=errors))
        )
        try:
            out = Output(capsys)
            await until(lambda: all(out.latest(n).startswith("up | hotend") for n in ("p1", "p2", "p3")), "all up")

            # Unplugged, and frozen so that it stays down (each reconnect fails its handshake) until resumed.
            sims[1].pause()
            await sims[1].disconnect()
            await until(lambda: out.latest("p2").startswith("down"), "p2 down")
            polls = [sims[0].printer.executed_count, sims[2].printer.executed_count]
            await until(
                lambda: (
                    sims[0].printer.executed_count > polls[0] + 10 and sims[2].printer.executed_count > polls[1] + 10
                ),
                "the others polled on",
            )
            assert out.latest("p2").startswith("down")
            assert out.latest("p1").startswith("up | hotend") and out.latest("p3").startswith("up | hotend")
            assert "p2: connection lost" in errors.getvalue()

            sims[1].resume()  # plugged back in: it reconnects by itself
            await until(lambda: out.latest("p2").startswith("up | hotend"), "p2 back up")
        finally:
            watching.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watching
