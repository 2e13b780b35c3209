"""The benchmark suite: marlin_aio against its baselines on the simulated printer, side by side.

Run it with `python -m benchmarks` (see `benchmarks/__main__.py` and BENCHMARKS.md). Absolute times on a shared
machine move from run to run, so every claim is a ratio measured in one invocation: each scenario alternates our
client and its baselines, a fresh `marlin-sim` process per run (the simulated printer never shares a process,
and so never shares CPU accounting, with the client), at least three runs each, and reports medians.

- `_worker`: the client side of one run, in its own process (marlin_aio, the bare-asyncio floor, blocking
  pyserial, Printrun's printcore).
- `_procs`: starting and always stopping the simulator and the worker processes, each bounded in time.
- `_scenarios`: round trips, 100 Hz polling, streaming at 250000 baud, memory; their summaries and targets.
- `_files`: the G-code files, written lazily. `_report`: the machine description and the tables.
"""
