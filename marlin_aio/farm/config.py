"""The farm's printers from the command line (`--port NAME=PORT`, `--sims N`) or a TOML file, checked before
anything is opened.

A TOML file lists printers under `[[printer]]`, with defaults for all of them under `[defaults]`:

    [defaults]
    baud = 250000
    poll_interval_s = 0.1

    [[printer]]
    name = "prusa-1"
    port = "/dev/serial/by-id/usb-Prusa_Research_Original_Prusa_i3_MK3-if00"
    max_hotend_celsius = 280

    [[printer]]
    name = "ender"
    port = "/dev/ttyUSB1"
    baud = 115200

Names become MQTT topic levels and Home Assistant ids, so they are letters, digits, `-` and `_`. A locked
printer (Marlin's PASSWORD_FEATURE) gets `password = "1234"`, which is sent as `M511 P1234` and never printed,
logged or published (a quoted string: a number is refused without showing it).
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any

from .supervisor import RESERVED_NAMES, PrinterSpec

__all__ = ["NAME_PATTERN", "NAME_RULE", "check_unique", "load_config", "specs_from_options"]

NAME_RULE = "letters, digits, '-' and '_' (it becomes an MQTT topic level)"
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
"""What a printer name may be (`NAME_RULE` says it in words)."""
_FIELDS = {
    "name": str,
    "port": str,
    "baud": int,
    "poll_interval_s": float,
    "timeout_s": float,
    "max_hotend_celsius": float,
    "max_bed_celsius": float,
    "max_chamber_celsius": float,
    "password": str,
}


def _check_name(name: str, where: str) -> str:
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(f"{where}: printer name {name!r} must be {NAME_RULE}")
    if name in RESERVED_NAMES:
        # `PREFIX/bridge/availability` is the bridge's own: a printer of that name would overwrite it.
        raise ValueError(f"{where}: printer name {name!r} is reserved (the bridge's own topic); choose another")
    return name


def _spec(values: dict[str, Any], where: str) -> PrinterSpec:
    unknown = sorted(set(values) - set(_FIELDS))
    if unknown:
        raise ValueError(f"{where}: unknown setting {unknown[0]!r} (known: {', '.join(_FIELDS)})")
    checked: dict[str, Any] = {}
    for key, value in values.items():
        kind = _FIELDS[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or isinstance(value, bool):
            what = {int: "a whole number", float: "a number", str: "a string"}[kind]
            # A password is never shown, not even a mistyped one (`password = 1234` without quotes).
            shown = "something else (not shown)" if key == "password" else repr(value)
            raise ValueError(f"{where}: {key} must be {what}, got {shown}")
        checked[key] = value
    if "name" not in checked or "port" not in checked:
        raise ValueError(f"{where}: every printer needs a name and a port")
    _check_name(checked["name"], where)
    if checked.get("baud", 1) <= 0:
        raise ValueError(f"{where}: baud must be positive, got {checked['baud']}")
    for key in ("poll_interval_s", "timeout_s", "max_hotend_celsius", "max_bed_celsius", "max_chamber_celsius"):
        if key in checked and not (math.isfinite(checked[key]) and checked[key] > 0):
            raise ValueError(f"{where}: {key} must be a positive number, got {checked[key]}")
    return PrinterSpec(**checked)


def load_config(path: Path) -> list[PrinterSpec]:
    """The printers a TOML file lists.

    Raises:
        ValueError: the file is not TOML, or a printer is not valid (the message names which and why).
        OSError: it cannot be read.
    """
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    unknown = sorted(set(document) - {"defaults", "printer"})
    if unknown:
        raise ValueError(f"{path}: unknown section {unknown[0]!r} (use [defaults] and [[printer]])")
    defaults = document.get("defaults", {})
    printers = document.get("printer", [])
    if not isinstance(defaults, dict) or not isinstance(printers, list) or not printers:
        raise ValueError(f"{path}: list the printers as [[printer]] tables, each with a name and a port")
    specs = [_spec(defaults | entry, f"{path}: printer {index + 1}") for index, entry in enumerate(printers)]
    return check_unique(specs)


def specs_from_options(
    ports: list[str], sim: int, *, baud: int, poll_interval_s: float, sim_speed: float
) -> list[PrinterSpec]:
    """The printers of repeated `--port [NAME=]PORT` options and `--sims N` (named sim1, sim2, ...).

    Raises:
        ValueError: a bad name, a name or port given twice, or no printer at all.
    """
    specs: list[PrinterSpec] = []
    for index, text in enumerate(ports):
        name, sep, port = text.partition("=")
        if not sep or "://" in name:
            name, port = f"printer{index + 1}", text
        if not port.strip():
            raise ValueError(f"--port {text}: no port after the name (give NAME=PORT)")
        specs.append(
            PrinterSpec(name=_check_name(name, f"--port {text}"), port=port, baud=baud, poll_interval_s=poll_interval_s)
        )
    specs += [
        PrinterSpec(name=f"sim{index + 1}", port=None, poll_interval_s=poll_interval_s, sim=True, sim_speed=sim_speed)
        for index in range(sim)
    ]
    if not specs:
        raise ValueError("no printers: give --port [NAME=]PORT (repeatable), --config FILE or --sims N")
    return check_unique(specs)


def check_unique(specs: list[PrinterSpec]) -> list[PrinterSpec]:
    """Return `specs` if no name and no port is given twice.

    Raises:
        ValueError: a name or a port given twice.
    """
    seen_names: set[str] = set()
    seen_ports: set[str] = set()
    for spec in specs:
        if spec.name in seen_names:
            raise ValueError(f"printer name {spec.name!r} is given twice")
        seen_names.add(spec.name)
        if spec.port is not None:
            if spec.port in seen_ports:
                raise ValueError(f"port {spec.port} is given twice (one process per port)")
            seen_ports.add(spec.port)
    return specs
