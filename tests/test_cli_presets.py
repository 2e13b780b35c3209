"""Presets (issue 25): the presets file read by `marlin_aio.farm.presets`, `marlin-temp presets`, and `set --preset`
against the simulated printer on a real pty, with a config folder of the test's own (`XDG_CONFIG_HOME`)."""

from __future__ import annotations

import asyncio
import json
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from tmux_screen import Tmux
from typer.testing import CliRunner

from marlin_aio.farm.presets import (
    DEFAULT_PRESETS,
    Preset,
    find_preset,
    parse_presets,
    preset_targets,
    presets_toml,
)
from marlin_aio.protocol import DEFAULT_LIMITS, HeaterLimits
from marlin_aio.simulator import SimulatorConfig, serve_pty
from marlin_temp.common.connect import Exit
from marlin_temp.common.model import SetTargets, WatchControls, WatchModel
from marlin_temp.main import app

runner = CliRunner()
TARGETS = ("M104", "M109", "M140", "M190")


def config_home(tmp_path: Path) -> dict[str, str | None]:
    """The environment of a user whose config folder is `tmp_path` (and who names no presets file)."""
    return {"XDG_CONFIG_HOME": str(tmp_path), "MARLIN_TEMP_PRESETS": None}


def presets_file(tmp_path: Path) -> Path:
    return tmp_path / "marlin-temp" / "presets.toml"


def write_presets(tmp_path: Path, text: str) -> Path:
    path = presets_file(tmp_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


# ------------------------------------------------------------------------------------------- the file (pure)


def test_the_default_file_reads_back_as_the_defaults() -> None:
    assert [p.name for p in DEFAULT_PRESETS] == ["PLA", "PETG", "ABS", "cooldown"]
    assert DEFAULT_PRESETS[0] == Preset("PLA", 200.0, 60.0) and DEFAULT_PRESETS[1] == Preset("PETG", 240.0, 80.0)
    assert parse_presets(presets_toml(DEFAULT_PRESETS), "x") == DEFAULT_PRESETS
    odd = (Preset("PLA+", 205.5, None), Preset("bed-only", None, 55.0))
    assert parse_presets(presets_toml(odd), "x") == odd


def test_presets_keep_the_files_order() -> None:
    text = "[preset.Zeta]\nhotend = 1\n[preset.Alpha]\nbed = 2\n[preset.Mid]\nhotend = 3\nbed = 4\n"
    assert [p.name for p in parse_presets(text, "x")] == ["Zeta", "Alpha", "Mid"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[preset.PLA\n", "f.toml: not valid TOML"),
        ("[material.PLA]\nhotend = 200\n", "f.toml: unknown section 'material'"),
        ("[preset.PLA]\nnozzle = 200\n", "f.toml: preset 'PLA': unknown key 'nozzle' (known: hotend, bed)"),
        ('[preset.PLA]\nhotend = "abc"\n', "f.toml: preset 'PLA': hotend must be a number of degrees C, got 'abc'"),
        ("[preset.PLA]\nbed = -5\n", "f.toml: preset 'PLA': bed target must not be negative"),
        ("[preset.PLA]\nbed = nan\n", "f.toml: preset 'PLA': bed target must be a finite number"),
        ("[preset.PLA]\n", "f.toml: preset 'PLA': no target"),
        ("[preset.pla]\nbed = 1\n[preset.PLA]\nbed = 2\n", "f.toml: preset 'PLA': the same name as preset 'pla'"),
        ('[preset."P L A"]\nbed = 1\n', "f.toml: preset 'P L A': a name is"),
        ("[preset.-x]\nbed = 1\n", "f.toml: preset '-x': a name is"),
        ("", "f.toml: no presets"),
    ],
)
def test_a_bad_file_is_one_line_naming_the_file_the_preset_and_the_key(text: str, message: str) -> None:
    with pytest.raises(ValueError, match="^" + re.escape(message)) as caught:
        parse_presets(text, "f.toml")
    assert "\n" not in str(caught.value)


def test_a_preset_is_found_in_any_case_and_checked_against_the_limits_it_is_used_with() -> None:
    assert find_preset(DEFAULT_PRESETS, "petg").name == "PETG"
    with pytest.raises(ValueError, match=r"no preset named 'nylon' \(presets: PLA, PETG, ABS, cooldown\)"):
        find_preset(DEFAULT_PRESETS, "nylon")
    assert preset_targets(DEFAULT_PRESETS[2], DEFAULT_LIMITS) == {"hotend": 250.0, "bed": 100.0}
    with pytest.raises(ValueError, match="preset 'ABS': bed target 100 C is above the limit of 90 C"):
        preset_targets(DEFAULT_PRESETS[2], HeaterLimits(260, 90, 60))


# ------------------------------------------------------------------------------------------- marlin-temp presets


def test_with_no_file_the_presets_are_the_defaults(tmp_path: Path) -> None:
    result = runner.invoke(app, ["presets", "--json"], env=config_home(tmp_path))
    assert result.exit_code == Exit.OK, result.output
    listing = json.loads(result.stdout)
    assert listing["file"] == str(presets_file(tmp_path)) and listing["exists"] is False
    assert [(p["key"], p["name"], p["hotend"], p["bed"]) for p in listing["presets"]] == [
        ("1", "PLA", 200.0, 60.0),
        ("2", "PETG", 240.0, 80.0),
        ("3", "ABS", 250.0, 100.0),
        ("4", "cooldown", 0.0, 0.0),
    ]
    table = runner.invoke(app, ["presets"], env=config_home(tmp_path))
    assert "the default presets" in table.stdout and "--init" in table.stdout and "PETG" in table.stdout


def test_init_writes_the_defaults_and_never_overwrites(tmp_path: Path) -> None:
    result = runner.invoke(app, ["presets", "--init"], env=config_home(tmp_path))
    assert result.exit_code == Exit.OK, result.output
    path = presets_file(tmp_path)
    assert parse_presets(path.read_text(), str(path)) == DEFAULT_PRESETS
    assert f"presets: {path}" in result.stdout
    path.write_text("[preset.Mine]\nhotend = 210\n")
    again = runner.invoke(app, ["presets", "--init"], env=config_home(tmp_path))
    assert again.exit_code == Exit.USAGE
    assert "exists already; not overwritten" in one_line(again.output)
    assert path.read_text() == "[preset.Mine]\nhotend = 210\n"


def test_a_file_named_by_the_option_or_the_variable_wins_and_must_exist(tmp_path: Path) -> None:
    mine = tmp_path / "mine.toml"
    mine.write_text("[preset.Nylon]\nhotend = 255\nbed = 70\n")
    for args, env in (
        (["presets", "--json", "--presets", str(mine)], config_home(tmp_path)),
        (["presets", "--json"], config_home(tmp_path) | {"MARLIN_TEMP_PRESETS": str(mine)}),
    ):
        result = runner.invoke(app, args, env=env)
        assert result.exit_code == Exit.OK, result.output
        assert [p["name"] for p in json.loads(result.stdout)["presets"]] == ["Nylon"]
    missing = runner.invoke(app, ["presets", "--presets", str(tmp_path / "nope.toml")], env=config_home(tmp_path))
    assert missing.exit_code == Exit.USAGE
    assert "nope.toml does not exist" in one_line(missing.output)


def test_a_bad_file_exits_2_with_one_line(tmp_path: Path) -> None:
    path = write_presets(tmp_path, "[preset.PLA]\nhotend = 200\n[preset.PETG]\nhotend = 'abc'\n")
    result = runner.invoke(app, ["presets"], env=config_home(tmp_path))
    assert result.exit_code == Exit.USAGE
    assert f"{path}: preset 'PETG': hotend must be a number of degrees C, got 'abc'" in one_line(result.output)


# ------------------------------------------------------------------------------------------- set --preset


async def set_on(tmp_path: Path, *args: str) -> tuple[int, str, list[str]]:
    """Run `set` against a fresh simulator: exit code, output, and the target commands the printer ran."""
    async with serve_pty(SimulatorConfig(), time_scale=100) as sim:
        result = await asyncio.to_thread(
            runner.invoke, app, ["set", "--port", sim.url, *args], env=config_home(tmp_path)
        )
        ran = [command for command in sim.printer.executed if command.startswith(TARGETS)]
        return result.exit_code, result.output, ran


async def test_set_preset_sets_the_presets_targets(tmp_path: Path) -> None:
    code, output, ran = await set_on(tmp_path, "--preset", "petg")
    assert code == Exit.OK, output
    assert ran == ["M104 S240", "M140 S80"]
    assert "preset PETG: hotend target 240 C" in output


async def test_set_preset_reads_the_file_and_waits(tmp_path: Path) -> None:
    write_presets(tmp_path, "[preset.Warm]\nhotend = 60\nbed = 40\n")
    code, output, ran = await set_on(tmp_path, "--preset", "WARM", "--wait", "--wait-timeout", "120")
    assert code == Exit.OK, output
    assert ran == ["M104 S60", "M140 S40"]
    assert "reached: hotend target 60 C" in output


async def test_an_explicit_target_replaces_the_presets_own(tmp_path: Path) -> None:
    # PETG's 240 is above --max-hotend 230, but --hotend replaces it: only what is sent is checked.
    code, output, ran = await set_on(tmp_path, "--preset", "PETG", "--hotend", "215", "--max-hotend", "230")
    assert code == Exit.OK, output
    assert ran == ["M104 S215", "M140 S80"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--preset", "nylon"], "no preset named 'nylon' (presets: PLA, PETG, ABS, cooldown)"),
        (["--preset", "PETG", "--max-hotend", "230"], "preset 'PETG': hotend target 240 C is above the limit of 230 C"),
        (["--preset", "PLA", "--off"], "do not combine it with --preset"),
    ],
)
async def test_a_preset_that_cannot_be_set_exits_2_and_sends_nothing(
    tmp_path: Path, args: list[str], message: str
) -> None:
    code, output, ran = await set_on(tmp_path, *args)
    assert code == Exit.USAGE, output
    assert message in one_line(output)
    assert ran == []


async def test_set_preset_with_a_bad_file_exits_2_naming_the_file_preset_and_key(tmp_path: Path) -> None:
    path = write_presets(tmp_path, "[preset.PLA]\nhotend = 200\nnozzle = 0.4\n")
    code, output, ran = await set_on(tmp_path, "--preset", "PLA")
    assert code == Exit.USAGE, output
    assert f"{path}: preset 'PLA': unknown key 'nozzle'" in one_line(output)
    assert ran == []


# ------------------------------------------------------------------------------------------- watch's keys


def test_watchs_keys_1_to_9_are_the_presets_in_order() -> None:
    presets = (Preset("Warm", 60.0, 40.0), Preset("Bed", None, 55.0))
    controls = WatchControls(presets=presets)
    model = WatchModel(window_s=60)
    assert controls.press("1", model) == SetTargets(hotend=60.0, bed=40.0, label="Warm")
    assert controls.press("2", model) == SetTargets(hotend=None, bed=55.0, label="Bed")
    assert controls.press("3", model) is None
    items = controls.help_items()
    assert "1 Warm" in items and "2 Bed" in items and not any(item.startswith("3 ") for item in items)
    many = tuple(Preset(f"P{n}", float(n), None) for n in range(1, 12))
    controls = WatchControls(presets=many)
    assert controls.press("9", model) == SetTargets(hotend=9.0, label="P9")
    assert [item for item in controls.help_items() if item[:1].isdigit()][-1] == "9 P9"


def test_a_preset_above_the_limits_is_refused_when_its_key_is_pressed() -> None:
    controls = WatchControls(HeaterLimits(230, 140, 60))
    assert controls.press("2", WatchModel(window_s=60)) is None  # PETG: 240
    assert controls.notice is not None and controls.notice.error
    assert "PETG: hotend target 240 C is above the limit of 230 C" in controls.notice.title


def test_watch_with_a_bad_presets_file_exits_2_before_connecting(tmp_path: Path) -> None:
    path = write_presets(tmp_path, "[preset.PLA]\nhotend = 200\nbed = 'sixty'\n")
    result = runner.invoke(app, ["watch", "--port", "/dev/marlin-test-no-such-port"], env=config_home(tmp_path))
    assert result.exit_code == Exit.USAGE
    assert f"{path}: preset 'PLA': bed must be a number of degrees C, got 'sixty'" in one_line(result.output)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (.ci/run installs it)")
def test_the_live_views_keys_are_the_files_presets(tmp_path: Path) -> None:
    write_presets(tmp_path, "[preset.Warm]\nhotend = 65\nbed = 45\n[preset.PLA]\nhotend = 200\nbed = 60\n")
    tmux = Tmux()
    command = (
        f"XDG_CONFIG_HOME={shlex.quote(str(tmp_path))} {sys.executable} -m marlin_temp watch --sim --sim-speed 20 "
        "--refresh 0.3; echo MARLIN-EXIT=$?; sleep 600"  # keep the pane alive to read the exit status
    )
    try:
        tmux.run("new-session", "-d", "-s", "w", "-x", "100", "-y", "40", f"stty cols 100 rows 40; {command}")
        screen = tmux.wait_for(lambda s: "polls/s" in s and "h hotend" in s, "the live view with its key help")
        assert "1 Warm" in screen and "2 PLA" in screen and "PETG" not in screen
        tmux.run("send-keys", "-t", "w", "1")
        tmux.wait_for(lambda s: "Warm: hotend target 65 °C, bed target 45 °C" in s, "the Warm preset's notice")
        tmux.run("send-keys", "-t", "w", "q")
        assert "MARLIN-EXIT=0" in tmux.wait_for(lambda s: "MARLIN-EXIT=" in s, "watch to exit")
    finally:
        subprocess.run(["tmux", "-L", tmux.socket, "kill-server"], capture_output=True, check=False)
