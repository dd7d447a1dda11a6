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

import contextlib
import math
import signal
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.stats import PixelStats
from ..errors import McrtError
from ..samplers._hash import hash_keys_int
from ..samplers._stratified import split_sample
from ..samplers.base import is_mcrt_sampler
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
    checkpoint: FilmCheckpoint | None = None  # the film's sums, to develop again later

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


def sequential_block_sums(blocks: int, size: int,
                          contributions: Callable[[mi.UInt32], list[mi.Float]],
                          outputs: int) -> list[mi.Float64]:
    """Per block of ``size`` consecutive lanes: the sums of ``contributions(lane)``
    (in float64).

    One kernel over the ``blocks`` blocks; each loops over its lanes in order, so
    the float sums are the same whatever the thread count (unlike atomic
    scatter-adds) and many outputs cost one pass over the lanes (unlike one
    ``dr.block_sum`` per output). ``contributions`` gathers what it needs from
    lane-indexed arrays and returns ``outputs`` values per lane.
    """
    first = dr.arange(mi.UInt32, blocks) * size

    def body(k, *sums):
        return (k + 1, *(total + mi.Float64(value)
                         for total, value in zip(sums, contributions(first + k))))

    # float64 running sums: a float32 one drifts with the block size (a block of
    # 2^18 copies of 0.3 sums to ~1e-5 relative off; 2^22 to ~1e-2).
    state = dr.while_loop((mi.UInt32(0), *[dr.zeros(mi.Float64, blocks)] * outputs),
                          lambda k, *sums: k < size, body)
    result = list(state[1:])
    dr.eval(result)
    return result


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold back Ctrl-C (SIGINT) until the block is done, then raise it.

    Used to commit a pass's results as one step. Outside the main thread
    (where Python delivers signals) this is a no-op.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


@dataclass
class FilmCheckpoint:
    """Everything needed to finish an interrupted :func:`render_film` later.

    ``accum`` holds the float64 filter-weighted sums of the film's block (the
    weight channel included), ``passes_done`` of ``passes`` passes, ``seconds``
    the render time spent so far.
    """

    accum: np.ndarray
    nonfinite: np.ndarray
    passes_done: int
    passes: int
    spp: int
    seed: int
    seconds: float

    def save(self, path: Path, key: str) -> None:
        """Write atomically as ``.npz`` (``key`` identifies the render)."""
        from ..core.atomic import atomic_path

        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, key=np.array(key), accum=self.accum, nonfinite=self.nonfinite,
                     counters=np.array([self.passes_done, self.passes, self.spp, self.seed]),
                     seconds=np.array(self.seconds))

    @classmethod
    def load(cls, path: Path, key: str) -> FilmCheckpoint | None:
        """The checkpoint at ``path`` if it exists, is readable and belongs to ``key``."""
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["key"]) != key:
                    return None
                done, passes, spp, seed = (int(v) for v in data["counters"])
                state = cls(accum=data["accum"].astype(np.float64),
                            nonfinite=data["nonfinite"].astype(np.int64), passes_done=done,
                            passes=passes, spp=spp, seed=seed, seconds=float(data["seconds"]))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            return None
        return state if 0 < state.passes_done <= state.passes else None


class RenderInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`render_film`: the passes finished so far, developed
    (``partial``, its ``spp`` counts only those passes), and a checkpoint to resume."""

    def __init__(self, partial: FilmRender | None, checkpoint: FilmCheckpoint) -> None:
        super().__init__("render interrupted")
        self.partial = partial
        self.checkpoint = checkpoint


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
        self.passes_done = 0
        self.pixels_xy = pixels_xy  # (pixels, 2) film coordinates of the sampled grid
        rfilter = film.rfilter()
        self.box = rfilter.is_box_filter()
        reach = 0 if self.box else math.ceil(rfilter.radius() + 0.5) - 1
        self.offsets = [(dx, dy) for dy in range(-reach, reach + 1)
                        for dx in range(-reach, reach + 1)]

    def add(self, pixel: mi.Vector2i, position: mi.Point2f, values: list[mi.Float]) -> None:
        """Accumulate one evaluated pass (lanes pixel-major, ``group`` per pixel).

        The pass is summed into a separate array and committed at the end, with
        Ctrl-C deferred, so an interrupt never leaves half a pass in the sums.
        """
        finite = dr.isfinite(values[0])
        for v in values[1:]:
            finite &= dr.isfinite(v)
        kept = [dr.select(finite, v, 0.0) for v in values]
        bad = dr.select(finite, 0.0, 1.0)
        dr.eval(kept, bad)
        pass_bad = np.array(dr.block_sum(bad, self.group), dtype=np.int64)
        if self.box:  # the sample counts for its own pixel only, with weight 1
            # float64: Dr.Jit's float32 block_sum adds sequentially in chunks and
            # drifts (2^14+ copies of 0.3 sum to 2e-5 relative off).
            sums = [[dr.block_sum(mi.Float64(v), self.group) for v in kept]]
        else:
            sums = self._filtered_sums(pixel, position, kept)
        pass_accum = np.zeros_like(self.accum)
        for (dx, dy), per_channel in zip(self.offsets, sums):
            block = np.stack([np.array(v, dtype=np.float64) for v in per_channel], axis=-1)
            target = self.pixels_xy + (dx, dy) - self.origin
            inside = ((target >= 0) & (target < (self.accum.shape[1], self.accum.shape[0]))).all(1)
            pass_accum[target[inside, 1], target[inside, 0]] += block[inside]
        with deferred_interrupts():
            self.accum += pass_accum
            self.nonfinite += pass_bad
            self.passes_done += 1

    def _filtered_sums(self, pixel: mi.Vector2i, position: mi.Point2f,
                       kept: list[mi.Float]) -> list[list[mi.Float]]:
        """Per pixel and offset ``d``: the filter-weighted sums of its samples for
        the pixel ``d`` away (the filter is separable: ``w = w(dx) w(dy)``)."""
        rfilter, group = self.film.rfilter(), self.group
        first = dr.arange(mi.UInt32, len(self.pixels_xy)) * group
        centre = dr.gather(mi.Point2f, mi.Point2f(pixel) + 0.5, first)
        reach = sorted({dx for dx, _ in self.offsets})

        def contributions(lane: mi.UInt32) -> list[mi.Float]:
            pos = dr.gather(mi.Point2f, position, lane)
            vals = [dr.gather(mi.Float, v, lane) for v in kept]
            wx = {d: rfilter.eval(centre.x + d - pos.x) for d in reach}
            wy = {d: rfilter.eval(centre.y + d - pos.y) for d in reach}
            return [v * (wx[dx] * wy[dy]) for dx, dy in self.offsets for v in vals]

        flat = sequential_block_sums(len(self.pixels_xy), group, contributions,
                                     len(self.offsets) * len(kept))
        c = len(kept)
        return [flat[i * c:(i + 1) * c] for i in range(len(self.offsets))]

    def develop(self) -> mi.TensorXf:
        """Hand the sums to a cleared film (it normalises by the weight channel)."""
        self.film.clear()
        block = mi.ImageBlock(mi.TensorXf(self.accum.astype(np.float32)), self.offset,
                              self.film.rfilter(), border=self.border > 0)
        self.film.put_block(block)
        return self.film.develop()

    def checkpoint(self, spp: int, passes: int, seed: int, seconds: float) -> FilmCheckpoint:
        return FilmCheckpoint(accum=self.accum.copy(), nonfinite=self.nonfinite.copy(),
                              passes_done=self.passes_done, passes=passes, spp=spp, seed=seed,
                              seconds=seconds)

    def restore(self, state: FilmCheckpoint) -> None:
        if state.accum.shape != self.accum.shape or state.nonfinite.shape != self.nonfinite.shape:
            raise McrtError("the saved partial render does not match this film")
        self.accum[...] = state.accum
        self.nonfinite[...] = state.nonfinite
        self.passes_done = state.passes_done


def render_film(scene: mi.Scene, sampler: mi.Sampler | None = None, spp: int | None = None,
                seed: int = 0, sensor: int = 0, progress: bool = False,
                max_lanes: int | None = None, passes: int | None = None,
                on_pass: Callable[[int, int], None] | None = None,
                resume: FilmCheckpoint | None = None) -> FilmRender:
    """Render ``scene`` with ``sampler`` (default: the sensor's) at ``spp``.

    Returns the developed film as a numpy array together with the effective
    sample count (samplers may round it), number of passes, wall time and the
    per-pixel count of non-finite samples (left out of the image, see
    :class:`_FilmSplatter`; the image is bit-identical across runs).
    ``max_lanes`` caps the samples of one pass (default
    :data:`MAX_LANES_PER_PASS`); ``passes`` forces the number of passes (it must
    divide the sample count); ``on_pass(index, count)`` runs before each pass is
    traced (e.g. to move geometry for a motion-blur sub-frame).

    Ctrl-C raises :class:`RenderInterrupted` with the passes finished so far;
    ``resume`` continues from its checkpoint. mcrt's samplers continue their
    exact sequences, so a resumed render is bit-identical to an uninterrupted
    one; Mitsuba's samplers (whose random state lives in C++) continue with a
    seed derived from ``(seed, passes done)`` instead, so resumed passes never
    repeat earlier ones.
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
    group = _pass_plan(pixels, spp, max_lanes or MAX_LANES_PER_PASS, passes)
    n_passes = spp // group

    film.prepare(integrator.aov_names())
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    grid_xy = pixel_of_index(film, dr.arange(mi.UInt32, pixels))
    splatter = _FilmSplatter(film, np.array(grid_xy, dtype=np.int64).T.reshape(-1, 2), group)
    seconds_before = 0.0
    if resume is not None:
        if (resume.spp, resume.passes, resume.seed) != (spp, n_passes, seed):
            raise McrtError("the saved partial render was made with other settings")
        splatter.restore(resume)
        seconds_before = resume.seconds
    pixel, _ = _seeded_lanes(film, sampler, _resume_seed(sampler, seed, splatter.passes_done),
                             pixels, group)
    if is_mcrt_sampler(sampler):
        for _ in range(splatter.passes_done):
            sampler.advance()  # counter-based: the exact next samples

    bar = _progress_bar(n_passes, pixels * group, enabled=progress and n_passes > 1,
                        initial=splatter.passes_done)
    dr.sync_thread()
    start = time.perf_counter()

    def result(image: mi.TensorXf) -> FilmRender:
        array = np.array(image, dtype=np.float32)
        done = splatter.passes_done
        seconds = seconds_before + time.perf_counter() - start
        return FilmRender(image=array, channels=channel_names(film, array.shape[-1]),
                          spp=done * group, passes=done, seconds=seconds, pixels=pixels,
                          nonfinite=splatter.nonfinite.reshape(int(grid[1]), int(grid[0])),
                          checkpoint=splatter.checkpoint(spp, n_passes, seed, seconds))

    try:
        for index in range(splatter.passes_done, n_passes):
            if on_pass is not None:
                on_pass(index, n_passes)
            s = trace(scene, sensor_obj, sampler, integrator, pixel, spp)
            values = [s.rgb.x, s.rgb.y, s.rgb.z]
            values += ([dr.select(s.valid, 1.0, 0.0), mi.Float(1.0)] if has_alpha
                       else [mi.Float(1.0)])
            values += s.aovs
            sampler.advance()
            sampler.schedule_state()
            position = mi.Point2f(s.position)
            dr.eval(values, position)  # one kernel: samples and the sampler's next state
            splatter.add(pixel, position, values)
            bar.update(1)
    except KeyboardInterrupt:
        bar.close()
        partial = result(splatter.develop()) if splatter.passes_done else None
        elapsed = seconds_before + time.perf_counter() - start
        raise RenderInterrupted(partial, splatter.checkpoint(spp, n_passes, seed, elapsed)) \
            from None
    image = splatter.develop()
    dr.sync_thread()
    bar.close()
    return result(image)


def _resume_seed(sampler: mi.Sampler, seed: int, passes_done: int) -> int:
    """The seed to continue a render after ``passes_done`` passes (see render_film)."""
    if passes_done == 0 or is_mcrt_sampler(sampler):
        return seed
    return hash_keys_int(seed, passes_done, 0x2E5)


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
                 sensor: int = 0, progress: bool = False, max_lanes: int | None = None,
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
    group = _pass_plan(pixels, spp, max_lanes or MAX_LANES_PER_PASS, passes)
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


def _progress_bar(passes: int, lanes: int, enabled: bool, initial: int = 0):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=passes, initial=initial, unit="pass", desc="render", leave=False,
                dynamic_ncols=True, postfix={"samples/pass": lanes})
