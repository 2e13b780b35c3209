"""`Unknown command`, read exactly: the echo says whether the firmware lacks the command or the line arrived damaged.

Marlin echoes what it received (`echo:Unknown command: "M73 P0 R10"`). The same text as sent means the firmware was
built without that command: Marlin skipped the line, and so does the print, with one warning per command (an option
stops instead). Different text means the line arrived damaged past its checksum (two flips of one bit): nothing
ran. One line at a time, nothing is behind it, so it goes again under the next number and lands exactly in its place;
with send-ahead the lines behind it already ran, so the print stops naming them and the line to resume from.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.protocol.printjob import PrintState
from marlin_aio.simulator import Faults, SimulatorConfig, run_in_simulated_time, serve_memory
from marlin_aio.simulator._campaign import CampaignResult, Scenario, run_print
from marlin_temp.main import app

# A PrusaSlicer-like head: M73 (progress) near the top, which Marlin 2.1 lacks unless SET_PROGRESS_MANUALLY is on
# (the simulator lacks it, as the default build does).
PRUSA_LIKE = ["M73 P0 R10", "G90", "G1 X1 F6000", "M73 P50 R5", "G1 X2", "M73 P100 R0", "G1 X3"]


async def _print(lines: list[str], *, send_ahead: bool, stop_on_unknown: bool) -> tuple[object, list[str]]:
    config = SimulatorConfig(motion_time_scale=0.0)
    async with serve_memory(config, Faults(), baud_rate=250_000) as server:
        async with marlin_aio.connect(server.url) as printer:
            handle = await printer.start_print(lines, send_ahead=send_ahead, stop_on_unknown=stop_on_unknown)
            try:
                outcome: object = await handle.wait()
            except marlin_aio.MarlinError as exc:
                outcome = exc
        # (The simulator records every command it processed, an unknown one too: only the moves show what ran.)
        return outcome, [text for text in server.printer.executed if text.startswith("G1")]


@pytest.mark.parametrize("send_ahead", [False, True], ids=["ping-pong", "send-ahead"])
def test_a_command_the_firmware_lacks_is_skipped_with_one_warning_and_the_print_goes_on(
    send_ahead: bool, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="marlin_aio")
    progress, ran = run_in_simulated_time(_print(PRUSA_LIKE, send_ahead=send_ahead, stop_on_unknown=False))
    assert isinstance(progress, marlin_aio.PrintProgress), progress
    assert progress.state is PrintState.DONE and progress.unknown_codes == ("M73",)
    assert progress.lines_acked == len(PRUSA_LIKE)
    assert ran == ["G1 X1 F6000", "G1 X2", "G1 X3"]  # the simulator, as Marlin, ran no M73
    told = [r.getMessage() for r in caplog.records if "does not know M73" in r.getMessage()]
    assert len(told) == 1 and "line 1 of" in told[0], told


@pytest.mark.parametrize("send_ahead", [False, True], ids=["ping-pong", "send-ahead"])
def test_stop_on_unknown_stops_the_print_at_that_line(send_ahead: bool) -> None:
    error, ran = run_in_simulated_time(_print(PRUSA_LIKE[1:], send_ahead=send_ahead, stop_on_unknown=True))
    assert isinstance(error, marlin_aio.CommandNotExecutedError), error
    assert "print stopped at line 3 of" in str(error) and "Unknown command" in str(error)
    assert ran[0] == "G1 X1 F6000"
    if send_ahead and len(ran) > 1:
        # Lines written behind it ran: the error names them, and the line to resume from is past them.
        assert "had been sent behind it and may have run: resume from line" in str(error)


def test_the_cli_says_which_commands_the_printer_skipped(tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(PRUSA_LIKE) + "\n")
    result = CliRunner().invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50"])
    assert result.exit_code == 0, result.output
    assert "the printer does not know M73: Marlin skipped those lines" in result.stderr
    assert "--stop-on-unknown" in CliRunner().invoke(app, ["print", "--help"], env={"COLUMNS": "200"}).stdout
    stopped = CliRunner().invoke(app, ["print", str(gcode), "--sim", "--sim-speed", "50", "--stop-on-unknown"])
    assert stopped.exit_code != 0
    assert "print stopped at line 1 of part.gcode" in stopped.stderr


# Line 15 of the campaign's relative file, `N15 G1 X0.1 F6360*..`, with bit 0 of `G` and of `1` flipped: `F0 X0.1
# F6360` passes the checksum (the two flips cancel in the XOR) and Marlin answers `Unknown command`.
BLIND_SPOT = (("N15 ", 4, 0), ("N15 ", 5, 0))


def _blind_spot_print(*, send_ahead: bool, advanced_ok: bool) -> CampaignResult:
    """The campaign's 100-line relative print, with line 15 damaged in the checksum's blind spot."""
    return run_print(
        Scenario(
            seed=1,
            lines=100,
            send_ahead=send_ahead,
            advanced_ok=advanced_ok,
            relative=True,
            poll_interval_s=None,
            user_interval_s=None,
            flip_once=BLIND_SPOT,
        )
    )


@pytest.mark.parametrize("advanced_ok", [False, True], ids=["plain-ok", "advanced-ok"])
def test_a_damaged_line_marlin_did_not_know_goes_again_one_line_at_a_time_and_runs_in_its_place(
    advanced_ok: bool,
) -> None:
    # Before: the print stopped at line 15 ("arrived damaged in a way its checksum could not show").
    result = _blind_spot_print(send_ahead=False, advanced_ok=advanced_ok)
    assert result.bits_flipped == 2 and result.problems == []
    assert result.state is PrintState.DONE and result.position_checked  # M114: every move ran once
    assert result.executed_in_order and result.lines_executed == 100


@pytest.mark.parametrize("advanced_ok", [False, True], ids=["plain-ok", "advanced-ok"])
def test_with_send_ahead_the_stop_names_the_lines_behind_that_ran_and_the_resume_repeats_none(
    advanced_ok: bool,
) -> None:
    result = _blind_spot_print(send_ahead=True, advanced_ok=advanced_ok)
    assert result.state is PrintState.FAILED and result.error is not None
    assert "print stopped at line 15 of" in result.error
    assert "lines 16-19 had been sent behind it and may have run: resume from line 20" in result.error
    # What ran by the stop: lines 1-14 and some of 16-19 (the rest run after it), so a resume from line 20 runs
    # nothing twice, and line 15 never ran.
    assert 15 <= result.lines_executed <= 18 and not result.executed_in_order
