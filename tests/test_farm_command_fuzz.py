"""`parse_command` against hostile payloads (issue 21): one MQTT message must not knock the farm over.

The contract, as h11 holds its parser to it: for any printer name and any bytes, `parse_command` returns a
`FarmCommand` or raises `CommandError`, never anything else; the error's message is one printable line short enough
to publish; nothing is opened or written (an audit hook watches). A command it returns is within the printer's
limits: targets at most the limits, G-code lines printable ASCII of at most 96 characters, a path a file inside the
allowed directory.

Hypothesis feeds it arbitrary bytes, arbitrary JSON documents and JSON objects shaped like commands with random
field values; the examples below pin each limit's refusal and its wording, and that the valid commands of
tests/test_farm.py still parse to the same commands. No broker, no printer: `FarmPrinter` on an unused URL does no I/O.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from marlin_aio.farm.commands import (
    ACTIONS,
    MAX_COMMAND_AGE_S,
    MAX_ERROR_CHARS,
    MAX_GCODE_CHARS,
    MAX_JSON_DEPTH,
    MAX_PROMPT_BUTTON,
    CommandError,
    FarmCommand,
    parse_command,
)
from marlin_aio.farm.supervisor import FarmPrinter, PrinterSpec

NOW_S = 1_750_000_000.0
SPEC = PrinterSpec("a", "socket://127.0.0.1:1")
PRINTERS = {"a": FarmPrinter(SPEC)}
LIMITS = {"hotend": SPEC.max_hotend_celsius, "bed": SPEC.max_bed_celsius, "chamber": SPEC.max_chamber_celsius}

# Audit events that open, write or reach out: none may happen inside parse_command (stat calls raise no event).
_FORBIDDEN_EVENTS = (
    "open",
    "os.mkdir",
    "os.remove",
    "os.rmdir",
    "os.rename",
    "os.symlink",
    "os.link",
    "os.truncate",
    "os.chmod",
    "os.chown",
    "os.utime",
    "socket.",
    "subprocess.",
)
_UNSAFE = re.compile(r"[\x00-\x1f\x7f-\x9f\ud800-\udfff]")
"""What no string of a command may hold: C0, DEL, C1 and lone surrogates."""
_watching = False
_seen_events: list[str] = []


def _audit(event: str, args: tuple[object, ...]) -> None:
    if _watching and event.startswith(_FORBIDDEN_EVENTS):
        _seen_events.append(event)


# Audit hooks cannot be removed: this one costs one flag test per event while no parse is watched.
sys.addaudithook(_audit)


@contextlib.contextmanager
def _no_files_touched() -> Iterator[None]:
    global _watching
    _seen_events.clear()
    _watching = True
    try:
        yield
    finally:
        _watching = False
    assert not _seen_events, f"parse_command opened or wrote: {_seen_events}"


@pytest.fixture(scope="module")
def jobs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The allowed directory: a file, a file in a folder, a symlink loop, symlinks in and out, a secret beside it."""
    root = tmp_path_factory.mktemp("farm")
    jobs = root / "jobs"
    (jobs / "sub").mkdir(parents=True)
    (jobs / "small.gcode").write_text("G28\n")
    (jobs / "sub" / "inner.gcode").write_text("G28\n")
    (root / "secret.gcode").write_text("G28\n")
    (jobs / "loop1").symlink_to("loop2")
    (jobs / "loop2").symlink_to("loop1")
    (jobs / "outside.gcode").symlink_to(root / "secret.gcode")
    (jobs / "inside.gcode").symlink_to("small.gcode")
    return jobs


def check(
    payload: bytes, allowed_dir: Path | None, *, printer: str = "a", now_s: float | None = NOW_S
) -> FarmCommand | CommandError:
    """`parse_command`'s answer to `payload`, after checking the contract on it: a command within the limits, or a
    CommandError with one clean line; nothing opened or written."""
    answer: FarmCommand | CommandError
    with _no_files_touched():
        try:
            answer = parse_command(printer, payload, PRINTERS, allowed_dir, now_s=now_s)
        except CommandError as exc:  # anything else fails the test, as it would end the farm
            answer = exc
    if isinstance(answer, CommandError):
        message = str(answer)
        assert message, "an empty refusal"
        assert message.isprintable(), message  # no control characters, no line breaks of any kind
        assert len(message) <= MAX_ERROR_CHARS, message
        assert answer.command_id is None or isinstance(answer.command_id, str | int)
        return answer
    command = answer
    assert command.printer == printer
    assert command.action in ACTIONS and command.action != "set_target"  # set_target becomes set_temperatures
    assert (
        command.id is None
        or (isinstance(command.id, int) and not isinstance(command.id, bool) and abs(command.id) < 2**63)
        or (isinstance(command.id, str) and len(command.id) <= 128 and not _UNSAFE.search(command.id))
    )
    for heater, celsius in command.targets.items():
        if heater == "tool":
            assert isinstance(celsius, int) and not isinstance(celsius, bool) and celsius >= 0
        else:
            assert math.isfinite(celsius) and 0 <= celsius <= LIMITS[heater], (heater, celsius)
    for line in command.gcode:
        assert 0 < len(line) <= MAX_GCODE_CHARS, line
        assert all(" " <= c <= "~" for c in line), line
    if command.path is not None:
        assert allowed_dir is not None
        assert command.path.is_relative_to(allowed_dir.resolve()) and command.path.is_file(), command.path
    assert (command.path is not None) == (command.action == "print")
    assert (command.index is not None) == (command.action == "answer_prompt")
    if command.index is not None:
        assert isinstance(command.index, int) and not isinstance(command.index, bool)
        assert 0 <= command.index <= MAX_PROMPT_BUTTON
    return command


def refusal(payload: bytes | str, allowed_dir: Path | None = None, **kwargs: Any) -> str:
    """The message `payload` is refused with (a str payload is sent as its UTF-8)."""
    answer = check(payload.encode() if isinstance(payload, str) else payload, allowed_dir, **kwargs)
    assert isinstance(answer, CommandError), f"{payload!r:.100} was accepted: {answer}"
    return str(answer)


def accepted(payload: dict[str, Any], allowed_dir: Path | None = None, **kwargs: Any) -> FarmCommand:
    answer = check(json.dumps(payload).encode(), allowed_dir, **kwargs)
    assert isinstance(answer, FarmCommand), f"{payload} was refused: {answer}"
    return answer


# ---- properties ------------------------------------------------------------------------------------------------

_JSON_ALPHABET = '[]{}":,\\ 0123456789.eE+-ntrufalsNIiy\x00\n'
_any_payload = st.binary(max_size=600) | st.text(alphabet=_JSON_ALPHABET, max_size=300).map(str.encode)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(printer=st.just("a") | st.text(max_size=80), payload=_any_payload)
def test_any_bytes_give_a_command_or_one_clean_line(jobs: Path, printer: str, payload: bytes) -> None:
    check(payload, jobs, printer=printer)


_scalars = (
    st.none() | st.booleans() | st.integers(min_value=-(10**40), max_value=10**40) | st.floats() | st.text(max_size=20)
)
_documents = st.recursive(
    _scalars,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=16,
)


def _encode(document: object, ascii_only: bool) -> bytes:
    # json.dumps writes NaN and Infinity as the bare constants, and with ensure_ascii=False a lone surrogate as bytes
    # that are not UTF-8: both are payloads a broker could carry.
    return json.dumps(document, ensure_ascii=ascii_only).encode("utf-8", "surrogatepass")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(document=_documents, ascii_only=st.booleans())
def test_any_json_document_gives_a_command_or_one_clean_line(jobs: Path, document: object, ascii_only: bool) -> None:
    check(_encode(document, ascii_only), jobs)


_gcode_texts = st.sampled_from(
    ["G28", "M105", "M104 S200", "M140 S100", "G1 X1 ; move", "M117 [[[[[[", "M117 " + "A" * 91, "m0104 s280"]
) | st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), min_size=1, max_size=40)
_bad_gcode_texts = st.sampled_from(
    [
        "M104S280",
        "M104 B1000",
        "M511 P1234\x1b",
        "M104 S200\nM112",
        "M104 \x1b",
        "M105\x7f",
        "G1 X\u00e9",
        "G1 *12",
        "; only a comment",
        "M117 " + "A" * 92,
    ]
) | st.text(st.characters(max_codepoint=0xA0), max_size=100)
_paths = st.sampled_from(["small.gcode", "sub/inner.gcode", "./sub/../small.gcode", "inside.gcode"])
_bad_paths = st.sampled_from(
    [
        "outside.gcode",
        "loop1",
        "loop1/x",
        "sub",
        "missing.gcode",
        "../secret.gcode",
        "/etc/passwd",
        "",
        ".",
        "a\x00b",
        "\u00e9" * 255,
        "x" * 256,
        "bad\nname.gcode",
    ]
) | st.text(max_size=300)


def _mostly(good: st.SearchStrategy[Any], bad: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    """`good` four times in five: a command with several fields still gets through often enough to be checked."""
    return st.integers(0, 4).flatmap(lambda pick: bad if pick == 0 else good)


_printable = st.characters(min_codepoint=0x20, exclude_categories=["Cc", "Cs"])
_field_values: dict[str, st.SearchStrategy[Any]] = {
    "id": _mostly(st.integers(-(10**12), 10**12) | st.text(_printable, max_size=20), st.text(max_size=130) | _scalars),
    "time": _mostly(st.floats(NOW_S - 1.5 * MAX_COMMAND_AGE_S, NOW_S + 1.5 * MAX_COMMAND_AGE_S), _scalars),
    "hotend": _mostly(st.floats(0, 300) | st.integers(0, 300), st.floats(-10, 400) | _scalars),
    "bed": _mostly(st.floats(0, 150) | st.integers(0, 150), st.text(max_size=10) | _scalars),
    "chamber": _mostly(st.floats(0, 70), _scalars),
    "tool": _mostly(st.integers(0, 3), st.integers(-2, 10) | _scalars),
    "heater": _mostly(
        st.sampled_from(["hotend", "bed", "chamber", "hotend 1", "hotend_2"]),
        st.sampled_from(["hotend \u00b2", "hotend 9999", "hotend -1", "Bed"]) | _scalars,
    ),
    "celsius": _mostly(st.floats(0, 150) | st.integers(0, 150), st.floats(-10, 400) | _scalars),
    "command": _mostly(_gcode_texts, _bad_gcode_texts | _scalars),
    "commands": _mostly(
        st.lists(_gcode_texts, min_size=1, max_size=4),
        st.lists(_mostly(_gcode_texts, _bad_gcode_texts), min_size=1, max_size=4)
        | st.lists(st.just("G28"), min_size=100, max_size=101)
        | _documents,
    ),
    "path": _mostly(_paths, _bad_paths | _scalars),
    "name": _mostly(st.sampled_from(["PLA", "petg", "ABS", "cooldown"]), st.text(max_size=80) | _scalars),
    "index": _mostly(st.integers(0, 3), st.integers(-3, 10**6) | st.floats(0, 3) | _scalars),
}
# Each action with some of the fields it takes; or any action with any fields.
_ACTION_FIELDS = {
    "set_temperatures": ("hotend", "bed", "chamber", "tool"),
    "set_target": ("heater", "celsius"),
    "gcode": ("command", "commands"),
    "print": ("path",),
    "preset": ("name",),
    "answer_prompt": ("index",),
}
_commands = st.sampled_from(ACTIONS).flatmap(
    lambda action: st.fixed_dictionaries(
        {"action": st.just(action)},
        optional={name: _field_values[name] for name in ("id", "time", *_ACTION_FIELDS.get(action, ()))},
    )
) | st.fixed_dictionaries(
    {"action": st.sampled_from([*ACTIONS, "launch"]) | _scalars},
    optional=_field_values | {"surprise": _documents},
)


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=_commands, ascii_only=st.booleans(), clock=st.booleans())
def test_command_shaped_json_gives_a_command_within_limits_or_one_clean_line(
    jobs: Path, command: dict[str, Any], ascii_only: bool, clock: bool
) -> None:
    check(_encode(command, ascii_only), jobs, now_s=NOW_S if clock else None)


# ---- examples: each limit and its wording -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("payload", "wording"),
    [
        pytest.param(b"[" * 50000, "too deep", id="50 KB of ["),
        pytest.param(b"{" * 50000, "too deep", id="50 KB of {"),
        pytest.param(b'{"a":' * 20000, "too large", id="100 KB of {a:"),
        pytest.param(b'{"a":' * 12000, "too deep", id="60 KB of {a:"),
        pytest.param(b'{"action": "pause", "x": [[[[1]]]]}', "too deep", id="depth 5"),
        pytest.param(b'"\\"' + b'\\"' * 30000, "not JSON", id="unclosed string of escaped quotes"),
        pytest.param(b"NaN", "NaN", id="NaN"),
        pytest.param(b'{"action": "set_temperatures", "hotend": NaN}', "NaN", id="NaN target"),
        pytest.param(b'{"action": "set_temperatures", "bed": Infinity}', "Infinity", id="Infinity"),
        pytest.param(b'{"action": "set_temperatures", "bed": -Infinity}', "-Infinity", id="-Infinity"),
        pytest.param(b'{"action": "set_temperatures", "bed": 1e999}', "out of range", id="overflow to inf"),
        pytest.param(b'{"id": ' + b"7" * 5000 + b', "action": "pause"}', "too long (5000 digits", id="5000 digits"),
        pytest.param(b'{"action": "pause"}\xff', "not UTF-8", id="invalid UTF-8"),
        pytest.param(b'{"action": "\xc3"}', "not UTF-8", id="cut UTF-8"),
        pytest.param(b" " * 70_000 + b'{"action": "pause"}', "too large", id="70 KB"),
        pytest.param(b"{not json", "not JSON", id="not JSON"),
        pytest.param(b'["action", "pause"]', "a command is a JSON object", id="a list"),
        pytest.param(b'{"action": "pause", "action": "print"}', "'action' appears twice", id="repeated field"),
        pytest.param(b'{"id": 1.5, "action": "pause"}', "id must be", id="float id"),
        pytest.param(b'{"id": true, "action": "pause"}', "id must be", id="bool id"),
        pytest.param(b'{"id": [1], "action": "pause"}', "id must be", id="list id"),
        pytest.param(f'{{"id": {2**63}, "action": "pause"}}'.encode(), "64-bit integer", id="id past 64 bits"),
        pytest.param(('{"id": "' + "x" * 129 + '", "action": "pause"}').encode(), "id must be", id="long id"),
        pytest.param(b'{"id": "a\\u001bb", "action": "pause"}', "id contains a control character", id="ESC id"),
        pytest.param(b'{"id": "\\ud800", "action": "pause"}', "lone surrogate", id="surrogate id"),
        pytest.param(b'{"action": {"x": 1}}', "unknown action", id="dict action"),
        pytest.param(b'{"action": "launch\\u0085"}', "unknown action", id="C1 action"),
        pytest.param(b'{"action": "pause", "x": "\\u009b"}', "pause takes no 'x'", id="unknown field"),
        pytest.param(b'{"action": "gcode", "command": "M104 S200\\nM112"}', "line break", id="newline in G-code"),
        pytest.param(b'{"action": "gcode", "command": "M105\\u001b"}', "control character", id="ESC in G-code"),
        pytest.param(b'{"action": "gcode", "command": "M105\\u007f"}', "control character", id="DEL in G-code"),
        pytest.param(b'{"action": "gcode", "command": "M105\\t"}', "control character", id="tab in G-code"),
        pytest.param(b'{"action": "gcode", "commands": ["G28", "M105\\u009b"]}', "commands[1]", id="C1 in G-code"),
        pytest.param(b'{"action": "gcode", "command": "G1 X\\u00e9"}', "non-ASCII", id="non-ASCII G-code"),
        pytest.param(
            ('{"action": "gcode", "command": "M117 ' + "A" * 92 + '"}').encode(), "at most 96", id="97 characters"
        ),
        pytest.param(b'{"action": "gcode", "command": "M104 S300"}', "above the limit of 260", id="G-code target"),
        pytest.param(b'{"action": "set_temperatures", "hotend": 900}', "above the limit", id="target"),
        pytest.param(b'{"action": "set_temperatures", "bed": "abc"}', "abc", id="text target"),
        pytest.param(
            b'{"action": "set_target", "heater": "hotend \xc2\xb2", "celsius": 40}', "heater must be", id="hotend 2"
        ),
        pytest.param(
            ('{"action": "set_target", "heater": "hotend ' + "9" * 5000 + '", "celsius": 40}').encode(),
            "heater must be",
            id="hotend 9999...",
        ),
        pytest.param(b'{"action": "answer_prompt"}', 'answer_prompt needs "index"', id="no index"),
        pytest.param(b'{"action": "answer_prompt", "index": -1}', "got -1", id="negative index"),
        pytest.param(b'{"action": "answer_prompt", "index": 1.0}', "got 1.0", id="float index"),
        pytest.param(b'{"action": "answer_prompt", "index": "0"}', "got '0'", id="text index"),
        pytest.param(b'{"action": "answer_prompt", "index": true}', "got True", id="bool index"),
        pytest.param(b'{"action": "answer_prompt", "index": 100}', "at most 99", id="index 100"),
        pytest.param(b'{"action": "answer_prompt", "index": 0, "x": 1}', "takes no 'x'", id="answer field"),
        pytest.param(b'{"action": "pause", "time": "now"}', "time must be", id="text time"),
        pytest.param(b'{"action": "pause", "time": true}', "time must be", id="bool time"),
    ],
)
def test_hostile_payloads_are_refused_with_their_reason(payload: bytes, wording: str) -> None:
    assert wording in refusal(payload)


@pytest.mark.parametrize(
    ("path", "wording"),
    [
        ("a\x00b", "path contains a control character ('\\x00')"),
        ("bad\nname.gcode", "path contains a line break"),
        ("x" * 10_000, "path is 10000 characters long, at most 255"),
        ("\u00e9" * 255, "cannot be looked up in the allowed directory (File name too long)"),
        ("loop1", "a symlink loop"),
        ("loop1/x", "a symlink loop"),
        ("outside.gcode", "outside the allowed directory"),
        ("/etc/passwd", "outside the allowed directory"),
        ("../x", "outside the allowed directory"),
        ("../secret.gcode", "outside the allowed directory"),
        ("sub/../../secret.gcode", "outside the allowed directory"),
        ("sub", "no such file in the allowed directory"),
        ("missing.gcode", "no such file in the allowed directory"),
        ("", 'print needs "path"'),
    ],
)
def test_paths_that_leave_or_trip_the_allowed_directory_are_refused(jobs: Path, path: str, wording: str) -> None:
    message = refusal(json.dumps({"id": 4, "action": "print", "path": path}), jobs)
    assert wording in message
    assert path[:20] not in message or path.isprintable()  # a path is shown with repr, never raw


def test_prints_are_off_without_an_allowed_directory() -> None:
    assert "prints over MQTT are off" in refusal('{"action": "print", "path": "small.gcode"}', None)


def test_the_depth_limit_lets_every_command_through_and_stops_one_level_more() -> None:
    # The deepest real command: an object holding a list of strings.
    assert MAX_JSON_DEPTH >= 2
    under = {"action": "pause", "x": [[{"y": 1}]]}  # depth 4: read, then refused for its field
    assert "pause takes no 'x'" in refusal(json.dumps(under))
    over = {"action": "pause", "x": [[{"y": [1]}]]}
    assert "too deep" in refusal(json.dumps(over))
    # Brackets inside strings, escaped quotes included, are not nesting.
    command = accepted({"action": "gcode", "command": 'M117 "[[[[[[{{{{{{'})
    assert command.gcode == ('M117 "[[[[[[{{{{{{',)


def test_stale_and_future_commands_are_refused_and_a_fresh_one_is_taken() -> None:
    stale = refusal(json.dumps({"id": 7, "action": "cancel", "time": NOW_S - 60}))
    assert stale == f"stale: sent 60.0 s ago, commands older than {MAX_COMMAND_AGE_S:g} s are refused"
    future = refusal(json.dumps({"action": "pause", "time": NOW_S + 3600}))
    assert future == "sent 3600.0 s in the future: are the clocks set?"
    assert "stale" in refusal(json.dumps({"action": "pause", "time": 0}))
    assert "stale" in refusal(json.dumps({"action": "pause", "time": -(10**29)}))
    assert "in the future" in refusal(json.dumps({"action": "pause", "time": 10**29}))
    # The age is checked right after the action: a stale command with a bad field is refused for its age.
    assert "stale" in refusal(json.dumps({"action": "gcode", "command": "M104 S900", "time": NOW_S - 60}))
    fresh = accepted({"id": 8, "action": "gcode", "command": "G28", "time": NOW_S - MAX_COMMAND_AGE_S / 2})
    assert fresh == FarmCommand("a", "gcode", 8, gcode=("G28",))
    assert accepted({"action": "pause", "time": int(NOW_S) + 1}).action == "pause"
    # Without a clock the time is only checked to be a number; max_age_s is the caller's.
    assert accepted({"action": "pause", "time": 0}, now_s=None).action == "pause"
    assert "time must be" in refusal(json.dumps({"action": "pause", "time": "0"}), now_s=None)
    payload = json.dumps({"action": "pause", "time": NOW_S - 60}).encode()
    assert parse_command("a", payload, PRINTERS, None, now_s=NOW_S, max_age_s=120).action == "pause"


def test_a_refusal_carries_the_command_id_once_the_id_is_valid() -> None:
    with pytest.raises(CommandError) as caught:
        parse_command("a", b'{"id": "x-1", "action": "launch"}', PRINTERS, None)
    assert caught.value.command_id == "x-1"
    with pytest.raises(CommandError) as caught:
        parse_command("a", b'{"id": 1.5, "action": "pause"}', PRINTERS, None)
    assert caught.value.command_id is None
    with pytest.raises(CommandError) as caught:
        parse_command("a", b"[" * 50000, PRINTERS, None)
    assert caught.value.command_id is None


def test_values_are_shown_with_repr_cut_short_and_passwords_redacted() -> None:
    name = "evil\n\x1b[2J" + "x" * 1000
    message = refusal('{"action": "pause"}', printer=name)
    assert message.startswith("no printer named 'evil\\n\\x1b[2J") and "..." in message
    message = refusal(json.dumps({"action": "x" * 5000}))
    assert message.startswith("unknown action 'xxx") and len(message) <= MAX_ERROR_CHARS
    message = refusal(json.dumps({"action": "gcode", "command": "M511 P1234\x1b"}))
    assert "1234" not in message and "control character" in message


def test_valid_commands_parse_as_before(jobs: Path) -> None:
    assert accepted({"id": 1, "action": "set_temperatures", "hotend": 200, "bed": 60}) == FarmCommand(
        "a", "set_temperatures", 1, targets={"hotend": 200.0, "bed": 60.0}
    )
    assert accepted({"id": 10, "action": "set_temperatures", "hotend": 50, "tool": 1}) == FarmCommand(
        "a", "set_temperatures", 10, targets={"hotend": 50.0, "tool": 1}
    )
    assert accepted({"id": 2, "action": "set_target", "heater": "hotend", "celsius": 210}) == FarmCommand(
        "a", "set_temperatures", 2, targets={"hotend": 210.0}
    )
    assert accepted({"id": 11, "action": "set_target", "heater": "hotend_1", "celsius": 40}) == FarmCommand(
        "a", "set_temperatures", 11, targets={"hotend": 40.0, "tool": 1}
    )
    assert accepted({"id": "b", "action": "set_target", "heater": "bed", "celsius": "40"}) == FarmCommand(
        "a", "set_temperatures", "b", targets={"bed": 40.0}
    )
    assert accepted({"id": 3, "action": "gcode", "command": "G28"}) == FarmCommand("a", "gcode", 3, gcode=("G28",))
    assert accepted({"action": "gcode", "commands": ["G28", "M114 ; where", "M104 S50"]}) == FarmCommand(
        "a", "gcode", gcode=("G28", "M114", "M104 S50")
    )
    assert accepted({"action": "gcode", "command": "M117 " + "A" * 91}).gcode == ("M117 " + "A" * 91,)
    small = (jobs / "small.gcode").resolve()
    assert accepted({"id": 4, "action": "print", "path": "small.gcode"}, jobs) == FarmCommand(
        "a", "print", 4, path=small
    )
    assert accepted({"action": "print", "path": "inside.gcode"}, jobs).path == small  # a symlink inside: its file
    assert accepted({"action": "print", "path": "sub/inner.gcode"}, jobs).path == (jobs / "sub/inner.gcode").resolve()
    assert accepted({"action": "print", "path": str(small)}, jobs).path == small  # absolute, but inside
    for action in ("pause", "resume", "cancel", "emergency_stop"):
        assert accepted({"id": 5, "action": action}) == FarmCommand("a", action, 5)
    assert accepted({"id": 9, "action": "answer_prompt", "index": 1}) == FarmCommand("a", "answer_prompt", 9, index=1)
    assert accepted({"action": "pause", "id": "é-1"}).id == "é-1"
    assert accepted({"action": "pause", "id": 2**63 - 1}).id == 2**63 - 1
    assert accepted({"action": "pause", "id": -(2**63) + 1}).id == -(2**63) + 1


def test_a_print_may_stop_at_a_command_the_firmware_lacks_as_at_every_other_door(jobs: Path) -> None:
    # The start_print verb's stop_on_unknown, reached from MQTT as from the socket and the CLI (issue 34).
    assert accepted({"action": "print", "path": "small.gcode"}, jobs).stop_on_unknown is False
    assert accepted({"action": "print", "path": "small.gcode", "stop_on_unknown": True}, jobs).stop_on_unknown is True
    message = refusal(json.dumps({"action": "print", "path": "small.gcode", "stop_on_unknown": "yes"}), jobs)
    assert '"stop_on_unknown" must be true or false' in message
