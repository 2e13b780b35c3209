"""A farm that one message cannot knock over: hostile payloads, prints that end badly, forged retained topics,
retained and stale commands, floods, broker restarts; each against a real Mosquitto on 127.0.0.1 (as `test_farm`),
and each ending with the farm still publishing for every printer.

The command handler's property test (arbitrary topics, payloads and retain flags into `Bridge._on_message`) needs
no broker: it runs the handler with a task group of its own and counts the answers it queues.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import random
import time
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from conftest import until
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_farm import (
    MOSQUITTO,
    Broker,
    Subscriber,
    command,
    farm_and_bridge,
    not_polls,
    one_printer_farm,
    running,
    subscribed,
)
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.farm.bridge import (
    ANSWER_QUEUE,
    FIGHT_LIMIT,
    MAX_OTHER_PRINTERS,
    MAX_PENDING_COMMANDS,
    Bridge,
    BridgeSettings,
    BrokerSettings,
)
from marlin_aio.farm.config import NAME_PATTERN
from marlin_aio.farm.supervisor import SIM_RECORD_LIMIT, Farm, FarmEvent, PrinterSpec
from marlin_aio.simulator import SimulatorConfig, serve_pty, serve_tcp
from marlin_temp.main import app

needs_broker = pytest.mark.skipif(
    MOSQUITTO is None, reason="Mosquitto is not installed: apt-get install mosquitto (.ci/run installs it)"
)


def events_of(sub: Subscriber, printer: str) -> list[str]:
    return [event["event"] for event in sub.payloads(f"marlin/{printer}/events")]


async def publishing_for_all(sub: Subscriber, printers: list[str], more: int = 3) -> None:
    """Wait until every printer has `more` telemetry messages beyond what it had: the farm is alive and publishing."""
    seen = {name: len(sub.payloads(f"marlin/{name}/telemetry")) for name in printers}
    await sub.until(
        lambda: all(len(sub.payloads(f"marlin/{name}/telemetry")) >= seen[name] + more for name in printers),
        f"telemetry from every printer ({', '.join(printers)}) afterwards",
    )


def moves(count: int) -> str:
    """A print file of `count` long moves (each takes simulated time, so a print lasts)."""
    return "".join(f"G1 X{100 * (index % 2)} Y{50 * (index % 2)} F3000\n" for index in range(count))


def hostile_payloads(jobs: Path) -> dict[str, bytes]:
    """Every payload the issue reports as fatal, and their cousins, by what each is."""
    return {
        "deep list (50 KB)": b"[" * 50_000,
        "deep object": b'{"a":' * 20_000,
        "null byte in a path": b'{"id": "nul", "action": "print", "path": "a\\u0000b"}',
        "symlink loop": b'{"id": "loop", "action": "print", "path": "loop/x.gcode"}',
        "10,000-character path": json.dumps({"id": "long", "action": "print", "path": "x" * 10_000}).encode(),
        "absolute path": b'{"id": "abs", "action": "print", "path": "/etc/passwd"}',
        "NaN target": b'{"id": "nan", "action": "set_temperatures", "hotend": NaN}',
        "5000-digit target": b'{"id": "big", "action": "set_temperatures", "hotend": ' + b"9" * 5000 + b"}",
        "not UTF-8": b'{"id": "utf", "action": "gcode", "command": "M105 \xff\xfe"}',
        "over the size limit": b'{"id": "size", "action": "gcode", "command": "' + b"M" * 70_000 + b'"}',
        "escape in G-code": b'{"id": "esc", "action": "gcode", "command": "M117 \\u001b[2J"}',
        "list of 1000 commands": json.dumps({"id": "many", "action": "gcode", "commands": ["M105"] * 1000}).encode(),
        "id that is an object": b'{"id": {"x": 1}, "action": "pause"}',
        "empty": b"",
        "a JSON string": b'"hello"',
        "stale": json.dumps(
            {"id": "stale", "action": "gcode", "command": "M118 E1 late", "time": time.time() - 60}
        ).encode(),
    }


@needs_broker
async def test_each_hostile_payload_is_one_refusal_and_one_log_line_and_the_farm_goes_on(
    broker: Broker, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "loop").symlink_to(jobs / "loop")
    payloads = hostile_payloads(jobs)
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim_a,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_b,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="attacker") as attacker,
    ):
        specs = [PrinterSpec("a", sim_a.url, poll_interval_s=0.05), PrinterSpec("b", sim_b.url, poll_interval_s=0.05)]
        farm, bridge, _ = farm_and_bridge(specs, broker.port, allow_commands=True, allowed_dir=jobs)
        async with running(farm, bridge):
            await sub.until(lambda: farm.printers["a"].link_up and farm.printers["b"].link_up, "both connected")
            before = not_polls(list(sim_a.printer.executed))
            caplog.clear()
            with caplog.at_level(logging.WARNING, logger="marlin_temp.bridge"):
                for payload in payloads.values():
                    await attacker.publish("marlin/a/command", payload, qos=1)
                await sub.until(
                    lambda: len(sub.payloads("marlin/a/response")) >= len(payloads), "an answer to each payload"
                )
                await publishing_for_all(sub, ["a", "b"])
            answers = sub.payloads("marlin/a/response")
            assert len(answers) == len(payloads)  # one answer each, no more
            assert all(answer["ok"] is False for answer in answers), answers
            by_id = {answer["id"]: answer["error"] for answer in answers if answer["id"] is not None}
            assert "outside the allowed directory" in by_id["abs"]
            assert "stale" in by_id["stale"]
            assert "NUL" in by_id["nul"] or "control" in by_id["nul"], by_id["nul"]
            assert "loop" in by_id["loop"]
            errors = [answer["error"] for answer in answers]
            assert any("deep" in error for error in errors), errors
            assert all("\n" not in error and len(error) <= 300 for error in errors)
            refusals = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
            assert len(refusals) == len(payloads)  # one log line per refusal ...
            assert all("\n" not in line and len(line) < 400 for line in refusals)  # ... and each one line
            assert not_polls(list(sim_a.printer.executed)) == before  # nothing of any of them was written
            assert farm.printers["a"].link_up and farm.printers["b"].link_up
            assert bridge.refused == len(payloads)


@needs_broker
async def test_seeded_fuzz_of_command_payloads_leaves_one_answer_each_and_every_printer_published(
    broker: Broker, tmp_path: Path
) -> None:
    """300 payloads drawn from a seed (the seed is printed when it fails): mutated valid commands, random bytes,
    random JSON. Whatever runs, runs on its own printer; every payload gets one answer; the farm goes on."""
    seed = 21
    draw = random.Random(seed)
    valid: list[dict[str, Any]] = [
        {"action": "gcode", "command": "M105"},
        {"action": "set_temperatures", "hotend": 40},
        {"action": "set_target", "heater": "bed", "celsius": 30},
        {"action": "pause"},
        {"action": "print", "path": "none.gcode"},
    ]
    payloads: list[bytes] = []
    for _ in range(300):
        kind = draw.randrange(4)
        if kind == 0:
            payloads.append(bytes(draw.randrange(256) for _ in range(draw.randrange(1, 200))))
        elif kind == 1:
            body: dict[str, Any] = dict(draw.choice(valid))
            field = draw.choice([*body, "id", "time", "extra", "command", "path"])
            body[field] = draw.choice(
                [None, True, -1, 1e308, "", "\x00", "M104 S999", "../../etc", [[[[[]]]]], {"a": {}}, "é" * 50]
            )
            payloads.append(json.dumps(body).encode())
        elif kind == 2:
            text = json.dumps(draw.choice(valid))
            cut = draw.randrange(len(text))
            payloads.append(text[:cut].encode() + bytes([draw.randrange(256)]) + text[cut + 1 :].encode())
        else:
            depth = draw.randrange(1, 3000)
            payloads.append(b"[" * depth + b"]" * draw.randrange(depth + 1))
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim_a,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_b,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="fuzzer") as fuzzer,
    ):
        specs = [PrinterSpec("a", sim_a.url, poll_interval_s=0.05), PrinterSpec("b", sim_b.url, poll_interval_s=0.05)]
        farm, bridge, _ = farm_and_bridge(specs, broker.port, allow_commands=True, allowed_dir=tmp_path)
        async with running(farm, bridge):
            await sub.until(lambda: farm.printers["a"].link_up and farm.printers["b"].link_up, "both connected")
            for payload in payloads:
                await fuzzer.publish("marlin/a/command", payload, qos=1)
            try:
                await sub.until(
                    lambda: len(sub.payloads("marlin/a/response")) >= len(payloads), "an answer to each", 60
                )
                await publishing_for_all(sub, ["a", "b"])
            except (TimeoutError, AssertionError):
                pytest.fail(f"seed {seed}: {len(sub.payloads('marlin/a/response'))} answers to {len(payloads)}")
            assert len(sub.payloads("marlin/a/response")) == len(payloads), f"seed {seed}"
            assert not_polls(list(sim_b.printer.executed)) == []  # b was never touched
            assert all(t.done() is False for t in asyncio.all_tasks() if t.get_name() == "farm")


async def until_state(sub: Subscriber, printer: str, check: Any, what: str, timeout_s: float = 30) -> dict[str, Any]:
    await sub.until(lambda: any(check(s) for s in sub.payloads(f"marlin/{printer}/state")), what, timeout_s)
    state: dict[str, Any] = next(s for s in reversed(sub.payloads(f"marlin/{printer}/state")) if check(s))
    return state


def printing(state: dict[str, Any]) -> bool:
    return (state["print"] or {}).get("state") == "running" and (state["print"]["lines_acked"] or 0) > 20


@needs_broker
@pytest.mark.parametrize("ending", ["emergency stop", "reset", "unplugged"])
async def test_a_print_that_ends_badly_is_that_printers_print_failed_and_the_farm_goes_on(
    broker: Broker, tmp_path: Path, ending: str
) -> None:
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "long.gcode").write_text(moves(400))
    async with (
        serve_tcp(SimulatorConfig(), time_scale=50) as sim_a,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_b,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="home-assistant") as ha,
    ):
        specs = [PrinterSpec("a", sim_a.url, poll_interval_s=0.05), PrinterSpec("b", sim_b.url, poll_interval_s=0.05)]
        farm, bridge, events = farm_and_bridge(specs, broker.port, allow_commands=True, allowed_dir=jobs)
        async with running(farm, bridge):
            await sub.until(lambda: farm.printers["a"].link_up and farm.printers["b"].link_up, "both connected")
            answer = await command(sub, ha, "a", '{"id": 1, "action": "print", "path": "long.gcode"}', 1)
            assert answer == {"id": 1, "ok": True, "result": {"started": "long.gcode"}}
            await until_state(sub, "a", printing, "the print under way")
            if ending == "emergency stop":
                # Home Assistant's own button.
                answer = await command(sub, ha, "a", '{"id": 2, "action": "emergency_stop"}', 2)
                assert answer["ok"] is True
            elif ending == "reset":
                sim_a.printer.reset(sim_a.now())
                sim_a.poke()
            else:
                await sim_a.disconnect()
            await sub.until(lambda: "print_failed" in events_of(sub, "a"), "print_failed")
            failed = next(e for e in sub.payloads("marlin/a/events") if e["event"] == "print_failed")
            word = {"emergency stop": "halted", "reset": "reset", "unplugged": "link lost"}[ending]
            assert failed["message"].startswith(f"long.gcode: {word} at file line "), failed
            state = await until_state(
                sub, "a", lambda s: (s["print"] or {}).get("state") == "failed", "the state to say failed"
            )
            assert word in state["print"]["error"]
            await publishing_for_all(sub, ["b"])
            if ending == "reset":
                # The link outlived the reset: the printer is reported reset, and polled on.
                await sub.until(lambda: "reset" in events_of(sub, "a"), "the reset event")
            else:
                # The link ended: the printer's supervisor connects it again (a halted board was reset by it).
                await sub.until(lambda: events_of(sub, "a").count("connected") >= 2, "a reconnected")
            await publishing_for_all(sub, ["a", "b"])
            # No second print_* event, and nothing of this print on b.
            assert [e for e in events_of(sub, "a") if e.startswith("print_")] == ["print_started", "print_failed"]
            assert [event.kind for event in events if event.printer == "b"] == ["connected"]
            assert bridge.connections == 1  # the bridge never went down


@needs_broker
async def test_a_print_finished_or_cancelled_over_mqtt_is_an_event_and_a_state(broker: Broker, tmp_path: Path) -> None:
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "short.gcode").write_text(moves(10))
    (jobs / "long.gcode").write_text(moves(400))
    (jobs / "two\nlines.gcode").write_text(moves(4))
    async with one_printer_farm(
        broker, time_scale=50, client="home-assistant", allow_commands=True, allowed_dir=jobs
    ) as one:
        sub, ha, events = one.sub, one.client, one.events
        await command(sub, ha, "a", '{"id": 1, "action": "print", "path": "short.gcode"}', 1)
        await sub.until(lambda: "print_finished" in events_of(sub, "a"), "print_finished")
        await command(sub, ha, "a", '{"id": 2, "action": "print", "path": "long.gcode"}', 2)
        await until_state(sub, "a", printing, "the long print under way")
        answer = await command(sub, ha, "a", '{"id": 3, "action": "cancel"}', 3)
        assert answer["ok"] is True
        await sub.until(lambda: "print_cancelled" in events_of(sub, "a"), "print_cancelled")
        await until_state(sub, "a", lambda s: (s["print"] or {}).get("state") == "cancelled", "cancelled state")
        # A file name with a line break is refused (and its answer and log line are one line each).
        answer = await command(sub, ha, "a", json.dumps({"id": 4, "action": "print", "path": "two\nlines.gcode"}), 4)
        assert answer["ok"] is False and "path contains a line break" in answer["error"], answer
        assert "\n" not in answer["error"]
    kinds = [e for e in events_of(sub, "a") if e.startswith("print_")]
    assert kinds == ["print_started", "print_finished", "print_started", "print_cancelled"]
    finished = next(e for e in sub.payloads("marlin/a/events") if e["event"] == "print_finished")
    assert finished["message"] == "short.gcode: done at file line 10"
    assert all("\n" not in event.message for event in events)


@needs_broker
async def test_forged_retained_topics_are_put_back_and_a_clean_exit_leaves_everything_offline(
    broker: Broker,
) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="forger") as forger,
    ):
        farm, bridge, _ = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port)
        async with running(farm, bridge):
            config = "homeassistant/sensor/marlin_a/hotend_actual/config"
            await sub.until(
                lambda: bool(sub.texts(config)) and sub.texts("marlin/a/availability")[-1:] == ["online"],
                "discovery, and the printer online",
            )
            ours = {
                "marlin/a/availability": b"online",
                "marlin/bridge/availability": b"online",
                "marlin/a/state": bridge._retained["marlin/a/state"],
                config: bridge._retained[config],
            }
            forged = {
                "marlin/a/availability": b"offline",
                "marlin/bridge/availability": b"offline",
                "marlin/a/state": b'{"link": "down", "print": {"state": "running", "percent": 14.4}}',
                config: b"",  # deleted
            }
            for topic, payload in forged.items():
                await forger.publish(topic, payload, qos=1, retain=True)
            await sub.until(
                lambda: bridge.corrections >= len(forged), f"every forgery corrected ({bridge.corrections})"
            )
            # The bridge counts a correction as it decides to publish it: wait until the broker has passed each
            # one on (the last word on every topic is the bridge's own again), or a latecomer could subscribe
            # between the two and get the correction live rather than retained.
            await sub.until(
                lambda: all([p for t, p, _ in sub.messages if t == topic][-1:] == [ours[topic]] for topic in ours),
                "every correction through the broker",
            )
            # A client that comes now finds the bridge's own, not the forgeries.
            async with subscribed(broker.port, identifier="latecomer") as late:
                await late.until(
                    lambda: all(any(t == topic for t, _, _ in late.messages) for topic in ours), "the retained topics"
                )
                retained = {t: p for t, p, r in late.messages if r and t in ours}
            assert retained == ours
            await publishing_for_all(sub, ["a"])
        # Stopped cleanly (cancelled): the bridge and its printer say offline, and it stays so.
        async with subscribed(broker.port, identifier="after") as after:
            topics = ("marlin/a/availability", "marlin/bridge/availability")
            await after.until(
                lambda: all(after.texts(t) for t in topics) and bool(after.texts("marlin/a/state")), "retained topics"
            )
            assert [after.texts(t)[-1] for t in topics] == ["offline", "offline"]
            assert after.payloads("marlin/a/state")[-1]["link"] == "down"  # not the "up" of a bridge now gone
    assert bridge.corrections == len(forged)  # no fight: each forgery put right once


@needs_broker
async def test_a_bridge_that_fails_says_offline_on_its_way_out(broker: Broker) -> None:
    """Before, an exception out of the bridge ended its MQTT session with a clean DISCONNECT, which tells the broker
    to drop the Last Will: the retained availability stayed `online` for a dead farm. Now any failure publishes
    `offline` for the bridge and its printers before the session ends."""

    def bug() -> None:
        raise RuntimeError("a bug in a hook")

    async with serve_pty(SimulatorConfig(), time_scale=50) as sim, subscribed(broker.port) as sub:
        farm, bridge, _ = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port)
        bridge.on_connected = bug
        farm_task = asyncio.create_task(farm.run())
        try:
            with pytest.raises(ExceptionGroup) as caught:
                await asyncio.wait_for(bridge.run(), 30)
        finally:
            farm_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await farm_task
        assert caught.value.subgroup(RuntimeError) is not None
        await sub.until(lambda: sub.texts("marlin/bridge/availability")[-1:] == ["offline"], "the bridge offline")
        await sub.until(lambda: sub.texts("marlin/a/availability")[-1:] == ["offline"], "its printer offline")
        assert sub.texts("marlin/bridge/availability")[0] == "online"


@needs_broker
async def test_a_retained_command_never_runs_across_broker_restarts(broker: Broker) -> None:
    # A persistent session (QoS 1, not clean) for the watcher: answers published while it is away wait for it.
    async with subscribed(broker.port, identifier="watcher", clean=False):
        pass
    refusals: list[dict[str, Any]] = []
    async with serve_pty(SimulatorConfig(), time_scale=50) as sim:
        async with aiomqtt.Client("127.0.0.1", broker.port, identifier="stale-publisher") as publisher:
            payload = '{"id": "retained", "action": "gcode", "command": "M118 E1 stale"}'
            await publisher.publish("marlin/a/command", payload, qos=1, retain=True)
        farm, bridge, _ = farm_and_bridge(
            [PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port, allow_commands=True
        )
        async with running(farm, bridge):
            for restart in range(3):
                async with subscribed(broker.port, identifier="watcher", clean=False) as sub:

                    def answers() -> list[dict[str, Any]]:
                        return [a for a in sub.payloads("marlin/a/response") if a["id"] == "retained"]

                    # One refusal per connection of the bridge (each time the broker hands it the retained one).
                    wanted = restart + 1 - len(refusals)
                    await sub.until(lambda: len(answers()) >= wanted, "the retained command refused")  # noqa: B023
                    await publishing_for_all(sub, ["a"])
                    refusals += answers()
                if restart < 2:
                    connections = bridge.connections
                    broker.stop()
                    broker.start()
                    await until(lambda: bridge.connections > connections, "the bridge is back", limit_s=20)  # noqa: B023
                    assert bridge.connections > connections
    assert len(refusals) == 3
    assert all(a["ok"] is False and "retained" in a["error"] for a in refusals)
    assert "M118 E1 stale" not in list(sim.printer.executed)  # before: it ran 1, 2, then 3 times
    assert bridge.connections == 3


@needs_broker
async def test_after_a_broker_outage_every_printer_has_its_own_readings_of_the_outage(tmp_path: Path) -> None:
    """Before: one 1,000-message buffer for all printers left every printer a gap of most of the outage. Now each
    printer keeps its own newest readings (240 by default), so a short outage leaves no gap in any printer's
    telemetry once the broker is back: no two readings are half the outage apart."""
    # QoS 0 telemetry is kept for the watcher's persistent session while it is away (Mosquitto's option).
    broker = Broker(tmp_path, extra="queue_qos0_messages true\nmax_queued_messages 100000\n")
    broker.start()
    names = ["a", "b", "c"]
    try:
        async with subscribed(broker.port, identifier="watcher", clean=False):
            pass
        async with (
            serve_pty(SimulatorConfig(), time_scale=20) as sim_a,
            serve_pty(SimulatorConfig(), time_scale=20) as sim_b,
            serve_pty(SimulatorConfig(), time_scale=20) as sim_c,
        ):
            sims = (sim_a, sim_b, sim_c)
            specs = [PrinterSpec(name, sim.url, poll_interval_s=0.05) for name, sim in zip(names, sims, strict=True)]
            farm, bridge, _ = farm_and_bridge(specs, broker.port, rate_hz=10.0)
            times: dict[str, list[float]] = {name: [] for name in names}
            async with running(farm, bridge):
                async with subscribed(broker.port, identifier="watcher", clean=False) as sub:
                    await sub.until(lambda: all(sub.payloads(f"marlin/{n}/telemetry") for n in names), "telemetry")
                for name in names:
                    times[name] += [t["time"] for t in sub.payloads(f"marlin/{name}/telemetry")]
                broker.stop()
                down_at = time.time()
                await until(lambda: not bridge.connected, "the bridge saw the broker go", limit_s=20)
                readings = {name: farm.printers[name].readings for name in names}
                await until(
                    lambda: all(farm.printers[name].readings > readings[name] + 80 for name in names),
                    "readings during the outage",
                    limit_s=20,
                )
                broker.start()
                up_at = time.time()
                async with subscribed(broker.port, identifier="watcher", clean=False) as sub:
                    await sub.until(
                        lambda: all(
                            any(t["time"] > up_at + 0.5 for t in sub.payloads(f"marlin/{n}/telemetry")) for n in names
                        ),
                        "telemetry after the restart",
                    )
                for name in names:
                    times[name] += [t["time"] for t in sub.payloads(f"marlin/{name}/telemetry")]
    finally:
        broker.stop()
    outage_s = up_at - down_at
    assert outage_s > 1.0
    for name in names:
        series = sorted(times[name])
        gaps = [after - before for before, after in itertools.pairwise(series)]
        during = [t for t in series if down_at < t < up_at]
        assert len(during) >= 20, f"{name}: {len(during)} readings of the outage"
        # Relative to the outage, not a fixed time: a loaded machine may poll late, but only a lost buffer leaves a
        # gap of most of the outage.
        assert max(gaps) < outage_s / 2, f"{name}: a gap of {max(gaps):.2f} s in its telemetry ({outage_s:.1f} s)"
    assert bridge.telemetry_dropped == 0


@needs_broker
async def test_outsiders_cannot_grow_the_bridge_without_bound(broker: Broker) -> None:
    async with one_printer_farm(broker, time_scale=1, client="flooder", allow_commands=True) as one:
        sub, flooder, bridge = one.sub, one.client, one.bridge
        names = MAX_OTHER_PRINTERS + 500
        for index in range(names):
            await flooder.publish(f"marlin/made-up-{index}/availability", "online", qos=0)
        await flooder.publish("marlin/last/availability", "online", qos=1)
        await sub.until(lambda: bool(sub.texts("marlin/last/availability")), "the flood delivered")
        await sub.until(lambda: "last" in bridge._elsewhere, "the bridge has read the flood")
        assert len(bridge._elsewhere) == MAX_OTHER_PRINTERS  # the oldest names were forgotten
        # A flood of slow commands: a bounded number wait for the printer, the rest are refused at once.
        flood = MAX_PENDING_COMMANDS + 10
        for index in range(flood):
            await flooder.publish("marlin/a/command", json.dumps({"id": index, "action": "gcode", "command": "G4 S30"}))
        await sub.until(lambda: len(sub.payloads("marlin/a/response")) >= 10, "the refusals")
        busy = [a for a in sub.payloads("marlin/a/response") if "busy" in a.get("error", "")]
        assert len(busy) == 10
        assert bridge._pending["a"] == MAX_PENDING_COMMANDS
        # A command to a name no printer can have (here one whose answer's topic would be longer than MQTT
        # allows: it ended the bridge) is not answered; a name that could be a printer's is, once.
        ignored = bridge.ignored
        await flooder.publish("marlin/" + "x" * 65_500 + "/command", '{"id": 1, "action": "pause"}', qos=1)
        await flooder.publish("marlin/nobody/command", '{"id": 2, "action": "pause"}', qos=1)
        await sub.until(lambda: bool(sub.payloads("marlin/nobody/response")), "the answer to nobody")
        assert bridge.ignored == ignored + 1
        await publishing_for_all(sub, ["a"])
        # The slow commands still wait, and the emergency stop is never kept out by them.
        assert bridge._pending["a"] == MAX_PENDING_COMMANDS
        answer = await command(sub, flooder, "a", '{"id": "stop", "action": "emergency_stop"}', "stop")
        assert answer["ok"] is True
        await sub.until(lambda: "halted" in events_of(sub, "a"), "the printer halted")
    assert [a["id"] for a in sub.payloads("marlin/nobody/response")] == [2]


@needs_broker
async def test_a_flood_of_answers_never_pushes_an_event_out(broker: Broker) -> None:
    async with one_printer_farm(broker, time_scale=20, client="flooder", allow_commands=True) as one:
        sim, sub, flooder, bridge = one.sim, one.sub, one.client, one.bridge
        for index in range(3_000):  # each a name no bridge has: each answered, 3,000 answers
            await flooder.publish(f"marlin/x{index}/command", '{"action": "pause"}', qos=0)
        sim.printer.thermal_runaway(sim.now())
        sim.poke()
        await sub.until(lambda: "thermal_runaway" in events_of(sub, "a"), "the thermal runaway event", 60)
        await sub.until(lambda: bridge.refused + bridge.ignored == 3_000, "the flood read")
    assert bridge.events_lost == 0
    assert bridge.refused + bridge.ignored == 3_000


async def test_two_prints_started_at_once_start_one(tmp_path: Path) -> None:
    """Two print commands back to back (a double press, a redelivered message) both passed the "already running"
    check while the first one's M110 was on its way, and the file printed twice. Started in the same loop turn
    here, so the race is certain."""
    (tmp_path / "long.gcode").write_text(moves(400))
    async with serve_pty(SimulatorConfig(), time_scale=50) as sim:
        farm = Farm([PrinterSpec("a", sim.url, poll_interval_s=0.05)], lambda event: None)
        task = asyncio.create_task(farm.run())
        try:
            await until(lambda: farm.printers["a"].link_up, "the printer connected", limit_s=20)
            farm_printer = farm.printers["a"]
            path = tmp_path / "long.gcode"
            results = await asyncio.gather(
                farm.start_print(farm_printer, path), farm.start_print(farm_printer, path), return_exceptions=True
            )
            refused = [r for r in results if isinstance(r, BaseException)]
            running = "a print is already running: long.gcode on a (starting"
            assert len(refused) == 1 and str(refused[0]).startswith(running)
            handle = farm_printer.print_handle
            assert handle is not None
            await handle.cancel()
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    assert list(sim.printer.executed).count("M110 N0") == 2  # the handshake's, and one print's


@needs_broker
async def test_bridges_sharing_a_broker_keep_to_their_own_topics(
    broker: Broker, caplog: pytest.LogCaptureFixture
) -> None:
    """Two bridges with their own names: one going offline is not the other's to correct. Two bridges that both
    have a printer `a` (a mistake) correct each other a bounded number of times, then say so and stop."""
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim_1,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_2,
        subscribed(broker.port) as sub,
    ):
        farm_1, bridge_1, _ = farm_and_bridge(
            [PrinterSpec("a", sim_1.url, poll_interval_s=0.05)], broker.port, name="host1"
        )
        farm_2, bridge_2, _ = farm_and_bridge(
            [PrinterSpec("a", sim_2.url, poll_interval_s=0.05)], broker.port, name="host2"
        )
        async with running(farm_2, bridge_2):
            async with running(farm_1, bridge_1):
                await sub.until(
                    lambda: all(sub.texts(f"marlin/host{n}/availability")[-1:] == ["online"] for n in (1, 2)),
                    "both bridges online",
                )
                # Both publish marlin/a/state, with different ports in it: a fight, bounded.
                await sub.until(
                    lambda: "marlin/a/state" in bridge_1._given_up or "marlin/a/state" in bridge_2._given_up,
                    "one bridge giving up the fight",
                    60,
                )
            # Bridge 1 stopped: its own availability says so, and bridge 2 leaves it so.
            await sub.until(lambda: sub.texts("marlin/host1/availability")[-1:] == ["offline"], "host1 offline")
            await publishing_for_all(sub, ["a"])
            assert sub.texts("marlin/host1/availability")[-1] == "offline"
            assert sub.texts("marlin/host2/availability")[-1] == "online"
    # At most FIGHT_LIMIT corrections of each topic the bridges share, then they stop.
    assert bridge_1.corrections <= FIGHT_LIMIT * len(bridge_1._retained)
    assert bridge_2.corrections <= FIGHT_LIMIT * len(bridge_2._retained)
    assert any("another client keeps publishing there" in r.getMessage() for r in caplog.records)


def test_reserved_and_topic_breaking_names_are_refused_at_start_up(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["farm", "--port", "bridge=socket://127.0.0.1:1", "--duration", "1"])
    assert result.exit_code == 2
    assert "printer name 'bridge' is reserved" in result.output
    result = CliRunner().invoke(
        app, ["farm", "--bridge-name", "host1", "--port", "host1=socket://127.0.0.1:1", "--duration", "1"]
    )
    assert result.exit_code == 2 and "printer name 'host1' is the bridge's own (--bridge-name)" in result.output
    result = CliRunner().invoke(app, ["farm", "--bridge-name", "a/b", "--sims", "1", "--duration", "1"])
    assert result.exit_code == 2 and "--bridge-name 'a/b' must be letters, digits" in result.output
    config = tmp_path / "farm.toml"
    config.write_text('[[printer]]\nname = "a/b"\nport = "/dev/ttyUSB0"\n')
    result = CliRunner().invoke(app, ["farm", "--config", str(config), "--duration", "1"])
    assert result.exit_code == 2 and "must be letters, digits" in result.output
    with pytest.raises(ValueError, match="cannot be named 'bridge'"):
        Farm([PrinterSpec("bridge", "socket://127.0.0.1:1")], lambda event: None)
    farm = Farm([PrinterSpec("a+#", "socket://127.0.0.1:1")], lambda event: None)
    with pytest.raises(ValueError, match="cannot be a topic level"):
        Bridge(farm, BrokerSettings())


async def test_in_process_simulated_printers_keep_a_small_record() -> None:
    """`farm --sims 20` ran for hours: each simulated printer kept 100,000 commands. The farm's keep 1,000."""
    farm = Farm([PrinterSpec("sim1", None, poll_interval_s=0.005, sim=True, sim_speed=20)], lambda event: None)
    task = asyncio.create_task(farm.run())
    try:
        await until(
            lambda: "sim1" in farm.sims and farm.sims["sim1"].printer.executed_count > SIM_RECORD_LIMIT + 100,
            "the polls add up",
            limit_s=30,
        )
        printer = farm.sims["sim1"].printer
        assert printer.executed_count > SIM_RECORD_LIMIT + 100
        assert len(printer.executed) == SIM_RECORD_LIMIT == 1_000
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


# --------------------------------------------------------------------------------- the handler, without a broker

_topic_names = st.one_of(
    st.sampled_from(["a", "b", "bridge", "nobody", "", "made-up"]),
    st.text(min_size=0, max_size=80),
)
_payloads = st.one_of(
    st.binary(max_size=300),
    st.integers(1, 5_000).map(lambda n: b"[" * n),
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=40),
        lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4),
        max_leaves=20,
    ).map(lambda value: json.dumps(value).encode()),
    st.fixed_dictionaries(
        {"action": st.sampled_from(["gcode", "print", "set_temperatures", "set_target", "cancel", "x"])},
        optional={
            "id": st.integers() | st.text(max_size=200) | st.none(),
            "command": st.text(max_size=120),
            "commands": st.lists(st.text(max_size=20), max_size=5),
            "path": st.sampled_from(["a\x00b", "../x", "/etc/passwd", "loop/x", "x" * 5000, "ok.gcode", "a\nb"]),
            "hotend": st.floats() | st.integers() | st.text(max_size=5),
            "time": st.floats() | st.text(max_size=5),
        },
    ).map(lambda body: json.dumps(body).encode()),
)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    messages=st.lists(
        st.tuples(_topic_names, st.sampled_from(["command", "availability", "state"]), _payloads, st.booleans()),
        min_size=1,
        max_size=12,
    )
)
@example(messages=[("/0", "command", b"", False)])  # a topic of four levels: not one the subscription matches
def test_the_command_handler_answers_every_command_once_and_never_raises(
    tmp_path: Path, messages: list[tuple[str, str, bytes, bool]]
) -> None:
    """Whatever arrives on whatever topic (names from topic levels, any payload, retained or not), the handler
    raises nothing, answers exactly once each command owed an answer (for its own printers; for a name no bridge
    has, when the name could be a printer's and the message is not retained) and no other (here the printers are
    not connected, so even a valid command is answered with an error), and keeps its sets bounded."""
    (tmp_path / "loop").mkdir(exist_ok=True)
    (tmp_path / "ok.gcode").write_text("G28\n")

    async def handle() -> None:
        farm = Farm([PrinterSpec("a", "socket://127.0.0.1:1"), PrinterSpec("b", "socket://127.0.0.1:1")], print)
        bridge = Bridge(farm, BrokerSettings(), BridgeSettings(allow_commands=True, allowed_dir=tmp_path))
        expected = 0
        async with asyncio.TaskGroup() as group:
            bridge._group = group
            for name, leaf, payload, retained in messages:
                before = set(bridge._elsewhere)
                bridge._on_message(f"marlin/{name}/{leaf}", payload, retained)
                owed = name in farm.printers or (
                    name not in before and not retained and NAME_PATTERN.fullmatch(name) is not None
                )
                if leaf == "command" and owed:
                    expected += 1
        answers = [json.loads(text) for _, text in bridge._answers]
        assert len(answers) == expected
        assert all(answer["ok"] is False for answer in answers)  # nothing is connected: nothing ran
        assert all("\n" not in answer["error"] for answer in answers)
        assert len(bridge._elsewhere) <= MAX_OTHER_PRINTERS
        assert all(count == 0 for count in bridge._pending.values())

    asyncio.run(handle())


def test_answers_never_push_an_event_out_of_its_queue() -> None:
    """Deterministic, with no broker: the bridge is away, 10 events are queued, then 5,000 answers (a flood of
    commands). Before, one queue held both and the flood pushed every event out; now each kind has its own bound."""
    farm = Farm([PrinterSpec("a", "socket://127.0.0.1:1")], lambda event: None)
    bridge = Bridge(farm, BrokerSettings(), BridgeSettings(allow_commands=True, event_queue=100))
    for index in range(10):
        bridge.on_event(FarmEvent("a", "thermal_runaway", f"runaway {index}"))
    for index in range(5_000):
        bridge._answer("nobody", index, error="no printer named 'nobody'")
    assert [json.loads(text)["message"] for _, text in bridge._events] == [f"runaway {i}" for i in range(10)]
    assert bridge.events_lost == 0
    assert len(bridge._answers) == ANSWER_QUEUE and bridge.answers_dropped == 5_000 - ANSWER_QUEUE


def test_events_are_one_line_whatever_their_message() -> None:
    seen: list[FarmEvent] = []
    farm = Farm([PrinterSpec("a", "socket://127.0.0.1:1")], seen.append)
    farm.emit(farm.printers["a"], "print_failed", "x\ny\r\x1b[2J\u2028 M511 P1234")
    assert seen[0].message == "x\\ny\\r\\x1b[2J\\u2028 M511 ****"
    assert farm.printers["a"].last_error == seen[0].message
    assert marlin_aio.redact("M511 P1234") == "M511 ****"
