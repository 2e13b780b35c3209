"""What the results file says about the machine, and the tables printed at the end (Markdown, readable as text).

Over 400 lines because it renders every scenario's tables, one function each of the same shape (rows from the
summary, then `_table`), read side by side the way `_scenarios` sums them up; the seam, if it grows further, is
one module per scenario's tables.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import math
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

__all__ = ["machine_info", "render"]

Json = dict[str, Any]
MIB = 1024 * 1024
MB = 1_000_000
_ROOT = Path(__file__).resolve().parent.parent


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def _git(*arguments: str) -> str:
    try:
        completed = subprocess.run(
            ["git", *arguments], cwd=_ROOT, capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return completed.stdout.strip()


def machine_info() -> Json:
    """CPU model, cores, Python, OS, date, the commit measured and the versions of the clients compared."""
    commit = _git("rev-parse", "--short", "HEAD")
    if commit and _git("status", "--porcelain", "--", "marlin_aio"):
        commit += " + uncommitted changes in marlin_aio/"
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "python": f"{platform.python_implementation()} {platform.python_version()}",
        "os": platform.platform(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "commit": commit or None,
        "versions": {name: _version(name) for name in ("marlin-aio", "pyserial", "pyserial-asyncio-fast", "printrun")},
    }


def _n(value: float | None, digits: int = 0) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return f"{value:,.{digits}f}"


def _x(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None or math.isnan(value) else f"{value:.{digits}f}x"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


#: A Raspberry Pi 3's core runs this suite's Python 5 to 8 times slower than one of the x86 server cores it was
#: measured on (the figure issue 24 gives; not measured on a Pi here): the estimates scale by that range.
PI3_SLOWER = (5, 8)


def _pi3(us: float | None, per_s: float, what: str) -> str:
    """`us` microseconds of CPU `per_s` times a second, as it would be on a Raspberry Pi 3 (an estimate)."""
    if us is None or math.isnan(us):
        return ""
    low, high = (us * factor for factor in PI3_SLOWER)
    share = f", {low * per_s / 1e4:.0f} to {high * per_s / 1e4:.0f}% of one of its cores at {per_s:g} a second"
    return (
        f"Estimated for a Raspberry Pi 3 (a core {PI3_SLOWER[0]} to {PI3_SLOWER[1]} times slower than this one; "
        f"not measured on one): {low:,.0f} to {high:,.0f} us of CPU per {what}{share if per_s else ''}."
    )


def _roundtrips(entry: Json) -> list[str]:
    summary, labels, ratios = entry["summary"], entry["labels"], entry["ratios"]
    rows = []
    for key, values in summary.items():
        runs = " / ".join(_n(v) for v in values["runs_rate_per_s"])
        ratio = "-" if key == "marlin_aio" else _x(ratios.get(key))
        rows.append([labels[key], _n(values["rate_per_s"]), runs, _n(values["cpu_us_per_round_trip"]), ratio])
    seconds = entry["settings"]["seconds_per_run"]
    lines = [
        f"### Round trips: M105 sent and answered back to back ({seconds:g} s per run, unpaced pty)",
        "",
        *_table(["client", "round trips/s (median)", "runs", "client CPU us per round trip", "marlin_aio is"], rows),
        "",
        _pi3(summary["marlin_aio"]["cpu_us_per_round_trip"], 0, "round trip (marlin_aio)"),
    ]
    gain = entry["ratios"].get("uvloop_gain_marlin_aio")
    if gain is not None:
        lines[-1] += f" On uvloop marlin_aio makes {_x(gain)} the round trips."
    return lines


def _polling(entry: Json) -> list[str]:
    summary, labels = entry["summary"], entry["labels"]
    rows = []
    for key, v in summary.items():
        rows.append(
            [
                labels[key],
                _n(v["readings_per_s"], 1),
                _n(v["interval_median_ms"], 2),
                _n(v["interval_p99_ms"], 2),
                _n(v["interval_max_ms"], 1),
                f"{_n(v['cpu_s_per_min'], 2)} ({_n(v.get('cpu_system_s_per_min'), 2)} in the kernel)",
                _n(v["cpu_ms_per_1000_readings"], 0),
            ]
        )
    seconds = entry["settings"]["seconds_per_run"]
    lines = [
        f"### Temperature polling ({seconds:g} s per run, unpaced pty)",
        "",
        *_table(
            [
                "client",
                "readings/s",
                "interval median ms",
                "interval p99 ms",
                "interval max ms",
                "client CPU s/min",
                "CPU us per reading",
            ],
            rows,
        ),
    ]
    lines += [
        "",
        f"marlin_aio uses {_x(entry['ratios'].get('lean_floor_cpu'), 1)} the client CPU of the lean floor (one timer "
        "callback, a write, one line read and its hotend temperature taken) and "
        f"{_x(entry['ratios'].get('floor_cpu'), 1)} that of the floor (a task sleeping between polls, nothing parsed), "
        "on the same 10 ms schedule; marlin_aio reads the temperature of every reading it polls.",
        "",
        _pi3(summary["marlin_aio"]["cpu_ms_per_1000_readings"], 100, "reading (marlin_aio)"),
    ]
    calls = entry.get("calls_per_reading")
    if calls is not None:
        lines[-3] += (
            f" Function calls a polled reading (sys.setprofile, `benchmarks.hotpath`): marlin_aio "
            f"{calls['marlin_aio']:.0f}, the lean floor {calls['lean floor']:.0f}."
        )
    gain = entry["ratios"].get("uvloop_gain_marlin_aio")
    if gain is not None:
        lines[-1] += (
            f" On uvloop marlin_aio uses {_x(1 / gain if gain else math.nan)} the CPU it uses on asyncio's loop."
        )
    if "printcore" in summary:
        lines[-3] += (
            " printcore has no poller of its own, so its loop sends M105 as soon as the last one is answered: its "
            "CPU per reading is the cost of a reading flat out, without the timer wakeups of a paced schedule."
        )
    return lines


def _streaming(entry: Json) -> list[str]:
    summary, labels, settings = entry["summary"], entry["labels"], entry["settings"]
    limit = settings["wire_limit_s"]
    rows = [["wire limit (file bytes / 25,000 B/s)", _n(limit, 2), "", _n(settings["wire_bytes_per_s"]), "", "", ""]]
    numbered = entry["ratios"].get("numbered_wire_limit_s")
    if numbered:
        rows.append(
            [
                "numbered wire limit (`N..` + `*cs` bytes / 25,000 B/s)",
                _n(numbered, 2),
                "",
                _n(settings["file_bytes"] / numbered),
                "25,000 (100%)",
                "",
                _x(numbered / limit),
            ]
        )
    loop = entry["ratios"].get("firmware_loop_limit_s")
    if loop:
        rows.append(
            ["firmware loop limit (1 ms a line, `--command-time`)", _n(loop, 2), "", "", "", "", _x(loop / limit)]
        )
    for key, v in summary.items():
        rows.append(
            [
                labels[key] + ("" if v["all_complete"] else " (INCOMPLETE)"),
                _n(v["seconds"], 2),
                " / ".join(_n(s, 2) for s in v["runs_seconds"]),
                _n(v["file_bytes_per_s"]),
                f"{_n(v['numbered_bytes_per_s'])} ({v['numbered_share_of_wire'] * 100:.1f}%)",
                _n(v["cpu_s"], 2),
                _x(v["seconds"] / limit),
            ]
        )
    return [
        *_streaming_table(settings, rows),
        *_short_lines(entry.get("short_lines")),
        *_simulated_streaming(entry.get("simulated_time")),
    ]


def _simulated_streaming(simulated: Json | None) -> list[str]:
    if not simulated:
        return []
    from benchmarks import streaming_sim

    return [
        "",
        "The same file in simulated time (`python -m benchmarks.streaming_sim`: the in-memory link at 250000 baud, "
        "the clock moved only by the wire and the firmware, so the machine's load cannot change it):",
        "",
        *streaming_sim.render(simulated),
    ]


def _short_lines(short: Json | None) -> list[str]:
    if not short:
        return []
    loop, wire = short["firmware_loop_limit_s"], short["numbered_wire_limit_s"]
    rows = [
        ["firmware loop limit (1 ms a line)", _n(loop, 2), "", _n(short["lines"] / loop), ""],
        ["numbered wire limit", _n(wire, 2), "", _n(short["lines"] / wire), ""],
    ]
    for key, v in short["summary"].items():
        rows.append(
            [
                short["labels"][key] + ("" if v["all_complete"] else " (INCOMPLETE)"),
                _n(v["seconds"], 2),
                " / ".join(_n(s, 2) for s in v["runs_seconds"]),
                _n(v["lines_per_s"]),
                f"{max(loop, wire) / v['seconds'] * 100:.1f}%",
            ]
        )
    return [
        "",
        f"### Streaming {short['lines']:,} short lines (`{short['line']}`) at 250000 baud: the firmware's loop binds",
        "",
        *_table(["client", "seconds (median)", "runs", "lines/s", "share of the limit that binds"], rows),
        "",
        f"Send-ahead is {_x(short.get('ping_pong_over_send_ahead'))} faster than ping-pong on these lines.",
    ]


def _streaming_table(settings: Json, rows: list[list[str]]) -> list[str]:
    return [
        f"### Streaming {settings['lines']:,} lines ({settings['file_bytes']:,} bytes) at 250000 baud, "
        "Marlin's buffers (4 commands, 128-byte receive buffer), instant moves",
        "",
        *_table(
            [
                "client",
                "seconds (median)",
                "runs",
                "file B/s",
                "numbered B/s on the wire (share of 25,000)",
                "client CPU s",
                "time vs wire limit",
            ],
            rows,
        ),
    ]


def _memory(entry: Json) -> list[str]:
    summary, labels, settings = entry["summary"], entry["labels"], entry["settings"]
    rows = []
    for key, v in summary.items():
        streamed = f"{v['streamed_bytes'] / MB:,.1f} of {v['file_bytes'] / MB:,.1f} MB in {v['stream_s']:.1f} s"
        if not v["finished"]:
            streamed += f" (stopped at the {settings['cap_s']:g} s cap)"
        rows.append(
            [
                labels[key],
                _n(v["peak_rss_bytes"] / MIB, 1),
                _n(v.get("stream_rss_max_bytes", math.nan) / MIB, 2),
                streamed,
                _n(v["rss_slope_bytes_per_mb"] * 100 / MIB, 3),
                _n(v["extrapolated_peak_rss_bytes"] / MIB, 1),
                _n(v.get("ru_maxrss_bytes", math.nan) / MIB, 1),
            ]
        )
    difference = entry["ratios"]["peak_rss_difference_bytes"] / MB
    extrapolated = entry["ratios"]["extrapolated_difference_bytes"] / MB
    return [
        "### Memory: peak RSS of a process that only streams (unpaced pty, instant moves)",
        "",
        *_table(
            [
                "file",
                "peak RSS MiB (VmHWM)",
                "RSS MiB while streaming (max)",
                "streamed",
                "RSS growth MiB per 100 MB streamed",
                "peak RSS MiB extrapolated to the whole file",
                "ru_maxrss MiB (includes the parent's, see BENCHMARKS.md)",
            ],
            rows,
        ),
        "",
        f"Peak RSS difference: {difference:+.2f} MB measured, {extrapolated:+.2f} MB extrapolated to the whole file. "
        "Each worker first reads the whole file once to validate it; the stream then reads it lazily.",
    ]


def _us_per_reading(v: Json) -> float:
    """CPU microseconds per reading of a many-printers case: a printer's share of a core over its readings."""
    return _ratio_or_nan(v["cpu_share_per_printer"] * 1e6, v["readings_per_s_median"])


def _ratio_or_nan(a: float, b: float) -> float:
    return a / b if b and not math.isnan(b) else math.nan


def _many(entry: Json) -> list[str]:
    labels = entry["labels"]
    rows = []
    for name, case in entry["cases"].items():
        for key, v in case["summary"].items():
            rows.append(
                [
                    name,
                    labels[key].split(":")[0],
                    f"{v['cpu_share'] * 100:.1f}%",
                    f"{v['cpu_share_per_printer'] * 100:.2f}%",
                    _n(_us_per_reading(v), 0),
                    "-" if key == "marlin_aio" else _x(case["cpu_ratio"]),
                    f"{_n(v['readings_per_s_median'], 1)} (slowest {_n(v['readings_per_s_min'], 1)})",
                    _n(v["interval_p99_ms"], 2),
                    f"{_n(v['lag_p99_ms'], 2)} (max {_n(v['lag_max_ms'], 1)})",
                    str(v["timeouts"]),
                ]
            )
    seconds = entry["settings"]["seconds_per_run"]
    return [
        f"### Many printers in one process ({seconds:g} s per run; the printers served by one marlin-sim process)",
        "",
        *_table(
            [
                "case",
                "client",
                "client CPU (share of a core)",
                "CPU per printer",
                "CPU us per reading",
                "marlin_aio CPU vs floor",
                "readings/s a printer (median)",
                "interval p99 ms (all printers)",
                "loop lag p99 ms",
                "timeouts",
            ],
            rows,
        ),
        "",
        f"marlin_aio: {labels['marlin_aio'].split(': ', 1)[-1]}; "
        f"lean floor: {labels['lean_floor'].split(': ', 1)[-1]}. "
        "Loop lag is how late a 10 ms timer runs on the same loop.",
    ]


def _farm(entry: Json) -> list[str]:
    if "skipped" in entry:
        return ["### A farm of printers through Mosquitto", "", f"Skipped: {entry['skipped']}."]
    labels, settings = entry["labels"], entry["settings"]
    rows = []
    for key, v in entry["summary"].items():
        bridged = key.startswith("bridge")
        rows.append(
            [
                labels[key],
                f"{v['cpu_share'] * 100:.1f}%",
                f"{v['cpu_share_per_printer'] * 100:.2f}%",
                _n(v["readings_per_s"], 0),
                _n(v["received_per_s"], 0) if bridged else "-",
                f"{_n(v['latency_p50_ms'], 1)} / {_n(v['latency_p99_ms'], 1)}" if bridged else "-",
                str(v["telemetry_dropped"]) if bridged else "-",
            ]
        )
    return [
        f"### A farm of {settings['printers']} printers polled every {settings['interval_s'] * 1000:g} ms, telemetry "
        f"through Mosquitto ({settings['seconds_per_run']:g} s per run)",
        "",
        *_table(
            [
                "client",
                "client CPU (share of a core)",
                "CPU per printer",
                "readings/s (all printers)",
                "telemetry messages/s at the subscriber",
                "reading to subscriber ms (p50 / p99)",
                "readings dropped",
            ],
            rows,
        ),
        "",
        f"The bridge costs {_x(entry['ratios'].get('bridge_cpu_over_plain'))} the CPU of the same farm without it; "
        f"with the json module instead of orjson, {_x(entry['ratios'].get('orjson_gain'))} the bridge's CPU with it; "
        f"each message through paho's public publish instead of one write a batch through its private queue, "
        f"{_x(entry['ratios'].get('batch_gain'))}. "
        "Latency runs from the reading's time (in the payload) to its arrival at a subscriber in another process.",
    ]


def _serve(entry: Json) -> list[str]:
    from benchmarks import serve

    return ["### Sharing a printer: marlin-temp serve against a direct Printer", "", *serve.render(entry)]


def _startup(entry: Json) -> list[str]:
    from benchmarks import startup

    return ["### Start-up: import, connect and --help", "", *startup.render(entry)]


_RENDERERS = {
    "roundtrips": _roundtrips,
    "polling": _polling,
    "streaming": _streaming,
    "memory": _memory,
    "many": _many,
    "farm": _farm,
    "serve": _serve,
    "startup": _startup,
}


def _all_runs(entry: Json) -> list[Json]:
    groups = [entry.get("runs", {})] + [case["runs"] for case in entry.get("cases", {}).values()]
    return [run for runs in groups for results in runs.values() for run in results]


def _measured(target: Json) -> str:
    value = target["measured"]
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "not measured"
    unit = target["unit"]
    text = f"{value:.2f}{unit}" if unit == "x" else f"{value:,.2f} {unit}".rstrip()
    return text


def render(results: Json) -> str:
    """The Markdown tables for every scenario in `results`, the targets, and the machine they came from."""
    lines: list[str] = []
    targets: list[Json] = []
    for name, entry in results["scenarios"].items():
        lines += [*_RENDERERS[name](entry), ""]
        targets += entry["targets"]
    rows = [
        [t["name"], t["goal"], _measured(t), {True: "yes", False: "**no**", None: "not measured"}[t["met"]]]
        for t in targets
    ]
    lines += ["### Targets", "", *_table(["target", "goal", "measured", "met"], rows), ""]
    machine = results["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in machine["versions"].items() if v)
    loads = [
        run["load_average"]
        for entry in results["scenarios"].values()
        for run in _all_runs(entry)
        if isinstance(run.get("load_average"), float) and run["load_average"] == run["load_average"]
    ]
    load = f" Load average as the runs started: {min(loads):.2f} to {max(loads):.2f}." if loads else ""
    lines.append(
        f"Measured {machine['date']} on {machine['cpu']}, {machine['cores']} cores, {machine['python']}, "
        f"{machine['os']}; commit {machine['commit']}; {versions}."
        + (" Quick smoke run: short runs, not for comparison." if results.get("quick") else "")
        + load
    )
    older = [
        f"{name} on {entry['machine']['date']} (commit {entry['machine']['commit']})"
        for name, entry in results["scenarios"].items()
        if "machine" in entry and entry["machine"]["date"] != machine["date"]
    ]
    if older:
        lines.append("Kept from an earlier invocation: " + "; ".join(older) + ".")
    return "\n".join(lines)
