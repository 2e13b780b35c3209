"""The farm's `preset` command (issue 25): checked by `parse_command` as set_temperatures is, run through the bridge
against a real Mosquitto broker and the simulated printer, with a Home Assistant button per preset; and
`marlin-temp farm` giving the bridge the presets file's presets."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from test_farm import MOSQUITTO, Broker, command, not_polls, one_printer_farm, subscribed
from typer.testing import CliRunner

from marlin_aio.farm.commands import CommandError, parse_command
from marlin_aio.farm.discovery import preset_slugs
from marlin_aio.farm.presets import DEFAULT_PRESETS, Preset
from marlin_aio.farm.supervisor import FarmPrinter, PrinterSpec
from marlin_temp.common.connect import Exit
from marlin_temp.main import app

runner = CliRunner()
needs_mosquitto = pytest.mark.skipif(
    MOSQUITTO is None, reason="Mosquitto is not installed: apt-get install mosquitto (.ci/run installs it)"
)
PRINTERS = {
    "a": FarmPrinter(PrinterSpec("a", "socket://127.0.0.1:1")),
    "cool": FarmPrinter(PrinterSpec("cool", "x", max_hotend_celsius=230)),
}
MINE = (Preset("Warm", 60.0, 45.0), Preset("PLA+", 205.0, None))


def parsed(payload: object, printer: str = "a", presets: tuple[Preset, ...] = DEFAULT_PRESETS) -> object:
    """The command `payload` parses to, or the refusal's message."""
    try:
        return parse_command(printer, json.dumps(payload).encode(), PRINTERS, None, presets=presets)
    except CommandError as exc:
        return str(exc)


def test_a_preset_command_becomes_its_targets() -> None:
    command_ = parse_command("a", b'{"id": 1, "action": "preset", "name": "petg"}', PRINTERS, None)
    assert (command_.action, command_.targets, command_.preset, command_.id) == (
        "set_temperatures",
        {"hotend": 240.0, "bed": 80.0},
        "PETG",
        1,
    )
    mine = parse_command("a", b'{"action": "preset", "name": "pla+"}', PRINTERS, None, presets=MINE)
    assert mine.targets == {"hotend": 205.0}


@pytest.mark.parametrize(
    ("payload", "printer", "message"),
    [
        ({"action": "preset", "name": "nylon"}, "a", "no preset named 'nylon' (presets: PLA, PETG, ABS, cooldown)"),
        ({"action": "preset"}, "a", 'preset needs "name"'),
        ({"action": "preset", "name": 7}, "a", 'preset needs "name"'),
        ({"action": "preset", "name": "PLA", "hotend": 1}, "a", "preset takes no 'hotend'"),
        # That printer's own limit: the preset is refused whole, nothing is sent.
        ({"action": "preset", "name": "PETG"}, "cool", "preset 'PETG': hotend target 240 C is above the limit of 230"),
    ],
)
def test_a_preset_command_that_cannot_be_run_is_refused(payload: object, printer: str, message: str) -> None:
    refusal = parsed(payload, printer)
    assert isinstance(refusal, str) and message in refusal, refusal


def test_each_preset_gets_a_button_id_of_its_own() -> None:
    presets = (Preset("PLA+", 1.0), Preset("a-b", 1.0), Preset("a.b", 1.0), Preset("cooldown", 0.0))
    assert [slug for slug, _ in preset_slugs(presets)] == ["pla_plus", "a_b", "a_b_2", "cooldown"]


@needs_mosquitto
async def test_the_bridge_runs_a_preset_and_offers_a_button_for_each(broker: Broker) -> None:
    async with one_printer_farm(broker, allow_commands=True, presets=MINE) as one:
        sim, sub, commander = one.sim, one.sub, one.client
        answer = await command(sub, commander, "a", '{"id": 1, "action": "preset", "name": "WARM"}', 1)
        assert answer == {"id": 1, "ok": True, "result": {"targets": {"hotend": 60.0, "bed": 45.0}, "preset": "Warm"}}
        assert not_polls(list(sim.printer.executed))[-2:] == ["M104 S60", "M140 S45"]
        before = not_polls(list(sim.printer.executed))
        answer = await command(sub, commander, "a", '{"id": 2, "action": "preset", "name": "PETG"}', 2)
        assert answer["ok"] is False and answer["error"] == "no preset named 'PETG' (presets: Warm, PLA+)"
        assert not_polls(list(sim.printer.executed)) == before

        topic = "homeassistant/button/marlin_a/preset_pla_plus/config"
        await sub.until(lambda: bool(sub.payloads(topic)), "the preset buttons")
        button = sub.payloads(topic)[-1]
        assert button["command_topic"] == "marlin/a/command"
        assert json.loads(button["payload_press"]) == {"action": "preset", "name": "PLA+"}
        warm = sub.payloads("homeassistant/button/marlin_a/preset_warm/config")
        assert warm and json.loads(warm[-1]["payload_press"]) == {"action": "preset", "name": "Warm"}


def test_the_farm_reads_the_presets_file_only_with_commands(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[preset.PLA]\nhotend = 200\nfan = 100\n")
    result = runner.invoke(app, ["farm", "--sims", "1", "--allow-commands", "--presets", str(bad)])
    assert result.exit_code == Exit.USAGE
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert lines == [f"error: {bad}: preset 'PLA': unknown key 'fan' (known: hotend, bed)"]


@needs_mosquitto
async def test_marlin_temp_farm_gives_the_bridge_the_files_presets(broker: Broker, tmp_path: Path) -> None:
    presets = tmp_path / "presets.toml"
    presets.write_text("[preset.Nylon]\nhotend = 250\nbed = 70\n")
    args = ["farm", "--sims", "1", "--allow-commands", "--presets", str(presets), "--duration", "10"]
    args += ["--broker", f"127.0.0.1:{broker.port}"]
    async with subscribed(broker.port) as sub:
        result = await asyncio.to_thread(runner.invoke, app, args)
        assert result.exit_code == Exit.OK, result.output
        buttons = [t for t, _, _ in sub.messages if t.startswith("homeassistant/button/marlin_sim1/preset_")]
    assert set(buttons) == {"homeassistant/button/marlin_sim1/preset_nylon/config"}
