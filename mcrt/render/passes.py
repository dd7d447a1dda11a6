"""Render a scene in passes, with progress, into a film or into exact statistics.

Each pass traces ``g`` samples of every pixel (``g`` divides the sample count),
and the sampler is ``advance()``-d between passes, so the passes of one render
together form *one* stratified pattern per pixel (``jittered`` at 1024 spp in
four passes of 256 fills all 1024 strata), exactly as Mitsuba's own multi-pass
renders do.

Two accumulators share that loop:

* :func:`render_film` develops the scene's film (reconstruction filter and
  all), so a one-pass render equals ``mi.render`` with the same sampler and seed;
* :func:`render_stats` keeps per-pixel moments ``(n, mean, M2)`` of the samples
  in float64 (box-binned: a sample counts for the pixel it was drawn in), merged
  across passes with Chan's formula, with NaN/Inf samples counted and left out.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..analysis.statistics import PixelStats
from ..errors import McrtError
from ..samplers._stratified import split_sample
from .trace import film_grid_size, pixel_of_index, trace

#: Default cap on lanes per pass: big enough that typical renders run in one
#: kernel, small enough to bound memory and give a progress bar granularity.
MAX_LANES_PER_PASS = 1 << 22


def samples_per_pass(pixels: int, spp: int, max_lanes: int = MAX_LANES_PER_PASS) -> int:
    """Largest divisor ``g`` of ``spp`` with ``pixels * g <= max_lanes`` (at least 1)."""
    best = 1
    for g in range(1, spp + 1):
        if spp % g == 0 and pixels * g <= max_lanes:
            best = g
    return best


@dataclass
class FilmRender:
    """A developed image and how it was made."""

    image: np.ndarray  # (height, width, channels), float32
    channels: list[str]
    spp: int
    passes: int
    seconds: float  # wall time of the passes, synchronised (kernel compilation included)
    pixels: int
    nonfinite: np.ndarray | None = None  # (grid height, grid width) samples left out

    @property
    def nonfinite_samples(self) -> int:
        """NaN/Inf samples detected and left out of the image."""
        return 0 if self.nonfinite is None else int(self.nonfinite.sum())

    @property
    def samples(self) -> int:
        return self.pixels * self.spp

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")

    @property
    def rgb(self) -> np.ndarray:
        return self.image[..., :3]


def sampling_integrator(scene: mi.Scene) -> mi.SamplingIntegrator:
    """The scene's integrator, checked to be one mcrt can drive."""
    integrator = scene.integrator()
    if not isinstance(integrator, mi.SamplingIntegrator):
        raise McrtError(f"mcrt renders with sampling integrators (path, direct, ...); this scene "
                        f"uses {type(integrator).__name__}")
    return integrator


def channel_names(film: mi.Film, count: int) -> list[str]:
    """Names of the developed film's channels (R, G, B[, A], then AOVs)."""
    try:
        names = [f.name for f in film.bitmap().struct_()]
    except Exception:  # films without a bitmap view: generic names
        names = []
    if len(names) != count:
        names = (["R", "G", "B", "A"] + [f"C{i}" for i in range(4, count)])[:count]
    return names


def _pass_plan(pixels: int, spp: int, max_lanes: int, passes: int | None) -> int:
    """Samples per pixel per pass: as many as fit, or ``spp // passes`` if forced."""
    if passes is None:
        return samples_per_pass(pixels, spp, max_lanes)
    if passes <= 0 or spp % passes:
        raise McrtError(f"cannot split {spp} samples per pixel into {passes} equal passes")
    return spp // passes


def _seeded_lanes(film: mi.Film, sampler: mi.Sampler, seed: int, pixels: int, group: int):
    """Seed ``sampler`` for ``pixels * group`` pixel-major lanes; return the lanes'
    film pixels and linear pixel indices."""
    lanes = pixels * group
    sampler.set_samples_per_wavefront(group)
    sampler.seed(seed, lanes)
    pixel_index, _ = split_sample(dr.arange(mi.UInt32, lanes), group)
    return pixel_of_index(film, pixel_index), pixel_index


class _FilmSplatter:
    """Deterministic splatting of pixel-major samples into the film's block.

    Mitsuba's ``ImageBlock.put`` adds each sample into the pixels under its
    reconstruction filter with atomic float adds, whose order depends on thread
    scheduling: with any filter wider than a box the image changes in its last
    bits from run to run. Because a pass is pixel-major (a pixel's ``g`` samples
    are consecutive lanes), the same sums can be formed without atomics: for each
    offset ``d`` within the filter's reach, ``dr.block_sum`` over each pixel's
    lanes gives that pixel's total contribution to pixel ``P + d`` (a fixed,
    sequential order), and these per-pixel totals are added on the host in a fixed
    order of offsets. The result is bit-identical across runs and thread counts.

    A sample with a non-finite channel is left out entirely (no value, no
    weight) and counted per pixel: it never turns into a NaN pixel nor a
    silently darkened one.
    """

    def __init__(self, film: mi.Film, pixels_xy: np.ndarray, group: int) -> None:
        block = film.create_block()
        self.film, self.group = film, group
        self.offset, self.border = block.offset(), block.border_size()
        ext = np.array(block.size()) + 2 * self.border  # (width, height)
        self.origin = np.array(self.offset) - self.border  # film coords of block pixel (0, 0)
        self.channels = block.channel_count()
        self.accum = np.zeros((int(ext[1]), int(ext[0]), self.channels), np.float64)
        self.nonfinite = np.zeros(len(pixels_xy), np.int64)
        self.pixels_xy = pixels_xy  # (pixels, 2) film coordinates of the sampled grid
        rfilter = film.rfilter()
        self.box = rfilter.is_box_filter()
        reach = 0 if self.box else math.ceil(rfilter.radius() + 0.5) - 1
        self.offsets = [(dx, dy) for dy in range(-reach, reach + 1)
                        for dx in range(-reach, reach + 1)]

    def add(self, pixel: mi.Vector2i, position: mi.Point2f, values: list[mi.Float]) -> None:
        """Accumulate one evaluated pass (lanes pixel-major, ``group`` per pixel)."""
        finite = dr.isfinite(values[0])
        for v in values[1:]:
            finite &= dr.isfinite(v)
        kept = [dr.select(finite, v, 0.0) for v in values]
        bad = dr.select(finite, 0.0, 1.0)
        dr.eval(kept, bad)
        self.nonfinite += np.array(dr.block_sum(bad, self.group), dtype=np.int64)
        if self.box:  # the sample counts for its own pixel only, with weight 1
            sums = [[dr.block_sum(v, self.group) for v in kept]]
        else:
            sums = self._filtered_sums(pixel, position, kept)
        for (dx, dy), per_channel in zip(self.offsets, sums):
            block = np.stack([np.array(v, dtype=np.float64) for v in per_channel], axis=-1)
            target = self.pixels_xy + (dx, dy) - self.origin
            inside = ((target >= 0) & (target < (self.accum.shape[1], self.accum.shape[0]))).all(1)
            self.accum[target[inside, 1], target[inside, 0]] += block[inside]

    def _filtered_sums(self, pixel: mi.Vector2i, position: mi.Point2f,
                       kept: list[mi.Float]) -> list[list[mi.Float]]:
        """Per pixel and offset ``d``: the filter-weighted sums of its samples for
        the pixel ``d`` away. One kernel over pixels, looping over each pixel's
        samples in order (the filter is separable: ``w = w(dx) w(dy)``)."""
        rfilter, group = self.film.rfilter(), self.group
        count = len(self.pixels_xy)
        first = dr.arange(mi.UInt32, count) * group
        centre = dr.gather(mi.Point2f, mi.Point2f(pixel) + 0.5, first)
        reach = sorted({dx for dx, _ in self.offsets})
        n_sums = len(self.offsets) * len(kept)

        def body(k, *sums):
            lane = first + k
            pos = dr.gather(mi.Point2f, position, lane)
            vals = [dr.gather(mi.Float, v, lane) for v in kept]
            wx = {d: rfilter.eval(centre.x + d - pos.x) for d in reach}
            wy = {d: rfilter.eval(centre.y + d - pos.y) for d in reach}
            out, i = [], 0
            for dx, dy in self.offsets:
                w = wx[dx] * wy[dy]
                for v in vals:
                    out.append(dr.fma(v, w, sums[i]))
                    i += 1
            return (k + 1, *out)

        state = dr.while_loop((mi.UInt32(0), *[dr.zeros(mi.Float, count)] * n_sums),
                              lambda k, *sums: k < group, body)
        flat = list(state[1:])
        dr.eval(flat)
        c = len(kept)
        return [flat[i * c:(i + 1) * c] for i in range(len(self.offsets))]

    def develop(self) -> mi.TensorXf:
        """Hand the sums to the film (it normalises by the weight channel)."""
        block = mi.ImageBlock(mi.TensorXf(self.accum.astype(np.float32)), self.offset,
                              self.film.rfilter(), border=self.border > 0)
        self.film.put_block(block)
        return self.film.develop()


def render_film(scene: mi.Scene, sampler: mi.Sampler | None = None, spp: int | None = None,
                seed: int = 0, sensor: int = 0, progress: bool = False,
                max_lanes: int = MAX_LANES_PER_PASS, passes: int | None = None,
                on_pass: Callable[[int, int], None] | None = None) -> FilmRender:
    """Render ``scene`` with ``sampler`` (default: the sensor's) at ``spp``.

    Returns the developed film as a numpy array together with the effective
    sample count (samplers may round it), number of passes, wall time and the
    per-pixel count of non-finite samples (left out of the image, see
    :class:`_FilmSplatter`; the image is bit-identical across runs).
    ``passes`` forces the number of passes (it must divide the sample count);
    ``on_pass(index, count)`` runs before each pass is traced (e.g. to move
    geometry for a motion-blur sub-frame).
    """
    sensor_obj = scene.sensors()[sensor]
    integrator = sampling_integrator(scene)
    film = sensor_obj.film()
    sampler = sampler if sampler is not None else sensor_obj.sampler()
    if spp is not None:
        sampler.set_sample_count(spp)
    spp = sampler.sample_count()

    grid = film_grid_size(film)
    pixels = int(grid[0]) * int(grid[1])
    group = _pass_plan(pixels, spp, max_lanes, passes)
    n_passes = spp // group

    film.prepare(integrator.aov_names())
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    pixel, _ = _seeded_lanes(film, sampler, seed, pixels, group)
    grid_xy = pixel_of_index(film, dr.arange(mi.UInt32, pixels))
    splatter = _FilmSplatter(film, np.array(grid_xy, dtype=np.int64).T.reshape(-1, 2), group)

    bar = _progress_bar(n_passes, pixels * group, enabled=progress and n_passes > 1)
    dr.sync_thread()
    start = time.perf_counter()
    for index in range(n_passes):
        if on_pass is not None:
            on_pass(index, n_passes)
        s = trace(scene, sensor_obj, sampler, integrator, pixel, spp)
        values = [s.rgb.x, s.rgb.y, s.rgb.z]
        values += [dr.select(s.valid, 1.0, 0.0), mi.Float(1.0)] if has_alpha else [mi.Float(1.0)]
        values += s.aovs
        sampler.advance()
        sampler.schedule_state()
        position = mi.Point2f(s.position)
        dr.eval(values, position)  # one kernel: samples and the sampler's next state
        splatter.add(pixel, position, values)
        bar.update(1)
    image = splatter.develop()
    dr.sync_thread()
    seconds = time.perf_counter() - start
    bar.close()

    array = np.array(image, dtype=np.float32)
    return FilmRender(image=array, channels=channel_names(film, array.shape[-1]), spp=spp,
                      passes=n_passes, seconds=seconds, pixels=pixels,
                      nonfinite=splatter.nonfinite.reshape(int(grid[1]), int(grid[0])))


@dataclass
class StatsRender:
    """Per-pixel sample statistics of a render and how they were made."""

    stats: PixelStats  # over the film's sampled pixel grid (crop window [+ border])
    spp: int
    passes: int
    seconds: float

    @property
    def samples(self) -> int:
        return self.stats.samples + int(self.stats.nonfinite.sum())


def pass_moments(rgb: mi.Color3f, group: int) -> tuple[mi.Float64, list[mi.Float64],
                                                        list[mi.Float64], mi.Float64]:
    """Per-pixel ``(n, mean, M2, nonfinite)`` of one pass of pixel-major lanes.

    Each pixel's ``group`` consecutive lanes are reduced in float64 with
    ``dr.block_sum`` (two-pass: mean first, then squared deviations). A sample
    with any non-finite channel is excluded from all three channels and counted.
    """
    channels = [mi.Float64(c) for c in (rgb.x, rgb.y, rgb.z)]
    finite = dr.isfinite(channels[0]) & dr.isfinite(channels[1]) & dr.isfinite(channels[2])
    count = dr.block_sum(dr.select(finite, mi.Float64(1.0), 0.0), group)
    safe = dr.maximum(count, 1.0)
    means = [dr.block_sum(dr.select(finite, c, 0.0), group) / safe for c in channels]
    dr.eval(count, means)
    m2 = [dr.block_sum(dr.select(finite, dr.square(c - dr.repeat(m, group)), 0.0), group)
          for c, m in zip(channels, means)]
    return count, means, m2, group - count


def render_stats(scene: mi.Scene, sampler: mi.Sampler, spp: int | None = None, seed: int = 0,
                 sensor: int = 0, progress: bool = False, max_lanes: int = 1 << 22,
                 passes: int | None = None,
                 on_pass: Callable[[int, int], None] | None = None) -> StatsRender:
    """Render ``scene`` and return exact per-pixel sample moments (float64).

    The pixel grid is the film's sampled grid (:func:`film_grid_size`); a sample
    belongs to the pixel it was drawn in (box filter), whatever the scene's
    reconstruction filter. ``passes`` and ``on_pass`` as in :func:`render_film`.
    """
    sensor_obj = scene.sensors()[sensor]
    integrator = sampling_integrator(scene)
    film = sensor_obj.film()
    if spp is not None:
        sampler.set_sample_count(spp)
    spp = sampler.sample_count()
    grid = film_grid_size(film)
    width, height = int(grid[0]), int(grid[1])
    pixels = width * height
    group = _pass_plan(pixels, spp, max_lanes, passes)
    n_passes = spp // group
    pixel, _ = _seeded_lanes(film, sampler, seed, pixels, group)

    total = PixelStats.zeros(height, width, 3)
    bar = _progress_bar(n_passes, pixels * group, enabled=progress and n_passes > 1)
    dr.sync_thread()
    start = time.perf_counter()
    for index in range(n_passes):
        if on_pass is not None:
            on_pass(index, n_passes)
        s = trace(scene, sensor_obj, sampler, integrator, pixel, spp)
        rgb = mi.Color3f(s.rgb)
        sampler.advance()
        sampler.schedule_state()
        # One kernel for the samples and the sampler's next state: evaluating rgb
        # first would trace every path a second time to compute the state later.
        dr.eval(rgb)
        count, means, m2, bad = pass_moments(rgb, group)
        shape = (height, width)
        part = PixelStats(
            count=np.array(count, dtype=np.float64).astype(np.int64).reshape(shape),
            mean=np.stack([np.array(m, dtype=np.float64) for m in means], -1).reshape(*shape, 3),
            m2=np.stack([np.array(m, dtype=np.float64) for m in m2], -1).reshape(*shape, 3),
            nonfinite=np.array(bad, dtype=np.float64).astype(np.int64).reshape(shape))
        total = total.merge(part)
        bar.update(1)
    dr.sync_thread()
    seconds = time.perf_counter() - start
    bar.close()
    return StatsRender(stats=total, spp=spp, passes=n_passes, seconds=seconds)


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(passes: int, lanes: int, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=passes, unit="pass", desc="render", leave=False, dynamic_ncols=True,
                postfix={"samples/pass": lanes})
