"""Presets: named targets (PLA, PETG, ...) read from a small TOML file, in the file's order.

    [preset.PLA]
    hotend = 200
    bed = 60

    [preset.cooldown]
    hotend = 0
    bed = 0

Each preset has a hotend and/or a bed target in degrees C (0 turns that heater off). `marlin-temp set --preset`,
watch's keys 1-9 and the farm's `preset` command all read the same `Preset`s; with no file they use
`DEFAULT_PRESETS`, which is what `presets_toml(DEFAULT_PRESETS)` writes.

It lives with the farm because the farm's MQTT bridge takes presets and the library never imports the CLI; it reads
no file but the one it is given and imports nothing beyond the standard library and the protocol's target check,
so `marlin-temp set` loads it without the farm's MQTT extra.

The file's shape is checked here, whole (not TOML, an unknown section or key, a target that is not a number or is
negative, a bad or repeated name); a target is checked against a printer's limits only when that preset is used
(`preset_targets`), since one file serves printers with different limits.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from marlin_aio.protocol import HeaterLimits, check_target

__all__ = [
    "DEFAULT_PRESETS",
    "PRESET_HEATERS",
    "PRESET_NAME_RULE",
    "Preset",
    "find_preset",
    "load_presets",
    "parse_presets",
    "preset_targets",
    "presets_toml",
]

PRESET_HEATERS = ("hotend", "bed")
"""The keys a preset may have, each a target in degrees C."""
PRESET_NAME_RULE = "1 to 32 letters, digits, '_', '-', '+' or '.', starting with a letter or a digit"
# Not starting with '-', which the command line would read as an option (`--preset -x`).
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_+.-]{0,31}")
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


@dataclass(frozen=True, slots=True)
class Preset:
    """A named pair of targets (None: the preset leaves that heater alone)."""

    name: str
    hotend_celsius: float | None = None
    bed_celsius: float | None = None

    def targets(self) -> dict[str, float]:
        """The targets it sets, by heater ("hotend", "bed")."""
        pairs = (("hotend", self.hotend_celsius), ("bed", self.bed_celsius))
        return {heater: celsius for heater, celsius in pairs if celsius is not None}

    def describe(self) -> str:
        """ "hotend 200 C, bed 60 C" for lists and messages."""
        return ", ".join(f"{heater} {celsius:g} C" for heater, celsius in self.targets().items())


DEFAULT_PRESETS = (
    Preset("PLA", 200.0, 60.0),
    Preset("PETG", 240.0, 80.0),
    Preset("ABS", 250.0, 100.0),
    Preset("cooldown", 0.0, 0.0),
)
"""The presets when there is no file (and what `marlin-temp presets --init` writes)."""


def parse_presets(text: str, source: str) -> tuple[Preset, ...]:
    """The presets of a presets file's text, in its order; `source` (the file's path) starts every message.

    Raises:
        ValueError: one line naming `source`, the preset and the key: not TOML, a section other than [preset.NAME],
            a key other than hotend and bed, a target that is not a number or is negative, a bad name, a name given
            twice (in any case), a preset with no target, or no preset at all.
    """
    import tomllib  # when a file is read, not for every command's --help

    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{source}: not valid TOML: {exc}") from None
    unknown = [key for key in document if key != "preset"]
    if unknown:
        raise ValueError(f"{source}: unknown section {unknown[0]!r} (a presets file has [preset.NAME] tables only)")
    tables = document.get("preset", {})
    if not isinstance(tables, dict) or not tables:
        raise ValueError(f"{source}: no presets: add a [preset.NAME] table with hotend = C and/or bed = C")
    presets = []
    seen: dict[str, str] = {}
    for name, values in tables.items():
        where = f"{source}: preset {name!r}"
        if not _NAME.fullmatch(name):
            raise ValueError(f"{where}: a name is {PRESET_NAME_RULE}")
        if name.casefold() in seen:
            # Names are looked up whatever their case (`--preset pla`), so two that differ only in case clash.
            raise ValueError(f"{where}: the same name as preset {seen[name.casefold()]!r} (case does not count)")
        seen[name.casefold()] = name
        if not isinstance(values, dict):
            raise ValueError(f"{where}: a preset is a table: [preset.{name}] with hotend = C and/or bed = C")
        targets: dict[str, float] = {}
        for key, value in values.items():
            if key not in PRESET_HEATERS:
                raise ValueError(f"{where}: unknown key {key!r} (known: {', '.join(PRESET_HEATERS)})")
            # A TOML string ("200") is refused too: the file says numbers, as the command line cannot.
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{where}: {key} must be a number of degrees C, got {value!r}")
            try:
                targets[key] = check_target(key, value, math.inf)
            except ValueError as exc:
                raise ValueError(f"{where}: {exc}") from None
        if not targets:
            raise ValueError(f"{where}: no target: give hotend = C and/or bed = C")
        presets.append(Preset(name, targets.get("hotend"), targets.get("bed")))
    return tuple(presets)


def load_presets(path: Path) -> tuple[Preset, ...]:
    """The presets of the file at `path`.

    Raises:
        ValueError: the file is not a valid presets file (the message names it, the preset and the key).
        OSError: it cannot be read.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not valid TOML: not UTF-8 text") from None
    return parse_presets(text, str(path))


def find_preset(presets: Iterable[Preset], name: str) -> Preset:
    """The preset called `name`, whatever its case.

    Raises:
        ValueError: no preset has that name (the message lists the names).
    """
    presets = tuple(presets)
    for preset in presets:
        if preset.name.casefold() == name.casefold():
            return preset
    names = ", ".join(preset.name for preset in presets) or "none"
    raise ValueError(f"no preset named {name!r} (presets: {names})")


def preset_targets(preset: Preset, limits: HeaterLimits) -> dict[str, float]:
    """The preset's targets, each checked against `limits`.

    Raises:
        ValueError: a target above its limit ("preset 'ABS': hotend target 300 C is above the limit of 260 C").
    """
    targets = preset.targets()
    for heater, celsius in targets.items():
        try:
            check_target(heater, celsius, limits.of(heater))
        except ValueError as exc:
            raise ValueError(f"preset {preset.name!r}: {exc}") from None
    return targets


def presets_toml(presets: Iterable[Preset]) -> str:
    """A presets file's text listing `presets` (`parse_presets` reads it back as the same presets)."""
    lines = [
        "# marlin-temp presets: set --preset NAME, watch's keys 1-9 (in this order), the farm's preset command.",
        "# Each [preset.NAME] has hotend and/or bed, in degrees C (0 turns that heater off).",
    ]
    for preset in presets:
        key = preset.name if _BARE_KEY.fullmatch(preset.name) else json.dumps(preset.name)
        lines += ["", f"[preset.{key}]"]
        lines += [f"{heater} = {_number(celsius)}" for heater, celsius in preset.targets().items()]
    return "\n".join(lines) + "\n"


def _number(celsius: float) -> str:
    # Whole degrees as integers (`200`, as a person writes them); others exactly, so the file reads back the same.
    return str(int(celsius)) if celsius.is_integer() else repr(celsius)
