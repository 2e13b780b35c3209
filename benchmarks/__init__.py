"""The benchmark suite: marlin_aio against its baselines on the simulated printer, side by side.

Run it with `python -m benchmarks` (see `benchmarks/__main__.py` and BENCHMARKS.md). Absolute times on a shared
machine move from run to run, so every claim is a ratio measured in one invocation: each scenario alternates our
client and its baselines, a fresh `marlin-sim` process per run (the simulated printer never shares a process,
and so never shares CPU accounting, with the client), at least three runs each, and reports medians.

- `_worker`: the client side of one run, in its own process: it runs one contender and prints its result.
- `_contender_marlin_aio`, `_contender_floor` (the bare-asyncio floor and the lean floor), `_contender_pyserial`
  (blocking pyserial), `_contender_printcore` (Printrun's printcore): one module per contender.
- `_measure`: how every contender is measured (clocks, CPU, RSS, intervals, the event loop's lag).
- `_procs`: starting and always stopping the simulator and the worker processes, each bounded in time.
- `_scenarios`: round trips, 100 Hz polling, streaming at 250000 baud, memory, many printers, the farm; their
  summaries and targets.
- `_files`: the G-code files, written lazily. `_report`: the machine description and the tables.
- `_profile`: `--profile` (py-spy or cProfile, and the summary). `_subscriber`: the farm's MQTT subscriber.
"""
