"""The adaptive render's per-pixel sums: float64 moments and sub-pixel sums.

One kernel reduces a traced wavefront (``m`` consecutive lanes per pixel): a
thread per pixel walks its lanes in sample order and

* continues the pixel's moments ``(n, mean, M2)`` with Welford's update, from
  the values its earlier passes left (so a pixel's moments are one sequential
  pass over all its samples: no merge formula, the same bits however its
  samples were split into passes or wavefronts), and
* adds each lane's value and a count of 1 to its sub-pixel in a local buffer
  (Dr.Jit's local memory: one indexed add per lane instead of a select per
  sub-pixel).

A sample with a non-finite R, G or B is left out of both and counted. The
moments of every pixel (8 float64) and the sub-pixel sums, ``s * s * (C + 1)``
float64 per pixel (one pixel-major array: a pixel's row of sums is contiguous),
stay on the device until the image is developed: the kernel gathers a pixel's
moments so far itself, and continues them into its luminance and standard
error (:func:`~.criterion.luminance_error_device`). The host keeps what the
error test reads after every pass - finite and non-finite counts, luminance,
its error - four float64 per pixel, read back for the wavefront's pixels only.
(With the moments on the host, a pass took and uploaded its pixels' rows, read
them back and recomputed their luminance error in numpy: the time per pass
without a kernel running was 3.75-4.19 ms on scenes/edges.xml, now 1.69-2.32,
benchmarks/adaptive_pass_cost.py, 3 alternated runs against the earlier tree.) A wavefront's
results are *pending* until :meth:`PixelSums.commit`, which the engine calls
for all of a pass's wavefronts at its end with interrupts held back, so the
sums always describe whole passes. The reduction adds a wavefront's sub-pixel
sums to its pixels' rows as the last commit left them (gathered), and the
commit writes the new rows and moments, a thread per pixel: one pixel is in one
wavefront per pass, so each slot gets exactly one write per commit, and the
arrays are updated in place (a scatter into an array that a pending gather still
reads would copy it whole first). Plain writes, not the atomic adds a commit
made before: on scenes/edges.xml the commit went from 5.0-5.2% to 3.2-3.4% of
the passes' time and the reduction from 6.3-6.4% to 7.0-7.2%
(benchmarks/adaptive_pass_cost.py, 3 alternated pairs). The row layout
touches ``row / 8`` cache lines per pixel where one array per (cell, value) took
one each: the commit kernel of a pass of ~13k pixels (benchmarks/adaptive_pass_cost.py)
fell from 6.1 to 4.0 ms (median, 2-core VM); a first wavefront of every pixel
costs one kernel that interleaves its sums (4.4 ms there; none before).

:func:`reduce_wavefront` takes and returns device arrays only, every width from
an input's, so :mod:`.frozen` records it with the wavefront's trace.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.stats import PixelStats
from ...core.upload import to_device
from ...errors import McrtError
from .criterion import luminance_error_device

#: Most sub-pixels one reduction kernel sums (its local buffer holds this many
#: cells of ``C + 1`` float64 per thread); a finer grid (``subpixels`` > 8) is
#: reduced by several kernels, one per block of cells.
CELLS_PER_KERNEL = 64

#: The per-pixel moments, one device array each: finite samples, mean and M2 of
#: R, G, B, non-finite samples.
N, MEAN, M2, BAD = 0, slice(1, 4), slice(4, 7), 7
STAT_COLUMNS = 8


@dataclass
class Pending:
    """One reduced wavefront, not yet committed."""

    ids: np.ndarray  # pixel ids (int64)
    slots: Any  # the same ids on the device (UInt32)
    m: int  # samples per pixel
    moments: list[Any]  # the pixels' new moments (STAT_COLUMNS device arrays)
    host: np.ndarray  # (4, ids.size): their count, non-finite count, luminance, its error
    cells: list[tuple[int, list[mi.Float64]]]  # (first cell, new sums per cell x channel)
    nonfinite: int  # non-finite samples in this wavefront


class PixelSums:
    """Moments and sub-pixel sums of ``pixels`` pixels (``s x s`` sub-pixels,
    ``channels`` values per sample: R, G, B [, A])."""

    def __init__(self, pixels: int, s: int, channels: int) -> None:
        self.pixels, self.s, self.channels = pixels, s, channels
        self.traced = np.zeros(pixels, np.int64)
        #: What the error test reads, per pixel: finite and non-finite samples
        #: (float64, exact integers), mean luminance and its standard error
        #: (:func:`~.criterion.luminance_error`), updated for the pixels each
        #: commit changes.
        self.count = np.zeros(pixels)
        self.bad = np.zeros(pixels)
        self.mean_y = np.zeros(pixels)
        self.se_y = np.full(pixels, np.nan)  # unknown until two samples are finite
        #: The moments on the device (``STAT_COLUMNS`` arrays), evaluated: a
        #: recorded wavefront reads them.
        self.moments = [dr.opaque(mi.Float64, 0.0, pixels) for _ in range(STAT_COLUMNS)]
        #: Sub-pixel sums, pixel-major: pixel ``p``'s ``(cell, value... count)``
        #: row is ``grid[p * row : (p + 1) * row]``.
        self.grid = dr.zeros(mi.Float64, pixels * self.row)
        #: Nothing committed or restored yet (the grid is still zero).
        self.empty = True

    @property
    def row(self) -> int:
        """Float64 per pixel in the sub-pixel sums: ``(value..., count)`` per cell."""
        return self.s * self.s * (self.channels + 1)

    # -- a pass -------------------------------------------------------------
    def reduce(self, ids: np.ndarray, m: int, values: Sequence[mi.Float], finite: mi.Bool,
               cell: Any) -> Pending:
        """Reduce one wavefront: lanes ``i*m .. i*m+m-1`` are pixel ``ids[i]``'s new
        samples (``values`` per channel, ``finite``, sub-pixel ``cell``)."""
        if len(values) != self.channels:
            raise McrtError(f"adaptive: expected {self.channels} channels, got {len(values)}")
        slots = to_device(mi.UInt32, ids)
        sums, out = reduce_wavefront(self.moments, self.prior(), slots, m, values, finite, cell,
                                     self.s)
        return self.pending(ids, slots, m, sums, out)

    def prior(self) -> Any:
        """The grid a wavefront adds its sums to: None while nothing is committed
        (the grid is zero: the reduction reads nothing)."""
        return None if self.empty else self.grid

    def pending(self, ids: np.ndarray, slots: Any, m: int, sums: list[list[mi.Float64]],
                out: list[mi.Float64]) -> Pending:
        """The :class:`Pending` of a wavefront that :func:`reduce_wavefront` reduced
        on the device (``slots``: ``ids`` on the device)."""
        moments = out[:STAT_COLUMNS]
        host = np.stack([np.asarray(x, dtype=np.float64)
                         for x in (moments[N], moments[BAD], *out[STAT_COLUMNS:])])
        cells = list(zip(range(0, self.s * self.s, CELLS_PER_KERNEL), sums, strict=True))
        return Pending(ids, slots, m, moments, host, cells,
                       int(round(host[1].sum() - self.bad[ids].sum())))

    def commit(self, pending: Pending) -> None:
        """Make ``pending`` current (call with interrupts held back)."""
        ids = pending.ids
        self.traced[ids] += pending.m
        for column, values in zip((self.count, self.bad, self.mean_y, self.se_y), pending.host,
                                  strict=True):
            column[ids] = values
        sums = [value for _, block in pending.cells for value in block]
        if self.empty and ids.size == self.pixels and bool(np.all(np.diff(ids) > 0)):
            # A first wavefront of every pixel, in order: its moments are the
            # moments and its sums the grid (0 + x == x), interleaved by one kernel
            # that writes it in order.
            self.moments = list(pending.moments)
            self.grid = mi.Float64(dr.ravel(_rows(sums)))
        else:
            # One kernel, a thread per pixel, writing the rows the reduction added
            # to (contiguous: row / 8 cache lines, not one per plane). One nested
            # scatter: a plain scatter per value would be a kernel each.
            dr.scatter(self.grid, _rows(sums), pending.slots)
            for moment, value in zip(self.moments, pending.moments, strict=True):
                dr.scatter(moment, value, pending.slots)
        dr.eval(self.grid, self.moments)
        self.empty = False

    # -- reading ------------------------------------------------------------
    def pixel_stats(self) -> PixelStats:
        """The per-pixel moments (flat arrays over the sampled grid)."""
        stats = np.stack([np.asarray(x, dtype=np.float64) for x in self.moments], -1)
        return PixelStats(count=stats[:, N].astype(np.int64), mean=stats[:, MEAN],
                          m2=stats[:, M2], nonfinite=stats[:, BAD].astype(np.int64))

    def counts(self) -> np.ndarray:
        """Finite samples per pixel (float64: exact integers)."""
        return self.count

    def sub_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """``(sums (pixels, s*s, C), counts (pixels, s*s))`` of the sub-pixels."""
        grid = np.array(self.grid, dtype=np.float64)  # a copy: the grid changes in place
        grid = grid.reshape(self.pixels, self.s * self.s, self.channels + 1)
        return grid[..., :-1], grid[..., -1].astype(np.int64)

    # -- checkpoints --------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """Copies of every array (a checkpoint's)."""
        stats = self.pixel_stats()
        sub_sum, sub_count = self.sub_pixels()
        return {"count": stats.count, "mean": stats.mean.copy(), "m2": stats.m2.copy(),
                "nonfinite": stats.nonfinite, "traced": self.traced.copy(),
                "sub_sum": sub_sum.copy(), "sub_count": sub_count}

    def nbytes(self) -> int:
        return 8 * self.pixels * (STAT_COLUMNS + 5 + self.row)

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`arrays` of an identical render."""
        s2 = self.s * self.s
        expected = {"count": (self.pixels,), "mean": (self.pixels, 3), "m2": (self.pixels, 3),
                    "nonfinite": (self.pixels,), "traced": (self.pixels,),
                    "sub_sum": (self.pixels, s2, self.channels), "sub_count": (self.pixels, s2)}
        if any(arrays[name].shape != shape for name, shape in expected.items()):
            raise McrtError("the saved adaptive render does not match this scene")
        stats = np.zeros((STAT_COLUMNS, self.pixels))
        stats[N], stats[MEAN], stats[M2] = arrays["count"], arrays["mean"].T, arrays["m2"].T
        stats[BAD] = arrays["nonfinite"]
        self.moments = [to_device(mi.Float64, column) for column in stats]
        self.traced[...] = arrays["traced"]
        self.count, self.bad = stats[N].copy(), stats[BAD].copy()
        mean_y, se_y = luminance_error_device(self.moments)
        self.mean_y, self.se_y = (np.asarray(x, dtype=np.float64) for x in (mean_y, se_y))
        grid = np.concatenate([arrays["sub_sum"], arrays["sub_count"][..., None]], -1)
        self.grid = to_device(mi.Float64, grid)
        self.empty = False


def _rows(columns: list[mi.Float64]) -> Any:
    """``columns`` as one dynamic array of rows (its ravel interleaves them)."""
    array_xf64: Any = mi.ArrayXf64  # the variant's (Mitsuba's stubs do not declare it)
    return array_xf64(columns)


def reduce_wavefront(moments: list[mi.Float64], grid: mi.Float64 | None, slots: mi.UInt32,
                     m: int, values: Sequence[mi.Float], finite: mi.Bool, cell: mi.UInt32,
                     s: int) -> tuple[list[list[mi.Float64]], list[mi.Float64]]:
    """Device arrays only (a frozen function records it, :mod:`.frozen`): the
    sub-pixel sums of each block of :data:`CELLS_PER_KERNEL` cells, added to the
    pixels' rows of ``grid`` (:meth:`PixelSums.prior`), and the moments of the
    pixels ``slots`` continued from ``moments`` (:attr:`PixelSums.moments`) over
    a wavefront of ``m`` lanes per pixel, followed by their mean luminance and
    its standard error."""
    blocks: list[list[mi.Float64]] = []
    out: list[mi.Float64] = []
    for lo in range(0, s * s, CELLS_PER_KERNEL):
        hi = min(lo + CELLS_PER_KERNEL, s * s)
        prior = [dr.gather(mi.Float64, x, slots) for x in moments] if lo == 0 else []
        sums, stats = _reduce_kernel(prior, grid, slots, m, values, finite, cell, s, lo, hi)
        blocks.append(sums)
        out = out or stats
    return blocks, out


def _reduce_kernel(prior: list[Any], grid: mi.Float64 | None, slots: mi.UInt32, m: int,
                   values: Sequence[mi.Float], finite: mi.Bool, cell: mi.UInt32, s: int,
                   lo: int, hi: int) -> tuple[list[mi.Float64], list[mi.Float64]]:
    """One thread per pixel over its ``m`` lanes: the sums of cells ``lo..hi-1``
    (value channels, then the count, per cell), added to the pixel's row of
    ``grid`` (the sums so far, unless None), and, given the pixel's moments so
    far (``prior``), its moments continued over the lanes (``STAT_COLUMNS``
    arrays), its mean luminance and their standard error."""
    width = len(values) + 1
    # The pixel count from an input's width (not a host integer: a frozen
    # function replays with other widths).
    first = dr.arange(mi.UInt32, dr.width(slots)) * m
    local = dr.alloc_local(mi.Float64, (hi - lo) * width, dr.zeros(mi.Float64))

    def body(k: Any, local: Any, *stat: Any) -> tuple[Any, ...]:
        lane = first + k
        c = dr.gather(mi.UInt32, cell, lane)
        keep = dr.gather(mi.Bool, finite, lane)
        x = [mi.Float64(dr.gather(mi.Float, v, lane)) for v in values]
        here = keep & (c >= lo) & (c < hi)
        slot = (c - lo) * width
        for j in range(width):
            add = x[j] if j < len(x) else mi.Float64(1.0)
            local.write(local.read(slot + j, here) + add, slot + j, here)
        if not stat:
            return (k + 1, local)
        return (k + 1, local, *_welford(stat, x[:3], keep))

    state = dr.while_loop((mi.UInt32(0), local, *prior), lambda k, *_: k < m, body)
    local = state[1]
    block = (hi - lo) * width
    sums = [local[j] for j in range(block)]
    if grid is not None:  # (the sum so far plus this wavefront's: the bits of adding it later)
        sums = [before + x for before, x in zip(_rows_of(grid, slots, s * s * width, lo * width,
                                                         block), sums, strict=True)]
    stats = list(state[2:])
    if stats:
        stats += luminance_error_device(stats)
    dr.eval(sums, stats)
    return sums, stats


def _rows_of(grid: mi.Float64, slots: mi.UInt32, row: int, start: int, count: int) -> list[Any]:
    """Values ``start .. start + count - 1`` of the pixels' rows of ``grid``: a
    whole row as one nested gather (packet loads and a transpose, not a gather
    instruction per value), else value by value."""
    if start == 0 and count == row:
        array_xf64: Any = mi.ArrayXf64  # (Mitsuba's stubs do not declare it)
        rows: Any = dr.gather(array_xf64, grid, slots, shape=(row, dr.width(slots)))
        return [rows[j] for j in range(row)]
    first = slots * row + start
    return [dr.gather(mi.Float64, grid, first + j) for j in range(count)]


def _welford(stat: Sequence[Any], x: Sequence[Any], keep: Any) -> list[Any]:
    """The moments ``(n, mean x 3, M2 x 3, nonfinite)`` with sample ``x`` added
    (where ``keep``; else counted as non-finite)."""
    n = dr.select(keep, stat[N] + 1.0, stat[N])
    safe = dr.maximum(n, 1.0)
    means, m2s = [], []
    for c in range(3):
        mean, m2 = stat[1 + c], stat[4 + c]
        delta = x[c] - mean
        new_mean = mean + delta / safe
        means.append(dr.select(keep, new_mean, mean))
        m2s.append(dr.select(keep, m2 + delta * (x[c] - new_mean), m2))
    return [n, *means, *m2s, dr.select(keep, stat[BAD], stat[BAD] + 1.0)]


__all__ = ["CELLS_PER_KERNEL", "Pending", "PixelSums", "reduce_wavefront"]
