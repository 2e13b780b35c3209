"""The wire format of `marlin-temp serve`'s local API: JSON-RPC 2.0, one message per line, sans-I/O.

One process owns each printer (`marlin_aio.service`); its clients (`marlin_aio.connect("serve:NAME")`, any
program) send requests and get each answered by its own reply, matched by `id`, and receive notifications
(readings, console lines, print progress, link events) for what they subscribed to. A message is one JSON object
on one line (`\\n`-terminated, UTF-8), at most `MAX_MESSAGE_BYTES`: a reader never has to guess where one ends,
and a client in any language needs nothing but a socket and a JSON parser (Moonraker's API is the model, framed
by lines instead of Klipper's 0x03).

This module only turns values into messages and back: the service and the client do the I/O. What travels:

- a `TemperatureReading` as `{"heaters": {"T": [actual, target, power], ...}, "waiting", "remaining_s", "time_s",
  "source"}` (`reading_to_json`);
- a `Reply` as its command, lines, the `ok` line's payload and times (`reply_to_json`);
- a `PrintProgress` as its fields (`progress_to_json`), `paused_by` and `cancelled_by` with them;
- the firmware's requests (`HostRequest`, `Prompt`) and what is open now, as `{"request": {"action", "argument",
  "prompt"} | null, "prompt": {"message", "buttons"} | null, "waiting_for_user", "last_host_request"}`
  (`requests_to_json`);
- an error as JSON-RPC's `{"code", "message", "data": {"type": "CommandTimeoutError"}}`, so the client raises the
  same `MarlinError` subclass the printer's own link would have raised (`error_to_json`, `error_from_json`).
"""

from __future__ import annotations

import json
import math
from typing import Any

import marlin_aio.errors as errors
from marlin_aio.protocol.events import Ok
from marlin_aio.protocol.hostrequests import HostRequest, Prompt
from marlin_aio.protocol.printjob import PrintProgress, PrintState
from marlin_aio.protocol.replies import Reply
from marlin_aio.protocol.temperatures import (
    HeaterReading,
    ReadingSource,
    TemperatureReading,
    Temperatures,
    looks_like_temperatures,
)

__all__ = [
    "INTERNAL_ERROR",
    "INVALID_PARAMS",
    "INVALID_REQUEST",
    "MARLIN_ERROR",
    "MAX_MESSAGE_BYTES",
    "METHOD_NOT_FOUND",
    "PARSE_ERROR",
    "RpcError",
    "decode_message",
    "encode_message",
    "error_from_json",
    "error_to_json",
    "host_request_from_json",
    "host_request_to_json",
    "notification",
    "progress_from_json",
    "progress_to_json",
    "prompt_from_json",
    "prompt_to_json",
    "reading_from_json",
    "reading_to_json",
    "reply_from_json",
    "reply_to_json",
    "request",
    "requests_to_json",
    "response",
]

#: The longest message either side accepts, newline included: a G-code upload travels as a path, not inline.
MAX_MESSAGE_BYTES = 1 << 20

# JSON-RPC 2.0's own codes, and one of ours (the server's range) for everything the printer or link refused.
PARSE_ERROR = -32700
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
MARLIN_ERROR = -32000

#: The error types a reply may name: marlin_aio's own (raised again as themselves) and the built-ins a caller of
#: `Printer` also gets (a bad argument, a print already running, an unreadable file).
_ERROR_TYPES: dict[str, type[Exception]] = {
    **{name: getattr(errors, name) for name in errors.__all__},
    "ValueError": ValueError,
    "RuntimeError": RuntimeError,
    "OSError": OSError,
    "FileNotFoundError": FileNotFoundError,
    "PermissionError": PermissionError,
}


class RpcError(Exception):
    """A request the service could not take as a request: not JSON, no such method, parameters that do not fit.

    `code` is JSON-RPC's (`PARSE_ERROR`, `INVALID_REQUEST`, `METHOD_NOT_FOUND`, `INVALID_PARAMS`).
    """

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def encode_message(message: dict[str, Any]) -> bytes:
    """`message` as one line of compact JSON (ASCII, so a control character never breaks the line).

    Raises:
        ValueError: it is longer than `MAX_MESSAGE_BYTES`, or holds a value JSON cannot carry (NaN).
    """
    data = json.dumps(message, separators=(",", ":"), allow_nan=False).encode("ascii") + b"\n"
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message of {len(data)} bytes is over the limit of {MAX_MESSAGE_BYTES}")
    return data


def decode_message(line: bytes) -> dict[str, Any]:
    """One received line as a JSON object.

    Raises:
        RpcError: `PARSE_ERROR` for what is not JSON (or not an object, or nested past reason).
    """
    try:
        message = json.loads(line, parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:
        raise RpcError(PARSE_ERROR, f"not JSON: {_first_line(str(exc))}") from None
    if not isinstance(message, dict):
        raise RpcError(INVALID_REQUEST, f"a message is a JSON object, got {type(message).__name__}")
    return message


def _no_constant(name: str) -> object:
    # JSON has no NaN or Infinity; Python's parser takes them, and an infinite timeout would be a wait for ever.
    raise ValueError(f"{name} is not a JSON number")


def request(request_id: int, method: str, params: dict[str, Any]) -> dict[str, Any]:
    """A request that expects a response with `request_id`."""
    return {"jsonrpc": "2.0", "id": request_id, "method": method, "params": params}


def notification(method: str, params: dict[str, Any]) -> dict[str, Any]:
    """A message that expects no response (the service's readings, console lines, progress and link events)."""
    return {"jsonrpc": "2.0", "method": method, "params": params}


def response(request_id: object, result: object = None, error: dict[str, Any] | None = None) -> dict[str, Any]:
    """The response to `request_id`: its result, or its error (`error_to_json`)."""
    if error is not None:
        return {"jsonrpc": "2.0", "id": request_id, "error": error}
    return {"jsonrpc": "2.0", "id": request_id, "result": result}


def error_to_json(exc: BaseException) -> dict[str, Any]:
    """A JSON-RPC error object for `exc`: its JSON-RPC code for an `RpcError`, else `MARLIN_ERROR` with the type
    named so the client raises the same one."""
    if isinstance(exc, RpcError):
        return {"code": exc.code, "message": str(exc)}
    kind = type(exc).__name__ if type(exc).__name__ in _ERROR_TYPES else _nearest(exc)
    data: dict[str, Any] = {"type": kind}
    step = getattr(exc, "step", None)
    if isinstance(step, str):
        data["step"] = step
    command = getattr(exc, "command", None)
    if isinstance(command, str):
        data["command"] = command
    return {"code": MARLIN_ERROR, "message": str(exc), "data": data}


def _nearest(exc: BaseException) -> str:
    for cls in type(exc).__mro__:
        if cls.__name__ in _ERROR_TYPES and _ERROR_TYPES[cls.__name__] is cls:
            return cls.__name__
    return "MarlinError"


def error_from_json(error: object) -> Exception:
    """The exception a response's error stands for: the same `MarlinError` subclass (or built-in) the service
    raised, else a `RemoteProtocolError` saying what the service answered."""
    if not isinstance(error, dict):
        return errors.RemoteProtocolError(f"the service answered a malformed error: {error!r}")
    message = str(error.get("message", "the service gave no reason"))
    data = error.get("data")
    kind = _ERROR_TYPES.get(data.get("type", "")) if isinstance(data, dict) else None
    if kind is None:
        if error.get("code") == METHOD_NOT_FOUND:
            return errors.RemoteProtocolError(f"the service does not know this request: {message}")
        return errors.MarlinError(message) if error.get("code") == MARLIN_ERROR else ValueError(message)
    assert isinstance(data, dict)
    if issubclass(kind, errors.PrintStalledError):
        return kind(message, command=str(data.get("command", "")), trace="")
    if issubclass(kind, errors.CommandTimeoutError):
        return kind(message, command=str(data.get("command", "")))
    if issubclass(kind, errors.HandshakeError):
        return kind(message, step=str(data.get("step", "")))
    return kind(message)


# ------------------------------------------------------------------------------------------- values


def reading_to_json(reading: TemperatureReading) -> dict[str, Any]:
    """A reading as JSON: each heater as `[actual, target, power]` (null where the firmware said none)."""
    temperatures = reading.temperatures
    return {
        "heaters": {
            key: [_finite(heater.actual), _finite(heater.target), heater.power]
            for key, heater in temperatures.heaters.items()
        },
        "waiting": temperatures.waiting,
        "remaining_s": temperatures.wait_remaining_s,
        "time_s": reading.wall_time_s,
        "source": reading.source.value,
    }


def _finite(value: float | None) -> float | None:
    return value if value is None or math.isfinite(value) else None


def reading_from_json(value: object, monotonic_s: float) -> TemperatureReading:
    """The reading `reading_to_json` made, stamped `monotonic_s` on the receiver's clock.

    Raises:
        RpcError: `INVALID_PARAMS` if it is not a reading's shape.
    """
    try:
        assert isinstance(value, dict)
        heaters = {}
        for key, fields in value["heaters"].items():
            actual, target, power = fields
            heaters[str(key)] = HeaterReading(
                actual=float(actual),
                target=None if target is None else float(target),
                power=None if power is None else int(power),
            )
        remaining = value.get("remaining_s")
        temperatures = Temperatures(
            heaters, bool(value.get("waiting")), None if remaining is None else float(remaining)
        )
        return TemperatureReading(temperatures, monotonic_s, float(value["time_s"]), ReadingSource(value["source"]))
    except (AssertionError, AttributeError, KeyError, TypeError, ValueError):
        raise RpcError(INVALID_PARAMS, f"not a reading: {str(value)[:200]}") from None


def reply_to_json(reply: Reply) -> dict[str, Any]:
    """A reply as JSON: the command, its lines, the `ok` line's payload and the times on the service's clock."""
    return {
        "command": reply.command,
        "lines": list(reply.lines),
        "ok": reply.ok.payload,
        "sent_s": reply.sent_s,
        "answered_s": reply.answered_s,
        "lines_dropped": reply.lines_dropped,
        "ok_lost": reply.ok_lost,
    }


def reply_from_json(value: object) -> Reply:
    """The reply `reply_to_json` made (an M105's temperatures parsed again from its `ok` payload).

    Raises:
        RpcError: `INVALID_PARAMS` if it is not a reply's shape.
    """
    try:
        assert isinstance(value, dict)
        payload = str(value["ok"])
        # Parsed when first read, as the link's own oks are: a reply nobody looks into costs no parsing.
        ok = Ok(
            payload=payload, temperatures=Temperatures.from_text(payload) if looks_like_temperatures(payload) else None
        )
        return Reply(
            command=str(value["command"]),
            lines=tuple(str(line) for line in value["lines"]),
            ok=ok,
            sent_s=float(value["sent_s"]),
            answered_s=float(value["answered_s"]),
            lines_dropped=int(value.get("lines_dropped", 0)),
            ok_lost=bool(value.get("ok_lost", False)),
        )
    except (AssertionError, KeyError, TypeError, ValueError):
        raise RpcError(INVALID_PARAMS, f"not a reply: {str(value)[:200]}") from None


_PROGRESS_FIELDS = (
    "lines_sent",
    "lines_acked",
    "lines_total",
    "bytes_acked",
    "source_bytes_acked",
    "source_bytes_total",
    "elapsed_s",
    "resends",
    "last_source_line",
)


def progress_to_json(progress: PrintProgress) -> dict[str, Any]:
    """A print's progress as JSON: its state and counts, and why the printer itself paused or cancelled it."""
    value: dict[str, Any] = {"state": progress.state.value}
    for name in _PROGRESS_FIELDS:
        value[name] = getattr(progress, name)
    value["paused_by"] = progress.paused_by
    value["cancelled_by"] = progress.cancelled_by
    value["may_have_run_through"] = progress.may_have_run_through
    value["unknown_codes"] = list(progress.unknown_codes)
    return value


def progress_from_json(value: object) -> PrintProgress:
    """The progress `progress_to_json` made.

    Raises:
        RpcError: `INVALID_PARAMS` if it is not a progress's shape.
    """
    try:
        assert isinstance(value, dict)
        fields = {name: value[name] for name in _PROGRESS_FIELDS}
        # Optional: a service from before the firmware's requests were served does not send them.
        paused_by, cancelled_by = value.get("paused_by"), value.get("cancelled_by")
        # Optional too: a service from before the feed was bounded does not say how far lines may have run.
        may_have_run_through = value.get("may_have_run_through")
        unknown_codes = value.get("unknown_codes") or ()  # optional: from a service before it was told
        return PrintProgress(
            state=PrintState(value["state"]),
            **fields,
            paused_by=None if paused_by is None else str(paused_by),
            cancelled_by=None if cancelled_by is None else str(cancelled_by),
            may_have_run_through=None if may_have_run_through is None else int(may_have_run_through),
            unknown_codes=tuple(str(code) for code in unknown_codes),
        )
    except (AssertionError, KeyError, TypeError, ValueError):
        raise RpcError(INVALID_PARAMS, f"not a print's progress: {str(value)[:200]}") from None


def prompt_to_json(prompt: Prompt | None) -> dict[str, Any] | None:
    """A prompt as `{"message", "buttons"}`, or None (only shown prompts travel: one being built is no prompt)."""
    if prompt is None:
        return None
    return {"message": prompt.message, "buttons": list(prompt.buttons)}


def prompt_from_json(value: object) -> Prompt | None:
    """The prompt `prompt_to_json` made (shown), or None for null.

    Raises:
        RpcError: `INVALID_PARAMS` if it is not a prompt's shape.
    """
    if value is None:
        return None
    try:
        assert isinstance(value, dict)
        buttons = value.get("buttons", [])
        assert isinstance(buttons, list)
        return Prompt(str(value["message"]), tuple(str(label) for label in buttons), shown=True)
    except (AssertionError, KeyError):
        raise RpcError(INVALID_PARAMS, f"not a prompt: {str(value)[:200]}") from None


def host_request_to_json(request: HostRequest | None) -> dict[str, Any] | None:
    """One request of the firmware as `{"action", "argument", "prompt"}`, or None."""
    if request is None:
        return None
    return {"action": request.action, "argument": request.argument, "prompt": prompt_to_json(request.prompt)}


def host_request_from_json(value: object) -> HostRequest | None:
    """The request `host_request_to_json` made, or None for null.

    Raises:
        RpcError: `INVALID_PARAMS` if it is not a request's shape.
    """
    if value is None:
        return None
    if not isinstance(value, dict) or not isinstance(value.get("action"), str):
        raise RpcError(INVALID_PARAMS, f"not a request of the printer: {str(value)[:200]}")
    return HostRequest(str(value["action"]), str(value.get("argument", "")), prompt_from_json(value.get("prompt")))


def requests_to_json(
    request: HostRequest | None, prompt: Prompt | None, waiting_for_user: bool, last: HostRequest | None
) -> dict[str, Any]:
    """A `request` notification's params: the request made now (None when only the state changed: a prompt
    answered, a wait for the user over) and the state after it: the open prompt, the wait, the last pause,
    resume, cancel or disconnect request."""
    return {
        "request": host_request_to_json(request),
        "prompt": prompt_to_json(prompt),
        "waiting_for_user": waiting_for_user,
        "last_host_request": host_request_to_json(last),
    }


def _first_line(text: str) -> str:
    return text.splitlines()[0] if text else text
