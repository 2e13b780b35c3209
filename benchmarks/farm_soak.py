"""`python -m benchmarks.farm_soak`: the farm's memory over a long run: `marlin-temp farm --sims N` publishing to a
real Mosquitto, its resident set size sampled every few seconds.

    python -m benchmarks.farm_soak                         # 20 simulated printers for 10 minutes
    python -m benchmarks.farm_soak --sims 20 --minutes 2   # a shorter look

It prints the RSS at each sample and the growth rate over the second half of the run (after start-up has
allocated what it keeps), in KB/s, with the machine's load average at the start and the end, and the farm's own
summary line (messages published, readings dropped, events lost). A farm whose memory is bounded shows a rate near
zero; the one of issue 21 grew by about 22.5 KB/s (each simulated printer kept 100,000 commands).

To measure another checkout (a "before"), put its packages first on the path:
`mkdir /tmp/old && ln -s OLD/cli /tmp/old/marlin_temp && ln -s OLD/marlin_aio /tmp/old/marlin_aio`, then run with
`--pythonpath /tmp/old`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._procs import mosquitto


def rss_kb(pid: int) -> int:
    """The process's resident set size in KB (Linux's /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for {pid}")


def slope_kb_s(samples: list[tuple[float, int]]) -> float:
    """Least-squares growth rate of RSS (KB/s) over `samples` of (seconds, KB)."""
    count = len(samples)
    mean_t = sum(t for t, _ in samples) / count
    mean_r = sum(r for _, r in samples) / count
    spread = sum((t - mean_t) ** 2 for t, _ in samples)
    return sum((t - mean_t) * (r - mean_r) for t, r in samples) / spread if spread else 0.0


def main(argv: list[str] | None = None) -> int:
    """Run the soak; exit status 0 (it measures, it does not judge)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.farm_soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sims", type=int, default=20, help="simulated printers (default 20)")
    parser.add_argument("--minutes", type=float, default=10.0, help="how long (default 10)")
    parser.add_argument("--interval", type=float, default=0.1, help="seconds between polls of each printer")
    parser.add_argument("--rate", type=float, default=None, help="telemetry per second and printer (farm's default)")
    parser.add_argument("--every", type=float, default=10.0, help="seconds between RSS samples (default 10)")
    parser.add_argument("--pythonpath", default=None, help="put this folder first on the farm's PYTHONPATH")
    args = parser.parse_args(argv)
    duration_s = args.minutes * 60
    env = dict(os.environ)
    if args.pythonpath:
        env["PYTHONPATH"] = args.pythonpath + os.pathsep + env.get("PYTHONPATH", "")
    with tempfile.TemporaryDirectory() as workdir, mosquitto(Path(workdir)) as broker:
        command = [
            sys.executable,
            "-m",
            "marlin_temp",
            "farm",
            *("--sims", str(args.sims), "--interval", str(args.interval)),
            *("--broker", f"127.0.0.1:{broker.port}", "--duration", str(duration_s)),
            *(("--rate", str(args.rate)) if args.rate is not None else ()),
        ]
        load_start = os.getloadavg()
        # Started in the scratch folder: `python -m` puts its working directory first on the path, which would
        # hide --pythonpath behind this checkout.
        farm = subprocess.Popen(
            command, env=env, cwd=workdir, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        started = time.monotonic()
        samples: list[tuple[float, int]] = []
        print(f"farm --sims {args.sims} for {args.minutes:g} min (pid {farm.pid}); load at start {load_start[0]:.2f}")
        try:
            while farm.poll() is None:
                elapsed = time.monotonic() - started
                try:
                    samples.append((elapsed, rss_kb(farm.pid)))
                except (OSError, RuntimeError):
                    break  # it ended between poll() and the read
                print(f"  {elapsed:6.0f} s  RSS {samples[-1][1] / 1024:7.1f} MB", flush=True)
                time.sleep(args.every)  # the sampling period (this is a measurement, not a synchronisation)
            _, stderr = farm.communicate(timeout=60)
        finally:
            if farm.poll() is None:
                farm.kill()
                farm.wait()
    load_end = os.getloadavg()
    second_half = [sample for sample in samples if sample[0] >= duration_s / 2]
    summary = next((line for line in stderr.splitlines() if "farm: stopped" in line), "(no summary line)")
    print(f"exit status {farm.returncode}; {summary.strip()}")
    if len(second_half) >= 2:
        first, last = second_half[0][1], second_half[-1][1]
        print(
            f"RSS {samples[0][1] / 1024:.1f} MB at start, {first / 1024:.1f} MB at half time, {last / 1024:.1f} MB at "
            f"the end; growth over the second half {slope_kb_s(second_half):+.2f} KB/s; "
            f"load {load_start[0]:.2f} -> {load_end[0]:.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
