"""The bridge's telemetry fast lane (issue 24): the JSON it writes with and without orjson, the MQTT PUBLISH packets
it frames itself, and a batch handed to paho in one write, read back through a real Mosquitto.

The payload's schema is pinned by `test_farm`; here, that the fast lane changes nothing a subscriber sees.
"""

from __future__ import annotations

import asyncio
import json
import math
import struct

import aiomqtt
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_farm import MOSQUITTO, Broker, subscribed

from marlin_aio import HeaterReading, TemperatureReading, Temperatures
from marlin_aio.farm.bridge import Bridge, BridgeSettings, BrokerSettings
from marlin_aio.farm.supervisor import Farm, PrinterSpec
from marlin_aio.farm.telemetry import _stdlib_json, compact_json, publish_packet, telemetry_payload
from marlin_aio.protocol import ReadingSource


def reading(
    heaters: dict[str, HeaterReading], wall_time_s: float = 1_795_823_276.5091, at_s: float = 0.0
) -> TemperatureReading:
    return TemperatureReading(Temperatures(heaters), at_s, wall_time_s, ReadingSource.POLL)


READINGS = [
    TemperatureReading(Temperatures.from_text("T:21.50 /0.00 B:21.30 /0.00 @:0 B@:0"), 0.0, 1.5, ReadingSource.POLL),
    TemperatureReading(
        Temperatures.from_text("T:210.02 /210.00 T0:210.02 /210.00 T1:25.00 /0.00 B:60.1 /60.0 @:127 @0:127 B@:64"),
        0.0,
        1_795_823_276.123,
        ReadingSource.POLL,
    ),
    reading({"T": HeaterReading(math.nan, None, None), "C": HeaterReading(-1e-7, math.inf, 300)}),
    reading({"B": HeaterReading(1e16, 123456789.125, -5)}, wall_time_s=0.0),
]


def parse_publish(packet: bytes) -> tuple[int, str, bytes, int]:
    """(first byte, topic, payload, bytes used) of the PUBLISH packet at the start of `packet` (MQTT 3.1.1, 3.3)."""
    remaining = shift = 0
    index = 1
    while True:
        digit = packet[index]
        remaining |= (digit & 0x7F) << shift
        index += 1
        shift += 7
        if not digit & 0x80:
            break
    (topic_length,) = struct.unpack_from("!H", packet, index)
    topic = packet[index + 2 : index + 2 + topic_length].decode()
    end = index + remaining
    return packet[0], topic, packet[index + 2 + topic_length : end], end


def test_a_publish_packet_is_framed_as_mqtt_says() -> None:
    # MQTT 3.1.1, 3.3: PUBLISH (0x3), no DUP, QoS 0, no RETAIN; the remaining length; the topic with its length;
    # no packet identifier at QoS 0; the payload.
    assert publish_packet("a/b", b"hi") == bytes.fromhex("30070003") + b"a/b" + b"hi"
    for size in (0, 1, 122, 123, 124, 16_378, 16_379, 16_380, 2_097_146, 2_097_147):
        packet = publish_packet("a/b", b"x" * size)
        assert parse_publish(packet) == (0x30, "a/b", b"x" * size, len(packet))
    assert publish_packet("a/b", b"x" * 123)[1:3] == b"\x80\x01"  # 128: the first length of two bytes
    with pytest.raises(ValueError, match="topic"):
        publish_packet("t" * 65_536, b"")


@given(topic=st.text(min_size=1, max_size=300), payload=st.binary(max_size=20_000))
def test_any_publish_packet_reads_back_whole(topic: str, payload: bytes) -> None:
    packet = publish_packet(topic, payload)
    assert parse_publish(packet + b"\x30\x00")[:3] == (0x30, topic, payload)  # and not one byte of what follows
    assert parse_publish(packet)[3] == len(packet)


@pytest.mark.parametrize("one", READINGS)
def test_telemetry_is_the_same_json_with_orjson_and_without(one: TemperatureReading) -> None:
    payload = telemetry_payload(one)
    assert json.loads(compact_json(payload)) == json.loads(_stdlib_json(payload)) == payload
    if (
        one in READINGS[:2]
    ):  # what printers report; a number in exponent form is written `1e-07` by json, `1e-7` by orjson
        assert compact_json(payload) == _stdlib_json(payload)
    assert all(value is None or math.isfinite(value) for h in payload["heaters"].values() for value in h.values())


def test_what_orjson_refuses_is_still_written() -> None:
    odd = {"last_error": "\udc80 a byte the port could not decode", "big": 2**70}
    assert json.loads(compact_json(odd)) == json.loads(_stdlib_json(odd))


def one_bridge(port: int) -> Bridge:
    # Never run: the test hands readings and an open MQTT session to the bridge's telemetry lane itself.
    farm = Farm([PrinterSpec("a", "socket://127.0.0.1:9"), PrinterSpec("b", "socket://127.0.0.1:9")], lambda _: None)
    return Bridge(farm, BrokerSettings(port=port), BridgeSettings(rate_hz=1.0))


@pytest.mark.skipif(MOSQUITTO is None, reason="Mosquitto is not installed")
@pytest.mark.parametrize("protocol", [aiomqtt.ProtocolVersion.V311, aiomqtt.ProtocolVersion.V5])
async def test_a_batch_of_telemetry_reaches_a_subscriber_as_each_message_would(
    broker: Broker, protocol: aiomqtt.ProtocolVersion
) -> None:
    # MQTT 3.1.1 (the bridge's own): the batch framed here and written at once; 5: each through paho's publish.
    bridge = one_bridge(broker.port)
    async with aiomqtt.Client("127.0.0.1", broker.port, protocol=protocol) as client:
        await client.publish("test/ready", b"1", qos=1, retain=True)
        async with subscribed(broker.port) as sub:
            await sub.until(lambda: bool(sub.texts("test/ready")), "subscribed")
            for index, one in enumerate(READINGS * 3):
                bridge._on_reading("ab"[index % 2], reading(one.temperatures.heaters, one.wall_time_s, at_s=index))
            # A message the MQTT client has yet to write (a slow broker): the telemetry waits in its buffers.
            client._client.publish("test/before", b"first", 0)
            bridge._telemetry.publish(client)
            assert bridge.published == 0 and [len(bridge._telemetry.buffers[name]) for name in "ab"] == [6, 6]
            await asyncio.sleep(0.1)  # the client writes it
            bridge._telemetry.publish(client)
            assert bridge.published == 12 and not any(bridge._telemetry.buffers.values())
            await sub.until(lambda: len(sub.payloads("marlin/b/telemetry")) == 6, "the whole batch")
    sent = [telemetry_payload(one) for one in READINGS * 3]
    assert sub.payloads("marlin/a/telemetry") == sent[0::2]
    assert sub.payloads("marlin/b/telemetry") == sent[1::2]
    assert next(topic for topic, _, _ in sub.messages if topic != "test/ready") == "test/before"
