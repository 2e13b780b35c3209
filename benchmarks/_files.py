"""G-code files for the streaming and memory scenarios, written lazily so a 200 MB file never sits in memory."""

from __future__ import annotations

from pathlib import Path

from marlin_aio.simulator import generate_moves

__all__ = ["write_moves", "write_moves_of_size"]

_CHUNK_LINES = 20_000


def write_moves(path: Path, count: int) -> int:
    """Write `generate_moves(count)` (the standard file when `count` is 17,000) to `path`; return its size."""
    with path.open("w", encoding="ascii", newline="\n") as out:
        for line in generate_moves(count):
            out.write(line + "\n")
    return path.stat().st_size


def write_moves_of_size(path: Path, size_bytes: int) -> int:
    """Write moves until the file holds at least `size_bytes`, a chunk at a time; return its size.

    Each chunk is a fresh seeded random walk (seed 0, 1, 2, ...), so the same size gives the same file.
    """
    written = 0
    seed = 0
    with path.open("w", encoding="ascii", newline="\n") as out:
        while written < size_bytes:
            for line in generate_moves(_CHUNK_LINES, seed=seed):
                out.write(line + "\n")
                written += len(line) + 1
                if written >= size_bytes:
                    break
            seed += 1
    return written
