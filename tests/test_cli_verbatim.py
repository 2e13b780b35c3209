"""Issue 20: what the printer says, and what the user typed, is printed as it is, never read as rich markup or emoji
codes, by every command: send, set, log, watch (its `:` line's reply) and the farm view.

The simulated printer gives the text: M115 lists `Cap:REPEAT:0` (`:repeat:` is one of rich's emoji codes), M118
prints what it is given (`M118 E1 :smile:` answers `echo::smile:`). Each part is rendered into a Console with
rich's defaults (markup and emoji on), as anyone embedding these functions would make one: the code must be right
whatever Console it is given, not only the ones `main.py` builds.
"""

from __future__ import annotations

import asyncio
import io
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.farm.supervisor import FarmPrinter, PrinterSpec
from marlin_aio.protocol import ReadingSource, parse_temperatures
from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.common.connect import ConnectOptions, Exit
from marlin_temp.common.model import SendCommand, WatchControls, WatchModel
from marlin_temp.common.render import controls_view, watch_view
from marlin_temp.console.send import check_commands, send_commands
from marlin_temp.farm.view import detail_view, farm_row, farm_view, plain_lines
from marlin_temp.heaters.command import heaters_left_on
from marlin_temp.logs.command import LogSettings, log_temperatures
from marlin_temp.main import app
from marlin_temp.watch.command import _outcome

runner = CliRunner()
EMOJI = ("🔁", "😄")  # what rich makes of :repeat: and :smile:
TRICKY = ["M118 E1 :smile:", "M118 E1 [bold]x[/]", "M118 :repeat:"]


def default_console(width: int = 200) -> Console:
    """A Console as rich makes one by default (markup and emoji codes on), recording what it prints."""
    return Console(record=True, width=width, file=io.StringIO(), color_system=None)


def rendered(renderable: object, width: int = 200) -> str:
    console = default_console(width)
    console.print(renderable)
    return console.export_text()


def reading(text: str, time_s: float = 0.0) -> TemperatureReading:
    temperatures = parse_temperatures(text)
    assert temperatures is not None
    return TemperatureReading(temperatures, time_s, 1_700_000_000 + time_s, ReadingSource.POLL)


# ------------------------------------------------------------------------------------------- send


async def test_send_prints_the_printers_lines_verbatim_on_a_console_with_emoji_and_markup_on() -> None:
    console, errors = default_console(), default_console()
    commands = check_commands(["M115", *TRICKY])
    code = await send_commands(ConnectOptions(sim=True, sim_speed=50), commands, console, errors)
    assert code == Exit.OK
    lines = console.export_text().splitlines()
    assert "Cap:REPEAT:0" in lines
    assert "echo::smile:" in lines and "echo:[bold]x[/]" in lines and ":repeat:" in lines
    assert "> M118 E1 [bold]x[/]" in lines  # the command as typed, above its reply
    assert not any(emoji in line for line in lines for emoji in EMOJI)


def test_send_through_the_command_line_prints_cap_repeat_and_smile_as_the_printer_said_them() -> None:
    result = runner.invoke(app, ["send", "--sim", "--sim-speed", "50", "M115", "M118 E1 :smile:", "M118 :smile:"])
    assert result.exit_code == Exit.OK, result.output
    lines = result.output.splitlines()
    assert "Cap:REPEAT:0" in lines and "echo::smile:" in lines and ":smile:" in lines
    assert not any(emoji in result.output for emoji in EMOJI)


@pytest.mark.parametrize("command", ["M104S280", "M104 S999", "m140 s-5", "M104 Sabc"])
async def test_send_a_target_beyond_the_limits_exits_2_with_one_line_and_sends_nothing(command: str) -> None:
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["send", "--port", sim.url, "M105", command])
        assert sim.printer.executed_count == 0  # not even the M105 before it: nothing connected
        async with marlin_aio.connect(sim.url) as printer:
            heaters = (await printer.read_temperatures()).temperatures.heaters
    assert result.exit_code == Exit.USAGE, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "command 2 of 2 was refused, nothing was sent" in lines[0], result.output
    assert "Traceback" not in result.output
    assert heaters["T"].target == 0 and heaters["B"].target == 0  # the printer's targets unchanged


def test_send_checks_targets_against_the_limits_it_is_given() -> None:
    limits = marlin_aio.HeaterLimits(hotend=300, bed=100, chamber=60)
    assert check_commands(["M104S280"], limits=limits) == ["M104S280"]
    with pytest.raises(Exception, match="above the limit of 100 C"):
        check_commands(["M140 S110"], limits=limits)


# ------------------------------------------------------------------------------------------- watch


async def test_the_colon_lines_reply_is_shown_verbatim_in_the_view() -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=20) as sim,
        marlin_aio.connect(sim.url) as printer,
    ):
        model = WatchModel()
        model.add(await printer.read_temperatures())
        controls = WatchControls()
        shown = []
        # M115's Cap:REPEAT:0 is further up than the view's last 8 lines: M118 prints it as the printer would.
        for text in ["M118 Cap:REPEAT:0", *TRICKY]:
            action = SendCommand(text)
            controls.finished(action, await _outcome(printer, action, model))
            shown.append(rendered(controls_view(controls)))
    assert "Cap:REPEAT:0" in shown[0]
    assert "echo::smile:" in shown[1] and "> M118 E1 :smile:" in shown[1]
    assert "echo:[bold]x[/]" in shown[2]
    assert ":repeat:" in shown[3]
    assert not any(emoji in text for text in shown for emoji in EMOJI)


def test_the_port_and_the_firmwares_name_are_shown_verbatim_in_the_view() -> None:
    model = WatchModel()
    for step in range(20):
        model.add(reading("T:25.0 /0.0 B:24.0 /0.0 @:0 B@:0", step / 10))
    text = rendered(watch_view(model, "socket://[bold]host:smile:", "Marlin :repeat: [red]x[/]", width=120))
    assert "socket://[bold]host:smile:" in text and "Marlin :repeat: [red]x[/]" in text
    assert not any(emoji in text for emoji in EMOJI)


# ------------------------------------------------------------------------------------------- the farm view


def test_the_farm_view_shows_errors_events_and_names_verbatim() -> None:
    error = "echo:[bold]x[/] Cap:REPEAT:0 :smile:"
    down = FarmPrinter(PrinterSpec(name="p[b]1", port="socket://127.0.0.1:1"))
    down.last_error = error
    down.connections = 1
    up = FarmPrinter(PrinterSpec(name="p:smile:2", port="socket://127.0.0.1:2"))
    up.link_up = True
    up.firmware = "Marlin :repeat:"
    model = WatchModel()
    for step in range(20):
        model.add(reading("T:25.0 /0.0 B:24.0 /0.0 @:0 B@:0", step / 10))
    rows = [farm_row(1, down, WatchModel()), farm_row(2, up, model)]
    farm = rendered(farm_view(rows, 200, events=[f"12:00:00 p[b]1: connection lost: {error}"]))
    assert "p[b]1" in farm and "p:smile:2" in farm
    assert f"connection lost: {error}" in farm and "echo:[bold]x[/] Cap:REPEAT:0" in farm
    detail = rendered(detail_view(rows[1], model, up, width=120))
    assert "Marlin :repeat:" in detail and "p:smile:2" in detail
    down_detail = rendered(detail_view(rows[0], WatchModel(), down, width=200))
    assert "echo:[bold]x[/] Cap:REPEAT:0" in down_detail
    assert not any(emoji in text for text in (farm, detail, down_detail) for emoji in EMOJI)
    assert "Cap:REPEAT:0" in plain_lines(rows)[0]


# ------------------------------------------------------------------------------------------- log


async def test_log_says_its_file_name_verbatim(tmp_path: Path) -> None:
    output = tmp_path / "[bold]temps:smile:.csv"
    errors = default_console(width=400)
    settings = LogSettings(output=output, interval_s=0.05, duration_s=0.3)
    assert await log_temperatures(ConnectOptions(sim=True, sim_speed=20), settings, errors) == Exit.OK
    text = errors.export_text()
    assert f"to {output} every 0.05 s" in text and f"to {output}" in text.splitlines()[-1]
    assert not any(emoji in text for emoji in EMOJI)


# ------------------------------------------------------------------------------------------- heaters left on


def test_the_heaters_left_on_are_named_with_actual_and_target_and_how_to_turn_them_off() -> None:
    both = reading("T:151.24 /200.00 B:60.00 /60.00 @:127 B@:40")
    assert heaters_left_on(both) == (
        "the heaters stay on (hotend 151.2/200 C, bed 60.0/60 C). Turn them off with: marlin-temp set --off"
    )
    one = reading("T:25.00 /250.00 B:24.00 /0.00 @:127 B@:0")
    assert heaters_left_on(one) == ("the heater stays on (hotend 25.0/250 C). Turn it off with: marlin-temp set --off")
    # Several hotends: each by number, the active one (T) not twice.
    tools = reading("T:180.00 /200.00 T0:180.00 /200.00 T1:30.00 /0.00 B:60.00 /60.00 @:0 B@:0")
    assert heaters_left_on(tools) == (
        "the heaters stay on (hotend 0 180.0/200 C, bed 60.0/60 C). Turn them off with: marlin-temp set --off"
    )
    assert heaters_left_on(reading("T:25.00 /0.00 B:24.00 /0.00 @:0 B@:0")) is None
    assert heaters_left_on(None) is None
    # A halt or a reset turned them off in the firmware itself.
    assert heaters_left_on(both, marlin_aio.PrinterHaltedError("halted")) is None
    assert heaters_left_on(both, marlin_aio.ConnectionLostError("gone")) is not None
