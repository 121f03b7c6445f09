"""A table's values at one arc length, each computed where it is first read."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from jaxtyping import Array


class Lookups(Sequence):
    """A table's F values at one arc length (`PiecewiseCubic.fields`, `Sinusoid.fields`), each
    computed where it is first read (`v[f]`, `v[a:b]`) and kept for later reads: the values a
    caller does not read are not traced at all. (XLA dropped them from the compiled program
    anyway, but tracing and lowering them was most of the work of a table's search terms:
    `_foot_terms` reads 11 of a spine table's 21 values, `_local_terms` 14.)"""

    def __init__(self, count: int, value: Callable[[int], Array]):
        self._value, self._read = value, [None] * count

    def __len__(self) -> int:
        return len(self._read)

    def __getitem__(self, f):
        if isinstance(f, slice):
            return [self[i] for i in range(len(self))[f]]
        f = range(len(self))[f]  # (negative indices counted from the end; IndexError past it)
        if self._read[f] is None:
            self._read[f] = self._value(f)
        return self._read[f]
