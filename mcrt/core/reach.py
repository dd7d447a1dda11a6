"""The samples within a reconstruction filter's reach of each pixel.

A film with a filter wider than a box develops pixel ``p`` from every sample
``s`` drawn in the pixels whose samples can lie within the filter's radius of
``p``'s centre, weighted by ``f(p_x + 1/2 - x_s) f(p_y + 1/2 - y_s)``. Both
filtered sinks of the pass engine (the film, :mod:`mcrt.core.accumulators`,
and the filtered statistics, :mod:`mcrt.core.filtered`) form their sums
*per target pixel*, gathering its sources in one fixed order (each source
pixel's sample ``k``, then the offsets), so no two lanes ever write one value
and the result does not depend on thread scheduling. :class:`FilterReach` is
that neighbourhood and its weights, in one place.

One lane gathers for a block of :data:`BLOCK` neighbouring targets at once:
the block's sources overlap, so each source sample is loaded once for all the
block's targets it reaches, and each of its 1D filter values is evaluated once
per target column (or row) instead of once per target. Every target still adds
its own terms in its own fixed order, with the same arithmetic, so the sums do
not depend on the block's shape (``benchmarks/packed_gather.py`` measures it).

A pass's samples come as a :class:`~mcrt.core.packed.Packed` whose last two
columns are the film position x, y; a non-finite sample is stored with its x
NaN and its channels zeroed, and gets no weight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from .packed import Packed

#: Targets (columns, rows) one lane gathers for.
BLOCK = (2, 2)
#: Sources a lane's kernel names one by one (every filter of Mitsuba's defaults: a
#: lanczos' 3-pixel reach gives 8 x 8); a wider filter's are visited by a symbolic
#: loop, in the same order with the same arithmetic (the same bits), so that its
#: kernel does not grow with the reach squared: a tent of radius 8 took 11 s to
#: compile, one of radius 20 minutes, where ``mi.render`` takes a fraction of one.
UNROLLED_SOURCES = 64


@dataclass
class TargetSums:
    """The sums of one block slot: ``values[c]`` belongs to target pixel
    ``index`` (row-major over the targets), where ``valid``."""

    index: Any
    valid: Any
    values: list[Any]


class FilterReach:
    """Target pixels ``size`` (w, h), the first at film pixel ``origin``, and
    their sources: the sampled grid ``grid`` (w, h), its first pixel at film
    pixel ``grid_origin``, ``group`` samples per pixel and pass."""

    def __init__(self, rfilter: mi.ReconstructionFilter, size: tuple[int, int],
                 origin: tuple[int, int], grid: tuple[int, int],
                 grid_origin: tuple[int, int], block: tuple[int, int] = BLOCK,
                 unrolled: int | None = None) -> None:
        self.rfilter = rfilter
        self.size, self.origin, self.grid, self.grid_origin = size, origin, grid, grid_origin
        self.reach = math.ceil(rfilter.radius() + 0.5) - 1  # a sample lies in [0, 1) of its pixel
        self.block = block
        #: At most this many sources are named one by one (None: UNROLLED_SOURCES).
        self.unrolled = UNROLLED_SOURCES if unrolled is None else unrolled

    def sums(self, packed: Packed, group: int, outputs: int,
             terms: Any) -> list[TargetSums]:
        """Per target pixel, the float64 sums of ``terms(weight, values)`` (a
        list of ``outputs`` values) over every sample in reach, in a fixed
        order: each source pixel's sample ``k`` (k = 0 .. group - 1), offset by
        offset (source ``target - (dx, dy)``, dy then dx ascending). ``weight``
        is the sample's filter weight for the target (0 outside the grid and for
        a non-finite sample), ``values`` its stored columns but the position.
        One :class:`TargetSums` per slot of the block, each lane's block of
        targets in turn."""
        (w, h), (bw, bh), r = self.size, self.block, self.reach
        gw, gh = self.grid
        cols, rows = -(-w // bw), -(-h // bh)
        lane = dr.arange(mi.UInt32, cols * rows)
        by = lane // cols
        first = mi.Vector2i(mi.Int32(lane - by * cols) * bw, mi.Int32(by) * bh)  # block's target
        slots = [(i, j) for j in range(bh) for i in range(bw)]
        index, valid = [], []
        for i, j in slots:
            index.append(mi.UInt32((first.y + j) * w + first.x + i))
            valid.append((first.x + i < w) & (first.y + j < h))
        centre = mi.Point2f(first + mi.Vector2i(self.origin)) + 0.5  # of slot (0, 0)
        zeros = [dr.zeros(mi.Float64, cols * rows) for _ in range(len(slots) * outputs)]
        span = (bw + 2 * r, bh + 2 * r)  # sources per row, rows
        if span[0] * span[1] > self.unrolled:
            looped = self._looped(packed, group, outputs, terms, first, centre, slots, span)
            totals = self._over_samples(looped, group, zeros)
            return [TargetSums(index[s], valid[s], totals[s * outputs:(s + 1) * outputs])
                    for s in range(len(slots))]
        # Sources by (sx, sy) relative to the block's first target, in the order every
        # target adds them: source = target - offset, offsets ascending (dy, then dx).
        sources = []
        for sy in range(bh - 1 + r, -r - 1, -1):
            for sx in range(bw - 1 + r, -r - 1, -1):
                g = first + mi.Vector2i(sx + self.origin[0] - self.grid_origin[0],
                                        sy + self.origin[1] - self.grid_origin[1])
                inside = (g.x >= 0) & (g.x < gw) & (g.y >= 0) & (g.y < gh)
                near = [s for s, (i, j) in enumerate(slots)
                        if abs(sx - i) <= r and abs(sy - j) <= r]
                sources.append((inside,
                                mi.UInt32(dr.select(inside, g.y * gw + g.x, 0)) * group, near))

        def body(k: Any, *totals: Any) -> tuple[Any, ...]:
            out = list(totals)
            for inside, base, near in sources:
                *values, x, y = packed.gather(base + k, inside)
                use = inside & ~dr.isnan(x)
                fx = {i: self.rfilter.eval(centre.x + i - x)
                      for i in sorted({slots[s][0] for s in near})}
                fy = {j: self.rfilter.eval(centre.y + j - y)
                      for j in sorted({slots[s][1] for s in near})}
                for s in near:
                    i, j = slots[s]
                    weight = dr.select(use, fx[i] * fy[j], 0.0)
                    for c, term in enumerate(terms(weight, values)):
                        out[s * outputs + c] = out[s * outputs + c] + term
            return (k + 1, *out)

        totals = self._over_samples(body, group, zeros)
        return [TargetSums(index[s], valid[s], totals[s * outputs:(s + 1) * outputs])
                for s in range(len(slots))]

    @staticmethod
    def _over_samples(body: Any, group: int, zeros: list[Any]) -> list[Any]:
        """``body(k, *totals)`` for each source pixel's sample k in turn."""
        if group == 1:
            return list(body(mi.UInt32(0), *zeros)[1:])
        state: Any = dr.while_loop((mi.UInt32(0), *zeros), lambda k, *s: k < group, body)
        return list(state[1:])

    def _looped(self, packed: Packed, group: int, outputs: int, terms: Any, first: Any,
                centre: Any, slots: list[tuple[int, int]], span: tuple[int, int]) -> Any:
        """The body of :meth:`sums` for a wide filter: source ``n`` of the same
        order (``sy`` then ``sx`` descending) in a symbolic loop, each slot adding
        the same terms where the source is in its reach and left as it was
        elsewhere, so every target's sums are the unrolled body's bits."""
        (bw, bh), r = self.block, self.reach
        gw, gh = self.grid
        shift = (self.origin[0] - self.grid_origin[0], self.origin[1] - self.grid_origin[1])

        def body(k: Any, *totals: Any) -> tuple[Any, ...]:
            def source(n: Any, *out_: Any) -> tuple[Any, ...]:
                out = list(out_)
                row = n // span[0]
                sx = mi.Int32(bw - 1 + r) - mi.Int32(n - row * span[0])
                sy = mi.Int32(bh - 1 + r) - mi.Int32(row)
                g = first + mi.Vector2i(sx + shift[0], sy + shift[1])
                inside = (g.x >= 0) & (g.x < gw) & (g.y >= 0) & (g.y < gh)
                base = mi.UInt32(dr.select(inside, g.y * gw + g.x, 0)) * group
                *values, x, y = packed.gather(base + k, inside)
                use = inside & ~dr.isnan(x)
                fx = [self.rfilter.eval(centre.x + i - x) for i in range(bw)]
                fy = [self.rfilter.eval(centre.y + j - y) for j in range(bh)]
                for s, (i, j) in enumerate(slots):
                    near = (dr.abs(sx - i) <= r) & (dr.abs(sy - j) <= r)
                    weight = dr.select(use, fx[i] * fy[j], 0.0)
                    for c, term in enumerate(terms(weight, values)):
                        out[s * outputs + c] = dr.select(near, out[s * outputs + c] + term,
                                                         out[s * outputs + c])
                return (n + 1, *out)

            state: Any = dr.while_loop((mi.UInt32(0), *totals),
                                       lambda n, *s: n < span[0] * span[1], source)
            return (k + 1, *state[1:])

        return body


def dense(slots: list[TargetSums], size: int) -> list[mi.Float64]:
    """The slots' sums as one array per output over ``size`` targets (each
    target written once, by its own lane)."""
    arrays = [dr.zeros(mi.Float64, size) for _ in slots[0].values]
    for slot in slots:
        for array, value in zip(arrays, slot.values, strict=True):
            dr.scatter(array, value, slot.index, slot.valid)
    return arrays
