"""`Printer` is one class over two backends (issue 33): every public member either works on a printer of
`marlin-temp serve` or raises `NotSupportedError` naming itself and saying why; none silently answers nothing.

The walk takes the members from `dir()`, so a member added later is walked too (and fails here until it has an
exercise, if it needs arguments). Through a real `marlin-temp serve` process over the simulator on a pty, and the
same walk on a printer on a pty of its own, where nothing may be unsupported.
"""

from __future__ import annotations

import asyncio
import inspect
import json
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from conftest import until
from test_serve import serving

import marlin_aio
from marlin_aio.aio.printer import ServedPrinter
from marlin_aio.simulator import SimulatorServer

#: What a served printer cannot serve: the wire and its window are the service's.
SERVED_UNSUPPORTED = {"trace", "send_ahead_window_bytes", "sending_ahead", "print_poll_interval_s"}

Exercise = Callable[[marlin_aio.Printer], Awaitable[None]]


async def _prompt(printer: marlin_aio.Printer) -> None:
    """Have the firmware open a prompt (Marlin's host actions, by M118's A1) and wait until the printer knows it."""
    for line in ("prompt_begin Walk", "prompt_button OK", "prompt_show"):
        await printer.send(f"M118 A1 action:{line}")
    await until(lambda: printer.prompt is not None, "the prompt")


async def _answer_prompt(printer: marlin_aio.Printer) -> None:
    await _prompt(printer)
    assert printer.prompt is not None and printer.prompt.buttons == ("OK",)
    await printer.answer_prompt(0)
    assert printer.prompt is None


async def _reopen(printer: marlin_aio.Printer) -> None:
    events: list[marlin_aio.LinkEvent] = []
    stop = printer.on_link_event(events.append)
    await printer.close()
    assert not printer.is_connected
    await printer.open()
    await until(lambda: "connected" in [event.kind for event in events], "the connected event")
    stop()
    assert printer.is_connected


async def _host_requests(printer: marlin_aio.Printer) -> None:
    requests = printer.host_requests()
    # gather starts the reader first: it listens before the line that asks is sent.
    request, _ = await asyncio.wait_for(
        asyncio.gather(anext(requests), printer.send("M118 A1 action:notification walk")), 30
    )
    await requests.aclose()
    assert (request.action, request.argument) == ("notification", "walk")


async def _on_host_request(printer: marlin_aio.Printer) -> None:
    seen: list[marlin_aio.HostRequest] = []
    stop = printer.on_host_request(seen.append)
    await printer.send("M118 A1 action:notification told")
    await until(lambda: any(request.argument == "told" for request in seen), "the request")
    stop()


async def _on_reading(printer: marlin_aio.Printer) -> None:
    seen: list[marlin_aio.TemperatureReading] = []
    stop = printer.on_reading(seen.append)
    async with printer.poll_temperatures(0.05):
        await until(lambda: len(seen) >= 2, "readings")
    stop()


async def _temperature_readings(printer: marlin_aio.Printer) -> None:
    readings = printer.temperature_readings()
    async with printer.poll_temperatures(0.05):
        reading = await asyncio.wait_for(anext(readings), 30)
    await readings.aclose()
    assert reading.hotend is not None


async def _failure(printer: marlin_aio.Printer) -> None:
    failure = asyncio.ensure_future(printer.wait_for_failure())
    printer.emergency_stop()
    assert isinstance(await asyncio.wait_for(failure, 30), marlin_aio.PrinterHaltedError)


async def _send(printer: marlin_aio.Printer) -> None:
    assert (await printer.send("M118 E1 walk")).lines == ("echo:walk",)


async def _sending_ahead(printer: marlin_aio.Printer) -> None:
    with printer.sending_ahead(4):
        replies = await asyncio.gather(*(printer.send("M105") for _ in range(4)))
    assert all(reply.temperatures is not None for reply in replies)


async def _start_print(printer: marlin_aio.Printer) -> None:
    handle = await printer.start_print(["G1 X3 F6000", "G1 X4"])
    assert (await asyncio.wait_for(handle.wait(), 60)).state is marlin_aio.PrintState.DONE


async def _print_file(printer: marlin_aio.Printer) -> None:
    progress = await asyncio.wait_for(printer.print_file(["G1 X1 F6000", "G1 X2"]), 60)
    assert (progress.state, progress.lines_acked) == (marlin_aio.PrintState.DONE, 2)


async def _call(printer: marlin_aio.Printer) -> None:
    assert isinstance(printer, ServedPrinter)
    assert (await printer.call("status"))["name"] == "sim"


def _returns(check: Callable[[object], bool], call: Callable[[marlin_aio.Printer], Awaitable[object]]) -> Exercise:
    async def exercise(printer: marlin_aio.Printer) -> None:
        value = await call(printer)
        assert check(value), value

    return exercise


#: How each member that needs more than a read or a call without arguments is tried.
EXERCISES: dict[str, Exercise] = {
    "answer_prompt": _answer_prompt,
    "call": _call,
    "close": _reopen,
    "open": _reopen,
    "on_link_event": _reopen,
    "disable_motors": _returns(lambda reply: isinstance(reply, marlin_aio.Reply), lambda p: p.disable_motors("E")),
    "extrude": _returns(lambda reply: isinstance(reply, marlin_aio.Reply), lambda p: p.extrude(1.0)),
    "home": _returns(lambda reply: isinstance(reply, marlin_aio.Reply), lambda p: p.home("X")),
    "move": _returns(lambda reply: isinstance(reply, marlin_aio.Reply), lambda p: p.move(x=5, y=5)),
    "position": _returns(lambda position: "X" in position, lambda p: p.position()),  # type: ignore[operator]
    "endstops": _returns(lambda endstops: "z_min" in endstops, lambda p: p.endstops()),  # type: ignore[operator]
    "set_fan": lambda p: p.set_fan(0.5),
    "set_temperatures": lambda p: p.set_temperatures(hotend=0, bed=0),
    "wait_for_temperatures": _returns(
        lambda reading: isinstance(reading, marlin_aio.TemperatureReading),
        lambda p: p.wait_for_temperatures(hotend=0, tolerance_c=1000, timeout_s=30),
    ),
    "host_requests": _host_requests,
    "on_host_request": _on_host_request,
    "on_reading": _on_reading,
    "temperature_readings": _temperature_readings,
    "poll_temperatures": _on_reading,
    "send": _send,
    "sending_ahead": _sending_ahead,
    "start_print": _start_print,
    "print_file": _print_file,
    # Last: the printer halts.
    "emergency_stop": _failure,
    "wait_for_failure": _failure,
}
LAST = ("emergency_stop", "wait_for_failure")


async def walk(printer: marlin_aio.Printer) -> dict[str, marlin_aio.NotSupportedError]:
    """Try every public member of `printer`; return the ones that said they are not supported, with their error
    (any other exception fails the walk)."""
    members = sorted(name for name in dir(printer) if not name.startswith("_"))
    members = [name for name in members if name not in LAST] + [name for name in LAST if name in members]
    unsupported: dict[str, marlin_aio.NotSupportedError] = {}
    done: set[Exercise] = set()
    for name in members:
        try:
            await _try(printer, name, done)
        except marlin_aio.NotSupportedError as exc:
            unsupported[name] = exc
        except Exception as exc:
            raise AssertionError(f"{name} raised {exc!r}") from exc
    return unsupported


async def _try(printer: marlin_aio.Printer, name: str, done: set[Exercise]) -> None:
    exercise = EXERCISES.get(name)
    if exercise is not None:
        if exercise not in done:  # one exercise serves several members (open, close, on_link_event)
            done.add(exercise)
            await exercise(printer)
        return
    attribute = inspect.getattr_static(printer, name)
    if isinstance(attribute, property):
        value = getattr(printer, name)
        if attribute.fset is not None:
            setattr(printer, name, value)  # the same value back: the setter works
        return
    value = getattr(printer, name)
    if not callable(value):
        return  # a plain attribute (port, baudrate): read
    required = [
        parameter
        for parameter in inspect.signature(value).parameters.values()
        if parameter.default is parameter.empty
        and parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
    ]
    assert not required, f"{name} needs arguments: give it an exercise in EXERCISES"
    result = value()
    if inspect.isawaitable(result):
        await result


async def test_every_member_of_a_served_printer_works_or_says_why(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, marlin_aio.connect(served.url(), timeout_s=30) as printer:
        assert type(printer) is ServedPrinter
        unsupported = await walk(printer)
    assert set(unsupported) == SERVED_UNSUPPORTED
    for name, error in unsupported.items():
        assert error.member == name
        assert str(error).startswith(f"{name}: "), error
        assert "marlin-temp serve" in str(error), error
    assert "marlin-temp serve --wire-log" in str(unsupported["trace"])
    # The setter says so too, not only the getter.
    with pytest.raises(marlin_aio.NotSupportedError, match=r"^print_poll_interval_s: "):
        printer.print_poll_interval_s = 2.0


async def test_every_member_of_a_printer_on_a_port_works(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url, timeout_s=30) as printer:
        assert type(printer) is marlin_aio.Printer
        assert await walk(printer) == {}


async def test_a_served_printer_tells_the_services_link_figures(tmp_path: Path) -> None:
    async with serving(tmp_path) as served, marlin_aio.connect(served.url()) as printer:
        loop = asyncio.get_running_loop()
        before = printer.stats.answered
        for index in range(5):
            await printer.send(f"M118 E1 count {index}")
        # The service polls too (every 0.05 s here): its counters run on with every client's commands and its polls.
        await until(lambda: printer.stats.answered >= before + 5, "the service's counters to move on")
        assert printer.stats.accounted
        await until(lambda: len(printer.round_trips) >= 10, "round trips")
        answered_s, latency_s = printer.round_trips[-1]
        assert 0 < latency_s < 5
        # On this process's clock, as readings are: a few seconds old at most, never from the future.
        assert loop.time() - 10 < answered_s <= loop.time() + 0.1
        times = [answered for answered, _ in printer.round_trips]
        assert times == sorted(times)


async def test_watch_through_the_service_shows_a_latency(tmp_path: Path) -> None:
    async with serving(tmp_path) as served:
        watch = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "watch",
            "--port",
            served.url(),
            "--duration",
            "4",
            "--refresh",
            "0.5",
            "--json",
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=served.env(),
        )
        out, err = await asyncio.wait_for(watch.communicate(), 60)
    assert watch.returncode == 0, err.decode()
    lines = [json.loads(line) for line in out.decode().splitlines() if line.startswith("{")]
    assert lines, out.decode()
    latencies = [line["latency_median_ms"] for line in lines if line["latency_median_ms"] is not None]
    assert latencies, lines
    assert all(0 < latency < 5000 for latency in latencies)
