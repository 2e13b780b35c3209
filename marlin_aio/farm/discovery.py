"""Home Assistant MQTT discovery: the retained config messages that make each printer a device with its sensors and,
with commands on, its target numbers and buttons."""

from __future__ import annotations

import json
import math
from typing import Any

import marlin_aio

from .bridgesettings import BridgeSettings
from .presets import Preset
from .supervisor import FarmPrinter

__all__ = ["discovery_messages", "heater_slug", "preset_slugs"]


def heater_slug(name: str) -> str:
    """A heater's name as a topic or entity id part: `"hotend 0"` gives `"hotend_0"`."""
    return name.replace(" ", "_")


def preset_slugs(presets: tuple[Preset, ...]) -> list[tuple[str, Preset]]:
    """Each preset with the id its Home Assistant button gets: its name in lower case, `+` as `plus` and other
    signs as `_` ("PLA+" is `pla_plus`), numbered where two would be the same ("a-b" and "a.b")."""
    slugs: list[tuple[str, Preset]] = []
    taken: set[str] = set()
    for preset in presets:
        base = "".join(c if c.isalnum() else "_" for c in preset.name.lower().replace("+", "_plus"))
        slug, number = base, 2
        while slug in taken:
            slug, number = f"{base}_{number}", number + 1
        taken.add(slug)
        slugs.append((slug, preset))
    return slugs


def discovery_messages(
    settings: BridgeSettings, farm_printer: FarmPrinter, heaters: tuple[str, ...]
) -> list[tuple[str, dict[str, Any]]]:
    """Home Assistant MQTT discovery for one printer: a device with, per heater, a temperature sensor, a target
    sensor and a power sensor, a link sensor and a sensor of the open prompt's message; each available while
    the bridge and the printer are. With commands on, also a number per heater target, a button per preset and
    the emergency stop button.

    As Home Assistant's MQTT documentation asks: an `origin` (this software and its version), the device's
    firmware as `sw_version`, `device_class: temperature` on temperatures and target numbers, no device class on
    a heater's power (a duty cycle in percent is not one of the classes), and `expire_after` on the telemetry
    sensors so a bridge that hangs without dying shows its readings as unavailable.
    """
    name = farm_printer.name
    node = f"marlin_{name}"
    device: dict[str, Any] = {
        "identifiers": [node],
        "name": name,
        "manufacturer": "Marlin",
        "model": farm_printer.machine or "Marlin printer",
    }
    if farm_printer.firmware:
        device["sw_version"] = farm_printer.firmware
    availability = [
        {"topic": settings.bridge_availability_topic},
        {"topic": settings.topic(name, "availability")},
    ]
    base = {
        "device": device,
        "origin": {"name": "marlin_aio", "sw_version": marlin_aio.__version__},
        "availability": availability,
        "availability_mode": "all",
    }
    # Ten telemetry periods, and a minute at least: missed messages at QoS 0 are not an outage.
    expire_after = max(60, math.ceil(10 / settings.rate_hz))
    messages: list[tuple[str, dict[str, Any]]] = []
    prefix = settings.discovery_prefix
    for heater in heaters:
        slug = heater_slug(heater)
        for what, unit, device_class, label in (
            ("actual", "°C", "temperature", heater),
            ("target", "°C", "temperature", f"{heater} target"),
            ("power_percent", "%", None, f"{heater} power"),
        ):
            object_id = f"{slug}_{what}"
            config = base | {
                "name": label,
                "unique_id": f"{node}_{object_id}",
                "state_topic": settings.topic(name, "telemetry"),
                "value_template": f"{{{{ value_json.heaters['{heater}'].{what} }}}}",
                "unit_of_measurement": unit,
                "state_class": "measurement",
                "expire_after": expire_after,
            }
            if device_class is not None:
                config["device_class"] = device_class
            messages.append((f"{prefix}/sensor/{node}/{object_id}/config", config))
    if settings.allow_commands:
        spec = farm_printer.spec
        for heater in heaters:
            slug = heater_slug(heater)
            limit = {"bed": spec.max_bed_celsius, "chamber": spec.max_chamber_celsius}.get(
                heater, spec.max_hotend_celsius
            )
            command = json.dumps({"action": "set_target", "heater": heater, "celsius": 0})
            messages.append(
                (
                    f"{prefix}/number/{node}/{slug}_target/config",
                    base
                    | {
                        "name": f"{heater} target",
                        "unique_id": f"{node}_{slug}_target_set",
                        "command_topic": settings.topic(name, "command"),
                        # Home Assistant fills in the number: the same check as any command applies.
                        "command_template": command.replace('"celsius": 0', '"celsius": {{ value }}'),
                        "state_topic": settings.topic(name, "telemetry"),
                        "value_template": f"{{{{ value_json.heaters['{heater}'].target }}}}",
                        "min": 0,
                        "max": limit,
                        "step": 1,
                        "mode": "box",
                        "unit_of_measurement": "°C",
                        "device_class": "temperature",
                    },
                )
            )
        for slug, preset in preset_slugs(settings.presets):
            messages.append(
                (
                    f"{prefix}/button/{node}/preset_{slug}/config",
                    base
                    | {
                        "name": f"preset {preset.name}",
                        "unique_id": f"{node}_preset_{slug}",
                        "command_topic": settings.topic(name, "command"),
                        "payload_press": json.dumps({"action": "preset", "name": preset.name}),
                    },
                )
            )
        messages.append(
            (
                f"{prefix}/button/{node}/emergency_stop/config",
                base
                | {
                    "name": "emergency stop",
                    "unique_id": f"{node}_emergency_stop",
                    "command_topic": settings.topic(name, "command"),
                    "payload_press": json.dumps({"action": "emergency_stop"}),
                },
            )
        )
    messages.append(
        (
            f"{prefix}/sensor/{node}/print_progress/config",
            base
            | {
                "name": "print progress",
                "unique_id": f"{node}_print_progress",
                "state_topic": settings.topic(name, "state"),
                "value_template": "{{ value_json.print.percent if value_json.print else 0 }}",
                "unit_of_measurement": "%",
                "state_class": "measurement",
            },
        )
    )
    messages.append(
        (
            f"{prefix}/sensor/{node}/prompt/config",
            base
            | {
                "name": "prompt",
                "unique_id": f"{node}_prompt",
                "state_topic": settings.topic(name, "state"),
                # What the printer asks of a person (a filament change), else empty: an automation's trigger.
                "value_template": "{{ value_json.prompt.message if value_json.prompt else '' }}",
            },
        )
    )
    messages.append(
        (
            f"{prefix}/sensor/{node}/link/config",
            base
            | {
                "name": "link",
                "unique_id": f"{node}_link",
                "state_topic": settings.topic(name, "state"),
                "value_template": "{{ value_json.link }}",
                "availability": [{"topic": settings.bridge_availability_topic}],
            },
        )
    )
    return messages
