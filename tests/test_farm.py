"""The print farm and its MQTT bridge, against a real Mosquitto broker started here on 127.0.0.1 and a free port.

The printers are simulated ones on real ptys and TCP ports; the broker is Debian's `mosquitto` (`.ci/run` installs
it). Messages are read back by a subscriber of our own (aiomqtt) and checked by topic and payload.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from conftest import until

import marlin_aio
from marlin_aio.farm.bridge import Bridge, BridgeSettings, BrokerSettings
from marlin_aio.farm.supervisor import Farm, FarmEvent, PrinterSpec
from marlin_aio.simulator import SimulatorConfig, SimulatorServer, serve_pty, serve_tcp

MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if os.path.exists("/usr/sbin/mosquitto") else None)
pytestmark = pytest.mark.skipif(
    MOSQUITTO is None, reason="Mosquitto is not installed: apt-get install mosquitto (.ci/run installs it)"
)


# Started as root, Mosquitto becomes the `mosquitto` user, who cannot read or write the test's private directory.
AS_US = "user root\n" if os.geteuid() == 0 else ""


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@dataclass
class Broker:
    """A Mosquitto process on 127.0.0.1:`port`; `stop()` and `start()` restart it on the same port."""

    directory: Path
    port: int = field(default_factory=free_port)
    process: subprocess.Popen[bytes] | None = None
    extra: str = ""
    """More lines for mosquitto.conf."""

    def start(self) -> None:
        config = self.directory / "mosquitto.conf"
        # Persistence keeps a subscriber's session across a restart (SIGTERM saves it), as a production broker would.
        config.write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence true\n"
            f"persistence_location {self.directory}/\nautosave_interval 1\n{AS_US}{self.extra}"
        )
        assert MOSQUITTO is not None
        self.process = subprocess.Popen(
            [MOSQUITTO, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        for _ in range(200):  # until it accepts connections, bounded
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", self.port), timeout=0.1):
                return
            if self.process.poll() is not None:
                raise RuntimeError(f"mosquitto exited with {self.process.returncode}")
            time.sleep(0.05)  # polling a condition (the port accepts), bounded
        raise RuntimeError("mosquitto did not start listening within 10 s")

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None


class Subscriber:
    """Every message under `#` with its topic, kept in order; `until()` waits for a condition on them."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, bytes, bool]] = []
        self._changed = asyncio.Event()

    def payloads(self, topic: str) -> list[Any]:
        return [json.loads(payload) for t, payload, _ in self.messages if t == topic]

    def texts(self, topic: str) -> list[str]:
        return [payload.decode() for t, payload, _ in self.messages if t == topic]

    async def until(self, condition: Callable[[], bool], what: str, timeout_s: float = 20.0) -> None:
        async with asyncio.timeout(timeout_s):
            while not condition():
                self._changed.clear()
                await self._changed.wait()
        assert condition(), what

    async def run(self, port: int, identifier: str = "test-subscriber", *, clean: bool = True) -> None:
        async with aiomqtt.Client("127.0.0.1", port, identifier=identifier, clean_session=clean) as client:
            await client.subscribe("#", qos=1)
            async for message in client.messages:
                payload = message.payload if isinstance(message.payload, bytes) else str(message.payload).encode()
                self.messages.append((message.topic.value, payload, message.retain))
                self._changed.set()


@contextlib.asynccontextmanager
async def subscribed(port: int, **kwargs: Any) -> AsyncIterator[Subscriber]:
    subscriber = Subscriber()
    task = asyncio.create_task(subscriber.run(port, **kwargs))
    try:
        yield subscriber
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await task


@contextlib.asynccontextmanager
async def running(farm: Farm, bridge: Bridge) -> AsyncIterator[None]:
    tasks = [asyncio.create_task(farm.run()), asyncio.create_task(bridge.run())]
    try:
        yield
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task


def farm_and_bridge(
    specs: list[PrinterSpec], port: int, *, farm_backoff_s: tuple[float, float] = (0.2, 0.5), **settings: Any
) -> tuple[Farm, Bridge, list[FarmEvent]]:
    events: list[FarmEvent] = []

    def listen(event: FarmEvent) -> None:
        events.append(event)
        bridge.on_event(event)

    farm = Farm(specs, listen, backoff_start_s=farm_backoff_s[0], backoff_max_s=farm_backoff_s[1])
    bridge = Bridge(
        farm,
        BrokerSettings(port=port, keepalive_s=5),
        BridgeSettings(backoff_start_s=0.2, backoff_max_s=0.5, **({"rate_hz": 10.0} | settings)),
    )
    return farm, bridge, events


@dataclass
class OnePrinter:
    """A farm of one simulated printer `a` with its bridge, running; a subscriber to everything; one more client."""

    sim: SimulatorServer
    sub: Subscriber
    client: aiomqtt.Client
    farm: Farm
    bridge: Bridge
    events: list[FarmEvent]


@contextlib.asynccontextmanager
async def one_printer_farm(
    broker: Broker, *, time_scale: float = 50.0, client: str = "commander", **settings: Any
) -> AsyncIterator[OnePrinter]:
    """Serve printer `a` (polled every 50 ms), run its farm and bridge (`settings` go to the bridge), and yield
    once the printer is connected."""
    async with (
        serve_pty(SimulatorConfig(), time_scale=time_scale) as sim,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier=client) as other,
    ):
        farm, bridge, events = farm_and_bridge(
            [PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port, **settings
        )
        async with running(farm, bridge):
            await sub.until(lambda: farm.printers["a"].link_up, "the printer connected")
            yield OnePrinter(sim, sub, other, farm, bridge, events)


async def test_telemetry_state_and_availability_arrive_with_only_the_heaters_each_printer_has(broker: Broker) -> None:
    async with (
        serve_pty(SimulatorConfig(has_bed=False), time_scale=20) as bedless,
        serve_pty(SimulatorConfig(has_chamber=True), time_scale=20) as chambered,
        subscribed(broker.port) as sub,
    ):
        specs = [
            PrinterSpec("bedless", bedless.url, poll_interval_s=0.05),
            PrinterSpec("chambered", chambered.url, poll_interval_s=0.05),
        ]
        farm, bridge, _ = farm_and_bridge(specs, broker.port)
        async with running(farm, bridge):
            await sub.until(
                lambda: (
                    len(sub.payloads("marlin/bedless/telemetry")) >= 3
                    and len(sub.payloads("marlin/chambered/telemetry")) >= 3
                ),
                "telemetry from both printers",
            )
    for telemetry in sub.payloads("marlin/bedless/telemetry"):
        assert set(telemetry["heaters"]) == {"hotend"}  # no bed: never published, not even as null
        assert telemetry["heaters"]["hotend"].keys() == {"actual", "target", "power_percent"}
        assert isinstance(telemetry["time"], float)
    for telemetry in sub.payloads("marlin/chambered/telemetry"):
        assert set(telemetry["heaters"]) == {"hotend", "bed", "chamber"}
        assert 0 <= telemetry["heaters"]["bed"]["power_percent"] <= 100
    assert "online" in sub.texts("marlin/bedless/availability")
    assert "online" in sub.texts("marlin/bridge/availability")
    states = sub.payloads("marlin/chambered/state")
    assert states[-1]["link"] in ("up", "down") and any(state["link"] == "up" for state in states)
    assert any(state["firmware"] and "Marlin" in state["firmware"] for state in states)
    connected = sub.payloads("marlin/bedless/events")
    assert connected and connected[0]["event"] == "connected"
    # A clean stop says offline, as the Last Will would after a crash.
    assert sub.texts("marlin/bridge/availability")[-1] == "offline"
    assert bridge.telemetry_dropped == 0 and bridge.events_lost == 0


@pytest.mark.parametrize("batched", [True, False])
async def test_telemetry_goes_out_in_batches_through_the_installed_paho_and_whole_either_way(
    broker: Broker, batched: bool
) -> None:
    """The batch path needs two private names (aiomqtt's `_client`, paho's `_packet_queue`): with the versions
    installed it must engage (a batch a write, no message one by one), so an upgrade that removes either fails here,
    not silently in the benchmarks. Either path delivers every message whole, in order, to a real Mosquitto."""
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim, subscribed(broker.port) as sub:
        farm, bridge, _ = farm_and_bridge(
            [PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port, batch_telemetry=batched
        )
        async with running(farm, bridge):
            await sub.until(lambda: len(sub.payloads("marlin/a/telemetry")) >= 10, "telemetry arriving")
            batches, one_by_one = bridge.telemetry_path
    if batched:
        assert batches > 0 and one_by_one == 0, bridge.telemetry_path
    else:
        assert batches == 0 and one_by_one >= 10, bridge.telemetry_path
    times = [telemetry["time"] for telemetry in sub.payloads("marlin/a/telemetry")]
    assert times == sorted(times) and all(isinstance(t, float) for t in times)


async def test_discovery_describes_each_heater_of_each_printer_with_valid_topics(broker: Broker) -> None:
    async with serve_pty(SimulatorConfig(has_bed=False), time_scale=20) as sim, subscribed(broker.port) as sub:
        farm, bridge, _ = farm_and_bridge([PrinterSpec("p1", sim.url, poll_interval_s=0.05)], broker.port)
        async with running(farm, bridge):
            await sub.until(
                lambda: (
                    any(t.startswith("homeassistant/") for t, _, _ in sub.messages)
                    and len(sub.payloads("marlin/p1/telemetry")) >= 2
                ),
                "discovery and telemetry",
            )
    configs = {t: json.loads(p) for t, p, _ in sub.messages if t.startswith("homeassistant/")}
    assert all(t.endswith("/config") and t.startswith("homeassistant/sensor/marlin_p1/") for t in configs)
    unique_ids = [config["unique_id"] for config in configs.values()]
    assert len(unique_ids) == len(set(unique_ids))
    assert not any("bed" in unique_id for unique_id in unique_ids)  # no bed, no bed sensor
    assert {"marlin_p1_hotend_actual", "marlin_p1_hotend_target", "marlin_p1_print_progress"} <= set(unique_ids)
    telemetry = sub.payloads("marlin/p1/telemetry")[-1]
    for config in configs.values():
        assert config["device"]["identifiers"] == ["marlin_p1"]
        assert config["state_topic"].startswith("marlin/p1/")
        assert {"topic": "marlin/bridge/availability"} in config["availability"]
        if config["state_topic"].endswith("telemetry"):
            # The template names a heater and a field the telemetry really has.
            heater = config["value_template"].split("'")[1]
            field_name = config["value_template"].split("].")[1].split()[0]
            assert field_name in telemetry["heaters"][heater]
            # Unavailable if telemetry stops (a bridge that hangs without dying): ten periods, a minute at least.
            assert config["expire_after"] == 60
        # As Home Assistant's MQTT documentation asks: who published it, the firmware as the device's software.
        assert config["origin"] == {"name": "marlin_aio", "sw_version": marlin_aio.__version__}
        assert config["device"]["sw_version"].startswith("Marlin 2.1")
        assert config.get("device_class") in (None, "temperature")  # no power_factor on a heater's duty
    power = configs["homeassistant/sensor/marlin_p1/hotend_power_percent/config"]
    assert "device_class" not in power and power["unit_of_measurement"] == "%"
    assert configs["homeassistant/sensor/marlin_p1/hotend_target/config"]["device_class"] == "temperature"
    # Retained: Home Assistant started later still finds the printer.
    async with subscribed(broker.port, identifier="late") as late:
        await late.until(
            lambda: (
                {t for t, _, retained in late.messages if retained and t.startswith("homeassistant/")} == set(configs)
            ),
            "the discovery messages, retained",
        )


async def test_unplugging_one_printer_turns_it_offline_and_back_while_the_other_goes_on(broker: Broker) -> None:
    # On TCP the simulator keeps listening after a disconnect, like a board plugged back in.
    async with (
        serve_tcp(SimulatorConfig(), time_scale=20) as unplugged,
        serve_pty(SimulatorConfig(), time_scale=20) as steady,
        subscribed(broker.port) as sub,
    ):
        specs = [
            PrinterSpec("a", unplugged.url, poll_interval_s=0.05),
            PrinterSpec("b", steady.url, poll_interval_s=0.05),
        ]
        farm, bridge, events = farm_and_bridge(specs, broker.port)
        async with running(farm, bridge):
            await sub.until(lambda: "online" in sub.texts("marlin/a/availability"), "a online")
            await unplugged.disconnect()
            await sub.until(lambda: sub.texts("marlin/a/availability")[-1:] == ["offline"], "a offline")
            telemetry_of_b = len(sub.payloads("marlin/b/telemetry"))
            await sub.until(lambda: sub.texts("marlin/a/availability")[-1:] == ["online"], "a back online")
            await sub.until(lambda: len(sub.payloads("marlin/b/telemetry")) > telemetry_of_b + 5, "b goes on")
    kinds = [event["event"] for event in sub.payloads("marlin/a/events")]
    assert kinds[:1] == ["connected"] and "connection_lost" in kinds and kinds.count("connected") >= 2
    assert [event.kind for event in events if event.printer == "b"] == ["connected"]  # b never noticed
    lost = next(event for event in sub.payloads("marlin/a/events") if event["event"] == "connection_lost")
    assert "lost" in lost["message"]


async def test_events_while_the_broker_is_down_are_delivered_after_it_restarts(broker: Broker) -> None:
    async with serve_tcp(SimulatorConfig(), time_scale=20) as sim:
        farm, bridge, events = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port)
        async with running(farm, bridge):
            # A persistent session (QoS 1, not clean): what is published while this subscriber is away waits for it.
            async with subscribed(broker.port, identifier="event-keeper", clean=False) as sub:
                await sub.until(lambda: bool(sub.payloads("marlin/a/events")), "the first event")
            broker.stop()
            await sim.disconnect()  # connection_lost, then connected again: both while the broker is down
            await until(
                lambda: sum(event.kind == "connected" for event in events) >= 2, "the farm's own events", limit_s=20
            )
            assert sum(event.kind == "connected" for event in events) >= 2
            await until(lambda: not bridge.connected, "the bridge saw the broker go", limit_s=10)
            assert not bridge.connected
            broker.start()
            async with subscribed(broker.port, identifier="event-keeper", clean=False) as sub:
                await sub.until(
                    lambda: (
                        [e["event"] for e in sub.payloads("marlin/a/events")][-2:] == ["connection_lost", "connected"]
                    ),
                    "the queued events after the restart",
                )
                await sub.until(lambda: "online" in sub.texts("marlin/bridge/availability"), "the bridge online again")
    assert bridge.events_lost == 0
    assert bridge.connections >= 2


async def test_a_killed_bridge_shows_offline_through_its_last_will(broker: Broker, tmp_path: Path) -> None:
    async with subscribed(broker.port) as sub:
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "farm",
            "--sims",
            "1",
            "--sim-speed",
            "20",
            "--broker",
            f"127.0.0.1:{broker.port}",
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
        )
        try:
            await sub.until(lambda: len(sub.payloads("marlin/sim1/telemetry")) >= 2, "the bridge publishing")
        finally:
            process.kill()  # no goodbye: only the broker can say it went
            await process.wait()
        await sub.until(lambda: sub.texts("marlin/bridge/availability")[-1:] == ["offline"], "the Last Will")


def not_polls(commands: list[str]) -> list[str]:
    """What a printer ran beyond the farm's own polling and start-up (M105, M155, M110, M115)."""
    return [c for c in commands if c.split()[0] not in ("M105", "M155", "M110", "M115")]


async def command(
    sub: Subscriber, client: aiomqtt.Client, printer: str, payload: str, id_: int | str
) -> dict[str, Any]:
    """Publish a command and wait for its answer (matched by id)."""
    await client.publish(f"marlin/{printer}/command", payload, qos=1)
    topic = f"marlin/{printer}/response"
    await sub.until(lambda: any(a.get("id") == id_ for a in sub.payloads(topic)), f"the answer to {payload}")
    answer: dict[str, Any] = next(a for a in sub.payloads(topic) if a.get("id") == id_)
    return answer


async def test_commands_run_and_bad_payloads_are_refused_with_nothing_written(broker: Broker, tmp_path: Path) -> None:
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "small.gcode").write_text("G28\nG1 X10 Y10 F3000\nG1 X20\n")
    (tmp_path / "secret.gcode").write_text("G28\n")
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim_a,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_b,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="commander") as commander,
    ):
        specs = [PrinterSpec("a", sim_a.url, poll_interval_s=0.05), PrinterSpec("b", sim_b.url, poll_interval_s=0.05)]
        farm, bridge, events = farm_and_bridge(specs, broker.port, allow_commands=True, allowed_dir=jobs)
        async with running(farm, bridge):
            await sub.until(lambda: farm.printers["a"].link_up and farm.printers["b"].link_up, "both connected")
            before = (not_polls(list(sim_a.printer.executed)), not_polls(list(sim_b.printer.executed)))
            refused = {
                1: ("a", "{not json"),
                2: ("nobody", '{"id": 2, "action": "gcode", "command": "M105"}'),
                3: ("a", '{"id": 3, "action": "set_temperatures", "hotend": 900}'),
                4: ("a", '{"id": 4, "action": "set_temperatures", "bed": "abc"}'),
                5: ("a", '{"id": 5, "action": "gcode", "command": "M104 S200\\nM112"}'),
                6: ("a", '{"id": 6, "action": "print", "path": "../secret.gcode"}'),
                7: ("a", '{"id": 7, "action": "launch"}'),
                8: ("a", '{"id": 8, "action": "gcode", "commands": ["M104 S50", "G1 X\\u00e9"]}'),
                9: ("a", '{"id": 9, "action": "gcode", "command": "M104 S300"}'),
                15: ("a", '{"id": 15, "action": "set_temperatures", "chamber": 30}'),
                16: ("a", '{"id": 16, "action": "set_target", "heater": "hotend 3", "celsius": 40}'),
            }
            for id_, (printer, payload) in refused.items():
                if id_ == 1:
                    await commander.publish("marlin/a/command", payload, qos=1)
                    await sub.until(lambda: bool(sub.payloads("marlin/a/response")), "the answer to bad JSON")
                    answer = sub.payloads("marlin/a/response")[0]
                    assert answer["ok"] is False and "not JSON" in answer["error"]
                    continue
                answer = await command(sub, commander, printer, payload, id_)
                assert answer["ok"] is False, answer
            errors = {a["id"]: a["error"] for t in ("a", "nobody") for a in sub.payloads(f"marlin/{t}/response")}
            assert "no printer named 'nobody'" in errors[2]
            assert "above" in errors[3] or "260" in errors[3]
            assert "abc" in errors[4]
            assert "line break" in errors[5]
            assert "outside the allowed directory" in errors[6]
            assert "unknown action" in errors[7]
            assert "non-ASCII" in errors[8]
            assert "above the limit of 260" in errors[9]  # typed G-code meets the same limits
            assert "has no chamber (it has 1 hotend, bed)" in errors[15]  # as marlin-temp set refuses it
            assert "has no hotend 3" in errors[16]
            # Nothing of any refused command reached either printer (M104 S50 came before the bad line: not sent).
            assert (not_polls(list(sim_a.printer.executed)), not_polls(list(sim_b.printer.executed))) == before

            answer = await command(sub, commander, "a", '{"id": 10, "action": "set_temperatures", "hotend": 50}', 10)
            assert answer == {"id": 10, "ok": True, "result": {"targets": {"hotend": 50.0}}}
            answer = await command(
                sub, commander, "b", '{"id": 11, "action": "set_target", "heater": "bed", "celsius": 40}', 11
            )
            assert answer["ok"] is True
            answer = await command(sub, commander, "a", '{"id": 12, "action": "gcode", "command": "M114"}', 12)
            assert answer["ok"] is True and answer["result"]["replies"][0]["lines"][0].startswith("X:")
            assert not_polls(list(sim_a.printer.executed))[-2:] == ["M104 S50", "M114"]
            assert not_polls(list(sim_b.printer.executed))[-1:] == ["M140 S40"]
            await sub.until(
                lambda: any(t["heaters"]["hotend"]["target"] == 50 for t in sub.payloads("marlin/a/telemetry")),
                "the new target in the telemetry",
            )

            answer = await command(sub, commander, "b", '{"id": 13, "action": "print", "path": "small.gcode"}', 13)
            assert answer["ok"] is True
            await sub.until(
                lambda: [e["event"] for e in sub.payloads("marlin/b/events")][-1:] == ["print_finished"],
                "the print to finish",
            )
            assert [c for c in not_polls(list(sim_b.printer.executed)) if c != "M140 S40"][-3:] == [
                "G28",
                "G1 X10 Y10 F3000",
                "G1 X20",
            ]
            await sub.until(
                lambda: any((s["print"] or {}).get("state") == "done" for s in sub.payloads("marlin/b/state")),
                "the state to show the print done",
            )

            # With commands on, Home Assistant gets a number per heater target and the emergency stop button, whose
            # payloads are the commands above.
            configs = {t: json.loads(p) for t, p, _ in sub.messages if t.startswith("homeassistant/")}
            number = configs["homeassistant/number/marlin_a/hotend_target/config"]
            assert number["command_topic"] == "marlin/a/command" and number["max"] == 260
            assert number["device_class"] == "temperature"
            assert json.loads(number["command_template"].replace("{{ value }}", "42"))["celsius"] == 42
            button = configs["homeassistant/button/marlin_a/emergency_stop/config"]
            assert json.loads(button["payload_press"]) == {"action": "emergency_stop"}

            answer = await command(sub, commander, "a", '{"id": 14, "action": "emergency_stop"}', 14)
            assert answer["ok"] is True
            await sub.until(lambda: "halted" in [e["event"] for e in sub.payloads("marlin/a/events")], "a halted")
            assert "b" not in {event.printer for event in events if event.kind == "halted"}


async def test_commands_are_off_unless_allowed(broker: Broker) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="commander") as commander,
    ):
        farm, bridge, _ = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], broker.port)
        async with running(farm, bridge):
            await sub.until(lambda: len(sub.payloads("marlin/a/telemetry")) >= 2, "telemetry")
            await commander.publish("marlin/a/command", '{"id": 1, "action": "gcode", "command": "G28"}', qos=1)
            # Our own publish is delivered to the subscriber after the bridge has had it; more telemetry after that
            # means the bridge went on without answering.
            await sub.until(lambda: bool(sub.texts("marlin/a/command")), "the command on the broker")
            seen = len(sub.payloads("marlin/a/telemetry"))
            await sub.until(lambda: len(sub.payloads("marlin/a/telemetry")) > seen + 3, "telemetry after it")
    assert sub.payloads("marlin/a/response") == []
    assert "G28" not in list(sim.printer.executed)
    configs = [t for t, _, _ in sub.messages if t.startswith("homeassistant/")]
    assert not any("/number/" in t or "/button/" in t for t in configs)  # no controls that would not work


async def test_a_target_above_the_limits_is_refused_however_the_gcode_spells_it(broker: Broker) -> None:
    async with one_printer_farm(broker, allow_commands=True) as one:
        sim, sub, commander = one.sim, one.sub, one.client
        before = not_polls(list(sim.printer.executed))
        # The default limits: hotend 260, bed 140. Each spelling is one Marlin's parser reads as the target.
        spellings = ["M104S280", "m104 s280", "M0104 S270", "M104 B1000", "M140S200"]
        for id_, text in enumerate(spellings, 1):
            answer = await command(
                sub, commander, "a", json.dumps({"id": id_, "action": "gcode", "command": text}), id_
            )
            assert answer["ok"] is False, (text, answer)
            assert "\n" not in answer["error"] and "limit" in answer["error"], answer
        # A list with one such command among good ones writes none of them.
        answer = await command(
            sub, commander, "a", json.dumps({"id": 9, "action": "gcode", "commands": ["M105", "M104S280"]}), 9
        )
        assert answer["ok"] is False
        assert not_polls(list(sim.printer.executed)) == before
        # Readings taken after the refusals still show no target set.
        seen = len(sub.payloads("marlin/a/telemetry"))
        await sub.until(lambda: len(sub.payloads("marlin/a/telemetry")) > seen + 2, "telemetry after them")
        heaters = sub.payloads("marlin/a/telemetry")[-1]["heaters"]
        assert heaters["hotend"]["target"] == 0 and heaters["bed"]["target"] == 0
        # Within the limits, the same spelling runs.
        answer = await command(sub, commander, "a", '{"id": 10, "action": "gcode", "command": "M104S200"}', 10)
        assert answer["ok"] is True
        assert not_polls(list(sim.printer.executed))[-1:] == ["M104S200"]


@contextlib.contextmanager
def secured_broker(directory: Path, extra: str) -> Iterator[int]:
    """A Mosquitto with `extra` configuration (password file, TLS) on a free port."""
    port = free_port()
    config = directory / "secure.conf"
    config.write_text(f"listener {port} 127.0.0.1\npersistence false\n{AS_US}{extra}")
    assert MOSQUITTO is not None
    process = subprocess.Popen([MOSQUITTO, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        for _ in range(200):
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.1):
                break
            assert process.poll() is None, process.stderr.read() if process.stderr else ""
            time.sleep(0.05)  # polling a condition (the port accepts), bounded
        yield port
    finally:
        process.terminate()
        process.wait(10)


@pytest.mark.skipif(shutil.which("mosquitto_passwd") is None, reason="mosquitto_passwd comes with Debian's mosquitto")
async def test_a_broker_that_wants_a_password_gets_it_and_a_wrong_one_is_retried_not_fatal(tmp_path: Path) -> None:
    passwords = tmp_path / "passwords"
    command = ["mosquitto_passwd", "-b", "-c", str(passwords), "farm", "s3cret"]
    await asyncio.to_thread(subprocess.run, command, check=True)
    passwords.chmod(0o600)
    extra = f"allow_anonymous false\npassword_file {passwords}\n"
    with secured_broker(tmp_path, extra) as port:
        async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
            spec = [PrinterSpec("a", sim.url, poll_interval_s=0.05)]
            farm, wrong, _ = farm_and_bridge(spec, port)
            wrong = Bridge(farm, BrokerSettings(port=port, username="farm", password="nope"), wrong.settings)
            async with running(farm, wrong):
                await until(lambda: farm.printers["a"].readings > 20, "readings flow", limit_s=5)
                assert farm.printers["a"].readings > 20  # the printers do not care that the broker said no
                assert wrong.connections == 0 and wrong.published == 0
            assert "nope" not in repr(wrong.broker)  # never printed
        async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
            farm, _, _ = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], port)
            right = Bridge(farm, BrokerSettings(port=port, username="farm", password="s3cret"), BridgeSettings())
            async with running(farm, right):
                await until(lambda: right.published > 5, "messages published", limit_s=10)
            assert right.connections >= 1 and right.published > 5


def openssl(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True)


def certificate_authority(directory: Path) -> tuple[Path, Path]:
    """A CA of the test's own: (its certificate, its key)."""
    ca, ca_key = directory / "ca.pem", directory / "ca.key"
    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=test CA",
            "-keyout", str(ca_key), "-out", str(ca))  # fmt: skip
    return ca, ca_key


def issue(directory: Path, name: str, ca: tuple[Path, Path], *, ip: str | None = None) -> tuple[Path, Path]:
    """A certificate for `name` signed by `ca`: (the certificate, its key)."""
    key, request, cert = (directory / f"{name}.{ext}" for ext in ("key", "csr", "pem"))
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", f"/CN={ip or name}", "-keyout", str(key),
            "-out", str(request))  # fmt: skip
    extensions = directory / f"{name}.ext"
    extensions.write_text(f"subjectAltName=IP:{ip}\n" if ip else "extendedKeyUsage=clientAuth\n")
    openssl("x509", "-req", "-in", str(request), "-CA", str(ca[0]), "-CAkey", str(ca[1]), "-CAcreateserial",
            "-days", "2", "-extfile", str(extensions), "-out", str(cert))  # fmt: skip
    return cert, key


async def publishes(farm: Farm, bridge: Bridge) -> bool:
    """Whether `bridge` connects and publishes (True), or its first attempt is refused (False)."""
    async with running(farm, bridge):
        await until(lambda: bridge.published > 5 or bridge.connect_failures > 0, "published, or refused", limit_s=30)
    if bridge.connect_failures:
        assert bridge.connections == 0 and bridge.published == 0 and bridge.broker_error
        return False
    return True


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl makes the test's certificates")
async def test_tls_with_our_own_certificate_authority_and_a_client_certificate(tmp_path: Path) -> None:
    ca = await asyncio.to_thread(certificate_authority, tmp_path)
    server = await asyncio.to_thread(issue, tmp_path, "server", ca, ip="127.0.0.1")
    client = await asyncio.to_thread(issue, tmp_path, "bridge", ca)
    tls = f"allow_anonymous true\ncafile {ca[0]}\ncertfile {server[0]}\nkeyfile {server[1]}\n"
    async with serve_pty(SimulatorConfig(), time_scale=20) as sim:
        farm, _, _ = farm_and_bridge([PrinterSpec("a", sim.url, poll_interval_s=0.05)], 1)
        # A refused TLS session ends only at the connect timeout (paho waits for a CONNACK): a short one here.
        with secured_broker(tmp_path, tls) as port:
            assert await publishes(farm, Bridge(farm, BrokerSettings(port=port, tls_ca=str(ca[0])), BridgeSettings()))
            plain = BrokerSettings(port=port, connect_timeout_s=1.0)
            assert not await publishes(farm, Bridge(farm, plain, BridgeSettings()))
        with secured_broker(tmp_path, tls + "require_certificate true\n") as port:
            anonymous = BrokerSettings(port=port, tls_ca=str(ca[0]), connect_timeout_s=1.0)
            assert not await publishes(farm, Bridge(farm, anonymous, BridgeSettings()))
            signed = BrokerSettings(port=port, tls_ca=str(ca[0]), tls_cert=str(client[0]), tls_key=str(client[1]))
            assert await publishes(farm, Bridge(farm, signed, BridgeSettings()))


async def test_an_absent_broker_never_slows_the_printers_and_each_keeps_its_own_newest_telemetry(
    tmp_path: Path,
) -> None:
    nobody = free_port()  # nothing listens here
    async with (
        serve_pty(SimulatorConfig(), time_scale=20) as busy,
        serve_pty(SimulatorConfig(), time_scale=20) as slow,
    ):
        specs = [
            PrinterSpec("busy", busy.url, poll_interval_s=0.02),
            PrinterSpec("slow", slow.url, poll_interval_s=0.2),
        ]
        farm, bridge, _ = farm_and_bridge(specs, nobody, telemetry_buffer=10, rate_hz=50.0)

        def newest_slow_buffered() -> bool:
            latest = farm.printers["slow"].latest
            buffered = bridge._telemetry.buffers["slow"]
            if not buffered or latest is None:
                return False
            return bool(json.loads(buffered[-1])["time"] == round(latest.wall_time_s, 3))

        async with running(farm, bridge):
            await until(
                lambda: farm.printers["busy"].readings > 100 and farm.printers["slow"].readings > 15,
                "readings flow",
                limit_s=30,
            )
            # The busy printer's readings do not push the slow one's out: its newest reading reaches its buffer (the
            # bridge samples 50 times a second, so between a reading and its sample the two differ for a moment).
            await until(newest_slow_buffered, "the slow printer's newest reading in its buffer")
        assert farm.printers["busy"].readings > 100  # polls went on at their rate
        assert bridge.telemetry_dropped > 50  # each buffer kept its newest 10 and counted the rest
        assert {name: len(buffer) for name, buffer in bridge._telemetry.buffers.items()} == {"busy": 10, "slow": 10}
        assert bridge.connections == 0


async def test_a_thermal_runaway_and_a_reset_are_events_of_their_own_printer_only(broker: Broker) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=20) as hot,
        serve_pty(SimulatorConfig(), time_scale=20) as rebooted,
        serve_pty(SimulatorConfig(), time_scale=20) as calm,
        subscribed(broker.port) as sub,
    ):
        specs = [
            PrinterSpec("hot", hot.url, poll_interval_s=0.05),
            PrinterSpec("rebooted", rebooted.url, poll_interval_s=0.05),
            PrinterSpec("calm", calm.url, poll_interval_s=0.05),
        ]
        farm, bridge, events = farm_and_bridge(specs, broker.port)
        async with running(farm, bridge):
            await sub.until(lambda: all(farm.printers[n].link_up for n in ("hot", "rebooted", "calm")), "all up")
            await sub.until(lambda: len(sub.payloads("marlin/calm/telemetry")) >= 2, "telemetry")
            hot.printer.thermal_runaway(hot.now())
            hot.poke()
            rebooted.printer.reset(rebooted.now())
            rebooted.poke()
            await sub.until(
                lambda: "thermal_runaway" in [e["event"] for e in sub.payloads("marlin/hot/events")], "the runaway"
            )
            await sub.until(
                lambda: "reset" in [e["event"] for e in sub.payloads("marlin/rebooted/events")], "the reset"
            )
            await sub.until(
                lambda: any(
                    s["last_error"] and "Thermal Runaway" in s["last_error"] for s in sub.payloads("marlin/hot/state")
                ),
                "the runaway in the state",
            )
            calm_telemetry = len(sub.payloads("marlin/calm/telemetry"))
            await sub.until(lambda: len(sub.payloads("marlin/calm/telemetry")) > calm_telemetry + 5, "calm goes on")
    assert [event.kind for event in events if event.printer == "calm"] == ["connected"]
    runaway = next(e for e in sub.payloads("marlin/hot/events") if e["event"] == "thermal_runaway")
    assert "Thermal Runaway" in runaway["message"]


async def test_bridges_sharing_a_broker_answer_only_for_their_own_printers(broker: Broker) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=50) as sim_a,
        serve_pty(SimulatorConfig(), time_scale=50) as sim_b,
        subscribed(broker.port) as sub,
        aiomqtt.Client("127.0.0.1", broker.port, identifier="commander") as commander,
    ):
        farm_a, bridge_a, _ = farm_and_bridge(
            [PrinterSpec("a", sim_a.url, poll_interval_s=0.05)], broker.port, allow_commands=True
        )
        farm_b, bridge_b, _ = farm_and_bridge(
            [PrinterSpec("b", sim_b.url, poll_interval_s=0.05)], broker.port, allow_commands=True
        )
        async with running(farm_a, bridge_a), running(farm_b, bridge_b):
            await sub.until(
                lambda: (
                    "online" in sub.texts("marlin/a/availability") and "online" in sub.texts("marlin/b/availability")
                ),
                "both printers online",
            )
            answer = await command(sub, commander, "b", '{"id": 1, "action": "gcode", "command": "M114"}', 1)
            assert answer["ok"] is True
            await command(sub, commander, "nobody", '{"id": 2, "action": "gcode", "command": "M114"}', 2)
            # The answer to the next command comes after any stray one to the first would have.
            await command(sub, commander, "b", '{"id": 3, "action": "gcode", "command": "M105"}', 3)
    answers_for_b = [a for a in sub.payloads("marlin/b/response") if a["id"] == 1]
    assert answers_for_b == [answer]  # bridge a left b's command to bridge b
    assert all(not a["ok"] for a in sub.payloads("marlin/nobody/response"))  # a name no bridge has: an error


async def test_sigterm_stops_the_farm_as_cleanly_as_its_duration_does(broker: Broker) -> None:
    async with subscribed(broker.port) as sub:
        process = await asyncio.create_subprocess_exec(
            *(sys.executable, "-m", "marlin_temp", "farm", "--sims", "1", "--sim-speed", "20"),
            *("--broker", f"127.0.0.1:{broker.port}"),
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.PIPE,
        )
        try:
            await sub.until(lambda: len(sub.payloads("marlin/sim1/telemetry")) >= 2, "the bridge publishing")
            process.send_signal(signal.SIGTERM)
            _, stderr = await asyncio.wait_for(process.communicate(), 30)
        finally:
            if process.returncode is None:
                process.kill()
                await process.wait()
        await sub.until(lambda: sub.texts("marlin/sim1/availability")[-1:] == ["offline"], "the printer offline")
        await sub.until(lambda: sub.texts("marlin/bridge/availability")[-1:] == ["offline"], "the bridge offline")
    assert process.returncode == 0
    assert b"farm: stopped after" in stderr
