"""Blocking pyserial (client "pyserial"): `write(b"M105\\n")`, then `readline()`, back to back; the round trips
of the simplest synchronous script.
"""

from __future__ import annotations

import time

import serial

from benchmarks._measure import ANSWER_TIMEOUT_S, QUIET_S, WARMUP_S, Meter, Result, RunFailedError

__all__ = ["pyserial_round_trips"]


def pyserial_round_trips(spec: Result) -> Result:
    """Blocking pyserial: `write(b"M105\\n")`, then `readline()`."""
    port = serial.Serial(spec["url"], 250_000, timeout=ANSWER_TIMEOUT_S)
    try:
        time.sleep(QUIET_S)
        port.reset_input_buffer()

        def round_trip() -> None:
            port.write(b"M105\n")
            if not port.readline().endswith(b"\n"):
                raise RunFailedError("pyserial: no answer to M105")

        deadline = time.perf_counter() + WARMUP_S
        while time.perf_counter() < deadline:
            round_trip()
        count = 0
        meter = Meter()
        end = meter.start + spec["seconds"]
        while time.perf_counter() < end:
            round_trip()
            count += 1
        wall, cpu = meter.stop()
    finally:
        port.close()
    return {"round_trips": count, "wall_s": wall, "cpu_s": cpu, **meter.split()}
