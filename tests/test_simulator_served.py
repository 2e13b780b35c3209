"""The simulated printer served on a real pseudo-terminal and on TCP, and the `marlin-sim` command.

Raw bytes only (os.read/os.write, asyncio streams, plain pyserial): the marlin_aio client is not involved, so a
failure here is the simulator's. Every wait is a read with a timeout, never a sleep.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import termios
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
import serial

from marlin_aio.protocol.commands import number_command
from marlin_aio.simulator import Faults, SimulatorConfig, SimulatorServer, generate_moves, serve_pty, serve_tcp

TIME_SCALE = 50.0
IDLE_M105 = "ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"
BAUD = 250_000
BYTE_S = 10 / BAUD


class PtyClient:
    """The host end of a pty, read through the event loop so the server keeps running meanwhile."""

    def __init__(self, path: str) -> None:
        # No tcsetattr here: the server made the terminal raw, and TCSAFLUSH would throw the banner away.
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.eof = False
        self._buffer = bytearray()
        self._arrived = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self.fd, self._on_readable)

    def _on_readable(self) -> None:
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.eof = True
            self._loop.remove_reader(self.fd)
        self._buffer += data
        self._arrived.set()

    def send(self, text: str) -> None:
        self.write(text.encode() + b"\n")

    def write(self, data: bytes) -> None:
        assert os.write(self.fd, data) == len(data)  # small enough for the pty's buffer

    async def readline(self, timeout_s: float = 5.0) -> str:
        async with asyncio.timeout(timeout_s):
            while b"\n" not in self._buffer:
                if self.eof:
                    raise EOFError("the pty was closed")
                self._arrived.clear()
                await self._arrived.wait()
        end = self._buffer.index(b"\n")
        line = self._buffer[:end].decode("latin-1")
        del self._buffer[: end + 1]
        return line

    async def wait_eof(self, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while not self.eof:
                self._arrived.clear()
                await self._arrived.wait()

    def close(self) -> None:
        if not self.eof:
            self._loop.remove_reader(self.fd)
        os.close(self.fd)


@asynccontextmanager
async def pty_client(path: str) -> AsyncIterator[PtyClient]:
    client = PtyClient(path)
    try:
        yield client
    finally:
        client.close()


async def read_until(readline: Callable[[], object], predicate: Callable[[str], bool]) -> list[str]:
    """Read lines until one satisfies `predicate`; return them all."""
    seen: list[str] = []
    while True:
        line = await readline()  # type: ignore[misc]
        assert isinstance(line, str)
        seen.append(line)
        if predicate(line):
            return seen


async def tcp_readline(reader: asyncio.StreamReader, timeout_s: float = 5.0) -> str:
    async with asyncio.timeout(timeout_s):
        line = await reader.readline()
    if not line:
        raise EOFError("the connection was closed")
    return line.decode("latin-1").rstrip("\n")


def host_port(server: SimulatorServer) -> tuple[str, int]:
    host, port = server.url.removeprefix("socket://").rsplit(":", 1)
    return host, int(port)


# ---------------------------------------------------------------------------------------------------------- pty


@pytest.mark.parametrize("baud_rate", [None, BAUD])
async def test_pty_serves_the_banner_and_answers_m105(baud_rate: int | None) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=baud_rate) as sim,
        pty_client(sim.url) as host,
    ):
        assert sim.url.startswith("/dev/")
        banner = await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        assert banner[:2] == ["start", "PowerUp"]
        for _ in range(3):
            host.send("M105")
            assert await host.readline() == IDLE_M105


@pytest.mark.parametrize("baud_rate", [None, BAUD])
async def test_pty_long_commands_keepalives_and_ordered_oks(baud_rate: int | None) -> None:
    config = SimulatorConfig(advanced_ok=True, homing_s=6.0)
    async with (
        serve_pty(config, time_scale=TIME_SCALE, baud_rate=baud_rate) as sim,
        pty_client(sim.url) as host,
    ):
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        host.send("G28\nM118 E1 after\nM114")
        replies = await read_until(host.readline, lambda line: line == "echo:after")
        assert replies == [
            "echo:busy: processing",
            "echo:busy: processing",
            "echo:busy: processing",
            "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
            "ok P15 B1",  # M118 and M114 were read in while G28 ran
            "echo:after",
        ]
        assert [await host.readline() for _ in range(3)] == ["ok P15 B2", replies[3], "ok P15 B3"]
        assert sim.printer.executed == ["G28", "M118 E1 after", "M114"]


async def test_pyserial_opens_the_pty_at_250000_baud() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE) as sim:

        def round_trip() -> list[bytes]:
            with serial.Serial(sim.url, 250000, timeout=5, exclusive=True) as port:
                port.reset_input_buffer()
                replies = []
                for _ in range(3):
                    port.write(b"M105\n")
                    replies.append(port.readline())
                return replies

        assert await asyncio.to_thread(round_trip) == [IDLE_M105.encode() + b"\n"] * 3


@pytest.mark.parametrize("baud_rate", [None, BAUD])
async def test_pty_reset_on_open_gives_pyserial_the_banner_after_its_open(baud_rate: int | None) -> None:
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=baud_rate, reset_on_open=True) as sim:
        sim.printer.take_output()

        def session() -> list[bytes]:
            # pyserial's open() flushes the input at its end: the banner must come after that, as from a board
            # that DTR reset.
            with serial.Serial(sim.url, 250000, timeout=5) as port:
                received = [port.readline() for _ in range(3)]
                while not received[-1].startswith(b"echo:  M301"):
                    received.append(port.readline())
                port.reset_input_buffer()  # a flush is no open: no second reset
                port.write(b"M105\n")
                received.append(port.readline())
                return received

        for cause in ("External Reset", "External Reset"):  # every open resets, not only the first
            received = await asyncio.to_thread(session)
            assert received[:3] == [b"start\n", cause.encode() + b"\n", b"Marlin 2.1.2.4\n"]
            assert received[-1] == IDLE_M105.encode() + b"\n"
            assert received.count(b"start\n") == 1


async def test_pty_reset_on_open_resets_on_a_plain_open_too_and_keeps_raw_bytes() -> None:
    # os.open sets nothing up, but it is an open: DTR rises and the board resets. A client that does not flush
    # reads the power-up banner that waited in the terminal, then the reset's.
    async with (
        serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, reset_on_open=True) as sim,
        pty_client(sim.url) as host,
    ):
        banner = await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        assert banner[:2] == ["start", "PowerUp"]
        banner = await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        assert banner[:2] == ["start", "External Reset"]
        host.write(b"M118 a\rM105\n")  # the host's bytes and the replies pass unchanged
        assert [await host.readline() for _ in range(3)] == ["a", "ok", IDLE_M105]
    with pytest.raises(ValueError, match="reset_on_open"):
        SimulatorServer(SimulatorConfig(), None, kind="tcp", reset_on_open=True)


async def test_pty_settings_changed_on_an_open_port_do_not_reset_the_board() -> None:
    # OctoPrint changes its port's timeouts (and may try another baud rate) in the middle of a session: each is a
    # tcsetattr() on the open port, which a real board never notices. Only the open's DTR edge resets it.
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, reset_on_open=True) as sim:

        def session() -> list[bytes]:
            with serial.Serial(sim.url, 250000, timeout=5) as port:
                received = [port.readline()]
                while not received[-1].startswith(b"echo:  M301"):
                    received.append(port.readline())
                port.write(b"M104 S200\n")
                received.append(port.readline())
                port.baudrate = 115200
                port.write_timeout = 1
                port.inter_byte_timeout = 0.1
                port.baudrate = 250000
                port.inter_byte_timeout = None
                port.timeout = 0.5  # a reset would print its banner within 0.05 s: none comes
                received.append(port.read(1))
                port.timeout = 5
                port.write(b"M105\n")
                received.append(port.readline())
                return received

        received = await asyncio.to_thread(session)
        assert sim.printer.executed == ["M104 S200", "M105"]
    assert received[:2] == [b"start\n", b"External Reset\n"]
    assert received.count(b"start\n") == 1
    assert received[-3:-1] == [b"ok\n", b""]
    assert received[-1].startswith(b"ok T:") and b" /200.00 " in received[-1]  # the target survived


async def test_pty_reset_on_open_only_when_the_last_close_dropped_dtr() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, reset_on_open=True) as sim:

        def session(hupcl: bool) -> list[bytes]:
            """Open, get an M105 answered, and close leaving HUPCL as `hupcl` says; return what was read."""
            with serial.Serial(sim.url, 250000, timeout=5) as port:
                port.write(b"M105\n")  # dropped if the board is in its bootloader: sent again after the banner
                received = [port.readline()]
                while not received[-1].startswith(b"ok T:"):
                    if received[-1].startswith(b"echo:  M301"):
                        port.write(b"M105\n")
                    received.append(port.readline())
                attributes = termios.tcgetattr(port.fileno())
                attributes[2] = attributes[2] | termios.HUPCL if hupcl else attributes[2] & ~termios.HUPCL
                termios.tcsetattr(port.fileno(), termios.TCSANOW, attributes)
                return received

        # The first open raises DTR (a reset); a close with HUPCL cleared leaves it up, one with HUPCL set drops it.
        opens = [await asyncio.to_thread(session, hupcl) for hupcl in (False, True, True, False, False)]
        assert [received.count(b"start\n") for received in opens] == [1, 0, 1, 1, 0]
        assert all(received[-1] == IDLE_M105.encode() + b"\n" for received in opens)


async def test_pty_disconnect_makes_the_host_see_the_link_drop() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE) as sim, pty_client(sim.url) as host:
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        host.send("G4 S60")
        await sim.disconnect()
        await host.wait_eof()
        assert not sim.connected


async def test_pyserial_raises_after_disconnect() -> None:
    async with serve_pty(SimulatorConfig(), time_scale=TIME_SCALE) as sim:
        port = serial.Serial(sim.url, 250000, timeout=5)
        try:
            await sim.disconnect()
            with pytest.raises(serial.SerialException):
                await asyncio.to_thread(port.read, 1)
        finally:
            port.close()


async def test_manual_clock_moves_only_when_poked() -> None:
    simulated = [0.0]
    async with (
        serve_pty(SimulatorConfig(), clock=lambda: simulated[0]) as sim,
        pty_client(sim.url) as host,
    ):
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        host.send("G4 S1")
        host.send("M105")
        with pytest.raises(TimeoutError):
            await host.readline(timeout_s=0.3)
        simulated[0] = 1.1  # G4's second, and the command loop's time over each of the two (about 5 ms)
        sim.poke()
        assert await host.readline() == "ok"
        assert await host.readline() == IDLE_M105


@pytest.mark.parametrize("baud_rate", [None, BAUD])
async def test_pause_holds_replies_until_resume(baud_rate: int | None) -> None:
    async with (
        serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=baud_rate) as sim,
        pty_client(sim.url) as host,
    ):
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        sim.pause()
        host.send("M105")
        with pytest.raises(TimeoutError):
            await host.readline(timeout_s=0.3)
        sim.resume()
        assert await host.readline() == IDLE_M105


async def test_faults_and_one_shots_while_served() -> None:
    faults = Faults()
    async with serve_pty(SimulatorConfig(), faults, time_scale=TIME_SCALE) as sim, pty_client(sim.url) as host:
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        faults.silent = True
        host.send("M105")
        with pytest.raises(TimeoutError):
            await host.readline(timeout_s=0.3)
        faults.silent = False
        host.send("M105")
        assert await host.readline() == IDLE_M105
        sim.printer.thermal_runaway(sim.now(), heater="bed")
        sim.poke()
        assert await host.readline() == "Error:Thermal Runaway, system stopped! Heater_ID: bed"
        assert await host.readline() == "Error:Printer halted. kill() called!"
        sim.printer.reset(sim.now())
        sim.poke()
        assert (await host.readline(), await host.readline()) == ("start", "External Reset")


async def test_a_server_paused_before_it_starts_holds_the_banner_on_the_wire() -> None:
    sim = serve_pty(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=BAUD)
    assert sim.baud_rate == BAUD
    sim.pause()
    async with sim, pty_client(sim.url) as host:
        with pytest.raises(TimeoutError):
            await host.readline(timeout_s=0.2)
        sim.resume()
        banner = await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        assert banner[:2] == ["start", "PowerUp"]


def test_server_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="time_scale"):
        serve_pty(time_scale=0)
    with pytest.raises(ValueError, match="baud_rate"):
        serve_tcp(baud_rate=0)
    with pytest.raises(RuntimeError, match="not started"):
        _ = serve_tcp().url


# ---------------------------------------------------------------------------------------------------------- tcp


@pytest.mark.parametrize("baud_rate", [None, BAUD])
async def test_tcp_resets_on_connect_and_answers_m105(baud_rate: int | None) -> None:
    async with serve_tcp(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=baud_rate) as sim:
        assert sim.url.startswith("socket://127.0.0.1:")
        reader, writer = await asyncio.open_connection(*host_port(sim))
        try:
            banner = await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
            assert banner[:2] == ["start", "External Reset"]
            for _ in range(3):
                writer.write(b"M105\n")
                assert await tcp_readline(reader) == IDLE_M105
        finally:
            writer.close()
            await writer.wait_closed()


async def test_tcp_connect_finds_the_board_in_its_bootloader() -> None:
    # 10 simulated seconds at time scale 50: 0.2 s of silence, in which what the host sends is lost.
    async with serve_tcp(SimulatorConfig(boot_delay_s=10.0), time_scale=TIME_SCALE) as sim:
        reader, writer = await asyncio.open_connection(*host_port(sim))
        try:
            writer.write(b"M118 E1 too early\n")
            banner = await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
            assert banner[:2] == ["start", "External Reset"]
            writer.write(b"M118 E1 in time\n")
            assert [await tcp_readline(reader) for _ in range(2)] == ["echo:in time", "ok"]
            assert sim.printer.executed == ["M118 E1 in time"]
        finally:
            writer.close()
            await writer.wait_closed()


async def test_tcp_accepts_one_client_at_a_time_and_disconnect_drops_it() -> None:
    async with serve_tcp(SimulatorConfig(), time_scale=TIME_SCALE) as sim:
        reader, writer = await asyncio.open_connection(*host_port(sim))
        await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
        second_reader, second_writer = await asyncio.open_connection(*host_port(sim))
        with pytest.raises(EOFError):
            await tcp_readline(second_reader)
        second_writer.close()
        assert sim.connected

        await sim.disconnect()
        with pytest.raises(EOFError):
            await tcp_readline(reader)
        writer.close()
        assert not sim.connected

        # Plugged back in: a new client finds a freshly reset board.
        reader, writer = await asyncio.open_connection(*host_port(sim))
        assert (await tcp_readline(reader), await tcp_readline(reader)) == ("start", "External Reset")
        writer.close()
        await writer.wait_closed()


# ------------------------------------------------------------------------------------------------- the wire


async def test_the_host_bytes_reach_the_printer_at_wire_speed_in_real_time() -> None:
    # 2,500-odd bytes at 25,000 bytes a second take at least 0.1 s of the loop's clock, however fast the
    # simulated firmware runs (time scale 50) and however fast the pty could carry them.
    config = SimulatorConfig(motion_time_scale=0.0)
    async with (
        serve_pty(config, time_scale=TIME_SCALE, baud_rate=BAUD) as sim,
        pty_client(sim.url) as host,
    ):
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        commands = [*generate_moves(60), "M118 E1 done"]
        data = "".join(number_command(command, n) + "\n" for n, command in enumerate(commands, start=1)).encode()
        assert 2500 <= len(data) < 2600
        loop = asyncio.get_running_loop()
        started = loop.time()
        host.write(data)
        replies = await read_until(host.readline, lambda line: line == "echo:done")
        assert loop.time() - started >= len(data) * BYTE_S
        assert replies.count("ok") == len(commands) - 1
        assert sim.printer.executed == commands
        assert sim.printer.executed_line_numbers == list(range(1, len(commands) + 1))
        assert (sim.printer.rx_overflows, sim.printer.rx_dropped_bytes) == (0, 0)


async def test_the_printer_replies_reach_the_host_at_wire_speed() -> None:
    async with serve_tcp(SimulatorConfig(), time_scale=TIME_SCALE, baud_rate=BAUD) as sim:
        reader, writer = await asyncio.open_connection(*host_port(sim))
        try:
            await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
            loop = asyncio.get_running_loop()
            started = loop.time()
            writer.write(b"M115\n")
            reply = await read_until(lambda: tcp_readline(reader), lambda line: line == "ok")
            reply_bytes = sum(len(line) + 1 for line in reply)
            assert reply_bytes > 900
            assert loop.time() - started >= (5 + reply_bytes) * BYTE_S
        finally:
            writer.close()
            await writer.wait_closed()


async def test_a_blocked_printer_overflows_at_wire_speed_and_counts_it() -> None:
    config = SimulatorConfig(command_buffer_size=1)
    async with (
        serve_pty(config, time_scale=TIME_SCALE, baud_rate=BAUD) as sim,
        pty_client(sim.url) as host,
    ):
        await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
        # M109 blocks the only command slot until M108, which the emergency parser sees however full the
        # receive buffer is; meanwhile 304 bytes of lines meet a 128-byte buffer.
        flood = b"M118 E1 0123456789\n" * 16
        host.write(b"M109 S200\n" + flood + b"M108\n")
        await read_until(host.readline, lambda line: line == "ok")
        replies = [await host.readline() for _ in range(12)]
        assert replies == ["echo:0123456789", "ok"] * 6  # the 6 whole lines that fitted (114 bytes)
        assert sim.printer.rx_overflows >= 1
        assert sim.printer.rx_dropped_bytes == len(flood) + 5 - 128
        assert sim.printer.executed == ["M109 S200"] + ["M118 E1 0123456789"] * 6


# -------------------------------------------------------------------------------------------------- the command


async def _start_command(*arguments: str) -> tuple[asyncio.subprocess.Process, str]:
    process = await asyncio.create_subprocess_exec(
        *arguments, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
    )
    assert process.stdout is not None
    async with asyncio.timeout(20):
        first_line = (await process.stdout.readline()).decode().strip()
    return process, first_line


async def _stop_command(process: asyncio.subprocess.Process, signum: int) -> str:
    process.send_signal(signum)
    async with asyncio.timeout(20):
        _, stderr = await process.communicate()
    assert process.returncode == 0
    assert b"Traceback" not in stderr
    assert b"marlin-sim:" in stderr
    return stderr.decode()


async def test_module_command_prints_the_pty_path_first_and_stops_on_sigint() -> None:
    process, url = await _start_command(
        sys.executable, "-m", "marlin_aio.simulator", "--time-scale", "20", "--baud", "250000"
    )
    stderr = ""
    try:
        assert url.startswith("/dev/")
        async with pty_client(url) as host:
            await read_until(host.readline, lambda line: line.startswith("echo:  M301"))
            host.send("M105")
            assert await host.readline() == IDLE_M105
            host.send(number_command("M400", 1))
            assert await host.readline() == "ok"
    finally:
        stderr = await _stop_command(process, signal.SIGINT)
    assert ", 250000 baud" in stderr
    assert "2 commands run, 1 of them numbered; 0 received bytes dropped in 0 overflows" in stderr


async def test_console_script_serves_tcp_and_stops_on_sigterm() -> None:
    script = Path(sys.executable).parent / "marlin-sim"
    if not script.exists():
        pytest.skip("the marlin-sim console script is not installed next to this interpreter")
    process, url = await _start_command(
        str(script),
        "--tcp",
        "0",
        "--advanced-ok",
        "--extruders",
        "2",
        "--motion-time-scale",
        "0",
        "--silent-after-lines",
        "1",
    )
    try:
        assert url.startswith("socket://127.0.0.1:")
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))
        await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
        writer.write(b"M115\n")
        identity = await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("ok"))
        assert " EXTRUDER_COUNT:2 " in identity[0]
        assert identity[-1] == "ok P15 B3"
        writer.write(b"N1 G1 X100 F60*0\nM105\n")  # 100 s of motion made instant, then the stall
        assert (await tcp_readline(reader)).startswith("ok N1 P15 B")  # B2 when M105 was read in with it
        with pytest.raises(TimeoutError):
            await tcp_readline(reader, timeout_s=0.3)
        writer.close()
        await writer.wait_closed()
    finally:
        await _stop_command(process, signal.SIGTERM)


async def test_command_rejects_bad_options() -> None:
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "marlin_aio.simulator", "--drop-ok", "2", stderr=asyncio.subprocess.PIPE
    )
    async with asyncio.timeout(20):
        _, stderr = await process.communicate()
    assert process.returncode == 2
    assert b"between 0 and 1" in stderr


def test_every_dialect_switch_has_a_flag() -> None:
    from marlin_aio.simulator.__main__ import _build_parser, _settings

    arguments = _build_parser().parse_args(
        [
            *("--checksum-required", "--plain-wait-lines", "--bare-busy", "--repetier-targets", "--m114-on-ok"),
            *("--password", "1234", "--not-executed", "0.25"),
        ]
    )
    config, faults = _settings(arguments)
    assert (config.checksum_required, config.plain_wait_lines, config.bare_busy) == (True, True, True)
    assert (config.repetier_targets, config.m114_on_ok, config.password) == (True, True, "1234")
    assert faults.not_executed_ratio == 0.25
    config, faults = _settings(_build_parser().parse_args([]))
    assert config == SimulatorConfig()
    assert faults == Faults()


def test_the_shared_option_table_builds_the_serve_settings() -> None:
    from marlin_aio.simulator._options import SimulatorSettings, build_parser, simulator_settings

    arguments = build_parser("marlin-temp sim").parse_args(
        [
            *("--tcp", "0", "--time-scale", "5", "--baud", "9600", "--no-bed", "--seed", "3", "--drop-ok", "0.5"),
            *("--boot-delay", "1.5", "--flip-bits", "0.001"),
        ]
    )
    settings = simulator_settings(arguments)
    assert (settings.tcp_port, settings.host, settings.time_scale, settings.baud_rate) == (0, "127.0.0.1", 5.0, 9600)
    assert settings.config == SimulatorConfig(has_bed=False, seed=3, boot_delay_s=1.5)
    assert settings.faults == Faults(drop_ok_ratio=0.5, flip_bit_ratio=0.001)
    assert simulator_settings(build_parser().parse_args([])) == SimulatorSettings()


async def test_command_serves_a_locked_repetier_dialect_over_tcp() -> None:
    process, url = await _start_command(
        sys.executable,
        *("-m", "marlin_aio.simulator", "--tcp", "0", "--time-scale", "20"),
        *("--password", "42", "--repetier-targets", "--m114-on-ok", "--checksum-required"),
    )
    stderr = ""
    try:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))
        await read_until(lambda: tcp_readline(reader), lambda line: line.startswith("echo:  M301"))
        writer.write(b"M105\n")
        assert await tcp_readline(reader) == "Error: Missing checksum"
        writer.write(f"{number_command('M110 N0', 0)}\n{number_command('M105', 1)}\n".encode())
        # Locked, M110 too is refused; its line number counts all the same (it was taken as the line was read).
        assert [await tcp_readline(reader) for _ in range(4)] == [
            "echo:Printer locked! (Unlock with M511 or LCD)",
            "ok",
        ] * 2
        writer.write(f"{number_command('M511 P42', 2)}\n{number_command('M104 S200', 3)}\n".encode())
        writer.write(f"{number_command('M114', 4)}\n".encode())
        assert [await tcp_readline(reader) for _ in range(4)] == [
            "ok",
            "TargetExtr0:200",
            "ok",
            "ok X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
        ]
        writer.close()
        await writer.wait_closed()
    finally:
        stderr = await _stop_command(process, signal.SIGTERM)
    assert "repetier_targets, m114_on_ok, locked (M511)" in stderr
    assert "3 commands run, 3 of them numbered" in stderr


async def test_command_rejects_a_password_it_could_not_send() -> None:
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "marlin_aio.simulator", "--password", "a;b", stderr=asyncio.subprocess.PIPE
    )
    async with asyncio.timeout(20):
        _, stderr = await process.communicate()
    assert process.returncode == 2
    assert b"password" in stderr
