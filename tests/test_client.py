"""The asyncio client against the simulated printer, no mocks of our code: on the in-memory link where a real port
adds nothing, and through a real pty (and socket://) for the handshake end to end, opening and its errors, the
exclusive lock, a port that stays silent or babbles, and an unplug as pyserial reports it."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os

import pytest
from conftest import TIME_SCALE

import marlin_aio
import marlin_aio.protocol
from marlin_aio.protocol.wire import BARE_LINE_END
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, serve_memory


def executed_codes(server: SimulatorServer, prefix: str) -> list[str]:
    return [c for c in server.printer.executed if c.startswith(prefix)]


async def test_handshake_identifies_the_firmware(sim: SimulatorServer) -> None:
    async with marlin_aio.connect(sim.url) as printer:
        assert printer.firmware is not None
        assert printer.firmware.name.startswith("Marlin")
        assert printer.capabilities.get("AUTOREPORT_TEMP") is True
        sent = [e.text for e in printer.trace.entries() if e.direction == "sent"]
        assert "N0 M110 N0*125" in sent
        assert any(text.endswith("M115*" + text.rsplit("*", 1)[1]) for text in sent if "M115" in text)


async def test_send_returns_the_lines_that_belong_to_the_command(mem_printer: marlin_aio.Printer) -> None:
    reply = await mem_printer.send("M119")
    assert reply.lines[0] == "Reporting endstop status"
    assert await mem_printer.endstops() == {"x_min": False, "y_min": False, "z_min": False}
    position = await mem_printer.position()
    assert set(position) >= {"X", "Y", "Z"}


async def test_concurrent_senders_each_get_their_own_reply(sim: SimulatorServer) -> None:
    async with marlin_aio.connect(sim.url) as printer:

        async def echo(index: int) -> tuple[int, marlin_aio.Reply]:
            return index, await printer.send(f"M118 E1 task {index}")

        results = await asyncio.gather(*(echo(i) for i in range(60)))
    for index, reply in results:
        assert reply.lines == (f"echo:task {index}",)
    # And the printer executed them in the order they were sent, each exactly once.
    assert executed_codes(sim, "M118") == [f"M118 E1 task {i}" for i in range(60)]


async def test_polling_at_100_hz_while_other_commands_run(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    readings: list[marlin_aio.TemperatureReading] = []
    enough = asyncio.Event()

    async def collect() -> None:
        async for reading in mem_printer.temperature_readings():
            readings.append(reading)
            if sum(r.source == "poll" for r in readings) >= 150:
                enough.set()

    collector = asyncio.create_task(collect())
    async with mem_printer.poll_temperatures(interval_s=0.01):
        await asyncio.wait_for(enough.wait(), 30)
        moves = [f"G1 X{i} Y{i} F6000" for i in range(1, 20)]
        replies = [await mem_printer.send(move) for move in moves]
        # G4 S4 holds the queue 4 simulated seconds (0.2 s here): some 20 poll slots pass behind it. They must be
        # skipped, not queued up to burst out afterwards: at most the one poll already waiting may remain (behind
        # the probe that asked whether G4's ok was lost, if one is still on its way).
        await mem_printer.send("G4 S4")
        assert mem_printer.stats.queued + mem_printer.stats.in_flight <= 2
        assert mem_printer.stats.queued <= 1
        entries = mem_printer.trace.entries()
    collector.cancel()
    dwell_sent = max(i for i, e in enumerate(entries) if e.direction == "sent" and "G4 S4" in e.text)
    dwell_ok = next(i for i, e in enumerate(entries) if i > dwell_sent and e.text.startswith("ok"))
    mid_dwell = [e.text for e in entries[dwell_sent + 1 : dwell_ok] if e.direction == "sent"]
    # Only what asks whether G4's ok was lost goes out mid-dwell: a bare line end and a probe, two at most (a poll's
    # M105 would also be one M105), never the skipped polls.
    assert len([text for text in mid_dwell if "M105" in text]) <= 2, mid_dwell
    assert all("M105" in text or text == BARE_LINE_END for text in mid_dwell), mid_dwell
    assert all(reply.lines == () for reply in replies)
    assert executed_codes(mem_sim, "G1 ") == moves
    assert mem_printer.stats.timeouts == 0
    poll_times = [r.monotonic_s for r in readings if r.source == "poll"]
    assert poll_times == sorted(poll_times)


async def test_auto_report_keeps_readings_coming_during_a_long_command(mem_printer: marlin_aio.Printer) -> None:
    sources: list[str] = []

    async def collect() -> None:
        async for reading in mem_printer.temperature_readings():
            sources.append(reading.source)

    collector = asyncio.create_task(collect())
    async with mem_printer.poll_temperatures(interval_s=0.01):
        before = len(sources)
        await mem_printer.send("G4 S4")  # 4 simulated seconds: several auto-reports arrive meanwhile
        during = sources[before:]
    collector.cancel()
    assert "auto" in during


async def test_long_m190_with_keepalives_never_times_out() -> None:
    # Three times the suite's time scale: the bed still takes about a second to heat, twice the client's timeout.
    async with (
        serve_memory(SimulatorConfig(), Faults(), time_scale=3 * TIME_SCALE) as server,
        marlin_aio.connect(server.url, timeout_s=0.5) as printer,
    ):
        wait_lines: list[marlin_aio.TemperatureReading] = []

        async def collect() -> None:
            async for reading in printer.temperature_readings():
                if reading.source == "wait":
                    wait_lines.append(reading)

        collector = asyncio.create_task(collect())
        # The bed needs far longer than the 0.5 s timeout to reach 45 C; keepalives and wait lines keep it alive.
        reply = await printer.send("M190 S45")
        collector.cancel()
        assert reply.latency_s > 0.5
        assert len(wait_lines) >= 3
        assert printer.stats.timeouts == 0
        assert server.printer.heater_celsius("B") >= 44.0


async def test_a_command_that_is_never_answered_times_out_and_the_queue_goes_on(
    mem_printer: marlin_aio.Printer,
) -> None:
    with pytest.raises(marlin_aio.CommandTimeoutError) as caught:
        await mem_printer.send("M105 T9", timeout_s=0.3)
    message = str(caught.value)
    assert "M105 T9" in message
    assert "waited" in message or "after" in message
    assert "last received" in message
    assert caught.value.command == "M105 T9"
    reading = await mem_printer.temperatures()
    assert reading.hotend is not None


async def test_a_silent_printer_is_detected_within_the_timeout(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url, timeout_s=0.4) as printer:
        mem_sim.printer.faults.silent = True
        with pytest.raises(marlin_aio.CommandTimeoutError, match="silent") as caught:
            await printer.send("G28")
        assert isinstance(caught.value, TimeoutError)


async def test_corrupted_lines_are_resent_and_executed_exactly_once(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url, timeout_s=2.0) as printer:
        mem_sim.printer.faults.corrupt_rx_ratio = 0.3
        moves = [f"G1 X{i} Y{i % 7} F9000" for i in range(80)]
        for move in moves:
            await printer.send(move)
        assert printer.stats.resend_requests > 0
    assert executed_codes(mem_sim, "G1 ") == moves


async def test_concurrent_senders_survive_corruption(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url, timeout_s=2.0, max_in_flight=4) as printer:
        mem_sim.printer.faults.corrupt_rx_ratio = 0.1
        results = await asyncio.gather(*(printer.send(f"M118 E1 n{i}") for i in range(40)))
        assert [r.lines for r in results] == [(f"echo:n{i}",) for i in range(40)]
    assert executed_codes(mem_sim, "M118") == [f"M118 E1 n{i}" for i in range(40)]


async def test_a_reset_fails_the_waiting_command_and_the_link_recovers(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    resets = mem_printer.stats.resets  # a memory link resets the board as it connects, as TCP does
    pending = asyncio.create_task(mem_printer.send("G4 S30"))
    await wait_until_sent(mem_printer, "G4 S30")
    mem_sim.printer.reset(mem_sim.now())
    mem_sim.poke()
    with pytest.raises(marlin_aio.PrinterResetError):
        await pending
    reading = await mem_printer.temperatures()
    assert reading.hotend is not None
    assert mem_printer.stats.resets == resets + 1


async def test_thermal_runaway_halts_with_the_printers_message(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    readings = mem_printer.temperature_readings()
    first = asyncio.ensure_future(readings.__anext__())
    pending = asyncio.create_task(mem_printer.send("G4 S30"))
    await wait_until_sent(mem_printer, "G4 S30")
    mem_sim.printer.thermal_runaway(mem_sim.now(), heater="E0")
    mem_sim.poke()
    with pytest.raises(marlin_aio.ThermalRunawayError, match="Thermal Runaway"):
        await pending
    with pytest.raises(marlin_aio.PrinterHaltedError):
        await first
    with pytest.raises(marlin_aio.ThermalRunawayError):
        await mem_printer.send("M105")
    await readings.aclose()


async def test_unplugging_fails_every_waiting_command(printer: marlin_aio.Printer, pty_sim: SimulatorServer) -> None:
    pending = [asyncio.create_task(printer.send(f"G4 S{20 + i}")) for i in range(3)]
    await wait_until_sent(printer, "G4 S20")
    await pty_sim.disconnect()
    for task in pending:
        # In words a user can act on, not pyserial's "device reports readiness to read but returned no data".
        with pytest.raises(marlin_aio.ConnectionLostError, match="the port went away \\(the printer was unplugged"):
            await asyncio.wait_for(task, 5)
    with pytest.raises(marlin_aio.ConnectionLostError):
        await printer.send("M105")
    assert not printer.is_connected


async def test_emergency_stop_is_written_at_once_and_fails_what_waits(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    pending = [asyncio.create_task(mem_printer.send(f"G4 S{10 + i}")) for i in range(3)]
    await wait_until_sent(mem_printer, "G4 S10")
    mem_printer.emergency_stop()
    for task in pending:
        with pytest.raises(marlin_aio.PrinterHaltedError):
            await task
    # The two dwells behind the first were never written: M112 went ahead of them.
    sent = [e.text for e in mem_printer.trace.entries() if e.direction == "sent"]
    assert sent[-1] == "M112"
    assert not any("G4 S11" in text for text in sent)


async def test_stats_is_a_frozen_snapshot_that_accounts_for_every_command(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    before = mem_printer.stats
    await mem_printer.send("M105")
    await mem_printer.send("M114")
    after = mem_printer.stats
    assert after.answered == before.answered + 2
    assert after.bytes_received > before.bytes_received
    assert after.accounted and after.in_flight == after.queued == 0
    assert before.answered == after.answered - 2  # the earlier snapshot did not move
    with pytest.raises(dataclasses.FrozenInstanceError):
        after.timeouts = 5  # type: ignore[misc]


def state_of(printer: marlin_aio.Printer) -> marlin_aio.LinkState:
    """The printer's state, read afresh (an assert on `printer.state` would narrow its type for the next one)."""
    return printer.state


async def test_the_library_logs_lines_at_debug_and_recoveries_at_info(
    mem_sim: SimulatorServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG, logger="marlin_aio")
    async with marlin_aio.connect(mem_sim.url) as printer:
        mem_sim.printer.faults.corrupt_rx_ratio = 0.3
        for _ in range(20):
            await printer.send("M114")
    wire = [r for r in caplog.records if r.name == "marlin_aio.wire"]
    assert any(r.getMessage().startswith(">> N") for r in wire)
    assert any(r.getMessage().startswith("<< ok") for r in wire)
    recoveries = [r for r in caplog.records if r.name == "marlin_aio" and r.levelno == logging.INFO]
    assert any("asked for line" in r.getMessage() for r in recoveries)
    assert any("connected to" in r.getMessage() for r in recoveries)


async def test_on_reading_calls_back_with_every_reading_until_stopped(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    seen: list[marlin_aio.TemperatureReading] = []
    enough = asyncio.Event()

    def callback(reading: marlin_aio.TemperatureReading) -> None:
        seen.append(reading)
        if len(seen) >= 20:
            enough.set()

    stop = mem_printer.on_reading(callback)
    async with mem_printer.poll_temperatures(0.005), asyncio.timeout(30):  # a bound, not a sync: the event syncs
        await enough.wait()
        stop()
        count = len(seen)
        await mem_printer.read_temperatures()  # one more reading, after the stop
    assert len(seen) == count >= 20
    assert all(r.hotend is not None for r in seen)
    assert any(r.source is marlin_aio.protocol.ReadingSource.POLL for r in seen)  # (auto-reports come too, with M155)


async def test_a_closed_printer_opens_again_and_an_open_one_refuses_to(sim: SimulatorServer) -> None:
    # On both real transports: a pty opened again after pyserial closed it, a TCP port connected to again.
    printer = marlin_aio.Printer(sim.url)
    async with printer:
        with pytest.raises(RuntimeError, match="already open"):
            await printer.open()
        await printer.send("M105")
    assert state_of(printer) is marlin_aio.LinkState.LOST
    with pytest.raises(marlin_aio.ConnectionLostError):
        await printer.send("M105")
    async with printer:  # a fresh link on the same port
        assert state_of(printer) is marlin_aio.LinkState.READY
        reading = await printer.read_temperatures()
        assert reading.source is marlin_aio.protocol.ReadingSource.POLL
        assert printer.stats.answered >= 1


async def test_a_reader_that_falls_behind_loses_its_oldest_readings_never_the_error(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    readings = mem_printer.temperature_readings()
    async with mem_printer.poll_temperatures(0.001):
        await anext(readings)  # subscribed; from here on this reader does not keep up
        for _ in range(1_100):  # over the 1,000-reading bound on its own; polls add more
            await mem_printer.read_temperatures()
    assert mem_printer.readings_dropped > 0
    mem_printer.emergency_stop()
    kept: list[marlin_aio.TemperatureReading] = []

    async def drain() -> None:
        async for reading in readings:
            kept.append(reading)

    with pytest.raises(marlin_aio.PrinterHaltedError):
        await drain()
    assert len(kept) <= 1000  # the queue's bound; the halt still got through


async def test_emergency_stop_on_a_closed_printer_raises_instead_of_doing_nothing(mem_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(mem_sim.url) as printer:
        assert state_of(printer) is marlin_aio.LinkState.READY
        printer.emergency_stop()
        assert state_of(printer) is marlin_aio.LinkState.HALTED
    assert state_of(printer) is marlin_aio.LinkState.LOST
    with pytest.raises(marlin_aio.ConnectionLostError, match="M112"):
        printer.emergency_stop()


async def test_bad_commands_are_rejected_before_anything_is_written(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    before = list(mem_printer.trace.entries())
    for bad in ["G1 X1\nM112", "M117 caf\u00e9", "M117 " + "x" * 100, "   ; only a comment", "G1\rX2"]:
        with pytest.raises(ValueError, match=r"\S"):
            await mem_printer.send(bad)
    for kwargs in [{"hotend": 900}, {"hotend": float("nan")}, {"bed": -5}, {"hotend": "abc"}, {"bed": 141}]:
        with pytest.raises(ValueError, match="target"):
            await mem_printer.set_temperatures(**kwargs)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="fan"):
        await mem_printer.set_fan(1.5)
    assert mem_printer.trace.entries() == before


async def test_targets_are_set_and_reached(mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer) -> None:
    await mem_printer.set_temperatures(hotend=60, bed=35)
    reading = await mem_printer.wait_for_temperatures(tolerance_c=1.5, timeout_s=60)
    assert reading.hotend is not None and abs(reading.hotend.actual - 60) <= 1.5
    assert reading.bed is not None and abs(reading.bed.actual - 35) <= 1.5
    assert "M104 S60" in mem_sim.printer.executed
    assert "M140 S35" in mem_sim.printer.executed


async def test_waiting_for_an_unreachable_temperature_times_out(mem_printer: marlin_aio.Printer) -> None:
    await mem_printer.set_temperatures(hotend=250)
    with pytest.raises(marlin_aio.TemperatureTimeoutError, match="250"):
        await mem_printer.wait_for_temperatures(hotend=250, timeout_s=0.3)
    await mem_printer.set_temperatures(hotend=0)


async def test_fan_commands(mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer) -> None:
    await mem_printer.set_fan(0.5)
    await mem_printer.set_fan(0.0)
    assert mem_sim.printer.executed[-2:] == ["M106 S128", "M107"]


# ---------------------------------------------------------------------------------------------------- opening


async def test_a_missing_port_is_reported_clearly() -> None:
    with pytest.raises(marlin_aio.PortNotFoundError, match="no such port"):
        async with marlin_aio.connect("/dev/does-not-exist-marlin"):
            pass


async def test_a_port_in_use_is_reported_clearly(pty_sim: SimulatorServer) -> None:
    async with marlin_aio.connect(pty_sim.url):
        with pytest.raises(marlin_aio.PortBusyError, match="in use"):
            async with marlin_aio.connect(pty_sim.url):
                pass


async def test_nothing_listening_on_tcp_is_a_connect_error() -> None:
    with pytest.raises(marlin_aio.ConnectError, match="refused"):
        async with marlin_aio.connect("socket://127.0.0.1:9"):
            pass


async def test_a_silent_port_fails_the_handshake_with_the_step(dead_pty: tuple[int, str]) -> None:
    _, path = dead_pty
    with pytest.raises(marlin_aio.HandshakeTimeoutError, match="nothing was received") as caught:
        async with marlin_aio.connect(path, timeout_s=0.5):
            pass
    assert caught.value.step == "sync"


async def test_garbage_at_the_wrong_baud_rate_suggests_the_other_rate(dead_pty: tuple[int, str]) -> None:
    master, path = dead_pty
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()

    async def babble() -> None:
        while not stop.is_set():
            os.write(master, b"\x80\xfe\x13\xff\xc3\x00garbage\xf0\n")
            await asyncio.sleep(0.05)

    noise = loop.create_task(babble())
    try:
        with pytest.raises(
            marlin_aio.HandshakeTimeoutError, match=r"wrong baud rate\? 250000 is set \(Marlin boards use 115200\)"
        ):
            async with marlin_aio.connect(path, timeout_s=0.6):
                pass
    finally:
        stop.set()
        await noise


async def wait_until_sent(printer: marlin_aio.Printer, text: str) -> None:
    """Wait (on events, not time) until `text` was written: the trace grows as lines go out."""
    for _ in range(10_000):
        if any(e.direction == "sent" and text in e.text for e in printer.trace.entries()):
            return
        await asyncio.sleep(0)
    raise AssertionError(f"{text!r} was never sent")


@pytest.mark.parametrize(
    "error",
    [
        "device reports readiness to read but returned no data (device disconnected or multiple access on port?)",
        "write failed: [Errno 5] Input/output error",  # a write that found the port gone, as pyserial words it
    ],
)
def test_a_port_that_went_away_is_said_in_words_whichever_way_pyserial_noticed(error: str) -> None:
    import serial

    from marlin_aio.aio.link import _why_lost

    assert _why_lost(serial.SerialException(error)).startswith(": the port went away")
    assert _why_lost(ValueError("something else")) == ": something else"


async def test_send_refuses_a_target_above_the_clients_limit_before_writing(
    mem_printer: marlin_aio.Printer, mem_sim: SimulatorServer
) -> None:
    before = mem_sim.printer.executed_count
    for command in ("M104 S300", "N7 m140 s200", "M190 R141"):
        with pytest.raises(ValueError, match="above the limit"):
            await mem_printer.send(command)
    await mem_printer.send("M104 S200")  # within the limit: sent as before
    assert mem_sim.printer.executed_count == before + 1


@pytest.mark.parametrize("advanced_ok", [False, True], ids=["plain-ok", "advanced-ok"])
async def test_a_g28_answered_long_after_its_timeout_never_answers_the_next_caller(advanced_ok: bool) -> None:
    # Before: a G28 taking 3x its timeout on a board without busy keepalives, then `send("M118 E1 tag0")`
    # returned G28's lines (8 of 8 runs, polling and ADVANCED_OK included). The G28 now waits in doubt for its
    # own late ok (or a probe's answer), and the next caller gets its own reply.
    config = SimulatorConfig(keepalive_interval_s=0, homing_s=3.0, advanced_ok=advanced_ok)
    async with serve_memory(config, time_scale=TIME_SCALE) as server, marlin_aio.connect(server.url) as printer:
        homing_real_s = config.homing_s / TIME_SCALE
        with pytest.raises(marlin_aio.CommandTimeoutError):
            await printer.send("G28", timeout_s=homing_real_s / 3)
        for tag in range(3):
            reply = await printer.send(f"M118 E1 tag{tag}", timeout_s=5.0)
            assert reply.lines == (f"echo:tag{tag}",)
        assert "G28" in server.printer.executed
