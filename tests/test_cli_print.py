"""`marlin-temp print` through CliRunner, a real process and a real terminal (tmux), against the simulated printer;
the progress view as pure functions rendered by a recording Console."""

from __future__ import annotations

import asyncio
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console
from test_cli_print_safety import served
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

from marlin_aio import PrintProgress, PrintState
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.main import app
from marlin_temp.printing.command import print_status
from marlin_temp.printing.plan import GcodePlan, HeatWait, plan_print, transliterate
from marlin_temp.printing.view import PrintStatus, RateWindow, plain_status, print_view

runner = CliRunner()


def write_gcode(path: Path, lines: int) -> Path:
    path.write_text(
        "; test part\n" + "".join(f"G1 X{(i * 0.5) % 200:.3f} Y{(i * 0.37) % 200:.3f}\n" for i in range(lines))
    )
    return path


def test_print_streams_the_file_and_reports(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 2_000)
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50"])
    assert result.exit_code == 0, result.output
    assert "done: 2000 commands" in result.output
    assert "ping-pong" in result.output  # the default: no link fault can run a line twice


@pytest.mark.parametrize("option", ["--send-ahead", "--window=96"])
def test_print_send_ahead(tmp_path: Path, option: str) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 300)
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50", option])
    assert result.exit_code == 0, result.output
    assert "send-ahead" in result.output and "done: 300 commands" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["print", "/no/such/file.gcode", "--sim"], "no such file"),
        (["print", "{dir}", "--sim"], "is a directory"),
        (["print", "{empty}", "--sim"], "no G-code commands"),
        (["print", "{comments}", "--sim"], "no G-code commands"),
        (["print", "{bad}", "--sim"], "line 2: non-ASCII characters in a G1 command"),
        (["print", "{long}", "--sim"], "line 1: command is"),
        (["print", "{good}", "--sim", "--ping-pong", "--window", "64"], "do not combine"),
        (["print", "{good}", "--sim", "--from-line", "99"], "--from-line 99 is past the last command (line 4)"),
        (["print", "{nomoves}", "--sim", "--from-line", "2"], "needs a file with moves"),
    ],
)
def test_print_bad_input_exits_2_with_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    files = {
        "bad": "G28\nG1 X1\u00e9 Y2\n",
        "empty": "",
        "comments": "; only a comment\n\n   ; and another\n",
        "long": "M117 " + "x" * 120 + "\n",
        "nomoves": "M140 S0\nM104 S0\n",
    }
    for name, text in files.items():
        (tmp_path / f"{name}.gcode").write_text(text, encoding="utf-8")
    write_gcode(tmp_path / "good.gcode", 3)
    (tmp_path / "dir").mkdir()
    args = [
        re.sub(r"\{(\w+)\}", lambda m: str(tmp_path / (m[1] if m[1] == "dir" else f"{m[1]}.gcode")), a) for a in args
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == Exit.USAGE, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], result.output


async def test_a_stalled_print_exits_9_with_the_diagnosis(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 3_000)
    faults = Faults(silent_after_lines=1_500)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), faults, time_scale=50) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url, "--timeout", "1"])
    assert result.exit_code == Exit.TIMEOUT, result.output
    assert "print stalled at line" in result.output
    assert "silent" in result.output
    assert "last lines sent (>>) and received (<<)" in result.output
    assert result.output.count(">>") >= 5


def test_ctrl_c_without_a_terminal_cancels_cleanly(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 50_000)
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_temp", "print", str(gcode), "--sim"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    assert "printing part.gcode" in process.stderr.readline()  # streaming has begun
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == Exit.INTERRUPTED, stderr
    assert "cancelled after line" in stderr
    assert "heaters and fan turned off" in stderr
    assert "Traceback" not in stderr


# ------------------------------------------------------------------------------------------- the file's plan


def test_a_display_message_beyond_ascii_is_transliterated_not_a_reason_to_refuse(tmp_path: Path) -> None:
    assert transliterate("M117 café crème à 200°C") == "M117 cafe creme a 200C"
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\nM117 café\nG1 X1 ; déplacement\nM118 Straße\n", encoding="utf-8")
    plan = plan_print(gcode)
    assert plan.commands == 4
    assert plan.transliterated == ((2, "M117 café", "M117 cafe"), (4, "M118 Straße", "M118 Strasse"))
    assert list(plan.lines()) == ["G28\n", "M117 cafe\n", "G1 X1\n", "M118 Strasse\n"]


def test_the_plan_knows_where_the_file_waits_for_heat(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M190 S60\n; comment\nM104 S200\nM109 T1 S210.5\nG28\nm191 r40\n", encoding="utf-8")
    plan = plan_print(gcode)
    # Keyed by the line answered just before each wait (0: the wait is the first command).
    assert plan.heat_waits == {
        0: HeatWait(1, "B", 60.0),
        3: HeatWait(4, "T1", 210.5),
        5: HeatWait(6, "C", 40.0),
    }
    assert plan.heat_wait_running(3, in_flight=True) == HeatWait(4, "T1", 210.5)
    assert plan.heat_wait_running(3, in_flight=False) is None  # paused before it: not sent, not waiting


def test_from_line_selects_the_header_then_line_n_on(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M140 S0\nG28\nG92 E0\nG1 X1\nG1 X2\nM109 S0\nG1 X3\nG1 X4\n", encoding="utf-8")
    plan = plan_print(gcode, from_line=7)
    assert (plan.first_move_line, plan.header_lines, plan.commands) == (4, 3, 5)
    # Skipped lines stay as empty lines, so the print's line numbers are the file's.
    assert list(plan.lines()) == ["M140 S0\n", "G28\n", "G92 E0\n", "\n", "\n", "\n", "G1 X3\n", "G1 X4\n"]
    assert plan.heat_waits == {}  # the skipped M109 is not waited for


# ------------------------------------------------------------------------------------------- the view, pure


def progress(acked: int, sent: int, last_line: int, state: PrintState = PrintState.RUNNING) -> PrintProgress:
    return PrintProgress(state, sent, acked, None, acked * 20, acked * 20, None, 60.0, 0, last_line)


def rendered(status: PrintStatus, width: int = 120) -> str:
    console = Console(record=True, width=width)
    console.print(print_view(status))
    return console.export_text()


def heating_plan() -> GcodePlan:
    return GcodePlan(Path("part.gcode"), 1_000, heat_waits={2: HeatWait(3, "T", 200.0)})


def test_while_the_file_waits_for_heat_the_view_says_heating_not_a_rate() -> None:
    from marlin_aio import TemperatureReading
    from marlin_aio.protocol import ReadingSource, parse_temperatures

    temperatures = parse_temperatures("T:187.2 /200.0 B:60.0 /60.0 @:127 B@:30 W:?")
    assert temperatures is not None
    reading = TemperatureReading(temperatures, 10.0, 1_700_000_000.0, ReadingSource.WAIT)
    status = print_status(progress(2, 3, 2), heating_plan(), reading, 0.0)
    assert status.state == "heating" and status.eta_s is None
    text = rendered(status)
    assert "heating hotend 187/200 C" in text
    assert "lines/s" not in text and "ETA" not in text
    assert "heating hotend 187/200 C" in plain_status(status)
    # Once the wait was answered, the rate is back.
    after = print_status(progress(3, 4, 3), heating_plan(), reading, 15.0)
    assert after.state == "printing" and "15 lines/s" in rendered(after)


def test_the_rate_is_the_recent_rate_not_the_average_since_the_start() -> None:
    window = RateWindow(window_s=10.0)
    for tenth in range(600):  # 60 s at 100 lines/s
        window.add(tenth / 10, tenth * 10)
    for tenth in range(200):  # then 20 s at 15 lines/s
        window.add(60 + tenth / 10, 6_000 + int(tenth * 1.5))
    rate = window.lines_per_s()
    assert rate is not None and 14 <= rate <= 16  # the average since the start would be about 79
    window.clear()
    assert window.lines_per_s() is None


def test_the_eta_comes_from_the_recent_rate() -> None:
    status = PrintStatus("part.gcode", 100, 1_000, lines_per_s=15.0)
    assert status.eta_s == pytest.approx(60.0)
    assert "ETA 0:01:00" in rendered(status)


def test_the_cancel_question_has_a_line_of_its_own_and_the_label_stays() -> None:
    status = PrintStatus(
        "part.gcode", 500, 1_000, lines_per_s=15.0, temperatures="hotend 200.0/200 °C", question="cancel the print?"
    )
    lines = rendered(status).splitlines()
    bar_line = next(line for line in lines if "500/1000 lines" in line)
    assert bar_line.startswith("part.gcode")
    assert "cancel" not in bar_line
    assert any(line.strip() == "cancel the print?" for line in lines)


def test_paused_shows_paused_and_the_keys() -> None:
    status = print_status(progress(10, 10, 10, PrintState.PAUSED), heating_plan(), None, 12.0, keys="p pause  r resume")
    text = rendered(status)
    assert status.state == "paused" and "paused" in text and "lines/s" not in text
    assert "p pause  r resume" in text


# ------------------------------------------------------------------------------------------- against the simulator


def file_commands(path: Path) -> set[str]:
    return {line.split(";")[0].strip() for line in path.read_text(encoding="utf-8").splitlines()} - {""}


async def test_a_cafe_prints_transliterated_with_a_warning(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\nM117 café\n" + "".join(f"G1 X{i}\n" for i in range(20)), encoding="utf-8")
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url])
        executed = list(sim.printer.executed)
    assert result.exit_code == Exit.OK, result.output
    assert "warning: line 2: 'M117 café' is sent as 'M117 cafe'" in result.output
    assert "done: 22 commands" in result.output
    assert "M117 cafe" in executed


async def test_from_line_runs_the_header_then_line_n_on(tmp_path: Path) -> None:
    header = ["M140 S0", "M104 S0", "G28", "M83"]  # relative extrusion: a resume of it is safe
    moves = [f"G1 X{i} Y{i % 7} E0.1" for i in range(1, 101)]
    gcode = tmp_path / "part.gcode"
    gcode.write_text("; sliced\n" + "\n".join(header + moves) + "\n", encoding="utf-8")
    from_line = 1 + len(header) + 60  # the file line of moves[59]
    assert gcode.read_text().splitlines()[from_line - 1] == moves[59]
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        args = ["print", str(gcode), "--port", sim.url, "--from-line", str(from_line)]
        result = await asyncio.to_thread(runner.invoke, app, args)
        ran = [command for command in sim.printer.executed if command in file_commands(gcode)]
    assert result.exit_code == Exit.OK, result.output
    assert "the 4 header commands before the first move (line 6) run first, then line 65 on" in result.output
    assert ran == header + moves[59:]


async def test_a_heater_wait_in_the_file_shows_heating_not_zero_lines_per_s(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M109 S150\n" + "".join(f"G1 X{i}\n" for i in range(50)), encoding="utf-8")
    # 25x: the heat-up takes about two seconds of real time, and the plain lines (every 0.1 s) catch it.
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=25) as sim:
        result = await asyncio.to_thread(
            runner.invoke, app, ["print", str(gcode), "--port", sim.url, "--refresh", "0.1"]
        )
    assert result.exit_code == Exit.OK, result.output
    heating = [line for line in result.stdout.splitlines() if re.search(r"(heating|waiting for) hotend", line)]
    assert heating, result.output
    assert all("lines/s" not in line and "ETA" not in line for line in heating), heating


# ------------------------------------------------------------------------------------------- keys, in a terminal


def dwells_run(sim: SimulatorServer) -> int:
    return sum(1 for command in list(sim.printer.executed) if command.startswith("G4"))


def done_lines(screen: str) -> int:
    found = re.findall(r"(\d+)/\d+ lines", screen)
    return int(found[-1]) if found else -1


def hotend_celsius(screen: str) -> float:
    found = re.findall(r"hotend (\d+\.\d)/", screen)
    return float(found[-1]) if found else -1.0


@needs_tmux
def test_print_keys_pause_resume_and_emergency_stop(tmux: Tmux, tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    # The hotend heats while the print runs (no wait), so time visibly passes on the screen while it is paused;
    # dwells of 5 ms pace the print (at most 200 lines/s), so it is still running when the keys are pressed.
    gcode.write_text("M104 S260\n" + "G4 P5\n" * 30_000)
    with served(SimulatorConfig(), time_scale=1) as (sim, _):
        command = f"{sys.executable} -m marlin_temp print {gcode} --port {sim.url}; echo MARLIN-EXIT=$?; sleep 600"
        tmux.run("new-session", "-d", "-s", "w", "-x", "150", "-y", "30", command)
        tmux.wait_for(lambda s: done_lines(s) > 20 and hotend_celsius(s) > 0, "the print to run")
        assert "p pause" in tmux.screen() and "emergency stop" in tmux.screen()

        tmux.run("send-keys", "-t", "w", "p")
        paused = tmux.wait_for(lambda s: "paused" in s, "paused")
        # What was in flight completes; after that, nothing more goes while the hotend goes on heating.
        warmer = hotend_celsius(paused) + 3
        first = tmux.wait_for(lambda s: hotend_celsius(s) > warmer, "time to pass while paused")
        ran = dwells_run(sim)
        later = tmux.wait_for(lambda s: hotend_celsius(s) > hotend_celsius(first) + 3, "more time to pass")
        assert done_lines(later) == done_lines(first)
        assert dwells_run(sim) == ran
        assert "paused" in later

        tmux.run("send-keys", "-t", "w", "r")
        tmux.wait_for(lambda s: "paused" not in s and done_lines(s) > done_lines(later) + 20, "the print to go on")

        tmux.run("send-keys", "-t", "w", "!")
        after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "print to exit")
        assert f"MARLIN-EXIT={int(Exit.HALTED)}" in after, after
        assert "emergency stop: M112 sent after line" in after and "halted" in after
        assert "Marlin turns its heaters off as it halts" in " ".join(after.split())
        assert sim.printer.halted


def test_print_help_explains_the_keys_and_what_to_check_before_from_line() -> None:
    result = runner.invoke(app, ["print", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "p pauses" in text and "r resumes" in text and "! is the emergency stop" in text
    assert "--from-line" in text
    for check in ("still stuck to the bed", "homing in the header (G28)", "starts a layer", "absolute extrusion"):
        assert check in text, check


@needs_tmux
def test_ctrl_c_in_a_terminal_asks_on_a_line_of_its_own_and_y_cancels(tmux: Tmux, tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G4 P5\n" * 30_000)
    command = f"{sys.executable} -m marlin_temp print {gcode} --sim; echo MARLIN-EXIT=$?; sleep 600"
    tmux.run("new-session", "-d", "-s", "w", "-x", "150", "-y", "30", command)
    tmux.wait_for(lambda s: done_lines(s) > 20, "the print to run")
    tmux.run("send-keys", "-t", "w", "C-c")
    asked = tmux.wait_for(lambda s: "cancel the print?" in s, "the question")
    question = next(line for line in asked.splitlines() if "cancel the print?" in line)
    assert question.startswith("cancel the print?")  # not drawn over the bar's label
    assert any(line.startswith("part.gcode") and "lines" in line for line in asked.splitlines())
    tmux.run("send-keys", "-t", "w", "y")
    after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "print to exit")
    assert f"MARLIN-EXIT={int(Exit.INTERRUPTED)}" in after, after
    assert "cancelled after line" in after and "heaters and fan turned off" in after


def test_from_line_warns_when_absolute_extrusion_would_resume_from_the_headers_e(tmp_path: Path) -> None:
    header = "M82\nG28\nG92 E0\n"
    layers = "G1 Z0.2\nG1 X1 E10\nG1 X2 E20\n;LAYER:1\nG1 Z0.4\nG1 X3 E30\nG1 X4 E40\n"
    gcode = tmp_path / "absolute.gcode"
    gcode.write_text(header + layers, encoding="utf-8")
    warning = plan_print(gcode, from_line=8, force=True).extrusion_warning  # refused without force
    assert warning is not None
    assert "goes to E30" in warning and "push out 30 mm" in warning and "'G92 E20'" in warning
    # A layer that sets E itself, relative extrusion, or the whole file: nothing to warn about.
    gcode.write_text(header + layers.replace(";LAYER:1\n", ";LAYER:1\nG92 E20\n"), encoding="utf-8")
    assert plan_print(gcode, from_line=8).extrusion_warning is None
    gcode.write_text(header.replace("M82", "M83") + layers, encoding="utf-8")
    assert plan_print(gcode, from_line=8).extrusion_warning is None
    gcode.write_text(header + layers, encoding="utf-8")
    assert plan_print(gcode, from_line=2).extrusion_warning is None


async def test_an_unplugged_print_names_the_line_it_reached_and_how_to_go_on(tmp_path: Path) -> None:
    gcode = write_gcode(tmp_path / "part.gcode", 20_000)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        printing = asyncio.create_task(asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url]))
        for _ in range(2_000):
            if sim.printer.executed_line_count > 300:
                break
            await asyncio.sleep(0.01)  # polling a condition (lines run), bounded
        await sim.disconnect()
        result = await printing
    assert result.exit_code == Exit.LOST, result.output
    error = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(error) == 1, result.output
    match = re.search(r"line (\d+) of part\.gcode surely ran(, lines up to (\d+) may have run)?", error[0])
    assert match is not None, error[0]
    reached = int(match[1])
    assert reached > 100  # well into the file (the printer had run over 300 lines; acks trail a little)
    # The resume goes on after every line that may have run (written, never answered), never repeating one.
    may = int(match[3]) if match[3] else reached
    assert may >= reached
    assert f"--from-line {may + 1}" in error[0]
    assert "the port went away" in error[0]  # in words, not pyserial's
