"""The processes of a run: the simulated printer (`marlin-sim`) and the client worker, each bounded in time.

Every simulator is stopped in a `finally`, SIGTERM first and SIGKILL if it does not go within a few seconds, and
every worker runs under a timeout after which it is killed; nothing here is ever left behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import selectors
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks._worker import RESULT_MARKER

__all__ = [
    "UNPACED",
    "BenchmarkRunError",
    "Broker",
    "Simulator",
    "mosquitto",
    "mosquitto_path",
    "run_worker",
    "simulator",
    "subscriber",
]

#: The unpaced simulator of the ratio scenarios: no baud rate and no command loop time (`--command-time`), so a
#: command is answered the moment it arrives and the clients' own costs are all that differ.
UNPACED = ["--command-time", "0", "--report-time", "0"]

_START_TIMEOUT_S = 15.0
_STOP_TIMEOUT_S = 5.0
_SUMMARY = re.compile(
    r"stopped; (?P<commands>\d+) commands run, (?P<numbered>\d+) of them numbered; "
    r"(?P<dropped>\d+) received bytes dropped in (?P<overflows>\d+) overflows"
)


class BenchmarkRunError(RuntimeError):
    """A simulator or worker process failed, hung, or printed no result."""


@dataclass
class Simulator:
    """A running `marlin-sim`: `url` to open (`urls` with `--printers N`); after it stopped, `summary` holds its own
    counters, summed over its printers."""

    url: str
    arguments: list[str]
    summary: dict[str, int] = field(default_factory=dict)
    urls: list[str] = field(default_factory=list)


@contextlib.contextmanager
def simulator(arguments: Sequence[str], printers: int = 1) -> Iterator[Simulator]:
    """Start `python -m marlin_aio.simulator ARGUMENTS` in its own process and yield its URL; always stop it.

    With `printers` > 1 it serves that many (`--printers N`) and `urls` lists them all.

    Raises:
        BenchmarkRunError: it did not print its URL within 15 s.
    """
    with tempfile.TemporaryFile(mode="w+") as stderr:
        if printers > 1:
            arguments = [*arguments, "--printers", str(printers)]
        process = subprocess.Popen(
            [sys.executable, "-m", "marlin_aio.simulator", *arguments],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=stderr,
            text=True,
        )
        sim: Simulator | None = None
        try:
            assert process.stdout is not None
            with selectors.DefaultSelector() as selector:
                selector.register(process.stdout, selectors.EVENT_READ)
                if not selector.select(_START_TIMEOUT_S):
                    raise BenchmarkRunError(f"marlin-sim {' '.join(arguments)} printed no URL within 15 s")
            # One URL per printer, each on its own line, printed as each printer starts.
            urls = [process.stdout.readline().strip() for _ in range(printers)]
            if not all(urls):
                raise BenchmarkRunError(f"marlin-sim {' '.join(arguments)} exited without {printers} URL(s)")
            sim = Simulator(urls[0], list(arguments), urls=urls)
            yield sim
        finally:
            _stop(process)
            if process.stdout is not None:
                process.stdout.close()
            stderr.seek(0)
            match = _SUMMARY.search(stderr.read())
            if sim is not None and match is not None:
                sim.summary = {name: int(value) for name, value in match.groupdict().items()}


def run_worker(spec: dict[str, Any], timeout_s: float, prefix: Sequence[str] = ()) -> dict[str, Any]:
    """Run `python -m benchmarks._worker SPEC` (behind `prefix`, such as a profiler) and return its result.

    Raises:
        BenchmarkRunError: the worker failed, printed no result, or ran past `timeout_s` (it is then killed).
    """
    command = [*prefix, sys.executable, "-m", "benchmarks._worker", json.dumps(spec)]
    try:
        completed = subprocess.run(
            command,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            cwd=Path(__file__).resolve().parent.parent,
        )
    except subprocess.TimeoutExpired as exc:
        raise BenchmarkRunError(f"{spec['scenario']}/{spec['label']}: no result within {timeout_s:.0f} s") from exc
    for line in reversed(completed.stdout.splitlines()):
        if line.startswith(RESULT_MARKER):
            result: dict[str, Any] = json.loads(line[len(RESULT_MARKER) :])
            return result
    tail = (completed.stderr or completed.stdout).strip().splitlines()[-8:]
    raise BenchmarkRunError(
        f"{spec['scenario']}/{spec['label']}: worker exited {completed.returncode} without a result:\n  "
        + "\n  ".join(tail)
    )


def _stop(process: subprocess.Popen[Any]) -> None:
    """SIGTERM, then SIGKILL if it has not gone within a few seconds."""
    process.terminate()
    try:
        process.wait(_STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def mosquitto_path() -> str | None:
    """The Mosquitto broker's executable (Debian installs it in /usr/sbin), or None."""
    found = shutil.which("mosquitto")
    if found is None and os.path.exists("/usr/sbin/mosquitto"):
        found = "/usr/sbin/mosquitto"
    return found


@dataclass
class Broker:
    """A running Mosquitto on 127.0.0.1:`port`."""

    port: int


@contextlib.contextmanager
def mosquitto(workdir: Path) -> Iterator[Broker]:
    """Start Mosquitto on 127.0.0.1 and a free port (no persistence); always stop it.

    Raises:
        BenchmarkRunError: it is not installed, or did not listen within 10 s.
    """
    executable = mosquitto_path()
    if executable is None:
        raise BenchmarkRunError("mosquitto is not installed (apt install mosquitto)")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = workdir / f"mosquitto-{port}.conf"
    config.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    process = subprocess.Popen([executable, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                if time.monotonic() > deadline or process.poll() is not None:
                    raise BenchmarkRunError("mosquitto did not start listening within 10 s") from None
                time.sleep(0.05)  # polling a condition (the port accepts), bounded
        yield Broker(port)
    finally:
        _stop(process)


@contextlib.contextmanager
def subscriber(port: int, output: Path) -> Iterator[Path]:
    """Run `benchmarks._subscriber` against the broker until the block ends; then its samples are in `output`.

    Raises:
        BenchmarkRunError: it did not subscribe within 15 s.
    """
    process = subprocess.Popen(
        [sys.executable, "-m", "benchmarks._subscriber", str(port), str(output)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=Path(__file__).resolve().parent.parent,
    )
    try:
        assert process.stdout is not None
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            if not selector.select(_START_TIMEOUT_S) or process.stdout.readline().strip() != "ready":
                raise BenchmarkRunError("the benchmark's MQTT subscriber did not subscribe within 15 s")
        yield output
    finally:
        _stop(process)
        if process.stdout is not None:
            process.stdout.close()
