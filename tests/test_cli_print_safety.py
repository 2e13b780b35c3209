"""`marlin-temp print` refuses what would do harm and never leaves the printer hot without saying so: binary files,
targets over the limits and dangerous --from-line resumes refused before connecting; M108 on a cancel during the
file's heat-up; the Ctrl-C question holding the print and taking its own answer; the heaters named on every way
out; the printer's text shown verbatim. Against the simulated printer, through CliRunner, real processes and tmux."""

from __future__ import annotations

import asyncio
import contextlib
import queue
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, TypeVar

import pytest
from rich.console import Console
from tmux_screen import Tmux, needs_tmux
from typer.testing import CliRunner

from marlin_aio.protocol.heaters import HeaterLimits
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_pty
from marlin_temp.common.connect import ConnectOptions, Exit
from marlin_temp.main import app
from marlin_temp.printing.command import PrintSettings, print_gcode
from marlin_temp.printing.plan import plan_print
from marlin_temp.printing.view import PrintStatus, print_view

runner = CliRunner()
_T = TypeVar("_T")


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


# ------------------------------------------------------------------------------------------- refused up front


def test_a_binary_file_is_refused_with_one_line_naming_the_byte(tmp_path: Path) -> None:
    png = tmp_path / "photo.gcode"
    png.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 8)
    result = runner.invoke(app, ["print", str(png), "--sim"])
    assert result.exit_code == Exit.USAGE
    assert one_line(result.output) == f"error: {png} is not a text G-code file (binary data at byte 8)"
    # No NUL at all, but mostly bytes no text holds.
    noise = tmp_path / "noise.gcode"
    noise.write_bytes(b"G28\n" + bytes(range(0x80, 0x100)) * 10)
    result = runner.invoke(app, ["print", str(noise), "--sim"])
    assert result.exit_code == Exit.USAGE
    assert one_line(result.output).endswith("is not a text G-code file (binary data at byte 4)")


@pytest.mark.parametrize("encoding", ["utf-8", "latin-1"])
def test_a_file_with_a_few_accented_comments_is_still_text(tmp_path: Path, encoding: str) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_bytes("; pièce imprimée, réglée à 200°C\nG28\nG1 X1 ; déplacement\n".encode(encoding))
    assert plan_print(gcode).commands == 2


async def test_a_target_over_the_limit_is_refused_naming_the_line_before_connecting(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\n" + "G1 X1\n" * 10 + "M104S280 ; as Marlin reads it: M104 S280\nG1 X2\n")
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url])
        ran = sim.printer.executed_count
    assert result.exit_code == Exit.USAGE
    assert one_line(result.output) == (
        f"error: {gcode}: line 12: hotend target 280 C is above the limit of 260 C (--max-hotend)"
    )
    assert ran == 0  # not even a handshake: refused before connecting


def test_the_limits_given_are_the_ones_checked(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("m0104 s250\nM190 S120\n")
    assert plan_print(gcode).commands == 2  # within the library's defaults
    with pytest.raises(ValueError, match=r"line 1: hotend target 250 C is above the limit of 240 C \(--max-hotend\)"):
        plan_print(gcode, limits=HeaterLimits(240, 140, 60))
    with pytest.raises(ValueError, match=r"line 2: bed target 120 C is above the limit of 100 C \(--max-bed\)"):
        plan_print(gcode, limits=HeaterLimits(260, 100, 60))


def absolute_file(path: Path) -> Path:
    """A file with absolute extrusion whose layer at line 3000 goes on at E148.7: a resume there from the
    header's G92 E0 would push 148.7 mm of filament out at once."""
    header = "M82\nM140 S0\nG28\nG92 E0\n"  # lines 1-4
    moves = [f"G1 X{i % 200} Y{i % 150} E{i * 0.05:.2f}\n" for i in range(1, 2996)]  # lines 5-2999
    path.write_text(header + "".join(moves) + ";LAYER:9\nG1 Z2\nG1 X1 E148.7\nG1 X2 E148.8\n")
    return path


def test_a_resume_that_would_push_out_filament_at_once_is_refused_without_force(tmp_path: Path) -> None:
    gcode = absolute_file(tmp_path / "part.gcode")
    result = runner.invoke(app, ["print", str(gcode), "--sim", "--from-line", "3000"])
    assert result.exit_code == Exit.USAGE
    line = one_line(result.output)
    assert "--from-line 3000" in line and "push out 148.7 mm of filament at once" in line
    assert "'G92 E149.75'" in line  # where E stood before line 3000: the line to put there
    assert line.endswith("add --force to resume anyway")
    plan = plan_print(gcode, from_line=3000, force=True)
    assert plan.resume_dangers and "148.7 mm" in plan.resume_dangers[0]


@pytest.mark.parametrize(
    ("text", "from_line", "danger"),
    [
        # Relative extrusion in the header, absolute from a skipped line on: every E would be read as a step.
        ("M83\nG28\nG1 Z0.2\nM82\nG92 E0\nG1 X1 E10\nG1 X2 E20\nG1 X3 E30\n", 7, "still in relative extrusion"),
        # The hotend heated only after the first move: the header leaves it cold.
        ("G28\nG1 Z5\nM109 S210\nG1 X1 E1\nG1 X2 E1\n", 5, "the header does not heat it"),
    ],
)
def test_other_dangerous_resumes_are_refused_too(tmp_path: Path, text: str, from_line: int, danger: str) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text(text)
    with pytest.raises(ValueError, match="add --force to resume anyway") as refused:
        plan_print(gcode, from_line=from_line)
    assert danger in str(refused.value) and "\n" not in str(refused.value)
    assert plan_print(gcode, from_line=from_line, force=True).resume_dangers


async def test_a_harmless_change_is_a_note_and_the_resume_runs(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M83\nM104 S215\nG28\nG1 Z5\nM104 S205\nG1 X1 E1\nG1 X2 E1\n")
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        args = ["print", str(gcode), "--port", sim.url, "--from-line", "6"]
        result = await asyncio.to_thread(runner.invoke, app, args)
    assert result.exit_code == Exit.OK, result.output
    assert "note: the header sets the hotend to 215 C; the skipped part had changed it to 205 C" in result.output
    assert "warning" not in result.output.replace("warning: the file ended with heaters on", "")


async def test_with_force_a_dangerous_resume_warns_and_runs(tmp_path: Path) -> None:
    gcode = absolute_file(tmp_path / "part.gcode")
    plan = plan_print(gcode, from_line=3000, force=True)
    console, errors = Console(record=True, width=400), Console(record=True, width=400)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        code = await print_gcode(ConnectOptions(port=sim.url), PrintSettings(plan=plan), console, errors)
        executed = list(sim.printer.executed)
    said = errors.export_text()
    assert code == Exit.OK, said
    assert "warning: the first extruding move from line 3000 on" in said and "(resuming anyway: --force)" in said
    ran = [command for command in executed if command.startswith(("G1 Z", "G1 X1 E1", "G1 X2 E1"))]
    assert ran == ["G1 Z2", "G1 X1 E148.7", "G1 X2 E148.8"]  # the resumed part, as the file has it


# ------------------------------------------------------------------------------------------- cancel during heat-up


@contextlib.contextmanager
def served(config: SimulatorConfig, time_scale: float) -> Iterator[tuple[SimulatorServer, asyncio.AbstractEventLoop]]:
    """A simulated printer on a pty, run by an event loop of its own thread, for a command in another process."""
    loop = asyncio.new_event_loop()
    started = threading.Event()
    servers: list[SimulatorServer] = []
    stop = asyncio.Event()

    async def serve() -> None:
        async with serve_pty(config, time_scale=time_scale) as server:
            servers.append(server)
            started.set()
            await stop.wait()

    thread = threading.Thread(target=loop.run_until_complete, args=(serve(),), daemon=True)
    thread.start()
    try:
        assert started.wait(30), "the simulator did not start"
        yield servers[0], loop
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(30)
        loop.close()


def on_loop(loop: asyncio.AbstractEventLoop, call: Callable[[], _T]) -> _T:
    """Run `call` in the simulator's own thread, between its events."""

    async def run() -> _T:
        return call()

    return asyncio.run_coroutine_threadsafe(run(), loop).result(30)


def pause_in_the_bed_wait(sim: SimulatorServer, loop: asyncio.AbstractEventLoop, below_celsius: float) -> None:
    """Freeze the board once it runs the file's M190 and the bed is still far from its target (so the wait is
    certainly under way): checked and frozen in the simulator's thread, with nothing happening in between."""

    async def pause_when_waiting() -> None:
        # The board has no event for "a wait began": its state is polled (bounded by the caller's timeout).
        for _ in range(12_000):
            waiting = any(command.startswith("M190") for command in sim.printer.executed)
            if waiting and sim.printer.heater_celsius("B") < below_celsius:
                sim.pause()
                return
            await asyncio.sleep(0.005)
        raise AssertionError("the board never ran the file's M190 with the bed far from its target")

    asyncio.run_coroutine_threadsafe(pause_when_waiting(), loop).result(60)


class Lines:
    """The lines of a process's stream, read by a thread of their own, to wait for one without blocking forever."""

    def __init__(self, stream: IO[str]) -> None:
        self.seen: list[str] = []
        self._queue: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self._queue.put(line)

    def wait_for(self, text: str, limit_s: float = 60.0) -> str:
        while True:
            try:
                line = self._queue.get(timeout=limit_s)
            except queue.Empty:
                raise AssertionError(f"no line with {text!r}; got:\n{''.join(self.seen)}") from None
            self.seen.append(line)
            if text in line:
                return line

    def rest(self) -> str:
        while not self._queue.empty():
            self.seen.append(self._queue.get())
        return "".join(self.seen)


def start_print(gcode: Path, sim: SimulatorServer, *options: str) -> tuple[subprocess.Popen[str], Lines]:
    process = subprocess.Popen(
        [sys.executable, "-m", "marlin_temp", "print", str(gcode), "--port", sim.url, *options],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    return process, Lines(process.stderr)


def test_a_cancel_during_the_files_heat_up_ends_the_wait_with_m108(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M190 S100\nG28\n" + "G1 X1 Y1\n" * 50)
    with served(SimulatorConfig(), time_scale=20) as (sim, loop):
        process, stderr = start_print(gcode, sim)
        pause_in_the_bed_wait(sim, loop, below_celsius=40)
        process.send_signal(signal.SIGINT)  # no terminal: Ctrl-C cancels at once
        stderr.wait_for("M108 sent: the heat-up wait ended")
        on_loop(loop, sim.resume)
        assert process.wait(60) == Exit.INTERRUPTED, stderr.rest()
        bed = on_loop(loop, lambda: sim.printer.heater_celsius("B"))
        executed = list(sim.printer.executed)
    assert bed < 90  # the wait for 100 C ended long before the bed got there
    assert "G28" not in executed  # nothing of the file after the wait ran
    assert "M140 S0" in executed and "cancelled after line" in stderr.rest()


def test_without_the_emergency_parser_the_cancel_says_it_waits_for_the_heat_up(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M190 S40\nG28\n" + "G1 X1 Y1\n" * 50)
    with served(SimulatorConfig(emergency_parser=False), time_scale=20) as (sim, loop):
        process, stderr = start_print(gcode, sim)
        pause_in_the_bed_wait(sim, loop, below_celsius=32)
        process.send_signal(signal.SIGINT)
        line = stderr.wait_for("emergency parser")
        on_loop(loop, sim.resume)
        assert process.wait(120) == Exit.INTERRUPTED, stderr.rest()
        bed = on_loop(loop, lambda: sim.printer.heater_celsius("B"))
        executed = list(sim.printer.executed)
    assert "the cancel takes effect when the heat-up ends" in line
    assert bed > 38  # the wait ran to its end: nothing could end it sooner
    assert "M108" not in executed and "G28" not in executed


# ------------------------------------------------------------------------------------------- the heaters on the way out


def test_a_cancel_with_keep_heaters_says_which_are_on_and_leaves_them(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M140 S60\nM104 S200\n" + "G4 P5\n" * 30_000)
    with served(SimulatorConfig(), time_scale=1) as (sim, _):
        process, stderr = start_print(gcode, sim, "--keep-heaters")
        stderr.wait_for("printing part.gcode")
        for _ in range(3_000):
            if sum(1 for command in list(sim.printer.executed) if command.startswith("G4")) > 20:
                break
            threading.Event().wait(0.01)  # polling a condition (dwells run), bounded
        process.send_signal(signal.SIGINT)
        assert process.wait(60) == Exit.INTERRUPTED, stderr.rest()
        targets = [command for command in sim.printer.executed if command[:4] in ("M104", "M140")]
    said = stderr.rest()
    assert targets == ["M140 S60", "M104 S200"]  # nothing turned them off
    assert "heaters left as they were (--keep-heaters)" in said
    warning = next(line for line in said.splitlines() if "heaters left on" in line)
    assert re.search(r"hotend \d+\.\d/200 C, bed \d+\.\d/60 C", warning), warning
    assert warning.endswith("turn them off with: marlin-temp set --off")


async def test_a_file_that_ends_with_heaters_on_says_so(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M104 S150\nG28\nG1 X1\n")
    off = tmp_path / "off.gcode"
    off.write_text("M104 S150\nG28\nG1 X1\nM104 S0\n")
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url])
        turned_off = await asyncio.to_thread(runner.invoke, app, ["print", str(off), "--port", sim.url])
    assert result.exit_code == Exit.OK, result.output
    assert re.search(
        r"warning: the file ended with heaters on: hotend \d+\.\d/150 C; turn them off with: marlin-temp set --off",
        result.output,
    ), result.output
    assert turned_off.exit_code == Exit.OK and "heaters on" not in turned_off.output, turned_off.output


async def test_a_lost_link_names_the_heaters_last_seen_on(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M140 S60\n" + "G1 X1 Y1\nG1 X2 Y2\n" * 10_000)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        printing = asyncio.create_task(asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url]))
        for _ in range(2_000):
            if sim.printer.executed_line_count > 300:
                break
            await asyncio.sleep(0.01)  # polling a condition (lines run), bounded
        await sim.disconnect()
        result = await printing
    assert result.exit_code == Exit.LOST, result.output
    lines = result.output.splitlines()
    error = next(index for index, line in enumerate(lines) if line.startswith("error:"))
    assert re.search(r"line \d+ of part\.gcode surely ran", lines[error]), lines[error]
    assert re.fullmatch(
        r"warning: heaters on when last read: bed \d+\.\d/60 C; turn them off with: marlin-temp set --off",
        lines[error + 1],
    ), result.output


async def test_a_stalled_print_names_the_heaters_too(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M104 S180\n" + "G1 X1 Y1\nG1 X2 Y2\n" * 1_000)
    async with serve_pty(SimulatorConfig(motion_time_scale=0), Faults(silent_after_lines=500), time_scale=50) as sim:
        args = ["print", str(gcode), "--port", sim.url, "--timeout", "1"]
        result = await asyncio.to_thread(runner.invoke, app, args)
    assert result.exit_code == Exit.TIMEOUT, result.output
    assert result.output.count("error:") == 1, result.output
    assert re.search(r"heaters on when last read: hotend \d+\.\d/180 C; turn them off with", result.output)


# ------------------------------------------------------------------------------------------- verbatim


def test_the_printers_text_and_the_file_name_are_shown_verbatim() -> None:
    status = PrintStatus("[bold]x:smile:.gcode", 1, 10, message="[red]Hello :smile: [/]", note="[b]note")
    console = Console(record=True, width=120)
    console.print(print_view(status))
    text = console.export_text()
    assert "[bold]x:smile:.gcode" in text and "printer: [red]Hello :smile: [/]" in text and "[b]note" in text
    assert "\N{SMILING FACE WITH OPEN MOUTH AND SMILING EYES}" not in text


async def test_display_text_and_warnings_about_it_stay_as_written(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\nM117 [bold]Layer :smile: café\nG1 X1\n", encoding="utf-8")
    async with serve_pty(SimulatorConfig(motion_time_scale=0), time_scale=50) as sim:
        result = await asyncio.to_thread(runner.invoke, app, ["print", str(gcode), "--port", sim.url])
    assert result.exit_code == Exit.OK, result.output
    assert "warning: line 2: 'M117 [bold]Layer :smile: café' is sent as 'M117 [bold]Layer :smile: cafe'" in (
        result.output
    )
    assert "printer: [bold]Layer :smile: cafe" in result.stdout


# ------------------------------------------------------------------------------------ the question, in a terminal


def done_lines(screen: str) -> int:
    found = re.findall(r"(\d+)/\d+ lines", screen)
    return int(found[-1]) if found else -1


def hotend_celsius(screen: str) -> float:
    found = re.findall(r"hotend (\d+\.\d)/", screen)
    return float(found[-1]) if found else -1.0


def after_exit(screen: str) -> str:
    """What the screen shows after the command's exit line (a key that fell into the shell is echoed there)."""
    return screen.split("MARLIN-EXIT=", 1)[1].split("\n", 1)[1] if "MARLIN-EXIT=" in screen else ""


@needs_tmux
def test_the_question_holds_the_print_and_no_lets_it_go_on(tmux: Tmux, tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    # The hotend heats while the print runs (no wait), so time visibly passes on the screen while it is held.
    gcode.write_text("M104 S260\n" + "G4 P5\n" * 30_000)
    with served(SimulatorConfig(), time_scale=1) as (sim, _):
        command = f"{sys.executable} -m marlin_temp print {gcode} --port {sim.url}; echo MARLIN-EXIT=$?; sleep 600"
        tmux.run("new-session", "-d", "-s", "w", "-x", "150", "-y", "30", command)
        tmux.wait_for(lambda s: done_lines(s) > 20 and hotend_celsius(s) > 0, "the print to run")
        tmux.run("send-keys", "-t", "w", "C-c")
        asked = tmux.wait_for(lambda s: "cancel the print?" in s and "paused" in s, "the question, paused")
        first = tmux.wait_for(lambda s: hotend_celsius(s) > hotend_celsius(asked) + 3, "time to pass while asking")
        dwells = sum(1 for command in list(sim.printer.executed) if command.startswith("G4"))
        later = tmux.wait_for(lambda s: hotend_celsius(s) > hotend_celsius(first) + 3, "more time to pass")
        assert done_lines(later) == done_lines(first) and "cancel the print?" in later
        assert sum(1 for command in list(sim.printer.executed) if command.startswith("G4")) == dwells

        tmux.run("send-keys", "-t", "w", "n")
        tmux.wait_for(
            lambda s: "cancel the print?" not in s and done_lines(s) > done_lines(later) + 20, "the print to go on"
        )
        tmux.run("send-keys", "-t", "w", "C-c")
        tmux.wait_for(lambda s: "cancel the print?" in s, "the question again")
        tmux.run("send-keys", "-t", "w", "y")
        after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "print to exit")
    assert f"MARLIN-EXIT={int(Exit.INTERRUPTED)}" in after, after
    assert "cancelled after line" in after
    assert after_exit(after).strip() == "", after  # neither answer reached the shell


@needs_tmux
def test_when_the_print_ends_under_the_question_the_answer_is_still_ours(tmux: Tmux, tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("M140 S50\n" + "G4 P5\n" * 30_000)
    with served(SimulatorConfig(), time_scale=1) as (sim, loop):
        command = f"{sys.executable} -m marlin_temp print {gcode} --port {sim.url}; echo MARLIN-EXIT=$?; sleep 600"
        tmux.run("new-session", "-d", "-s", "w", "-x", "150", "-y", "30", command)
        tmux.wait_for(lambda s: done_lines(s) > 20 and "/50 °C" in s, "the print to run, the bed heating")
        tmux.run("send-keys", "-t", "w", "C-c")
        tmux.wait_for(lambda s: "cancel the print?" in s, "the question")
        asyncio.run_coroutine_threadsafe(sim.disconnect(), loop).result(30)  # the print fails under the question
        ended = tmux.wait_for(lambda s: "the print has ended: press any key" in s, "the question to say so")
        assert "MARLIN-EXIT=" not in ended  # still waiting for the key
        tmux.run("send-keys", "-t", "w", "z")
        after = tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "print to exit")
    assert f"MARLIN-EXIT={int(Exit.LOST)}" in after, after
    assert "z" not in after_exit(after), after  # the answer was read by the print, not left for the shell
    assert "heaters on when last read: bed" in " ".join(after.split())
