"""A printer's password (Marlin's PASSWORD_FEATURE, `M511 P<password>`) never shows in clear text: not in errors,
not in the `marlin_aio` log (INFO and DEBUG, the wire log included), not in the trace, not on the farm's MQTT topics.

The redaction rule is tested on its own (every spelling Marlin reads as M511); the rest against the simulated
printer on a real pty, locked with a password, whose M511 `ok` is lost (`Faults.drop_ok_codes`), and the farm
against a real Mosquitto broker (the helpers of tests/test_farm.py).
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import aiomqtt
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_farm import MOSQUITTO, Broker, command, farm_and_bridge, running, subscribed

import marlin_aio
from marlin_aio.farm.config import load_config
from marlin_aio.farm.supervisor import PrinterSpec
from marlin_aio.protocol.secrets import redact
from marlin_aio.simulator import SimulatorConfig, serve_pty

#: Digits that no time, count or port in a message could make up by chance (unlike "1234" in "+1.234 s").
PASSWORD = "271828"

SPELLINGS = [
    ("M511 P1234", "M511 ****"),
    ("N12 M511 P1234*87", "N12 M511 ****"),
    ("N12M511 P1234*87", "N12M511 ****"),
    ("m511 p1234", "m511 ****"),
    ("M0511P1234", "M0511 ****"),
    ("M 511 P1234", "M 511 ****"),
    ("  M511 P1234 ; unlock", "  M511 ****"),
    ("M511P1234", "M511 ****"),
    ("M511 P 1234", "M511 ****"),
    ("M511.0 P1234", "M511 ****"),
    ('echo:Unknown command: "M511 P1234"', 'echo:Unknown command: "M511 ****'),
    ("first M511 P1234\nN3 M511 P1234*12\nok", "first M511 ****\nN3 M511 ****\nok"),
]

UNTOUCHED = [
    "M105",
    "N12 G1 X511 Y10*93",
    "M5110 P1234",
    "G1 XM511 P1",  # no command word: glued to the X
    "echo:Printer locked! (Unlock with M511 or LCD)",  # Marlin's own lock message
    "unlock it with M511 P<password> (connect with password=...)",  # the library's hint
    "no 'ok' for 'M511 ****' after 2.0 s; last sent 'N1 M511 ****' 2.0 s ago",  # already redacted
]


@pytest.mark.parametrize(("text", "redacted"), SPELLINGS)
def test_every_spelling_marlin_reads_as_m511_loses_its_password_and_checksum(text: str, redacted: str) -> None:
    assert redact(text) == redacted
    assert "1234" not in redact(text)
    assert redact(redact(text)) == redact(text)  # idempotent: a message of redacted pieces may be redacted whole


@pytest.mark.parametrize("text", UNTOUCHED)
def test_text_that_carries_no_password_comes_back_as_it_was(text: str) -> None:
    assert redact(text) == text


def test_a_line_without_511_is_returned_as_is_without_a_regex() -> None:
    line = "N1234 G1 X10.5 Y20.3 E0.123*87"
    assert redact(line) is line


@given(st.text(alphabet="Mm 0511N*\n;'", max_size=20), st.sampled_from(["M511", "m511", "M0511", "M 511"]))
def test_nothing_after_an_m511_survives(before: str, word: str) -> None:
    text = f"N7 {word} P{PASSWORD}*42"
    assert PASSWORD not in redact(before + text)


# ------------------------------------------------------------------------------------------- the library


def assert_clean(caplog: pytest.LogCaptureFixture) -> None:
    logged = "\n".join(record.getMessage() for record in caplog.records)
    assert "M511" in logged  # the lines about it were logged, redacted
    assert PASSWORD not in logged


async def test_a_handshake_whose_m511_ok_is_lost_fails_without_the_password(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="marlin_aio")
    async with serve_pty(SimulatorConfig(password=PASSWORD), time_scale=20) as sim:
        sim.printer.faults.drop_ok_codes = frozenset({"M511"})
        with pytest.raises(marlin_aio.HandshakeTimeoutError) as caught:
            async with marlin_aio.connect(sim.url, timeout_s=1.0, password=PASSWORD):
                pass
        # The wire kept it: the printer got the password and is unlocked.
        assert sim.printer.executed[-1] == f"M511 P{PASSWORD}"
    message = str(caught.value)
    assert "M511 ****" in message and PASSWORD not in message
    cause = caught.value.__cause__
    assert isinstance(cause, marlin_aio.CommandTimeoutError) and cause.command == "M511 ****"
    assert_clean(caplog)
    # The wire log at DEBUG showed the line as sent, redacted.
    assert any(r.name == "marlin_aio.wire" and "M511 ****" in r.getMessage() for r in caplog.records)


async def test_a_typed_m511_that_times_out_is_redacted_in_error_trace_and_log(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG, logger="marlin_aio")
    async with serve_pty(SimulatorConfig(password=PASSWORD), time_scale=20) as sim:
        texts: list[str] = []
        for spelling in (f"M511 P{PASSWORD}", f"m0511p{PASSWORD}"):
            sim.printer.faults.silent = False
            async with marlin_aio.connect(sim.url, timeout_s=2.0, password=PASSWORD) as printer:
                # The board falls silent: nothing answers the M511 (a lost ok alone is found by a probe and is no
                # timeout), so it times out with the printer's last words in its message.
                sim.printer.faults.silent = True
                with pytest.raises(marlin_aio.CommandTimeoutError) as caught:
                    await printer.send(spelling, timeout_s=0.5)
                assert PASSWORD not in str(caught.value) and PASSWORD not in caught.value.command
                assert "511 ****" in str(caught.value)
                trace = printer.trace
                texts += [entry.text for entry in trace.entries()]
                assert PASSWORD not in trace.format(0.0)
        assert any("M511 ****" in text for text in texts) and any("m0511 ****" in text for text in texts)
    assert_clean(caplog)


async def test_an_m511_whose_ok_is_lost_behind_a_later_answer_is_logged_redacted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG, logger="marlin_aio")
    async with (
        serve_pty(SimulatorConfig(password=PASSWORD), time_scale=20) as sim,
        marlin_aio.connect(sim.url, timeout_s=2.0, password=PASSWORD, max_in_flight=2) as printer,
    ):
        sim.printer.faults.drop_ok_codes = frozenset({"M511"})
        # Both on the wire at once (an M105's answer cannot be taken for another's): it proves the M511 ran.
        unlock, position = await asyncio.gather(printer.send(f"M511 P{PASSWORD}"), printer.send("M105"))
        assert unlock.ok_lost and not position.ok_lost
        assert PASSWORD not in printer.trace.format(0.0)
    lost = [r.getMessage() for r in caplog.records if "was lost" in r.getMessage()]
    assert lost == ["the ok of 'M511 ****' was lost; 'M105' was answered after it"]
    assert_clean(caplog)


# ------------------------------------------------------------------------------------------- the farm


def test_a_printer_spec_never_shows_its_password(tmp_path: Path) -> None:
    assert PASSWORD not in repr(PrinterSpec("a", "/dev/ttyUSB0", password=PASSWORD))
    config = tmp_path / "farm.toml"
    config.write_text(f'[[printer]]\nname = "a"\nport = "/dev/ttyUSB0"\npassword = {PASSWORD}\n')
    with pytest.raises(ValueError, match="password must be a string") as caught:
        load_config(config)
    assert PASSWORD not in str(caught.value)
    config.write_text(f'[[printer]]\nname = "a"\nport = "/dev/ttyUSB0"\npassword = "{PASSWORD}"\n')
    (spec,) = load_config(config)
    assert spec.password == PASSWORD and PASSWORD not in repr(spec)


@pytest.mark.skipif(MOSQUITTO is None, reason="Mosquitto is not installed: apt-get install mosquitto")
async def test_the_farms_topics_and_logs_never_carry_the_password(
    broker: Broker, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with (
        serve_pty(SimulatorConfig(password=PASSWORD), time_scale=20) as lost,
        serve_pty(SimulatorConfig(password=PASSWORD), time_scale=20) as locked,
        serve_pty(SimulatorConfig(), time_scale=20) as plain,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="commander") as commander,
    ):
        lost.printer.faults.drop_ok_codes = frozenset({"M511"})
        specs = [
            PrinterSpec("lost", lost.url, poll_interval_s=0.05, timeout_s=1.0, password=PASSWORD),
            PrinterSpec("locked", locked.url, poll_interval_s=0.05, password=PASSWORD),
            PrinterSpec("plain", plain.url, poll_interval_s=0.05),
        ]
        # No second attempt during the test: the failed connection stays the retained state's last error.
        farm, bridge, events = farm_and_bridge(specs, broker.port, farm_backoff_s=(600, 600), allow_commands=True)
        async with running(farm, bridge):
            # The handshake's M511 loses its ok: the connection fails, said in an event and in the retained state.
            await sub.until(
                lambda: any(s["last_error"] for s in sub.payloads("marlin/lost/state")),
                "the failed connection in the state",
            )
            (failed,) = [e for e in sub.payloads("marlin/lost/events") if e["event"] == "connect_failed"]
            assert "M511 ****" in failed["message"]
            assert lost.printer.executed[-1] == f"M511 P{PASSWORD}"  # the printer got it
            await sub.until(lambda: farm.printers["locked"].link_up and farm.printers["plain"].link_up, "both up")
            # Typed G-code: answered; refused before anything is written; its ok lost.
            answer = await command(
                sub, commander, "locked", f'{{"id": 1, "action": "gcode", "command": "M511 P{PASSWORD}"}}', 1
            )
            assert answer["ok"] is True and answer["result"]["replies"][0]["command"] == "M511 ****"
            answer = await command(
                sub, commander, "locked", f'{{"id": 2, "action": "gcode", "command": "M511 P{PASSWORD}\\nM112"}}', 2
            )
            assert answer["ok"] is False and "line break" in answer["error"]
            locked.printer.faults.drop_ok_codes = frozenset({"M511"})
            answer = await command(
                sub, commander, "locked", f'{{"id": 3, "action": "gcode", "command": "N5 m0511 p{PASSWORD}"}}', 3
            )
            # The next poll's answer proves it ran: answered, its ok marked lost, and logged so (redacted).
            assert answer["ok"] is True and answer["result"]["replies"][0]["command"] == "N5 m0511 ****"
            # A firmware without PASSWORD_FEATURE echoes the unknown command back: the reply lines are redacted too.
            answer = await command(
                sub, commander, "plain", f'{{"id": 4, "action": "gcode", "command": "M511 P{PASSWORD}"}}', 4
            )
            assert answer["ok"] is True and answer["result"]["replies"][0]["lines"] == [
                'echo:Unknown command: "M511 ****'
            ]
    # What the farm published (the command topic carries the commander's own messages, not the farm's).
    published = [(topic, payload) for topic, payload, _ in sub.messages if not topic.endswith("/command")]
    assert {"marlin/lost/state", "marlin/lost/events", "marlin/locked/response"} <= {t for t, _ in published}
    for topic, payload in published:
        assert PASSWORD.encode() not in payload, topic
    assert all(PASSWORD not in event.message for event in events)
    assert PASSWORD not in repr(farm.printers["lost"].last_error)
    logged = "\n".join(record.getMessage() for record in caplog.records)
    assert "M511 ****" in logged and PASSWORD not in logged
