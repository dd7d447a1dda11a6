"""The samples within a reconstruction filter's reach of each pixel.

A film with a filter wider than a box develops pixel ``p`` from every sample
``s`` drawn in the pixels whose samples can lie within the filter's radius of
``p``'s centre, weighted by ``f(p_x + 1/2 - x_s) f(p_y + 1/2 - y_s)``. Both
filtered sinks of the pass engine (the film, :mod:`mcrt.core.accumulators`,
and the filtered statistics, :mod:`mcrt.core.filtered`) form their sums
*per target pixel*, gathering its sources in one fixed order (the offsets,
then each source pixel's samples), so no two lanes ever write one value and
the result does not depend on thread scheduling. :class:`FilterReach` is that
neighbourhood and its weights, in one place.

A pass's samples come as a :class:`~mcrt.core.packed.Packed` whose last two
columns are the film position x, y; a non-finite sample is stored with its x
NaN and its channels zeroed, and gets no weight.
"""

from __future__ import annotations

import math
from typing import Any

import drjit as dr
import mitsuba as mi

from .packed import Packed


class FilterReach:
    """Target pixels ``size`` (w, h), the first at film pixel ``origin``, and
    their sources: the sampled grid ``grid`` (w, h), its first pixel at film
    pixel ``grid_origin``, ``group`` samples per pixel and pass."""

    def __init__(self, rfilter: mi.ReconstructionFilter, size: tuple[int, int],
                 origin: tuple[int, int], grid: tuple[int, int],
                 grid_origin: tuple[int, int]) -> None:
        self.rfilter = rfilter
        self.size, self.origin, self.grid, self.grid_origin = size, origin, grid, grid_origin
        reach = math.ceil(rfilter.radius() + 0.5) - 1  # a sample lies in [0, 1) of its pixel
        self.offsets = [(dx, dy) for dy in range(-reach, reach + 1)
                        for dx in range(-reach, reach + 1)]

    def _sources(self, group: int) -> tuple[mi.Point2f, list[tuple[Any, Any]]]:
        """Each target's centre, and per offset: (inside the grid, the first
        lane of the source pixel's samples)."""
        w, _ = self.size
        gw, gh = self.grid
        t = dr.arange(mi.UInt32, w * self.size[1])
        ty = t // w
        target = mi.Vector2i(mi.Int32(t - ty * w) + self.origin[0],
                             mi.Int32(ty) + self.origin[1])
        sources = []
        for dx, dy in self.offsets:
            g = target - mi.Vector2i(dx + self.grid_origin[0], dy + self.grid_origin[1])
            inside = (g.x >= 0) & (g.x < gw) & (g.y >= 0) & (g.y < gh)
            sources.append((inside, mi.UInt32(dr.select(inside, g.y * gw + g.x, 0)) * group))
        return mi.Point2f(target) + 0.5, sources

    def sums(self, packed: Packed, group: int, outputs: int,
             terms: Any) -> list[mi.Float64]:
        """Per target pixel, the float64 sums of ``terms(weight, values)`` (a
        list of ``outputs`` values) over every sample in reach, in a fixed
        order: each source pixel's sample ``k`` (k = 0 .. group - 1), offset by
        offset. ``weight`` is the sample's filter weight for the target (0
        outside the grid and for a non-finite sample), ``values`` its stored
        columns but the position."""
        w, h = self.size
        centre, sources = self._sources(group)  # the same in every iteration

        def body(k: Any, *totals: Any) -> tuple[Any, ...]:
            out = list(totals)
            for inside, base in sources:
                *values, x, y = packed.gather(base + k, inside)
                weight = dr.select(inside & ~dr.isnan(x), self.rfilter.eval(centre.x - x)
                                   * self.rfilter.eval(centre.y - y), 0.0)
                for c, term in enumerate(terms(weight, values)):
                    out[c] = out[c] + term
            return (k + 1, *out)

        zeros = [dr.zeros(mi.Float64, w * h) for _ in range(outputs)]
        if group == 1:
            return list(body(mi.UInt32(0), *zeros)[1:])
        state: Any = dr.while_loop((mi.UInt32(0), *zeros), lambda k, *s: k < group, body)
        return list(state[1:])
