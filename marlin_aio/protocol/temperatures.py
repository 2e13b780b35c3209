"""Temperature reports: the `T:21.50 /0.00 B:21.30 /0.00 @:0 B@:0` fields Marlin prints, parsed.

The same fields arrive three ways: after `ok` (M105), on their own line starting with a space (M155 auto-report),
and with ` W:` at the end while M109/M190 wait. One parser serves all three.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import StrEnum

__all__ = [
    "HEATER_NAMES",
    "HeaterReading",
    "ReadingSource",
    "TemperatureReading",
    "Temperatures",
    "heater_name",
    "parse_fields",
    "parse_temperatures",
]

#: Names for Marlin's sensor letters in reports; hotends by number are "hotend 0", "hotend 1".
HEATER_NAMES = {"T": "hotend", "B": "bed", "C": "chamber", "L": "cooler", "P": "probe", "M": "board", "R": "redundant"}


def heater_name(key: str) -> str:
    """The name of a report's heater key, for people: `"T0"` gives `"hotend 0"`, `"B"` gives `"bed"`."""
    if key[:1] == "T" and key[1:].isdigit():
        return f"hotend {key[1:]}"
    return HEATER_NAMES.get(key, key)


@dataclass(frozen=True, slots=True)
class HeaterReading:
    """One sensor: its temperature, target and heater power (0-127 in Marlin's soft PWM) in degrees Celsius."""

    actual: float
    target: float | None = None
    power: int | None = None
    raw: float | None = None  # the ADC value Marlin prints in parentheses when asked to

    @property
    def power_fraction(self) -> float | None:
        """Power as a fraction of full power (0.0-1.0), or None when not reported."""
        return None if self.power is None else min(max(self.power / 127.0, 0.0), 1.0)


class Temperatures:
    """All sensors of one report, keyed by Marlin's letter: T (active hotend), T0..Tn, B, C, L, P, M, R.

    `waiting` is true for M109/M190 wait lines; `wait_remaining_s` is their `W:` countdown (None for `W:?`).
    A report made with `Temperatures.from_text` parses its text the first time any of these is read: an M105
    answer nobody looks at (a stream's probe, a bare round trip) costs nothing to parse.
    """

    __slots__ = ("_heaters", "_remaining", "_text", "_waiting")

    def __init__(
        self, heaters: dict[str, HeaterReading], waiting: bool = False, wait_remaining_s: float | None = None
    ) -> None:
        self._heaters: dict[str, HeaterReading] | None = heaters
        self._waiting = waiting
        self._remaining = wait_remaining_s
        self._text = ""

    @classmethod
    def from_text(cls, text: str) -> Temperatures:
        """A report of the fields in `text`, parsed when first read (no sensor found gives no heaters)."""
        report = cls.__new__(cls)
        report._heaters = None
        report._waiting = False
        report._remaining = None
        report._text = text
        return report

    def _parse(self) -> dict[str, HeaterReading]:
        parsed = parse_temperatures(self._text)
        if parsed is None:
            self._heaters = {}
        else:
            self._heaters, self._waiting, self._remaining = parsed.heaters, parsed.waiting, parsed.wait_remaining_s
        return self._heaters

    @property
    def heaters(self) -> dict[str, HeaterReading]:
        """Every sensor reported, by letter."""
        heaters = self._heaters
        return heaters if heaters is not None else self._parse()

    @property
    def waiting(self) -> bool:
        """True for an M109/M190 wait line (it has `W:`)."""
        if self._heaters is None:
            self._parse()
        return self._waiting

    @property
    def wait_remaining_s(self) -> float | None:
        """The `W:` countdown in seconds, None for `W:?` or when not waiting."""
        if self._heaters is None:
            self._parse()
        return self._remaining

    @property
    def hotend(self) -> HeaterReading | None:
        """The active hotend (`T`), falling back to `T0`."""
        return self.heaters.get("T") or self.heaters.get("T0")

    @property
    def bed(self) -> HeaterReading | None:
        """The bed (`B`), if the printer has one."""
        return self.heaters.get("B")

    @property
    def chamber(self) -> HeaterReading | None:
        """The chamber (`C`), if the printer has one."""
        return self.heaters.get("C")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Temperatures):
            return NotImplemented
        return (self.heaters, self.waiting, self.wait_remaining_s) == (
            other.heaters,
            other.waiting,
            other.wait_remaining_s,
        )

    __hash__ = None  # type: ignore[assignment]  # mutable contents (a dict), like the dataclass it replaces

    def __repr__(self) -> str:
        return (
            f"Temperatures(heaters={self.heaters!r}, waiting={self.waiting!r}, "
            f"wait_remaining_s={self.wait_remaining_s!r})"
        )


_NUMBER = r"-?(?:\d+(?:\.\d*)?|\.\d+|inf|nan)"
# One field: a sensor `X:actual /target (raw)` or a power `X@:n` / `@n:n`, or `W:n|?`. The key must start a word:
# `B@:` must not be read as `@:` and ` W:` must not match inside another token.
_FIELD = re.compile(
    rf"(?<!\S)([TBCLPMR]?@\d*|[TBCLPMR]\d*|W):[ \t]*({_NUMBER}|\?)?"
    rf"(?:[ \t]*/[ \t]*({_NUMBER}))?(?:[ \t]*\(({_NUMBER})\))?"
)
_LEADING = re.compile(r"[ \t]*[TBC]\d*:")
# The report of a one-hotend printer, as Marlin prints it a hundred times a second when polled: `T:21.50 /0.00
# B:21.30 /0.00 @:0 B@:0` (the bed's part optional). Matched whole, it is read without the general loop below.
_PLAIN = r"-?\d+\.\d+"
_COMMON = re.compile(
    rf"[ \t]*T:({_PLAIN}) /({_PLAIN})(?: B:({_PLAIN}) /({_PLAIN}))? @:(\d{{1,9}})(?: B@:(\d{{1,9}}))?[ \t]*"
)


def looks_like_temperatures(text: str) -> bool:
    """Tell whether `text` (a line, or what follows `ok `) starts with a temperature field."""
    return _LEADING.match(text) is not None


def parse_temperatures(text: str) -> Temperatures | None:
    """Parse the temperature fields in `text`; return None when it holds no sensor reading.

    Fields the parser does not know are skipped, so a firmware that adds one does not break the rest.
    """
    common = _COMMON.fullmatch(text)
    if common is not None:
        actual, target, bed_actual, bed_target, power, bed_power = common.groups()
        heaters = {"T": HeaterReading(float(actual), float(target), int(power))}
        if bed_actual is not None:
            bed_power_127 = None if bed_power is None else int(bed_power)
            heaters["B"] = HeaterReading(float(bed_actual), float(bed_target), bed_power_127)
        return Temperatures(heaters)
    return parse_fields(text)


def parse_fields(text: str) -> Temperatures | None:
    """`parse_temperatures` without its fast path for the common report: every field, whatever the shape."""
    # findall with plain tuples is markedly cheaper than match objects.
    fields = _FIELD.findall(text)
    actual: dict[str, tuple[float, float | None, float | None]] = {}
    powers: dict[str, int] = {}
    waiting = False
    remaining: float | None = None
    for key, value, target, raw in fields:
        if not value or value == "?":
            if key == "W":
                waiting = True
            continue
        if key == "W":
            waiting = True
            remaining = float(value)
        elif "@" in key:
            power = float(value)
            if math.isfinite(power):  # `@:nan` from a confused board must not break the whole report
                # `@:` is the active hotend, `@0:` hotend 0, `B@:` the bed, `C@:` the chamber.
                letter, _, index = key.partition("@")
                powers[(letter or "T") + index] = int(power)
        else:
            actual[key] = (float(value), float(target) if target else None, float(raw) if raw else None)
    if not actual:
        return None
    heaters = {
        key: HeaterReading(actual=a, target=t, power=powers.get(key), raw=r) for key, (a, t, r) in actual.items()
    }
    return Temperatures(heaters=heaters, waiting=waiting, wait_remaining_s=remaining)


class ReadingSource(StrEnum):
    """What produced a temperature reading (a string too, so it compares with and prints as "poll" and so on)."""

    POLL = "poll"
    """The `ok T:...` of an M105."""
    AUTO = "auto"
    """An auto-report (M155)."""
    WAIT = "wait"
    """A wait line of M109/M190/M191."""
    LOG = "log"
    """Read back from a temperature log (`marlin-temp plot`), not from a printer."""


@dataclass(frozen=True, slots=True)
class TemperatureReading:
    """One temperature report as the client received it, stamped on arrival.

    `monotonic_s` is the event loop's clock (for intervals and rates), `wall_time_s` is `time.time()` (for logs).
    `source` says what produced it: an M105 reply, an auto-report or a wait line.
    """

    temperatures: Temperatures
    monotonic_s: float
    wall_time_s: float
    source: ReadingSource

    @property
    def hotend(self) -> HeaterReading | None:
        """The active hotend's reading."""
        return self.temperatures.hotend

    @property
    def bed(self) -> HeaterReading | None:
        """The bed's reading."""
        return self.temperatures.bed
