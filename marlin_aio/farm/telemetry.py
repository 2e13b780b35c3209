"""What the bridge publishes of each printer, and how its telemetry gets to the broker: the payloads of a reading
(`telemetry_payload`) and of a printer's state (`state_payload`), compact JSON, MQTT framing, and `TelemetryLane`,
which holds each printer's newest readings in a bounded buffer of its own and hands them to the MQTT client in
batches.

Backpressure: each reading goes, as it is read (at most at the rate), into its printer's own bounded buffer whatever
the broker does, which drops (and counts) that printer's oldest when the broker cannot keep up or is away: every
printer keeps its newest readings. The buffers go out together, at most TELEMETRY_BATCH_S after a reading, in one
write to the broker's socket (see `TelemetryLane.publish`), and only once the MQTT client has written the last batch.
The serial loops never wait for the broker.
"""

from __future__ import annotations

import asyncio
import json
import math
import struct
from collections import deque
from collections.abc import Callable
from typing import Any

import aiomqtt
import paho.mqtt.client as mqtt

import marlin_aio
import marlin_aio.protocol

from .supervisor import FarmPrinter, redact_payload

__all__ = [
    "TELEMETRY_BATCH_S",
    "TelemetryLane",
    "compact_json",
    "publish_packet",
    "state_inputs",
    "state_payload",
    "telemetry_payload",
]

TELEMETRY_BATCH_S = 0.05
"""Telemetry goes out in batches, this long after the first reading of each, written to the broker's socket together:
at most this much more latency (nothing beside a reading every 5 s, the default rate) for one write every 50 ms
whatever the printers' number and rate. Each write costs the same whatever it holds (about 0.2 ms of CPU on a small
VM, waking the broker): at 50 printers polled at 10 Hz, 20 ms gave 17 writes a second, 50 ms gives 10."""


def _stdlib_json(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":")).encode()


try:
    import orjson
except ImportError:  # orjson comes with the `fast` extra; without it, the same JSON from the standard library
    compact_json: Callable[[Any], bytes] = _stdlib_json
else:

    def compact_json(value: Any) -> bytes:
        """`value` as compact JSON: orjson's, about fifteen times faster than json's on a telemetry payload (0.2
        against 3.2 us) and the same bytes for the bridge's payloads (compact, floats at their shortest, null for
        None; NaN, which json writes as NaN and orjson as null, is in none of them). What orjson refuses (a lone
        surrogate in a string, an int over 64 bits) json writes."""
        try:
            return orjson.dumps(value)
        except orjson.JSONEncodeError:
            return _stdlib_json(value)


def telemetry_payload(reading: marlin_aio.TemperatureReading) -> dict[str, Any]:
    """The telemetry of one reading: every heater reported, by name, in degrees Celsius and percent."""
    # Called for every message (500 a second for 50 printers at 10 Hz): heater names are looked up once each, and
    # each value is read once (15% of this function's time). A value that is not finite is written as null.
    heaters: dict[str, dict[str, float | None]] = {}
    reported = reading.temperatures.heaters
    numbered = "T0" in reported
    for key, heater in reported.items():
        if key == "T" and numbered:
            continue  # with several hotends, each is reported by number; `T` repeats the active one
        name = _HEATER_NAMES.get(key)
        if name is None:
            name = marlin_aio.protocol.heater_name(key)
            if len(_HEATER_NAMES) < 64:  # a confused printer may report any number of odd keys
                _HEATER_NAMES[key] = name
        actual, target, fraction = heater.actual, heater.target, heater.power_fraction
        heaters[name] = {
            "actual": actual if math.isfinite(actual) else None,
            "target": target if target is not None and math.isfinite(target) else None,
            "power_percent": None if fraction is None else round(fraction * 100, 1),
        }
    return {"time": round(reading.wall_time_s, 3), "heaters": heaters}


_HEATER_NAMES: dict[str, str] = {}


def state_payload(farm_printer: FarmPrinter) -> dict[str, Any]:
    """What a printer's state topic holds: its link, firmware, print, last error, port and open prompt, redacted
    (the state is retained, there for any later subscriber)."""
    # Made of the fields `state_inputs` gives: a field added here goes there too.
    prompt = farm_printer.prompt
    state: dict[str, Any] = redact_payload(
        {
            "link": "up" if farm_printer.link_up else "down",
            "firmware": farm_printer.firmware,
            "print": farm_printer.print_status(),
            "last_error": farm_printer.last_error,
            "port": farm_printer.url or farm_printer.spec.port,
            "prompt": None if prompt is None else {"message": prompt.message, "buttons": list(prompt.buttons)},
            "waiting_for_user": farm_printer.waiting_for_user,
        }
    )
    return state


def state_inputs(farm_printer: FarmPrinter) -> tuple[object, ...]:
    """What a printer's `state_payload` is made of but its print's progress: the bridge makes a new state only when
    these changed (or a print runs)."""
    return (
        farm_printer.link_up,
        farm_printer.firmware,
        farm_printer.last_error,
        farm_printer.url,
        farm_printer.prompt,
        farm_printer.waiting_for_user,
    )


def _check(rc: int) -> None:
    """Raise for a paho result code that is not success, as aiomqtt's `publish` does.

    Raises:
        aiomqtt.MqttCodeError: not MQTT_ERR_SUCCESS (no connection, say).
    """
    if rc != mqtt.MQTT_ERR_SUCCESS:
        raise aiomqtt.MqttCodeError(rc, "Could not publish message")


def publish_packet(topic: str, payload: bytes) -> bytes:
    """An MQTT 3.1.1 PUBLISH packet (section 3.3) at QoS 0, neither retained nor a duplicate, as it goes on the wire.

    Raises:
        ValueError: a topic longer than 65,535 bytes, or a packet longer than MQTT allows.
    """
    name = topic.encode()
    if len(name) > 0xFFFF:
        raise ValueError(f"topic of {len(name)} bytes, over MQTT's 65535")
    remaining = 2 + len(name) + len(payload)
    if remaining > 268_435_455:
        raise ValueError(f"packet of {remaining} bytes, over MQTT's 268435455")
    length = bytearray()  # the remaining length: 7 bits a byte, least significant first, the top bit for "more"
    while True:
        remaining, digit = divmod(remaining, 128)
        length.append(digit | 0x80 if remaining else digit)
        if not remaining:
            break
    return b"\x30" + length + struct.pack("!H", len(name)) + name + payload


class TelemetryLane:
    """Each printer's telemetry between its readings and the broker: at most one message per rate's period, kept in
    the printer's own buffer of `buffer_size` (its oldest dropped, and counted, when full), handed to the MQTT
    client in batches. `wake` is called when a batch is due: the bridge's publisher then calls `publish`."""

    def __init__(
        self,
        topics: dict[str, str],
        rate_hz: float,
        buffer_size: int,
        wake: Callable[[], None],
        *,
        batched: bool = True,
    ) -> None:
        # Each printer keeps its own newest readings while the broker is away: one busy printer (or fifty) never
        # pushes another's out.
        self.buffers: dict[str, deque[bytes]] = {name: deque(maxlen=buffer_size) for name in topics}
        """Each printer's telemetry messages not yet handed to the MQTT client, oldest first."""
        self._topics = topics
        # The printers with telemetry in their buffer, in the order they read it (a dict as an ordered set): the
        # publisher looks at these, not at all fifty buffers for each reading.
        self._waiting: dict[str, None] = {}
        self._wake = wake
        self._last_sent_s: dict[str, float] = {}
        self._min_gap_s = 0.9 / rate_hz
        self.dropped = 0
        """Telemetry messages dropped from a full per-printer buffer (the oldest)."""
        self.published = 0
        """Telemetry messages handed to the MQTT client."""
        self._batched = batched
        self.batches = 0
        """Batches handed to paho as one write (the private path of `publish`)."""
        self.one_by_one = 0
        """Messages handed to paho's public `publish` one at a time (the path without the private names, or with
        `batched=False`)."""

    @property
    def waiting(self) -> bool:
        """True while some printer's buffer holds telemetry."""
        return bool(self._waiting)

    def add(self, name: str, reading: marlin_aio.TemperatureReading) -> dict[str, Any] | None:
        """A printer's reading, as it is read: into its telemetry buffer unless one went out less than a rate's
        period ago (a tenth of it is allowed for jitter, so polls at the rate itself are all sent). Returns the
        payload buffered, or None for a reading skipped."""
        last = self._last_sent_s.get(name)
        if last is not None and reading.monotonic_s - last < self._min_gap_s:
            return None
        self._last_sent_s[name] = reading.monotonic_s
        payload = telemetry_payload(reading)
        buffer = self.buffers[name]
        if len(buffer) == buffer.maxlen:
            self.dropped += 1  # this printer's oldest goes: a slow broker never slows a printer
        buffer.append(compact_json(payload))
        if not self._waiting:
            # The first message since the last batch: the publisher comes for it, and for whatever the other
            # printers read meanwhile, TELEMETRY_BATCH_S from now. (A wake-up per reading cost a turn of the
            # publisher and a write to the socket per message.)
            asyncio.get_running_loop().call_later(TELEMETRY_BATCH_S, self._wake)
        self._waiting[name] = None
        return payload

    def publish(self, client: aiomqtt.Client) -> None:
        """Hand the buffered telemetry (QoS 0) to the MQTT client in one write, without waiting for it; or, while the
        client has not yet written what it was given (a slow broker), leave it in the buffers and look again
        TELEMETRY_BATCH_S later: the buffers, not the client, hold what waits, and drop their oldest when full.

        Speed over the plain API (issue 24): aiomqtt's `publish` awaits, for each QoS 0 message, paho's word that
        it was written, which QoS 0 does not need (written is not delivered): an Event, a `wait_for` task and a
        timer per message. paho's own `publish` does not wait, but paho writes each packet with a `send` of its
        own, which on a local broker costs as much as the rest of the message. So the batch is encoded here
        (`publish_packet`) and queued as one packet with paho's `_packet_queue`, which its `publish` calls: one
        `send`, one callback, for the lot. What it saves, at 50 printers and 500 messages a second: the awaited
        publishes were a fifth of the bridge's busy samples and the sends another fifth; with batches (and
        orjson, and the bridge making only changed states) the bridge's CPU went from about 3x the plain farm's
        to about 1.2-1.5x (benchmarks, farm scenario). It needs two private names (aiomqtt's `_client`, paho's
        `_packet_queue`) and MQTT 3.1.1 framing, the protocol the bridge asks for; lacking either, each message
        goes through paho's `publish`.

        Raises:
            aiomqtt.MqttCodeError: the MQTT client refused the batch or a message (no connection, say).
        """
        paho = client._client
        if paho.want_write():
            asyncio.get_running_loop().call_later(TELEMETRY_BATCH_S, self._wake)
            return
        queue_packet = getattr(paho, "_packet_queue", None)
        framed = self._batched and queue_packet is not None and paho.protocol in (mqtt.MQTTv31, mqtt.MQTTv311)
        packets: list[bytes] = []
        for name in self._waiting:
            buffer = self.buffers[name]
            topic = self._topics[name]
            while buffer:
                if framed:
                    packets.append(publish_packet(topic, buffer.popleft()))
                else:
                    _check(paho.publish(topic, buffer.popleft(), 0).rc)
                    self.one_by_one += 1
                self.published += 1
        self._waiting.clear()
        if packets:
            assert queue_packet is not None
            if paho.socket() is None:  # what paho's publish says when the session has just ended
                _check(mqtt.MQTT_ERR_NO_CONN)
            # mid 0, which paho never gives a message: its callback for the batch is aiomqtt's for no publish.
            _check(queue_packet(mqtt.PUBLISH, b"".join(packets), 0, 0, mqtt.MQTTMessageInfo(0)))
            self.batches += 1
