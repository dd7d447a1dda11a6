"""Accumulators of the pass engine: a filtered film and per-pixel moments.

Both keep float64 sums on the device and fold each pass in elementwise, in a
fixed order, with no atomic adds: a render is bit-identical across runs and
thread counts (Mitsuba's ``ImageBlock.put`` adds with atomics, whose order
depends on thread scheduling). A sample with a non-finite channel is left out
entirely (no value, no weight) and counted for the pixel it was drawn in.

A film with a box filter folds passes of up to :data:`FOLD` samples per pixel
into its sums inside the tracing kernel itself: nothing per lane is ever stored
(see :attr:`FilmAccumulator.fold`). Other passes of several samples per pixel
store the pass's values (at most :data:`~mcrt.core.engine.MAX_LANES_PER_PASS`
lanes) and reduce them per pixel, each pixel's samples in sample order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from .packed import Packed
from .reach import FilterReach, TargetSums
from .trace import CameraSamples, film_grid_size
from .upload import to_device

if TYPE_CHECKING:
    from .stats import PixelStats

#: Most samples of one pixel a kernel adds into a box-filtered film as it traces
#: them. The pixel's samples are neighbouring lanes, which on Dr.Jit's LLVM
#: backend lie in one SIMD packet (4, 8 or 16 lanes, aligned; a thread's block of
#: work is whole packets), and its non-atomic scatter-add (``NoConflicts``) sums a
#: packet's lanes per target before it adds the sum: one add per pixel and pass,
#: by one thread, whatever the thread count. In float64 the sum of four float32
#: values is exact but in extreme dynamic range, so its order does not matter.
FOLD = 4


def _finite(values: Sequence[Any]) -> mi.Bool:
    finite = dr.isfinite(values[0])
    for v in values[1:]:
        finite &= dr.isfinite(v)
    return finite


#: Films of fewer pixels keep Dr.Jit's cached buffers (:func:`release_cached_memory`).
RELEASE_PIXELS = 1 << 18


def release_cached_memory(pixels: int | None = None) -> None:
    """Return the buffers Dr.Jit keeps for reuse (freed pass data, copies) to the
    system, so that the next allocations of other sizes do not add to the peak.

    Given a film's ``pixels``, only from :data:`RELEASE_PIXELS` (512^2) on: a
    pass's buffers (up to 2^20 lanes) are what is cached, and below that a film's
    own buffers are smaller, so returning them lowers no peak, while the next
    render of the process maps and faults them in again. On the 2-core VM that cost an
    adaptive render of scenes/edges.xml 0.5-0.6 s of system time after two film
    renders (1.3-1.5 s instead of 1.0); the quick study did not change measurably."""
    if pixels is not None and pixels < RELEASE_PIXELS:
        return
    if dr.flag(dr.JitFlag.FreezingScope):  # a frozen render is recorded: nothing to return
        return
    dr.sync_thread()
    dr.flush_malloc_cache()


def _is_one(value: Any) -> bool:
    """Whether ``value`` is the literal 1 (the film's weight channel): not stored."""
    return bool(value.state == dr.VarState.Literal and dr.width(value) == 1 and value[0] == 1.0)


def _numpy(array, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    return np.array(array, dtype=np.float64).astype(dtype).reshape(shape)


class FilmAccumulator:
    """Filter-weighted sums of a film's image block (weight channel included).

    :meth:`develop` hands them to the film, which normalises by the weights and
    converts to its pixel format, so a render equals what ``mi.render`` develops
    from the same samples.
    """

    def __init__(self, film: mi.Film, channels: int) -> None:
        block = film.create_block()
        self.film = film
        self.offset = block.offset()
        self.border = int(block.border_size())
        size = block.size()
        self.ext = (int(size[0]) + 2 * self.border, int(size[1]) + 2 * self.border)  # (w, h)
        self.origin = (int(self.offset[0]) - self.border,
                       int(self.offset[1]) - self.border)  # film pixel of block (0, 0)
        grid = film_grid_size(film)
        self.grid = (int(grid[0]), int(grid[1]))
        inset = int(film.rfilter().border_size()) if film.sample_border() else 0
        crop = film.crop_offset()
        self.grid_origin = (int(crop[0]) - inset, int(crop[1]) - inset)
        self.channels = channels
        #: The weight channel (:func:`~mcrt.core.engine.film_values`: R, G, B, [A,] W).
        self.weight = 4 if mi.has_flag(film.flags(), mi.FilmFlags.Alpha) else 3
        rfilter = film.rfilter()
        self.box = bool(rfilter.is_box_filter()) and self.ext == self.grid \
            and self.origin == self.grid_origin
        self.reach = None if self.box else \
            FilterReach(rfilter, self.ext, self.origin, self.grid, self.grid_origin)
        self.sums = [dr.zeros(mi.Float64, self.ext[0] * self.ext[1]) for _ in range(channels)]
        self.nonfinite = dr.zeros(mi.UInt32, self.grid[0] * self.grid[1])
        self._pending: tuple[list[TargetSums], Any, Any] | None = None

    @property
    def fold(self) -> int:
        """Samples per pixel and pass this film adds in while tracing them
        (:data:`FOLD` for a box filter on the LLVM backend, else 1, or 0 when
        every pass is stored): the engine's ``fold`` (see
        :func:`~mcrt.core.engine.pass_shape`)."""
        if not self.box:
            return 0
        return FOLD if dr.backend_v(self.sums[0]) == dr.JitBackend.LLVM else 1

    # -- the engine's interface ------------------------------------------------
    def add(self, samples: CameraSamples, values: list[mi.Float], group: int) -> None:
        if len(values) != self.channels:
            raise McrtError(f"the film expects {self.channels} channels, got {len(values)}")
        if group <= self.fold and group & (group - 1) == 0:  # fold in while tracing
            finite = _finite(values)
            pixel = dr.arange(mi.UInt32, self.ext[0] * self.ext[1] * group) // group
            self._pending = ([TargetSums(pixel, True, [mi.Float64(dr.select(finite, v, 0.0))
                                                      for v in values])],
                             dr.select(finite, mi.UInt32(0), mi.UInt32(1)), pixel)
            return
        if not self.box:
            self._pending = self._filtered(samples, values, group)
            return
        # Store the pass's raw values (the sampler's next state is evaluated with
        # them), except the weight channel (the literal 1); then one kernel per
        # pass sums each pixel's samples in order.
        ones = [_is_one(v) for v in values]
        stored = [v for v, one in zip(values, ones, strict=True) if not one]
        dr.eval(stored)

        def own(lane: Any) -> list[Any]:  # the channels, non-finite samples zeroed; the flag
            raw = iter([dr.gather(mi.Float, v, lane) for v in stored])
            channels = [mi.Float(1.0) if one else next(raw) for one in ones]
            finite = _finite(channels)
            return [dr.select(finite, c, 0.0) for c in channels] + [dr.select(finite, 0.0, 1.0)]

        sums = sequential_block_sums(self.grid[0] * self.grid[1], group, own,
                                     self.channels + 1, evaluate=False)
        pixel = dr.arange(mi.UInt32, self.grid[0] * self.grid[1])  # the block is the grid
        self._pending = ([TargetSums(pixel, True, sums[:-1])], mi.UInt32(sums[-1]), None)

    def commit(self) -> None:
        """Add the pass into the sums in place: one add per element and pass (so
        no atomics and no second copy of the sums), in the kernel that traces the
        pass (box filter, up to :data:`FOLD` samples per pixel, summed within
        their SIMD packet) or that reduces each pixel's stored samples."""
        if self._pending is None:
            return
        slots, bad, lane_pixel = self._pending
        # Folded: each lane's pixel (a box film's block is its pixel grid). Stored:
        # one term per element of the block (a target of each slot, for a filter
        # wider than a box) and the counts over the grid.
        counts_at = lane_pixel if lane_pixel is not None else \
            dr.arange(mi.UInt32, dr.width(self.nonfinite))
        for slot in slots:
            for s, t in zip(self.sums, slot.values, strict=True):
                dr.scatter_add(s, t, slot.index, slot.valid, mode=dr.ReduceMode.NoConflicts)
        dr.scatter_add(self.nonfinite, bad, counts_at, mode=dr.ReduceMode.NoConflicts)
        dr.eval(self.sums, self.nonfinite)
        self._pending = None

    def state_bytes(self) -> int:
        """Size of :meth:`state` (float64 sums and the non-finite counts)."""
        return self.ext[0] * self.ext[1] * self.channels * 8 + self.grid[0] * self.grid[1] * 8

    def state(self) -> dict[str, np.ndarray]:
        w, h = self.ext
        sums = np.empty((h * w, self.channels))
        for c, s in enumerate(self.sums):  # (np.asarray: a view of a CPU array, not a copy)
            sums[:, c] = np.asarray(s, dtype=np.float64)
        return {"sums": sums.reshape(h, w, self.channels),
                "nonfinite": _numpy(self.nonfinite, (self.grid[1], self.grid[0]), np.int64)}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        w, h = self.ext
        sums, nonfinite = state["sums"], state["nonfinite"]
        if sums.shape != (h, w, self.channels) or nonfinite.shape != (self.grid[1], self.grid[0]):
            raise McrtError("the saved partial render does not match this film")
        self.sums = [to_device(mi.Float64, sums[..., c]) for c in range(self.channels)]
        self.nonfinite = to_device(mi.UInt32, nonfinite)

    # -- results ----------------------------------------------------------------
    def develop(self) -> Any:
        """Hand the sums to a cleared film and develop it (all on the device).

        The film divides each channel by the weight channel (R, G, B, [A,] W) in
        float32; the float64 sums are divided by their weight *before* they are
        rounded to float32 (the film then divides by a weight of exactly 1), so a
        pixel is its float64 mean correctly rounded: a float32 sum of a bright
        pixel overflowed to +Inf (every sample 3e38, or 1e33 at 2^19 spp) while
        its mean is finite, and was then developed as +Inf with no sample counted
        non-finite. A pixel of weight 0 is handed over as it is."""
        w, h = self.ext
        flat = dr.zeros(mi.Float, w * h * self.channels)
        index = dr.arange(mi.UInt32, w * h) * self.channels
        weight = self.sums[self.weight]
        weighed = weight != 0
        for c, s in enumerate(self.sums):  # interleave the channels: no two writes collide
            mean = dr.select(weighed, mi.Float64(1.0), s) if c == self.weight else \
                dr.select(weighed, s / weight, s)
            dr.scatter(flat, mi.Float(mean), index + c)
        self.film.clear()
        tensor: Any = mi.TensorXf(flat, shape=(h, w, self.channels))
        block = mi.ImageBlock(tensor, self.offset,
                              self.film.rfilter(), border=self.border > 0)
        self.film.put_block(block)
        del flat, tensor, block
        release_cached_memory(w * h)  # the interleaved copy, before the developed image
        return self.film.develop()

    # -- filtered splatting -------------------------------------------------------
    def _filtered(self, samples: CameraSamples, values: list[mi.Float],
                  group: int) -> tuple[list[TargetSums], Any, None]:
        """A pass for a filter wider than a box: per block pixel, the
        filter-weighted sums of the samples within the filter's reach, each
        target gathering its sources in a fixed order
        (:class:`~.reach.FilterReach`), so no two lanes ever write one value;
        and per grid pixel, its non-finite samples.

        The pass's samples are stored interleaved (:class:`~.packed.Packed`), a
        non-finite one with its channels zeroed and its x position NaN, which
        the gather reads as "no weight"."""
        ones = [_is_one(v) for v in values]
        finite = _finite(values)
        position = mi.Point2f(samples.position)
        columns: list[Any] = [dr.select(finite, v, 0.0) for v, one in zip(values, ones, strict=True)
                              if not one]
        columns += [dr.select(finite, position.x, dr.nan), position.y]
        packed = Packed.of(columns)
        dr.eval(packed.arrays)  # with the sampler's next state

        def nonfinite(lane: Any) -> list[Any]:
            x = packed.gather(lane)[-2]
            return [dr.select(dr.isnan(x), 1.0, 0.0)]

        bad = sequential_block_sums(self.grid[0] * self.grid[1], group, nonfinite, 1,
                                    evaluate=False)[0]
        assert self.reach is not None

        def terms(weight: Any, stored: list[Any]) -> list[Any]:
            raw = iter(stored)
            return [mi.Float64(weight if one else next(raw) * weight) for one in ones]

        sums = self.reach.sums(packed, group, self.channels, terms)
        return sums, mi.UInt32(bad), None


class MomentsAccumulator:
    """Per-pixel moments ``(n, mean, M2)`` of the RGB samples, float64, each
    sample counted for the pixel it was drawn in (box-binned), merged pass by
    pass with Chan's formula."""

    def __init__(self, film: mi.Film) -> None:
        grid = film_grid_size(film)
        self.grid = (int(grid[0]), int(grid[1]))
        n = self.grid[0] * self.grid[1]
        self.count = dr.zeros(mi.Float64, n)
        self.mean = [dr.zeros(mi.Float64, n) for _ in range(3)]
        self.m2 = [dr.zeros(mi.Float64, n) for _ in range(3)]
        self.nonfinite = dr.zeros(mi.Float64, n)
        self._pending: tuple | None = None

    def add(self, samples: CameraSamples, values: list[mi.Float], group: int) -> None:
        channels = [mi.Float64(c) for c in values[:3]]
        if group == 1:  # moments of one sample, folded in while tracing
            finite = _finite(channels)
            n_b = dr.select(finite, mi.Float64(1.0), 0.0)
            mean_b = [dr.select(finite, c, 0.0) for c in channels]
            m2_b = [mi.Float64(0.0)] * 3
            bad = 1.0 - n_b
        else:
            n_b, mean_b, m2_b, bad = block_moments(channels, group)
        n = self.count + n_b
        safe = dr.maximum(n, 1.0)
        mean, m2 = [], []
        for m_a, q_a, m_b, q_b in zip(self.mean, self.m2, mean_b, m2_b, strict=True):
            delta = m_b - m_a
            mean.append(dr.select(n > 0, m_a + delta * (n_b / safe), 0.0))
            m2.append(q_a + q_b + delta * delta * (self.count * n_b / safe))
        nonfinite = self.nonfinite + bad
        dr.eval(n, mean, m2, nonfinite)
        self._pending = (n, mean, m2, nonfinite)

    def commit(self) -> None:
        if self._pending is not None:
            self.count, self.mean, self.m2, self.nonfinite = self._pending
            self._pending = None

    def stats(self) -> PixelStats:
        from .stats import PixelStats  # the reference's type: a film render never needs it

        w, h = self.grid
        return PixelStats(
            count=_numpy(self.count, (h, w), np.int64),
            mean=np.stack([np.array(m, dtype=np.float64) for m in self.mean], -1).reshape(h, w, 3),
            m2=np.stack([np.array(m, dtype=np.float64) for m in self.m2], -1).reshape(h, w, 3),
            nonfinite=_numpy(self.nonfinite, (h, w), np.int64))

    def state(self) -> dict[str, np.ndarray]:
        s = self.stats()
        return {"count": s.count, "mean": s.mean, "m2": s.m2, "nonfinite": s.nonfinite}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        w, h = self.grid
        if state["mean"].shape != (h, w, 3):
            raise McrtError("the saved statistics do not match this film")
        self.count = to_device(mi.Float64, state["count"])
        self.mean = [to_device(mi.Float64, state["mean"][..., c]) for c in range(3)]
        self.m2 = [to_device(mi.Float64, state["m2"][..., c]) for c in range(3)]
        self.nonfinite = to_device(mi.Float64, state["nonfinite"])


def block_moments(channels: list[mi.Float64], group: int
                  ) -> tuple[mi.Float64, list[mi.Float64], list[mi.Float64], mi.Float64]:
    """Per block of ``group`` consecutive lanes: ``(n, mean, M2, nonfinite)`` of
    the samples (two-pass: mean first, then squared deviations, in float64). A
    sample with any non-finite channel is left out of all channels and counted."""
    finite = _finite(channels)
    dr.eval(channels, finite)
    count = dr.block_sum(dr.select(finite, mi.Float64(1.0), 0.0), group)
    safe = dr.maximum(count, 1.0)
    means = [dr.block_sum(dr.select(finite, c, 0.0), group) / safe for c in channels]
    dr.eval(count, means)
    m2 = [dr.block_sum(dr.select(finite, dr.square(c - dr.repeat(m, group)), 0.0), group)
          for c, m in zip(channels, means, strict=True)]
    return count, means, m2, group - count


def sequential_block_sums(blocks: int, size: int,
                          contributions: Callable[[mi.UInt32], list[mi.Float]],
                          outputs: int, evaluate: bool = True) -> list[mi.Float64]:
    """Per block of ``size`` consecutive lanes: the float64 sums of
    ``contributions(lane)``, each block's lanes added in order in one kernel
    (the same bits whatever the thread count; many outputs, one pass)."""
    first = dr.arange(mi.UInt32, blocks) * size

    def body(k: Any, *sums: Any) -> tuple[Any, ...]:
        return (k + 1, *(total + mi.Float64(value)
                         for total, value in zip(sums, contributions(first + k), strict=True)))

    state: Any = dr.while_loop((mi.UInt32(0), *[dr.zeros(mi.Float64, blocks)] * outputs),
                          lambda k, *sums: k < size, body)
    result = list(state[1:])
    if evaluate:  # else: lazy, computed by the kernel that uses the sums
        dr.eval(result)
    return result
