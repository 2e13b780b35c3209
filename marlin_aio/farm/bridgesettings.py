"""The MQTT bridge's settings: where the broker is and how to log in (`BrokerSettings`), what the bridge publishes
and how often (`BridgeSettings`), and the topics those settings name."""

from __future__ import annotations

import ssl
from dataclasses import dataclass, field
from pathlib import Path

import aiomqtt

from .commands import MAX_COMMAND_AGE_S
from .presets import DEFAULT_PRESETS, Preset

__all__ = ["EVENT_QUEUE", "TELEMETRY_BUFFER", "BridgeSettings", "BrokerSettings"]

EVENT_QUEUE = 10_000
"""Events kept until the broker has them (a long outage); past it the oldest is lost (counted, and logged)."""
TELEMETRY_BUFFER = 240
"""Telemetry messages kept per printer while the broker is slow or away (two minutes at the default rate)."""


@dataclass(frozen=True)
class BrokerSettings:
    """Where the broker is and how to log in. `password` is never printed (its repr hides it)."""

    host: str = "127.0.0.1"
    port: int = 1883
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    client_id: str | None = None
    tls_ca: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    keepalive_s: int = 30
    connect_timeout_s: float = 10.0
    """How long an attempt to open a session may take (a TLS handshake the broker refused ends only by it)."""

    @property
    def address(self) -> str:
        """`host:port`, for messages."""
        return f"{self.host}:{self.port}"

    def tls_context(self) -> ssl.SSLContext | None:
        """The TLS context the options ask for (a CA, a client certificate), or None for a plain connection.

        Raises:
            OSError: a CA, certificate or key file that cannot be read.
            ssl.SSLError: one that is not a valid CA, certificate or key.
        """
        if self.tls_ca is None and self.tls_cert is None:
            return None
        context = ssl.create_default_context(cafile=self.tls_ca)
        if self.tls_cert is not None:
            context.load_cert_chain(self.tls_cert, self.tls_key)
        return context

    def client(self, will_topic: str) -> aiomqtt.Client:
        """An MQTT client for this broker (not yet connected) whose Last Will publishes `offline`, retained, on
        `will_topic`.

        Raises:
            OSError: a CA, certificate or key file that cannot be read.
            ssl.SSLError: one that is not a valid CA, certificate or key.
        """
        return aiomqtt.Client(
            self.host,
            self.port,
            username=self.username,
            password=self.password,
            identifier=self.client_id,
            keepalive=self.keepalive_s,
            timeout=self.connect_timeout_s,
            tls_context=self.tls_context(),
            will=aiomqtt.Will(will_topic, "offline", qos=1, retain=True),
        )


@dataclass(frozen=True)
class BridgeSettings:
    """What the bridge publishes and how often."""

    prefix: str = "marlin"
    name: str = "bridge"
    """The bridge's own topic level: its availability is `PREFIX/NAME/availability`. Bridges that share a broker
    and a prefix each need their own (else one's Last Will is the other's to correct, and a killed bridge's printers
    stay available in Home Assistant)."""
    rate_hz: float = 0.2
    """Telemetry messages per second and printer. One every 5 s by default: Home Assistant's recorder keeps every
    state change, and a temperature is a new state at nearly every reading."""
    discovery: bool = True
    discovery_prefix: str = "homeassistant"
    backoff_start_s: float = 1.0
    backoff_max_s: float = 30.0
    allow_commands: bool = False
    """Take commands on `PREFIX/NAME/command` (off unless asked for)."""
    allowed_dir: Path | None = None
    """With commands: the directory prints may be started from (None: no prints over MQTT)."""
    telemetry_buffer: int = TELEMETRY_BUFFER
    """Telemetry messages kept per printer while the broker is slow or away; past it that printer's oldest is
    dropped (and counted)."""
    event_queue: int = EVENT_QUEUE
    """Events and answers kept until delivered; past it the oldest is lost (counted, and logged)."""
    max_command_age_s: float = MAX_COMMAND_AGE_S
    """A command with a `time` older (or further in the future) than this is refused."""
    presets: tuple[Preset, ...] = DEFAULT_PRESETS
    """What a `preset` command may name (`marlin-temp farm` gives the presets file's); with commands, Home
    Assistant gets a button for each."""
    batch_telemetry: bool = True
    """Hand each batch of telemetry to paho as one write (through two private names of aiomqtt's and paho's,
    `telemetry.TelemetryLane.publish`); False sends every message with paho's public `publish`, what the benchmarks'
    row "through paho's public API" measures."""

    def topic(self, printer: str, leaf: str) -> str:
        """`prefix/printer/leaf`."""
        return f"{self.prefix}/{printer}/{leaf}"

    @property
    def bridge_availability_topic(self) -> str:
        """The bridge's own availability (its Last Will sets it offline)."""
        return f"{self.prefix}/{self.name}/availability"
