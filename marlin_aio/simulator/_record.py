"""A bounded record: the last N items appended, plus a count of all of them.

The simulated printer records what it ran so tests can check it. A served simulator runs for hours at a hundred
commands a second, where an unbounded list grows by tens of megabytes an hour; this keeps only the recent part
and still knows the total.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence
from typing import TypeVar, overload

__all__ = ["BoundedRecord"]

_T = TypeVar("_T")


class BoundedRecord(Sequence[_T]):
    """The last `limit` items appended, oldest first (every item when `limit` is None); `total` counts them all.

    A read-only sequence: `len()`, iteration, `in`, indexing and slicing (a slice is a new list), and `==` with
    any other sequence of the same items (`record == ["M105", "G28"]`).
    """

    __slots__ = ("_items", "total")

    def __init__(self, limit: int | None = None) -> None:
        """An empty record keeping at most `limit` items.

        Raises:
            ValueError: if `limit` is negative.
        """
        if limit is not None and limit < 0:
            raise ValueError(f"limit must be None or at least 0, got {limit}")
        self._items: deque[_T] = deque(maxlen=limit)
        self.total = 0
        """How many items were ever appended, including those no longer kept."""

    @property
    def limit(self) -> int | None:
        """How many items are kept at most (None: all)."""
        return self._items.maxlen

    def append(self, item: _T) -> None:
        """Add `item`, forgetting the oldest one when the record is full."""
        self._items.append(item)
        self.total += 1

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[_T]:
        return iter(self._items)

    def __reversed__(self) -> Iterator[_T]:
        return reversed(self._items)

    def __contains__(self, item: object) -> bool:
        return item in self._items

    @overload
    def __getitem__(self, index: int) -> _T: ...

    @overload
    def __getitem__(self, index: slice) -> list[_T]: ...

    def __getitem__(self, index: int | slice) -> _T | list[_T]:
        if isinstance(index, slice):
            # A deque cannot be sliced; a list of the kept items can, with every slice form lists allow.
            return list(self._items)[index]
        return self._items[index]

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (str, bytes)) or not isinstance(other, Sequence):
            return NotImplemented
        return len(self._items) == len(other) and all(a == b for a, b in zip(self._items, other, strict=True))

    __hash__ = None  # type: ignore[assignment]  # contents change

    def __repr__(self) -> str:
        return f"BoundedRecord({list(self._items)!r}, limit={self.limit!r}, total={self.total!r})"
