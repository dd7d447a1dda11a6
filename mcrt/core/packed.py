"""Columns of per-lane values stored interleaved, for fast gathers.

A kernel that gathers several values of one lane (a stored sample's channels
and position) from separate arrays issues one gather per array. Stored
interleaved in groups of 2, 4 or 8 columns, Dr.Jit reads each group with
packet loads and a transpose instead (``JitFlag.PacketOps``, on by default),
on the LLVM backend without gather instructions at all. Groups must be a power
of two wide, so 5 columns are stored as 4 + 1: no padding, the same memory as
separate arrays.

Measured with ``benchmarks/packed_gather.py`` (256^2 pixels x 16 samples, the
25 neighbours of a 5x5 filter, the weights left out, median of 7): 5 separate
arrays 25.9 ms, one group of 5 (not a power of two: no packet loads) 32.2 ms,
4 + 1 columns 19.9 ms.

Example::

    packed = Packed.of([r, g, b, x, y])        # evaluated with the next kernel
    r, g, b, x, y = packed.gather(lane, active)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import drjit as dr
import mitsuba as mi

#: Widest group: Dr.Jit transposes packets of up to 8 values.
MAX_GROUP = 8


def group_sizes(columns: int) -> list[int]:
    """``columns`` split into powers of two of at most :data:`MAX_GROUP`,
    widest first (5 -> [4, 1], 11 -> [8, 2, 1])."""
    sizes = []
    while columns > 0:
        size = min(MAX_GROUP, 1 << (columns.bit_length() - 1))
        sizes.append(size)
        columns -= size
    return sizes


def _array_xf() -> Any:
    """The active variant's dynamic float vector (looked up on each use: the
    variant may change; Mitsuba's type stubs do not declare it callable)."""
    return mi.ArrayXf


class Packed:
    """Equal-length float columns, stored interleaved in power-of-two groups."""

    def __init__(self, groups: list[tuple[int, Any]]) -> None:
        self.groups = groups  # (width, flat array of width * lanes floats)

    @classmethod
    def of(cls, columns: Sequence[Any]) -> Packed:
        """Interleave ``columns`` (lazy: the arrays are written by the kernel
        that next evaluates them)."""
        groups, first = [], 0
        for size in group_sizes(len(columns)):
            part = columns[first:first + size]
            flat = mi.Float(part[0]) if size == 1 else dr.ravel(_array_xf()(list(part)))
            groups.append((size, flat))
            first += size
        return cls(groups)

    @property
    def arrays(self) -> list[Any]:
        """The flat arrays (to evaluate)."""
        return [flat for _, flat in self.groups]

    def gather(self, lane: Any, active: Any = True) -> list[Any]:
        """Every column's value at ``lane`` (0 where not ``active``)."""
        values: list[Any] = []
        for size, flat in self.groups:
            if size == 1:
                values.append(dr.gather(mi.Float, flat, lane, active))
                continue
            row: Any = dr.gather(_array_xf(), flat, lane, active, shape=(size, dr.width(lane)))
            values += [row[i] for i in range(size)]
        return values
