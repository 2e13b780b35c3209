"""A reproducible G-code workload for streaming tests and benchmarks: many short `G1` moves.

The path is a seeded random walk over a 200 x 200 mm bed, like the dense small segments a slicer writes for
curves: each move turns a little, is about `step_mm` long, extrudes in proportion (relative E, as after `M83`)
and repeats the feedrate, so every line stands alone and is about 34 bytes with its newline. The same arguments
give the same lines on every machine and Python version (`random.Random` with an integer seed is stable).
"""

from __future__ import annotations

import math
import random

__all__ = ["generate_moves"]

# Filament per mm of travel for a 0.45 mm wide, 0.2 mm high line from 1.75 mm filament.
_E_PER_MM = 0.45 * 0.2 / (math.pi * 0.875**2)
_MARGIN_MM = 10.0


def generate_moves(
    count: int = 17_000,
    *,
    seed: int = 0,
    step_mm: float = 0.5,
    feedrate_mm_min: int = 3000,
    bed_mm: float = 200.0,
) -> list[str]:
    """Return `count` lines such as `G1 X12.345 Y67.890 E0.01234 F3000` (no newline, no line number).

    Steps vary by +-20 % around `step_mm`; the walk stays 10 mm inside the bed, turning back at the edges.
    At the default 0.5 mm and F3000 (50 mm/s) each move takes about 10 ms of motion, so a printer that runs
    moves in real time takes about 100 of them a second.

    Raises:
        ValueError: if `count` is negative, or `step_mm`, `feedrate_mm_min` or `bed_mm` leave no room to move.
    """
    if count < 0:
        raise ValueError(f"count must not be negative, got {count}")
    if not step_mm > 0 or feedrate_mm_min <= 0:
        raise ValueError("step_mm and feedrate_mm_min must be positive")
    if not bed_mm > 2 * _MARGIN_MM + 2 * step_mm:
        raise ValueError(f"bed_mm must leave room inside its {_MARGIN_MM} mm margins, got {bed_mm}")
    rng = random.Random(seed)
    low, high = _MARGIN_MM, bed_mm - _MARGIN_MM
    x = y = bed_mm / 2
    heading = rng.uniform(0.0, 2 * math.pi)
    moves: list[str] = []
    for _ in range(count):
        heading += rng.uniform(-0.35, 0.35)
        length = step_mm * rng.uniform(0.8, 1.2)
        nx = x + length * math.cos(heading)
        ny = y + length * math.sin(heading)
        if not low <= nx <= high:
            heading = math.pi - heading  # bounce off a vertical edge
            nx = x + length * math.cos(heading)
        if not low <= ny <= high:
            heading = -heading  # bounce off a horizontal edge
            ny = y + length * math.sin(heading)
        x, y = nx, ny
        moves.append(f"G1 X{x:.3f} Y{y:.3f} E{length * _E_PER_MM:.5f} F{feedrate_mm_min}")
    return moves
