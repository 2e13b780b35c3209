"""Ports that are not a polite printer: one that chatters garbage with `ok` lines in it, one nobody answers while
the user presses Ctrl-C (or systemd sends SIGTERM), one unplugged while the client writes.

Each is a real pty whose far end a thread drives (`Chatter`), against the library in this process or a real
`marlin-temp` process. Every wait is bounded; none is a sleep standing in for an event.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import pty
import random
import signal
import struct
import sys
import termios
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

import marlin_aio
from marlin_aio.aio.handshake import handshake_bound_s
from marlin_aio.simulator import SimulatorConfig, serve_pty

#: Lines a chattering port mixes into its garbage: an M105's ok and a busy keepalive (each settles or restarts
#: something in a waiting command: the handshake waited for ever on them, at M115).
CHATTER_LINES = (b"ok T:20.0 /0.0 B:20.0 /0.0", b"echo:busy: processing")

#: An answer to everything the client may ask while watching: a flood of these keeps its poller writing.
ANSWER = b"ok T:20.0 /0.0 B:20.0 /0.0\n"


class Chatter:
    """A pty whose far end a thread writes to until `stop()`: garbage and `lines` (or only `lines` with
    `garbage=False`), a burst every `pause_s`; with `drain`, it also reads what the client writes."""

    def __init__(self, lines: tuple[bytes, ...], *, pause_s: float, garbage: bool = True, drain: bool = True) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self._lines = lines
        self._pause_s = pause_s
        self._garbage = garbage
        self._drain = drain
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="chatter", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        rng = random.Random(34)
        pending = b""
        while not self._stop.is_set():
            if not pending:
                noise = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 48))) if self._garbage else b""
                pending = noise + b"\n" + rng.choice(self._lines) + b"\n"
            try:
                if self._drain:
                    while os.read(self.master, 4096):
                        pass
            except (BlockingIOError, OSError):
                pass
            try:
                pending = pending[os.write(self.master, pending) :]
            except BlockingIOError:
                pass  # the client is not reading now: try again after the pause
            except OSError:
                return
            if self._pause_s or pending:
                self._stop.wait(self._pause_s or 0.001)  # the chatter's pace, not a synchronisation

    def unread_bytes(self) -> int:
        """What the client wrote and the far end has not read (the pty holds at most about 4 KiB of it)."""
        return int(struct.unpack("i", fcntl.ioctl(self.master, termios.FIONREAD, b"\0\0\0\0"))[0])

    def stop(self) -> None:
        """Stop writing (the pty stays open)."""
        self._stop.set()
        self._thread.join(timeout=10)
        assert not self._thread.is_alive(), "the chatter thread did not stop"

    def unplug(self) -> None:
        """Pull the cable: stop and close the far end, so the client's next read or write fails."""
        self.stop()
        os.close(self.master)
        self.master = -1

    def close(self) -> None:
        self.stop()
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)


@pytest.fixture
def chattering_pty() -> Iterator[Chatter]:
    """A port that chatters garbage with ok lines (and busy keepalives) in it, a burst every 20 ms, and reads
    nothing of what the client writes."""
    chatter = Chatter(CHATTER_LINES, pause_s=0.02, drain=False)
    try:
        yield chatter
    finally:
        chatter.close()


def _marlin_temp(*args: str) -> list[str]:
    return [sys.executable, "-m", "marlin_temp", *args]


async def _run(command: list[str], limit_s: float) -> tuple[int, str, float]:
    """Run `command` to its end (killed after `limit_s`, which fails the test); return its exit code, stderr and
    how long it took."""
    started = time.monotonic()
    process = await asyncio.create_subprocess_exec(
        *command, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE
    )
    try:
        async with asyncio.timeout(limit_s):
            _, stderr = await process.communicate()
    except TimeoutError:
        process.kill()
        await process.wait()
        raise AssertionError(f"{' '.join(command[2:])} still ran after {limit_s:g} s") from None
    assert process.returncode is not None
    return process.returncode, stderr.decode(), time.monotonic() - started


# ------------------------------------------------------------------------------------------- a chattering port


async def test_connect_on_a_chattering_port_fails_within_the_handshake_bound(chattering_pty: Chatter) -> None:
    timeout_s = 0.5
    loop = asyncio.get_running_loop()
    started = loop.time()

    async def connect() -> None:
        # The outer bound only keeps a hang from stopping the suite: its plain TimeoutError would fail the test.
        async with (
            asyncio.timeout(handshake_bound_s(timeout_s) + 30),
            marlin_aio.connect(chattering_pty.path, timeout_s=timeout_s),
        ):
            pass

    with pytest.raises(marlin_aio.HandshakeTimeoutError) as caught:
        await connect()
    elapsed = loop.time() - started
    assert elapsed <= handshake_bound_s(timeout_s) + 1.0, elapsed
    message = str(caught.value)
    assert "\n" not in message and chattering_pty.path in message, message
    assert caught.value.step in ("boot", "sync", "identify")


async def test_watch_on_a_chattering_port_fails_with_one_line_and_exit_6(chattering_pty: Chatter) -> None:
    code, stderr, elapsed = await _run(
        _marlin_temp("watch", "--port", chattering_pty.path, "--baud", "250000", "--timeout", "0.5"), limit_s=60
    )
    assert code == 6, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and chattering_pty.path in lines[0], stderr
    # One handshake at one rate: its bound, and the interpreter's start.
    assert elapsed < handshake_bound_s(0.5) + 20, elapsed


async def test_print_on_a_chattering_port_tries_both_rates_then_fails_with_one_line(
    chattering_pty: Chatter, tmp_path: Path
) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\nG1 X10 Y10 F3000\n")
    code, stderr, elapsed = await _run(
        _marlin_temp("print", str(gcode), "--port", chattering_pty.path, "--timeout", "0.5"), limit_s=60
    )
    assert code == 6, stderr
    lines = stderr.splitlines()
    assert lines[0] == "no answer at 250000 baud, trying 115200", stderr
    assert len(lines) == 2 and lines[1].startswith("error: no answer from"), stderr
    assert "Traceback" not in stderr
    assert elapsed < 2 * handshake_bound_s(0.5) + 20, elapsed


# ------------------------------------------------------------------------------------------- Ctrl-C, SIGTERM


@pytest.mark.parametrize(
    ("command", "signum"),
    [("watch", signal.SIGINT), ("print", signal.SIGINT), ("print", signal.SIGTERM), ("log", signal.SIGTERM)],
)
async def test_a_stop_signal_during_the_baud_fallback_ends_the_command_at_once_with_130(
    dead_pty: tuple[int, str], tmp_path: Path, command: str, signum: signal.Signals
) -> None:
    _, path = dead_pty
    timeout_s = 8.0  # the second handshake alone would take longer than the signal may
    extra = {
        "watch": [],
        "print": [str(tmp_path / "part.gcode")],
        "log": ["--output", str(tmp_path / "log.csv")],
    }[command]
    (tmp_path / "part.gcode").write_text("G28\n")
    process = await asyncio.create_subprocess_exec(
        *_marlin_temp(command, *extra, "--port", path, "--timeout", f"{timeout_s:g}"),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stderr is not None
    try:
        async with asyncio.timeout(60):
            first = (await process.stderr.readline()).decode()
        assert first.strip() == "no answer at 250000 baud, trying 115200", first
        process.send_signal(signum)
        signalled = time.monotonic()
        async with asyncio.timeout(30):
            rest = (await process.stderr.read()).decode()
            await process.wait()
        after_s = time.monotonic() - signalled
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
    assert process.returncode == 130, rest
    assert rest.splitlines() == ["interrupted"], rest
    assert after_s < timeout_s / 2, after_s


# ------------------------------------------------------------------------------------------- unplugged


async def test_a_write_to_an_unplugged_port_is_one_connection_lost_error_and_no_loop_error() -> None:
    loop = asyncio.get_running_loop()
    reported: list[str] = []
    previous = loop.get_exception_handler()
    loop.set_exception_handler(lambda _loop, context: reported.append(str(context.get("message"))))
    try:
        async with serve_pty(SimulatorConfig(), time_scale=20) as sim, marlin_aio.connect(sim.url) as printer:
            await sim.disconnect()
            # Written at once, before the loop's next read could notice the hang-up: the write is what fails.
            with pytest.raises(marlin_aio.ConnectionLostError, match="the port went away"):
                await asyncio.wait_for(printer.send("M105"), 10)
            assert not printer.is_connected
    finally:
        loop.set_exception_handler(previous)
    assert reported == []


async def test_a_port_that_takes_no_bytes_fails_the_handshake_instead_of_holding_the_loop(
    dead_pty: tuple[int, str],
) -> None:
    # Output stopped (as by XOFF): every write finds the port full. pyserial's write retried that for ever and
    # held the event loop: no timeout, no Ctrl-C, no SIGTERM; only SIGKILL ended it.
    _, path = dead_pty
    slave = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        termios.tcflow(slave, termios.TCOOFF)
        code, stderr, elapsed = await _run(
            _marlin_temp("send", "M105", "--port", path, "--baud", "250000", "--timeout", "0.5"), limit_s=60
        )
    finally:
        os.close(slave)
    assert code == 6, stderr
    assert stderr.splitlines() == [
        f"error: no answer from {path} within 0.5 s: nothing was received "
        "(is this the printer's port, and is it powered?)"
    ], stderr
    assert elapsed < handshake_bound_s(0.5) + 20, elapsed


async def test_watch_unplugged_while_writing_says_one_line_and_no_traceback() -> None:
    # The far end answers every poll; once watch shows readings, its output is stopped (its writes wait in the
    # transport's buffer) and then the cable is pulled: the write that fails is what used to print a traceback.
    chatter = Chatter((b"ok", ANSWER.strip()), pause_s=0.005, garbage=False)
    process = await asyncio.create_subprocess_exec(
        *_marlin_temp("watch", "--port", chatter.path, "--baud", "250000", "--timeout", "2", "--interval", "0.05"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdout is not None and process.stderr is not None
    try:
        async with asyncio.timeout(60):
            assert "hotend 20.0" in (await process.stdout.readline()).decode()
            termios.tcflow(chatter.slave, termios.TCOOFF)
            # Two more rows: polls were written (into the buffer) meanwhile, and the loop still runs.
            for _ in range(2):
                assert (await process.stdout.readline()).decode().strip()
        chatter.unplug()
        async with asyncio.timeout(30):
            _, stderr_bytes = await process.communicate()
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
        chatter.close()
    stderr = stderr_bytes.decode()
    assert process.returncode == 8, stderr
    assert "Fatal write error" not in stderr and "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "was lost: the port went away" in errors[0], stderr
