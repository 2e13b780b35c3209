"""The firmware's own requests through the farm's MQTT bridge, against a real Mosquitto broker and a simulated
printer on a real pty: a prompt shows in `marlin/NAME/state` and as an event, the `answer_prompt` command answers
it (the simulator records the button), and a bad answer is refused with one line and writes nothing. The farm view
of `watch` shows what the printer asks in the printer's state cell.
"""

from __future__ import annotations

import json

import pytest
from rich.console import Console
from test_farm import MOSQUITTO, Broker, command, not_polls, one_printer_farm

from marlin_temp.common.model import WatchModel
from marlin_temp.farm.view import farm_row, farm_table

pytestmark = pytest.mark.skipif(MOSQUITTO is None, reason="Mosquitto is not installed")


async def test_a_prompt_is_published_answered_over_mqtt_and_bad_answers_write_nothing(broker: Broker) -> None:
    async with one_printer_farm(broker, allow_commands=True) as farm:
        sim, sub, client = farm.sim, farm.sub, farm.client
        state_topic, events_topic = "marlin/a/state", "marlin/a/events"
        await sub.until(lambda: bool(sub.payloads(state_topic)), "the first state")
        assert sub.payloads(state_topic)[-1]["prompt"] is None
        assert sub.payloads(state_topic)[-1]["waiting_for_user"] is False

        sim.printer.open_prompt(sim.now(), "Door open", ["Continue", "Cancel"])
        sim.poke()
        await sub.until(
            lambda: any(s["prompt"] is not None for s in sub.payloads(state_topic)), "the prompt in the state"
        )
        opened = next(s["prompt"] for s in sub.payloads(state_topic) if s["prompt"] is not None)
        assert opened == {"message": "Door open", "buttons": ["Continue", "Cancel"]}
        await sub.until(
            lambda: "prompt_opened" in [e["event"] for e in sub.payloads(events_topic)], "the prompt_opened event"
        )
        event = next(e for e in sub.payloads(events_topic) if e["event"] == "prompt_opened")
        assert event["message"] == "Door open (buttons: Continue, Cancel)"
        configs = {t: json.loads(p) for t, p, _ in sub.messages if t.startswith("homeassistant/")}
        sensor = configs["homeassistant/sensor/marlin_a/prompt/config"]
        assert sensor["state_topic"] == state_topic and "value_json.prompt.message" in sensor["value_template"]

        before = not_polls(list(sim.printer.executed))
        bad = {
            1: ('{"id": 1, "action": "answer_prompt", "index": "0"}', "got '0'"),
            2: ('{"id": 2, "action": "answer_prompt", "index": -1}', "got -1"),
            3: ('{"id": 3, "action": "answer_prompt"}', 'needs "index"'),
            4: ('{"id": 4, "action": "answer_prompt", "index": 2}', "has no button 2"),
        }
        for id_, (payload, wording) in bad.items():
            answer = await command(sub, client, "a", payload, id_)
            assert answer["ok"] is False and wording in answer["error"], answer
            assert "\n" not in answer["error"]
        assert sim.printer.prompt_answers == []
        assert not_polls(list(sim.printer.executed)) == before  # no M876 went out
        assert farm.farm.printers["a"].prompt is not None  # still open

        answer = await command(sub, client, "a", '{"id": 5, "action": "answer_prompt", "index": 1}', 5)
        assert answer == {"id": 5, "ok": True, "result": {"answered": 1, "button": "Cancel"}}
        await sub.until(lambda: sim.printer.prompt_answers == [1], "the answer at the printer")
        await sub.until(lambda: sub.payloads(state_topic)[-1]["prompt"] is None, "the prompt gone from the state")
        await sub.until(
            lambda: "prompt_closed" in [e["event"] for e in sub.payloads(events_topic)], "the prompt_closed event"
        )
        answer = await command(sub, client, "a", '{"id": 6, "action": "answer_prompt", "index": 0}', 6)
        assert answer["ok"] is False and "no prompt is open" in answer["error"]
        assert sim.printer.prompt_answers == [1]


async def test_m600_waits_for_the_user_in_the_state_and_an_answer_gets_past_the_command_it_holds(
    broker: Broker,
) -> None:
    async with one_printer_farm(broker, allow_commands=True) as farm:
        sim, sub, client = farm.sim, farm.sub, farm.client
        state_topic = "marlin/a/state"
        # M600 holds its command (and this printer's queue) until someone answers: the answer must get past it.
        await client.publish("marlin/a/command", '{"id": 1, "action": "gcode", "command": "M600"}', qos=1)
        await sub.until(
            lambda: any(s["waiting_for_user"] for s in sub.payloads(state_topic)), "the wait for the user in the state"
        )
        waiting = next(s for s in sub.payloads(state_topic) if s["waiting_for_user"])
        await sub.until(
            lambda: any(
                s["prompt"] == {"message": "Load Filament", "buttons": ["Continue"]} for s in sub.payloads(state_topic)
            ),
            "M600's prompt in the state",
        )
        assert waiting["link"] == "up"
        events = [e["event"] for e in sub.payloads("marlin/a/events")]
        assert "paused_by_printer" in events
        answer = await command(sub, client, "a", '{"id": 2, "action": "answer_prompt", "index": 0}', 2)
        assert answer["ok"] is True
        responses = "marlin/a/response"
        await sub.until(lambda: any(a["id"] == 1 for a in sub.payloads(responses)), "the answer to M600")
        held = next(a for a in sub.payloads(responses) if a["id"] == 1)
        assert held["ok"] is True  # M600 finished once answered
        assert sim.printer.prompt_answers == [0]
        await sub.until(
            lambda: (
                not sub.payloads(state_topic)[-1]["waiting_for_user"]
                and sub.payloads(state_topic)[-1]["prompt"] is None
            ),
            "the wait over in the state",
        )
        await sub.until(
            lambda: "resumed_by_printer" in [e["event"] for e in sub.payloads("marlin/a/events")], "the resume event"
        )

        sim.printer.host_action(sim.now(), "cancel")
        sim.poke()
        await sub.until(
            lambda: "cancelled_by_printer" in [e["event"] for e in sub.payloads("marlin/a/events")], "the cancel event"
        )
        cancel = next(e for e in sub.payloads("marlin/a/events") if e["event"] == "cancelled_by_printer")
        assert cancel["message"] == "printer asked: cancel"

        # The farm view names what the printer asks in its state cell.
        sim.printer.open_prompt(sim.now(), "Load Filament", ["Continue"])
        sim.poke()
        farm_printer = farm.farm.printers["a"]
        await sub.until(lambda: any(s["prompt"] for s in sub.payloads(state_topic)[-1:]), "the prompt again")
        row = farm_row(1, farm_printer, WatchModel())
        console = Console(record=True, width=100)
        console.print(farm_table([row], width=100))
        assert "asks: Load Filament" in console.export_text()
