"""parse_temperatures: every field Marlin prints in M105 replies, auto-reports and M109/M190 wait lines."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from marlin_aio.protocol.temperatures import HeaterReading, Temperatures, parse_fields, parse_temperatures


def parse(text: str) -> Temperatures:
    parsed = parse_temperatures(text)
    assert parsed is not None
    return parsed


def test_m105_reply_fields() -> None:
    parsed = parse("T:21.50 /0.00 B:21.30 /0.00 @:0 B@:0")
    assert parsed == Temperatures(
        heaters={"T": HeaterReading(21.5, 0.0, 0), "B": HeaterReading(21.3, 0.0, 0)},
        waiting=False,
        wait_remaining_s=None,
    )


@pytest.mark.parametrize("letter", ["T", "T0", "T1", "T7", "T12", "B", "C", "L", "P", "M", "R"])
def test_every_sensor_letter_with_its_target(letter: str) -> None:
    parsed = parse(f" {letter}:35.25 /60.50")
    assert parsed.heaters == {letter: HeaterReading(actual=35.25, target=60.5)}


def test_all_sensors_on_one_line() -> None:
    parsed = parse(
        "T:200.10 /200.00 B:60.20 /60.00 C:30.30 /35.00 L:10.40 /12.00 P:25.50 /0.00 M:40.60 /0.00 R:199.70 /0.00 "
        "T0:200.10 /200.00 T1:150.80 /160.00 @:90 B@:127 C@:12 @0:90 @1:100"
    )
    assert parsed.heaters == {
        "T": HeaterReading(200.1, 200.0, 90),
        "B": HeaterReading(60.2, 60.0, 127),
        "C": HeaterReading(30.3, 35.0, 12),
        "L": HeaterReading(10.4, 12.0),
        "P": HeaterReading(25.5, 0.0),
        "M": HeaterReading(40.6, 0.0),
        "R": HeaterReading(199.7, 0.0),
        "T0": HeaterReading(200.1, 200.0, 90),
        "T1": HeaterReading(150.8, 160.0, 100),
    }


def test_multi_extruder_report_from_the_protocol_doc() -> None:
    parsed = parse("T:200.0 /200.0 B:60.0 /60.0 T0:200.0 /200.0 T1:25.0 /0.0 @:64 B@:0 @0:64 @1:0")
    assert parsed.heaters["T0"] == HeaterReading(actual=200.0, target=200.0, power=64)
    assert parsed.heaters["T1"] == HeaterReading(actual=25.0, target=0.0, power=0)
    assert parsed.hotend == HeaterReading(actual=200.0, target=200.0, power=64)


def test_repetier_report_without_targets() -> None:
    parsed = parse("T:21.50 B:21.30 @:0 B@:0")
    assert parsed.heaters == {"T": HeaterReading(21.5, None, 0), "B": HeaterReading(21.3, None, 0)}


def test_powers_go_to_the_right_heater() -> None:
    # `@:` is the active hotend, `@0:`/`@1:` the numbered ones, `B@:` the bed, `C@:` the chamber: different numbers
    # for each, so a power given to the wrong heater shows.
    parsed = parse("T:1.00 /0.00 T0:2.00 /0.00 T1:3.00 /0.00 B:4.00 /0.00 C:5.00 /0.00 @:11 @0:22 @1:33 B@:44 C@:55")
    powers = {key: reading.power for key, reading in parsed.heaters.items()}
    assert powers == {"T": 11, "T0": 22, "T1": 33, "B": 44, "C": 55}


def test_power_without_a_reading_is_dropped() -> None:
    parsed = parse("T:1.00 /0.00 @:11 B@:44")
    assert parsed.heaters == {"T": HeaterReading(1.0, 0.0, 11)}


def test_sensor_without_power_has_none() -> None:
    parsed = parse("T:1.00 /0.00 B:2.00 /3.00 @:11")
    assert parsed.heaters["B"].power is None


@pytest.mark.parametrize(
    ("text", "waiting", "remaining"),
    [
        (" T:196.82 /200.00 B:36.33 /60.00 @:26 B@:127 W:?", True, None),
        (" T:199.03 /200.00 B:38.50 /60.00 @:18 B@:127 W:9", True, 9.0),
        (" T:200.56 /200.00 B:41.76 /60.00 @:17 B@:127 W:0", True, 0.0),
        (" T:196.82 /200.00 B:36.33 /60.00 @:26 B@:127", False, None),
    ],
)
def test_wait_field(text: str, waiting: bool, remaining: float | None) -> None:
    parsed = parse(text)
    assert parsed.waiting is waiting
    assert parsed.wait_remaining_s == remaining
    assert set(parsed.heaters) == {"T", "B"}  # W is not a sensor


def test_raw_adc_values_in_parentheses() -> None:
    parsed = parse("T:21.50 /0.00 (4011.00) B:21.30 /0.00 (3999.50) @:0 B@:0")
    assert parsed.heaters["T"] == HeaterReading(21.5, 0.0, 0, raw=4011.0)
    assert parsed.heaters["B"] == HeaterReading(21.3, 0.0, 0, raw=3999.5)


def test_raw_adc_value_without_target() -> None:
    assert parse("T:21.50 (4011.00)").heaters["T"] == HeaterReading(21.5, None, None, raw=4011.0)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("T:-14.00 /0.00", HeaterReading(-14.0, 0.0)),
        ("T:-0.50 /-1.00", HeaterReading(-0.5, -1.0)),
        ("T:-273.15 /0.00 (0.00)", HeaterReading(-273.15, 0.0, raw=0.0)),
    ],
)
def test_negative_values(text: str, expected: HeaterReading) -> None:
    assert parse(text).heaters["T"] == expected


@pytest.mark.parametrize(
    "text",
    ["T:21.30/ 190.00", "T:21.30 /190.00", "T:21.30/190.00", "T:21.30 / 190.00", "T: 21.30 /190.00"],
)
def test_spacing_variants(text: str) -> None:
    assert parse(text + " B:20.00 /0.00").heaters == {
        "T": HeaterReading(21.3, 190.0),
        "B": HeaterReading(20.0, 0.0),
    }


def test_reading_without_target() -> None:
    assert parse("T:21.30 B:20.00").heaters == {"T": HeaterReading(21.3), "B": HeaterReading(20.0)}


def test_unknown_fields_are_ignored() -> None:
    parsed = parse("T:21.30 /0.00 X:5.00 /1.00 E0:3.00 /0.00 Q@:7 A:1 B:20.00 /0.00 FOO:bar @:3 B@:4 D:?")
    assert parsed.heaters == {"T": HeaterReading(21.3, 0.0, 3), "B": HeaterReading(20.0, 0.0, 4)}


def test_field_letters_inside_words_are_not_fields() -> None:
    # `B@:` must not be read as `@:`, `TB:` is not `B:`.
    parsed = parse("T:1.00 /0.00 TB:9.00 /9.00 B@:44")
    assert parsed.heaters == {"T": HeaterReading(1.0, 0.0)}


@pytest.mark.parametrize("text", ["", "   ", "@:0 B@:0", "W:?", "ok", "ok P15 B3", "X:1.00 Y:2.00 Z:3.00", "T:", "T:?"])
def test_no_sensor_gives_none(text: str) -> None:
    assert parse_temperatures(text) is None


@pytest.mark.parametrize(
    ("power", "fraction"),
    [(None, None), (0, 0.0), (127, 1.0), (64, 64 / 127), (255, 1.0), (-3, 0.0)],
)
def test_power_fraction(power: int | None, fraction: float | None) -> None:
    reading = HeaterReading(actual=20.0, target=0.0, power=power)
    if fraction is None:
        assert reading.power_fraction is None
    else:
        assert reading.power_fraction == pytest.approx(fraction)


def test_hotend_is_t() -> None:
    parsed = parse("T:201.00 /200.00 T0:199.00 /200.00 B:60.00 /60.00 C:30.00 /0.00")
    assert parsed.hotend == HeaterReading(201.0, 200.0)
    assert parsed.bed == HeaterReading(60.0, 60.0)
    assert parsed.chamber == HeaterReading(30.0, 0.0)


def test_hotend_falls_back_to_t0() -> None:
    parsed = parse("T0:199.00 /200.00 T1:150.00 /0.00 B:60.00 /60.00")
    assert parsed.hotend == HeaterReading(199.0, 200.0)


def test_missing_heaters_are_none() -> None:
    parsed = parse("B:60.00 /60.00")
    assert parsed.hotend is None
    assert parsed.chamber is None
    assert parsed.bed == HeaterReading(60.0, 60.0)


# ----------------------------------------------------------------------------------------------- round trip

_SENSORS = ["T", "T0", "T1", "T2", "B", "C", "L", "P", "M", "R"]
_POWER_KEYS = {"T": "@", "T0": "@0", "T1": "@1", "T2": "@2", "B": "B@", "C": "C@"}
_CENTI = st.integers(min_value=-5_000, max_value=50_000)  # hundredths of a degree: Marlin prints two decimals


@st.composite
def reports(draw: st.DrawFn) -> tuple[dict[str, HeaterReading], bool, float | None]:
    keys = draw(st.lists(st.sampled_from(_SENSORS), min_size=1, unique=True))
    heaters: dict[str, HeaterReading] = {}
    for key in keys:
        power = draw(st.none() | st.integers(min_value=0, max_value=127)) if key in _POWER_KEYS else None
        raw = draw(st.none() | st.integers(min_value=0, max_value=409_600).map(lambda c: c / 100))
        heaters[key] = HeaterReading(draw(_CENTI) / 100, draw(_CENTI) / 100, power, raw)
    waiting = draw(st.booleans())
    remaining = draw(st.none() | st.integers(min_value=0, max_value=60).map(float)) if waiting else None
    return heaters, waiting, remaining


def format_report(heaters: dict[str, HeaterReading], waiting: bool, remaining: float | None) -> str:
    """Marlin's layout: the sensors with two decimals, then the powers, then the wait countdown."""
    parts = []
    for key, reading in heaters.items():
        parts.append(f"{key}:{reading.actual:.2f} /{reading.target:.2f}")
        if reading.raw is not None:
            parts.append(f"({reading.raw:.2f})")
    parts += [f"{_POWER_KEYS[key]}:{reading.power}" for key, reading in heaters.items() if reading.power is not None]
    if waiting:
        parts.append("W:?" if remaining is None else f"W:{remaining:.0f}")
    return " " + " ".join(parts)


@settings(max_examples=200, deadline=None)
@given(reports())
def test_round_trip(report: tuple[dict[str, HeaterReading], bool, float | None]) -> None:
    heaters, waiting, remaining = report
    text = format_report(heaters, waiting, remaining)
    assert parse_temperatures(text) == Temperatures(heaters=heaters, waiting=waiting, wait_remaining_s=remaining)
    assert parse_temperatures("ok" + text) == Temperatures(heaters=heaters, waiting=waiting, wait_remaining_s=remaining)


def test_a_report_from_text_parses_on_first_read_and_equals_the_eager_one() -> None:
    text = "T:21.50 /200.00 B:60.10 /60.00 @:127 B@:40 W:7"
    lazy = Temperatures.from_text(text)
    assert lazy._heaters is None  # nothing parsed yet
    assert lazy.waiting is True and lazy.wait_remaining_s == 7.0
    assert lazy == parse_temperatures(text)
    assert lazy.hotend == HeaterReading(actual=21.5, target=200.0, power=127)
    assert Temperatures.from_text("T:abc").heaters == {}


_CELSIUS = st.sampled_from(["0.00", "21.50", "-3.25", "199.87", "1000.12", "5.0", "5", "nan", "1" * 30 + ".5"])


@settings(max_examples=300, deadline=None)
@given(
    st.tuples(_CELSIUS, _CELSIUS),
    st.none() | st.tuples(_CELSIUS, _CELSIUS),
    st.sampled_from(["0", "64", "127", "1" * 12]),
    st.none() | st.integers(0, 127),
    st.sampled_from(["", " ", "\t"]),
    st.sampled_from(["", " ", " \t"]),
)
def test_the_fast_path_for_the_common_report_reads_what_the_general_parser_reads(
    hotend: tuple[str, str],
    bed: tuple[str, str] | None,
    power: str,
    bed_power: int | None,
    before: str,
    after: str,
) -> None:
    # The one-hotend report (`T:.. /.. B:.. /.. @:.. B@:..`) skips the general loop; it must not read differently.
    text = f"{before}T:{hotend[0]} /{hotend[1]}"
    if bed is not None:
        text += f" B:{bed[0]} /{bed[1]}"
    text += f" @:{power}"
    if bed_power is not None:
        text += f" B@:{bed_power}"
    text += after
    assert repr(parse_temperatures(text)) == repr(parse_fields(text))  # repr: nan == nan
