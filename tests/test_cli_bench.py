"""`marlin-temp bench` through CliRunner against the simulated printer, clean and with faults; rendering pure.

Numbers are only checked to exist and be positive: how fast the simulator answers is not what is tested.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import re
from typing import Any

import pytest
from rich.console import Console
from typer.testing import CliRunner

from marlin_aio.simulator import Faults, SimulatorConfig, serve_pty
from marlin_temp.bench.command import (
    BenchResult,
    CorrectnessResult,
    LatencyResult,
    OrderCheck,
    ThroughputResult,
    bench_json,
    bench_table,
)
from marlin_temp.common.connect import Exit
from marlin_temp.main import app

runner = CliRunner()
FAST = ["--sim", "--sim-speed", "50"]
SMALL = ["--count", "30", "--lines", "60"]
METRICS = (
    "wire limit",
    "round trips",
    "latency median",
    "latency p99",
    "latency max",
    "round trips/s",
    "lines sent",
    "oks in order",
    "oks lost",
    "replies withheld",
    "out of order",
    "resends",
    "timeouts",
    "order check",
    "stream lines/s",
    "stream bytes/s",
    "wire use",
    "stream resends",
)


def row_value(output: str, metric: str) -> str:
    """The value column of a table row, e.g. '0' for 'out of order'."""
    match = re.search(rf"^\s*{re.escape(metric)}\s+(\S+)", output, re.MULTILINE)
    assert match is not None, f"no row {metric!r} in:\n{output}"
    return match.group(1)


def one_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


# ------------------------------------------------------------------------------------------- against --sim


def test_the_table_has_every_metric_and_a_clean_order_check() -> None:
    result = runner.invoke(app, ["bench", *FAST, *SMALL])
    assert result.exit_code == Exit.OK, result.output
    for metric in METRICS:
        assert metric in result.stdout, f"{metric!r} missing:\n{result.stdout}"
    assert row_value(result.stdout, "round trips") == "30"
    assert row_value(result.stdout, "lines sent") == "60"
    assert row_value(result.stdout, "oks in order") == "60"
    assert row_value(result.stdout, "out of order") == "0"
    assert row_value(result.stdout, "oks lost") == "0"
    assert row_value(result.stdout, "timeouts") == "0"
    assert row_value(result.stdout, "order check") == "clean"
    assert "--sim is unpaced" in result.stdout
    assert "error" not in result.output


def test_json_is_one_object_with_every_key() -> None:
    result = runner.invoke(app, ["bench", *FAST, *SMALL, "--json"])
    assert result.exit_code == Exit.OK, result.output
    report = json.loads(result.stdout)
    assert {"port", "firmware", "baud", "paced", "wire_limit_bytes_per_s", "clean", "problem"} <= report.keys()
    assert report["clean"] is True and report["problem"] is None
    assert report["paced"] is False and report["wire_limit_bytes_per_s"] == 25_000
    latency = report["latency"]
    assert latency["round_trips"] == 30 and latency["timeouts"] == 0
    for key in ("median_ms", "p99_ms", "max_ms", "round_trips_per_s"):
        assert latency[key] > 0, key
    assert latency["median_ms"] <= latency["p99_ms"] <= latency["max_ms"]
    correctness = report["correctness"]
    assert correctness["command"] == "M118 E1 bench <n>" and "M105 witness" in correctness["mode"]  # no ADVANCED_OK
    assert correctness["lines_sent"] == correctness["oks_in_order"] == 60
    assert correctness["out_of_order"] == 0 and correctness["timeouts"] == 0 and correctness["clean"] is True
    throughput = report["throughput"]
    assert throughput["command"] == "G4 P0" and "send-ahead" in throughput["mode"]
    assert throughput["lines"] == 60
    assert throughput["bytes_sent"] > 0 and throughput["lines_per_s"] > 0 and throughput["bytes_per_s"] > 0
    assert throughput["wire_ratio"] is None  # the in-process simulator is not paced
    assert throughput["stall"] is None


def test_duration_runs_each_part_for_that_long() -> None:
    result = runner.invoke(app, ["bench", *FAST, "--duration", "0.1", "--json"])
    assert result.exit_code == Exit.OK, result.output
    report = json.loads(result.stdout)
    assert report["latency"]["round_trips"] > 0
    assert report["correctness"]["lines_sent"] > 0 and report["correctness"]["out_of_order"] == 0
    assert report["throughput"]["lines"] > 0


def test_help_explains_the_numbers() -> None:
    result = runner.invoke(app, ["bench", "--help"])
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    phrases = ("median", "p99", "round trips/s", "oks in order", "out of order", "oks lost", "replies withheld")
    for phrase in (*phrases, "resends", "baud/10", "G4 P0", "ADVANCED_OK", "3 oks lost (recovered), 0 out of order"):
        assert phrase in text, phrase


# ------------------------------------------------------------------------------------------- with faults


async def invoke_against(faults: Faults, *args: str, config: SimulatorConfig | None = None) -> Any:
    async with serve_pty(config or SimulatorConfig(), faults, time_scale=50) as sim:
        return await asyncio.to_thread(runner.invoke, app, ["bench", "--port", sim.url, *args])


async def test_corrupted_lines_are_resent_and_the_order_stays_correct() -> None:
    result = await invoke_against(Faults(corrupt_rx_ratio=0.05), "--count", "30", "--lines", "200", "--json")
    assert result.exit_code == Exit.OK, result.output
    report = json.loads(result.stdout)
    correctness = report["correctness"]
    assert correctness["resends"] > 0
    assert correctness["lines_sent"] == correctness["oks_in_order"] == 200
    assert correctness["out_of_order"] == 0 and correctness["timeouts"] == 0
    assert report["throughput"]["lines"] == 200 and report["clean"] is True


@pytest.mark.parametrize("advanced_ok", [False, True], ids=["plain-ok", "advanced-ok"])
async def test_lost_oks_are_told_apart_from_reordering_and_are_not_a_failure(advanced_ok: bool) -> None:
    # A link that loses oks and keeps its order. The library proves each lost ok by a later answer (an M105
    # witness without ADVANCED_OK, the next `ok N<line>` with it) and withholds what it cannot attribute. The fault
    # draws are seeded (SimulatorConfig.seed), so the same oks are lost every run, none of them the handshake's.
    config = SimulatorConfig(advanced_ok=advanced_ok)
    result = await invoke_against(Faults(drop_ok_ratio=0.02), "--count", "30", "--lines", "300", config=config)
    assert result.exit_code == Exit.OK, result.output
    lost = int(row_value(result.stdout, "oks lost"))
    assert lost > 0
    assert row_value(result.stdout, "out of order") == "0"
    assert row_value(result.stdout, "timeouts") == "0"
    assert row_value(result.stdout, "order check") == "clean"
    in_order, withheld = (
        int(row_value(result.stdout, "oks in order")),
        int(row_value(result.stdout, "replies withheld")),
    )
    # A line whose own ok was lost is proven to have run; its reply keeps its echo when nothing after it printed
    # any (then it counts in order), else it is withheld. Either way no line is counted twice or lost.
    assert in_order + withheld == 300
    warning = one_line(result.stderr.split("\n", 1)[1])  # after the "bench on ..." line
    assert warning.startswith(f"warning: {lost} oks lost (recovered), 0 out of order:"), warning
    assert "error" not in result.stderr


async def test_the_readmes_fault_mix_keeps_the_order_check_clean() -> None:
    # Corrupted lines, lost oks and noise together, as the README runs `marlin-sim`: a lost ok outside the order
    # check's witnesses (the latency's M105s, the stream's G4 P0) costs a probe, never a silent 10 s and the rest.
    config = SimulatorConfig(seed=1)
    faults = Faults(corrupt_rx_ratio=0.02, drop_ok_ratio=0.005, noise_ratio=0.01)
    result = await invoke_against(faults, "--count", "100", "--lines", "400", "--json", config=config)
    assert result.exit_code == Exit.OK, result.output
    report = json.loads(result.stdout)
    correctness = report["correctness"]
    assert correctness["timeouts"] == 0 and correctness["out_of_order"] == 0, correctness
    assert correctness["lines_sent"] == correctness["oks_in_order"] + correctness["withheld"] == 400
    assert report["throughput"]["lines"] == 400 and report["clean"] is True


async def test_lost_oks_in_json() -> None:
    result = await invoke_against(Faults(drop_ok_ratio=0.02), "--count", "30", "--lines", "300", "--json")
    assert result.exit_code == Exit.OK, result.output
    report = json.loads(result.stdout)
    correctness = report["correctness"]
    assert correctness["lost_oks"] > 0 and correctness["out_of_order"] == 0 and correctness["clean"] is True
    assert correctness["oks_in_order"] + correctness["withheld"] == correctness["lines_sent"] == 300
    assert "M105 witness" in correctness["mode"]  # the simulator has no ADVANCED_OK by default
    assert report["clean"] is True and report["problem"] is None
    assert report["warning"].startswith(f"{correctness['lost_oks']} oks lost (recovered), 0 out of order")


# ------------------------------------------------------------------------------------------- the order check, pure


def test_reordered_echoes_are_out_of_order() -> None:
    check = OrderCheck()
    check.answered(0, [0])
    check.answered(1, [2])  # another line's echo
    check.answered(2, [1])  # an echo that came after a later one
    check.answered(3, [])  # no echo at all
    check.answered(4, [4])
    assert (check.in_order, check.out_of_order, check.withheld) == (2, 3, 0)


def test_withheld_replies_are_not_out_of_order() -> None:
    check = OrderCheck()
    check.answered(0, [0])
    check.lost_reply()
    check.lost_reply()
    check.answered(3, [3])
    assert (check.in_order, check.out_of_order, check.withheld) == (2, 0, 2)


# ------------------------------------------------------------------------------------------- rendering


def paced_result(bytes_per_s: float) -> BenchResult:
    return BenchResult(
        port="/dev/ttyUSB0",
        firmware="Marlin 2.1.2.4 (Jan  1 2024 12:00:00)",
        baud=115_200,
        paced=True,
        latency=LatencyResult(100, 0, 2.5, 3.0, 4.0, 0.3),
        correctness=CorrectnessResult(200, 200, 0, 3, 0, 64, 0.5),
        throughput=ThroughputResult(1000, int(bytes_per_s), 3000, 1.0, 1, 112),
    )


def test_a_paced_link_shows_its_share_of_the_wire_limit() -> None:
    result = paced_result(9_216)
    console = Console(record=True, width=100)
    console.print(bench_table(result))
    text = console.export_text()
    assert "Marlin 2.1.2.4 on /dev/ttyUSB0, 115200 baud" in text
    assert "11,520 B/s" in text  # 115200 / 10
    assert row_value(text, "wire use") == "80%"
    assert bench_json(result)["problem"] is None


def test_faster_than_the_wire_says_the_link_is_not_paced() -> None:
    console = Console(record=True, width=100)
    console.print(bench_table(paced_result(200_000)))
    assert "this link is not paced" in console.export_text()
    # And the JSON says the same (it said "paced": true beside a table calling the link not paced).
    assert bench_json(paced_result(200_000))["paced"] is False
    assert bench_json(paced_result(9_216))["paced"] is True


def test_lost_oks_alone_are_a_warning_and_with_a_failure_are_named_apart() -> None:
    clean = paced_result(9_216)
    lossy = dataclasses.replace(clean, correctness=CorrectnessResult(200, 197, 0, 0, 0, 64, 0.5, 3, 3))
    assert lossy.problem is None
    assert lossy.warning is not None and lossy.warning.startswith("3 oks lost (recovered), 0 out of order")
    assert bench_json(lossy)["clean"] is True
    console = Console(record=True, width=100)
    console.print(bench_table(lossy))
    text = console.export_text()
    assert row_value(text, "oks lost") == "3" and row_value(text, "replies withheld") == "3"
    assert row_value(text, "order check") == "clean" and "3 oks lost (recovered), 0 out of order" in text
    broken = dataclasses.replace(clean, correctness=CorrectnessResult(200, 190, 7, 0, 0, 64, 0.5, 3, 3))
    assert broken.problem is not None and broken.warning is None
    assert "7 of 200 oks came back out of order" in broken.problem and "3 oks lost (recovered)" in broken.problem


def test_the_problem_names_each_failure() -> None:
    clean = paced_result(9_216)
    broken = dataclasses.replace(
        clean,
        latency=LatencyResult(99, 1, 2.5, 3.0, 4.0, 0.3),
        correctness=CorrectnessResult(200, 190, 8, 0, 2, 64, 0.5),
    )
    assert broken.problem is not None
    assert "8 of 200 oks came back out of order" in broken.problem
    assert "3 commands timed out" in broken.problem
    assert bench_json(broken)["clean"] is False
