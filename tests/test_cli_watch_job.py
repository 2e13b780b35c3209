"""`marlin-temp watch --port serve:NAME` and the service's print job: shown over the table and in the plain and JSON
lines, paused, resumed and cancelled from the keys (a cancel only after its y).

The keys' meaning and the rendering are pure (`WatchControls`, `job_line`, `watch_view`) and tested without I/O, at
several widths with a recording Console; the rest runs a real `marlin-temp serve --sim` process (`tests/test_serve.py`'s
`serving`) with a print started through its socket, and watch as a real process: piped, and in a real terminal (tmux).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console
from test_cli_watch_keys import flat, model_with, press, sized
from test_serve import Served, raw_client, serving
from tmux_screen import Tmux, needs_tmux

from marlin_aio.farm.job import JobState
from marlin_temp.common.keys import PASTE
from marlin_temp.common.model import CancelJob, JobStatus, PauseJob, ResumeJob, WatchControls
from marlin_temp.common.render import job_line, plain_line, watch_view

WIDTHS = (30, 40, 60, 80, 120)


def job(state: str = "printing", **fields: Any) -> JobStatus:
    value: dict[str, Any] = {
        "id": "ab12cd34",
        "printer": "sim",
        "file": "part.gcode",
        "started_by": "socket client 3",
        "state": state,
        "active": JobState(state).active,  # as the service's `Job.to_json` says it
        "percent": 42.5,
        "surely_run_line": 0,
        "may_have_run_line": 0,
        "resume_line": 1,
        "error": None,
        "cancelled_by": None,
    }
    return JobStatus.from_json(value | fields)


def cancelled() -> JobStatus:
    return job(
        "cancelled",
        percent=12.3,
        cancelled_by="socket client 4",
        surely_run_line=160,
        may_have_run_line=163,
        resume_line=161,
    )


def rendered(renderable: Any, width: int) -> str:
    console = Console(record=True, width=width, color_system=None)
    console.print(renderable)
    return console.export_text()


# ------------------------------------------------------------------------------------------- keys (pure)


def test_p_pauses_and_resumes_and_only_y_after_c_cancels() -> None:
    controls = WatchControls()
    controls.show_job(job())
    assert press(controls, "p") == [PauseJob()]
    controls.show_job(job("paused"))
    assert "p resume" in controls.help_items()
    assert press(controls, "P") == [ResumeJob()]

    controls.show_job(job())
    assert press(controls, "c") == []
    assert controls.question == "cancel the print of part.gcode?"
    assert controls.help_items() == ["y cancels the print", "any other key goes on"]
    assert press(controls, "x") == []  # a stray key: the print goes on
    assert controls.question is None
    assert controls.notice is not None and "the print goes on" in controls.notice.title
    for other in ("q", "c", "\x1b", "\r", "n", "1", PASTE + "yyy"):
        assert press(controls, ["c", other]) == [], other  # not even a paste full of y
        assert controls.question is None
    assert press(controls, "cy") == [CancelJob()]
    assert press(controls, "cY") == [CancelJob()]


def test_without_a_running_job_p_and_c_are_nothing_and_not_offered() -> None:
    for shown in (None, job("starting", percent=None), job("cancelling"), job("done", percent=100.0), cancelled()):
        controls = WatchControls()
        controls.show_job(shown)
        assert press(controls, "pc") == [], shown
        assert controls.question is None
        assert not any(item.startswith(("p ", "c ")) for item in controls.help_items())


def test_the_cancel_question_closes_when_the_job_ends_meanwhile() -> None:
    controls = WatchControls()
    controls.show_job(job())
    press(controls, "c")
    controls.show_job(cancelled())
    assert controls.question is None
    assert controls.notice is not None and controls.notice.title == "the print ended: cancelled; nothing cancelled"
    assert press(controls, "y") == []


def test_the_job_keys_lead_the_help_and_digits_still_choose_presets() -> None:
    controls = WatchControls()
    controls.show_job(job())
    assert controls.help_items()[:3] == ["p pause", "c cancel print", "h hotend"]
    assert press(controls, "1")[0].label == "PLA"  # type: ignore[attr-defined]


# ------------------------------------------------------------------------------------------- rendering (pure)


@pytest.mark.parametrize("width", WIDTHS)
def test_the_job_line_fits_every_width_and_names_file_percent_state_and_starter(width: int) -> None:
    text = rendered(job_line(job(), width), width)
    assert all(len(line) <= width for line in text.splitlines())
    assert "part.gcode" in text and "42.5 %" in text and "printing" in text
    assert "started by socket client 3" in text
    assert ("━" in text) == (width >= 60)  # narrower, the bar would take a line of its own


@pytest.mark.parametrize("width", WIDTHS)
def test_an_ended_job_says_how_and_where_to_resume(width: int) -> None:
    text = flat(rendered(job_line(cancelled(), width), width))
    assert "part.gcode" in text and "cancelled by socket client 4" in text and "at 12.3 %" in text
    assert "ran line 160 (maybe up to 163)" in text and "resume with --from-line 161" in text
    done = flat(rendered(job_line(job("done", percent=100.0), width), width))
    assert "done" in done and "resume" not in done and "%" not in done
    failed = flat(rendered(job_line(job("failed", error="the printer halted: MINTEMP"), width), width))
    assert "failed" in failed and "the printer halted: MINTEMP" in failed


def test_a_file_name_is_shown_as_given_never_read_as_markup() -> None:
    text = rendered(job_line(job(file="[bold]x[/bold] :smile:.gcode"), 80), 80)
    assert "[bold]x[/bold] :smile:.gcode" in text


@pytest.mark.parametrize(("width", "height"), [(30, 12), (40, 20), (80, 30), (120, 40)])
def test_the_view_keeps_the_job_line_and_the_key_help_on_screen(width: int, height: int) -> None:
    model = model_with("T:190.00 /200.00 B:58.00 /60.00 @:60 B@:20")
    controls = WatchControls()
    controls.show_job(job())
    lines = rendered(watch_view(model, "serve:sim", "Marlin", width=width, height=height, controls=controls), width)
    assert len(lines.splitlines()) < height
    assert "part.gcode" in lines.splitlines()[0]  # over the table
    assert "q quit" in lines and ("c cancel print" in lines or " c " in lines)
    press(controls, "c")
    lines = rendered(watch_view(model, "serve:sim", "Marlin", width=width, height=height, controls=controls), width)
    assert len(lines.splitlines()) < height
    assert "cancel the print of part.gcode?" in flat(lines) and "y cancels the print" in flat(lines)


def test_a_printer_without_a_job_renders_as_before() -> None:
    model = model_with("T:190.00 /200.00 B:58.00 /60.00 @:60 B@:20")
    with_none = WatchControls()
    with_none.show_job(None)
    assert rendered(watch_view(model, "p", "Marlin", controls=with_none), 80) == rendered(
        watch_view(model, "p", "Marlin", controls=WatchControls()), 80
    )
    line = plain_line(model, wall_time_s=0)
    assert "job" not in line and line == plain_line(model, wall_time_s=0, job=None)
    assert plain_line(model, wall_time_s=0, job=job()).endswith(" polls/s | job part.gcode printing 42.5%")
    assert plain_line(model, wall_time_s=0, job=cancelled()).endswith(
        " | job part.gcode cancelled 12.3% resume --from-line 161"
    )


# ------------------------------------------------------------------------------------------- a real service

SERVE_ARGS = ("--sim", "--sim-speed", "1", "--interval", "0.05")


def slow_gcode(path: Path, lines: int = 3000) -> Path:
    """At --sim-speed 1 each line dwells 50 ms: minutes of printing, its percent moving visibly every second."""
    path.write_text("G4 P50\n" * lines)
    return path


async def start_print(served: Served, gcode: Path) -> dict[str, Any]:
    async with raw_client(served) as client:
        answer = await client.call("start_print", printer="sim", path=str(gcode))
    assert "result" in answer, answer
    return dict(answer["result"]["job"])


async def read_job(served: Served) -> dict[str, Any] | None:
    async with raw_client(served) as client:
        answer = await client.call("job", printer="sim")
    result: dict[str, Any] | None = answer["result"]
    return result


@contextlib.asynccontextmanager
async def piped_watch(served: Served, *args: str) -> Any:
    """`marlin-temp watch --port serve:sim@SOCKET` with stdout a pipe: its lines, read as they come; SIGINT ends it
    (as Ctrl-C does) and it must exit 0."""
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "marlin_temp",
        "watch",
        "--port",
        served.url(),
        "--refresh",
        "0.2",
        *args,
        stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=served.env(),
    )
    assert process.stdout is not None and process.stderr is not None
    lines: list[str] = []

    async def read() -> None:
        assert process.stdout is not None
        while line := await process.stdout.readline():
            lines.append(line.decode().rstrip("\n"))

    reader = asyncio.create_task(read())
    try:
        yield lines
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGINT)
        code = await asyncio.wait_for(process.wait(), 30)
        await reader
        errors = (await process.stderr.read()).decode()
    assert code == 0, errors
    assert "Traceback" not in errors, errors


async def test_piped_watch_says_the_job_in_each_line_and_its_changes_on_their_own(tmp_path: Path) -> None:
    from conftest import until

    gcode = slow_gcode(tmp_path / "part.gcode")
    async with serving(tmp_path, *SERVE_ARGS) as served:
        async with piped_watch(served) as lines:
            # No job yet: the view does not break, and says none.
            await until(lambda: sum(" polls/s" in line for line in lines) >= 2, "plain lines without a job")
            assert not any("job" in line for line in lines), lines
            await start_print(served, gcode)
            await until(lambda: any(" | job part.gcode printing " in line for line in lines), "the job in a line")
        said = [line for line in lines if line.startswith("job: ")]
        assert said and said[0].startswith("job: part.gcode on sim: "), lines
        assert "started by socket client" in said[-1]

        async with piped_watch(served, "--json") as json_lines:
            await until(lambda: any('"job"' in line for line in json_lines), "a JSON line with the job")
        statuses = [json.loads(line) for line in json_lines]
        assert statuses[-1]["job"]["file"] == "part.gcode" and statuses[-1]["job"]["state"] == "printing"
        async with raw_client(served) as client:
            await client.call("cancel", printer="sim")


# ------------------------------------------------------------------------------------------- a real terminal


@needs_tmux
async def test_watch_shows_the_served_job_pauses_it_and_cancels_it_only_after_y(tmux: Tmux, tmp_path: Path) -> None:
    gcode = slow_gcode(tmp_path / "part.gcode")
    async with serving(tmp_path, *SERVE_ARGS) as served:
        await start_print(served, gcode)
        command = (
            f"{sys.executable} -m marlin_temp watch --port {served.url()} --refresh 0.3; "
            "echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit status
        )
        env = ["-e", f"MARLIN_SERVE_SOCKET={served.socket}", "-e", f"PATH={os.environ['PATH']}"]
        await asyncio.to_thread(
            tmux.run, "new-session", "-d", "-s", "w", *env, "-x", "100", "-y", "40", sized(command, 100, 40)
        )

        async def screen_shows(condition: Any, what: str) -> str:
            return await asyncio.to_thread(tmux.wait_for, condition, what)

        async def keys(*typed: str) -> None:
            await asyncio.to_thread(tmux.run, "send-keys", "-t", "w", *typed)

        screen = await screen_shows(
            lambda s: "part.gcode" in s and "printing" in s and "c cancel print" in s, "the job and its keys"
        )
        assert "started by socket client" in flat(screen)
        first = screen.splitlines()[0]
        assert first.lstrip().startswith("print") and "part.gcode" in first and " %" in first

        await keys("p")
        await screen_shows(lambda s: "paused part.gcode" in flat(s) and "p resume" in s, "the pause")
        assert (await read_job(served) or {})["state"] == "paused"
        await keys("p")
        await screen_shows(lambda s: "resumed part.gcode" in flat(s) and "p pause" in s, "the resume")
        assert (await read_job(served) or {})["state"] == "printing"

        await keys("c")
        await screen_shows(lambda s: "cancel the print of part.gcode?" in flat(s), "the cancel question")
        await keys("x")  # a stray key: not cancelled
        await screen_shows(lambda s: "not cancelled: the print goes on" in flat(s), "the print going on")
        assert (await read_job(served) or {})["state"] == "printing"

        await keys("c")
        await screen_shows(lambda s: "cancel the print of part.gcode?" in flat(s), "the cancel question again")
        await keys("y")
        # The cancel's own report first, then the job line read anew (within a second): nothing left to cancel.
        await screen_shows(
            lambda s: "cancelled by" in flat(s) and "resume with --from-line" in flat(s), "the job cancelled"
        )
        screen = await screen_shows(lambda s: "c cancel print" not in s, "the cancel key gone with the job")
        ended = await read_job(served)
        assert ended is not None and ended["state"] == "cancelled" and ended["cancelled_by"]
        assert f"resume with --from-line {ended['resume_line']}" in flat(screen)

        await keys("q")
        after = await screen_shows(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
        assert "MARLIN-EXIT=0" in after
