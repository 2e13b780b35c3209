"""The service's wire format (`marlin_aio.protocol.rpc`), with no I/O: values survive the trip, errors come back
as the same types, and any bytes either decode to an object or raise `RpcError`."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

import marlin_aio
from marlin_aio.protocol import ReadingSource, parse_temperatures, rpc
from marlin_aio.protocol.events import Ok
from marlin_aio.protocol.printjob import PrintProgress, PrintState


def test_a_reading_survives_the_trip() -> None:
    temperatures = parse_temperatures("T:200.50 /210.00 B:60.00 /60.00 T0:200.50 /210.00 T1:25.00 /0.00 @:127 B@:0")
    assert temperatures is not None
    reading = marlin_aio.TemperatureReading(temperatures, 12.0, 1_700_000_000.5, ReadingSource.POLL)
    back = rpc.reading_from_json(json.loads(json.dumps(rpc.reading_to_json(reading))), 99.0)
    assert back.temperatures.heaters == reading.temperatures.heaters
    assert (back.wall_time_s, back.source, back.monotonic_s) == (reading.wall_time_s, ReadingSource.POLL, 99.0)


def test_a_reply_and_a_progress_survive_the_trip() -> None:
    reply = marlin_aio.Reply("M105", ("echo:x",), Ok(payload="T:20.00 /0.00 B:21.00 /0.00"), 1.0, 1.25)
    back = rpc.reply_from_json(json.loads(json.dumps(rpc.reply_to_json(reply))))
    assert (back.command, back.lines, back.latency_s) == ("M105", ("echo:x",), 0.25)
    assert back.temperatures is not None and back.temperatures.bed is not None
    assert back.temperatures.bed.actual == 21.0
    progress = PrintProgress(PrintState.PAUSED, 10, 9, 100, 90, 80, 800, 3.5, 1, 12)
    assert rpc.progress_from_json(json.loads(json.dumps(rpc.progress_to_json(progress)))) == progress


@pytest.mark.parametrize(
    "error",
    [
        marlin_aio.CommandTimeoutError("no ok", command="G28"),
        marlin_aio.ThermalRunawayError("Thermal Runaway, system stopped! Heater_ID: 0"),
        marlin_aio.HandshakeTimeoutError("no banner", step="boot"),
        marlin_aio.PrintStalledError("stalled at line 5", command="G1 X1", trace="..."),
        marlin_aio.PortNotFoundError("no printer named 'x'"),
        ValueError("hotend target 900 C is above the limit of 260 C"),
        RuntimeError("a print is already running"),
        FileNotFoundError("no such file"),
    ],
    ids=lambda error: type(error).__name__,
)
def test_an_error_comes_back_as_its_own_type(error: Exception) -> None:
    back = rpc.error_from_json(json.loads(json.dumps(rpc.error_to_json(error))))
    assert type(back) is type(error)
    assert str(back) == str(error)
    if isinstance(error, marlin_aio.CommandTimeoutError):
        assert back.command == error.command  # type: ignore[attr-defined]


def test_an_error_of_no_known_type_comes_back_as_its_nearest() -> None:
    class Odd(marlin_aio.PrinterResetError):
        pass

    assert type(rpc.error_from_json(rpc.error_to_json(Odd("reset")))) is marlin_aio.PrinterResetError
    assert isinstance(rpc.error_from_json({"code": 1}), ValueError)
    assert isinstance(rpc.error_from_json("nonsense"), marlin_aio.RemoteProtocolError)


@given(st.binary(max_size=300))
def test_any_bytes_decode_to_an_object_or_raise_rpc_error(data: bytes) -> None:
    try:
        message = rpc.decode_message(data)
    except rpc.RpcError as exc:
        assert exc.code in (rpc.PARSE_ERROR, rpc.INVALID_REQUEST)  # noqa: PT017  (a property: either outcome)
    else:
        assert isinstance(message, dict)


@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.text(), lambda c: st.lists(c) | st.dictionaries(st.text(), c)
    )
)
def test_any_json_shape_for_a_value_is_a_reading_or_invalid_params(value: object) -> None:
    try:
        rpc.reading_from_json(value, 0.0)
    except rpc.RpcError as exc:
        assert exc.code == rpc.INVALID_PARAMS  # noqa: PT017  (a property: either outcome)


def test_encoding_refuses_what_json_cannot_carry_and_what_is_too_long() -> None:
    with pytest.raises(ValueError, match="JSON compliant"):
        rpc.encode_message({"x": float("nan")})
    with pytest.raises(ValueError, match="over the limit"):
        rpc.encode_message({"x": "a" * rpc.MAX_MESSAGE_BYTES})
    assert rpc.encode_message({"x": "\n\u2028é"}).count(b"\n") == 1  # one line, whatever the text
