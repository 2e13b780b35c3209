"""`marlin-temp plot`: the tracking-curve figure from a log, as a PNG (matplotlib) or in the terminal."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from marlin_aio import heater_name

from .connect import UsageProblem
from .logfile import read_log

__all__ = ["plot_log"]

_COLOURS = {"T": "tab:red", "B": "tab:blue", "C": "tab:green"}


def plot_log(path: Path, output: Path | None, show: bool, console: Console) -> str:
    """Plot `path`; return a one-line message saying what was written.

    Raises:
        UsageProblem: matplotlib is missing and a PNG was asked for.
        ValueError: the file is not a temperature log.
        OSError: a file cannot be read or written.
    """
    elapsed, series = read_log(path)
    if not elapsed:
        raise ValueError(f"{path} has no readings")
    keys = [
        k for k in series if k[0] in "TBC" and (k != "T" or not any(x[1:].isdigit() for x in series if x[0] == "T"))
    ]
    message = ""
    if show:
        console.print(_terminal_plot(elapsed, {k: series[k] for k in keys}, console.width))
    if output is not None:
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            raise UsageProblem(
                "matplotlib is not installed: pip install 'marlin-aio[plot]' (or use --show for a terminal plot)"
            ) from None
        figure, axes = plt.subplots(figsize=(10, 5.5), dpi=100)
        for key in keys:
            colour = _COLOURS.get(key[0], "tab:purple")
            actual = [a if a is not None else float("nan") for a, _ in series[key]]
            target = [t if t is not None else float("nan") for _, t in series[key]]
            axes.plot(elapsed, actual, color=colour, label=f"{heater_name(key)} actual")
            axes.plot(elapsed, target, color=colour, linestyle="--", alpha=0.6, label=f"{heater_name(key)} target")
        axes.set_xlabel("time (s)")
        axes.set_ylabel("temperature (°C)")
        axes.set_title(f"Temperature tracking: {path.name}")
        axes.grid(True, alpha=0.3)
        axes.legend(loc="lower right")
        figure.tight_layout()
        figure.savefig(output)
        plt.close(figure)
        message = f"wrote {output} ({len(elapsed)} readings over {elapsed[-1] - elapsed[0]:.1f} s)"
    return message


def _terminal_plot(
    elapsed: list[float], series: dict[str, list[tuple[float | None, float | None]]], width: int
) -> object:
    from marlin_aio import HeaterReading, ReadingSource, TemperatureReading, Temperatures

    from .model import WatchModel
    from .render import chart

    span = max(elapsed[-1] - elapsed[0], 1.0)
    model = WatchModel(window_s=span)
    for index, time_s in enumerate(elapsed):
        heaters = {}
        for key, values in series.items():
            actual, target = values[index]
            if actual is not None:
                heaters[key] = HeaterReading(actual=actual, target=target)
        if heaters:
            model.add(TemperatureReading(Temperatures(heaters), time_s, time_s, ReadingSource.LOG))
    return chart(model, width=width, height=16, now=elapsed[-1])
