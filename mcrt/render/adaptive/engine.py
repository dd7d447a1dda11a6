"""The adaptive render loop: passes over compacted wavefronts of active pixels,
accumulated float64 moments and sub-pixel sums, Ctrl-C checkpoints, and the
developed result (see :mod:`mcrt.render.adaptive` for the method)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.accumulators import block_moments, sequential_block_sums
from ...core.engine import deferred_interrupts, sampling_integrator, supported_film, trace_pass
from ...core.job import Checkpoint, CheckpointPacer, Interrupted
from ...core.render import in_film_format
from ...core.sampling import bind_film_width
from ...core.stats import PixelStats, chan_merge
from ...core.trace import CameraSamples, film_grid_size, pixel_of_index
from ...errors import McrtError
from ...samplers._hash import hash_keys_int
from ...samplers.base import is_mcrt_sampler
from .criterion import dilate, error_ratio, luminance_error
from .ladder import batch_ladder, budget_batches, pass_batch_size
from .reconstruct import reconstruct, subpixel_filter
from .result import AdaptiveRender, PassRecord
from .settings import AdaptiveSettings

log = logging.getLogger(__name__)


class _Accumulator:
    """Per-pixel float64 moments and sub-pixel sums over the sampled grid (flat)."""

    def __init__(self, pixels: int, s: int, channels: int) -> None:
        self.count = np.zeros(pixels, np.int64)
        self.mean = np.zeros((pixels, 3))
        self.m2 = np.zeros((pixels, 3))
        self.nonfinite = np.zeros(pixels, np.int64)
        self.traced = np.zeros(pixels, np.int64)
        self.sub_sum = np.zeros((pixels, s * s, channels))
        self.sub_count = np.zeros((pixels, s * s), np.int64)
        #: Nothing added or restored yet (the sub-pixel grids are still all zero).
        self.empty = True

    def add(self, ids: np.ndarray, m: int, count, means, m2, bad, sub_count,
            sub_sums) -> None:
        """Merge one wavefront's per-pixel moments (Chan) and sub-pixel sums (pixels
        ``ids``, ``m`` samples each; evaluated Dr.Jit arrays)."""
        s2 = self.sub_count.shape[1]
        count = np.asarray(count, dtype=np.float64).astype(np.int64)
        means = np.stack([np.asarray(x, dtype=np.float64) for x in means], -1)
        m2 = np.stack([np.asarray(x, dtype=np.float64) for x in m2], -1)
        n, mean, merged = chan_merge(self.count[ids], self.mean[ids], self.m2[ids],
                                     count, means, m2)
        self.count[ids], self.mean[ids], self.m2[ids] = n, mean, merged
        self.nonfinite[ids] += np.asarray(bad, dtype=np.float64).astype(np.int64)
        self.traced[ids] += m
        sub_count = np.asarray(sub_count, dtype=np.int64).reshape(ids.size, s2)
        sub_sums = np.stack([np.asarray(x, dtype=np.float64) for x in sub_sums],
                            -1).reshape(ids.size, s2, -1)
        if self.empty and ids.size == self.count.size:
            # The first wavefront covers every pixel (ids are sorted and unique): the
            # grids become its sums (0 + x == x exactly), instead of adding them into
            # ~20 MB of untouched zero pages (page faults cost more than the adds).
            self.sub_count, self.sub_sum = sub_count, sub_sums
        else:
            self.sub_count[ids] += sub_count
            self.sub_sum[ids] += sub_sums
        self.empty = False

    def stats(self) -> PixelStats:
        return PixelStats(self.count, self.mean, self.m2, self.nonfinite)

    FIELDS = ("count", "mean", "m2", "nonfinite", "traced", "sub_sum", "sub_count")

    def arrays(self) -> dict[str, np.ndarray]:
        """Copies of every accumulator array (a snapshot)."""
        return {name: getattr(self, name).copy() for name in self.FIELDS}

    def nbytes(self) -> int:
        return sum(getattr(self, name).nbytes for name in self.FIELDS)

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        self.empty = False
        for name in self.FIELDS:
            mine = getattr(self, name)
            if arrays[name].shape != mine.shape:
                raise McrtError("the saved adaptive render does not match this scene")
            mine[...] = arrays[name]


def _sampler_label(sampler: mi.Sampler) -> str:
    from ...core.sampling import sampler_name

    return sampler_name(sampler)


def render_adaptive(scene: mi.Scene, sampler: mi.Sampler | None = None,
                    settings: AdaptiveSettings | None = None, seed: int = 0,
                    sensor: int | mi.Sensor = 0,
                    integrator: mi.SamplingIntegrator | None = None,
                    on_pass: Callable[[PassRecord], None] | None = None,
                    on_samples: Callable[..., None] | None = None,
                    resume: Checkpoint | None = None,
                    save: Callable[[Checkpoint], object] | None = None,
                    save_every: float | None = None) -> AdaptiveRender:
    """Render ``scene`` adaptively (see :mod:`mcrt.render.adaptive`).

    ``sampler`` defaults to the sensor's (its type and parameters are used, not
    its sample count; it is cloned, never modified); ``integrator`` to the
    scene's (a sampling integrator; for an ``adaptive`` one, its nested
    integrator, and its settings unless ``settings`` is given). ``on_pass(record)`` runs after
    each pass; ``on_samples(pass_index, pixel_ids, position, rgb)`` receives
    every traced wavefront as numpy arrays (for tests and visualisation).

    Ctrl-C raises :class:`~mcrt.core.job.Interrupted` with the passes finished
    so far as ``partial`` (a pass in flight is dropped whole) and the
    :class:`~mcrt.core.job.Checkpoint` to resume from as ``state``;
    ``resume`` continues from it; ``save(checkpoint)`` receives it while the
    render runs (``save_every`` as in :func:`~mcrt.core.render.render_film`), so
    that even a SIGKILL keeps the passes saved (the last pass is always saved:
    the caller discards it once the result is written). Every wavefront's
    samples depend only on (seed, pass, pixel), so a resumed render equals an
    uninterrupted one.
    """
    sensor_obj = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
    integrator, settings = _integrator_and_settings(scene, integrator, settings)
    film = supported_film(sensor_obj.film())
    sampler = (sampler if sampler is not None else sensor_obj.sampler()).clone()
    ladder = _ladder(sampler, settings)
    first = ladder[0]
    ours = is_mcrt_sampler(sampler)
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)

    grid = film_grid_size(film)
    bind_film_width(sampler, int(grid[0]))  # zsobol orders pixels along the film
    width, height = int(grid[0]), int(grid[1])
    pixels = width * height
    s = settings.subpixels
    acc = _Accumulator(pixels, s, 4 if has_alpha else 3)
    # leader: samples of a pixel that was active in every pass so far.
    active, batch, leader, k, seconds_before, records = _start(acc, pixels, first, resume)

    dr.sync_thread()
    start = time.perf_counter()

    def snapshot() -> Checkpoint:
        return Checkpoint(
            meta={"leader": leader, "next_pass": k, "records": [asdict(r) for r in records],
                  "seconds": seconds_before + time.perf_counter() - start},
            arrays={**acc.arrays(), "active": active.copy(), "batch": batch.copy()})

    def finish() -> AdaptiveRender:
        return _result(film, acc, width, height, s, settings, records, sampler, ladder,
                       has_alpha, seconds_before + time.perf_counter() - start)

    # The accumulator and the loop state change only together, at the end of a
    # pass and with interrupts held back, so they always describe the passes
    # finished so far: a checkpoint is copied from them only when one is saved.
    pacer = CheckpointPacer(save_every, state_bytes=acc.nbytes() + active.nbytes + batch.nbytes)
    try:
        while active.size:
            pass_start = time.perf_counter()
            spent = int(acc.traced.sum())
            sizes = np.unique(batch[active])
            lanes, bad_total = 0, 0
            staged: list[tuple] = []
            for m in sizes.tolist():
                for c, ids in enumerate(_chunks(active[batch[active] == m], m, settings)):
                    one_wavefront = k == 0 and ids.size == pixels
                    wave_seed = seed if ours or one_wavefront else hash_keys_int(seed, k, m, c)
                    bad_total += _trace_wavefront(scene, sensor_obj, sampler, integrator, film,
                                                  ids, m, k, wave_seed, ours, first, s,
                                                  acc, staged, on_samples)
                    lanes += ids.size * m
            with deferred_interrupts():
                for wavefront in staged:
                    acc.add(*wavefront)
                _check_progress(acc, spent)
                leader += int(sizes.max())
                failing, batch, active_next = _next_pass(acc, leader, ladder, settings,
                                                         (height, width))
                dr.sync_thread()
                record = PassRecord(index=k, active_pixels=int(active.size), samples=lanes,
                                    batch_sizes=tuple(sizes.tolist()),
                                    seconds=time.perf_counter() - pass_start,
                                    converged_pixels=int(pixels - failing.sum()),
                                    nonfinite=bad_total)
                records.append(record)
                active = active_next
                k += 1
            if on_pass is not None:
                on_pass(record)
            _save(save, pacer, snapshot, last=not active.size)
    except KeyboardInterrupt:
        raise Interrupted(finish() if k > 0 else None, k, k + 1, state=snapshot()) from None
    return finish()


def _ladder(sampler: mi.Sampler, settings: AdaptiveSettings) -> tuple[int, ...]:
    """The sampler's batch sizes from ``min_spp`` to ``max_spp`` (noted when the
    first is not ``min_spp``: the sampler rounds it)."""
    ladder = batch_ladder(sampler, settings.min_spp, settings.max_spp)
    if ladder[0] != settings.min_spp:
        log.info("adaptive: %s draws %d samples per pixel in its first pass (min_spp %d)",
                 _sampler_label(sampler), ladder[0], settings.min_spp)
    return ladder


def _check_progress(acc: _Accumulator, spent: int) -> None:
    """Every pass spends samples (budgets only grow: the loop terminates)."""
    if int(acc.traced.sum()) <= spent:
        raise McrtError("adaptive: a pass spent no samples; this is a bug")


def _save(save: Callable[[Checkpoint], object] | None, pacer: CheckpointPacer,
          snapshot: Callable[[], Checkpoint], last: bool) -> None:
    """Checkpoint while the render runs: paced, and always after the last pass
    (kept until the caller has written the result)."""
    if save is None:
        return
    if last:
        save(snapshot())
    else:
        pacer.maybe(save, snapshot)


def _integrator_and_settings(
        scene: mi.Scene, integrator: mi.SamplingIntegrator | None,
        settings: AdaptiveSettings | None) -> tuple[mi.SamplingIntegrator, AdaptiveSettings]:
    """The integrator that computes samples and the checked settings (an
    ``adaptive`` integrator is unwrapped; its settings apply unless given)."""
    if integrator is None:
        integrator = sampling_integrator(scene)
    if getattr(integrator, "is_adaptive", False):
        plugin: Any = integrator  # the scene's `adaptive` plugin
        settings = settings or plugin.settings
        integrator = plugin.nested
    settings = (settings or AdaptiveSettings()).check()
    if integrator.aov_names():
        log.warning("adaptive: the nested integrator's AOVs (%s) are not kept",
                    ", ".join(integrator.aov_names()))
    return integrator, settings


def _start(acc: _Accumulator, pixels: int, first: int, resume: Checkpoint | None
           ) -> tuple[np.ndarray, np.ndarray, int, int, float, list[PassRecord]]:
    """The loop's state before its first pass: ``(active, batch, leader, next
    pass, seconds so far, records)``, from ``resume`` if given (restored into
    ``acc``), else a fresh render's."""
    if resume is None:
        return (np.arange(pixels, dtype=np.int64), np.full(pixels, first, dtype=np.int64),
                0, 0, 0.0, [])
    acc.restore(resume.arrays)
    records = [PassRecord(**{**r, "batch_sizes": tuple(r["batch_sizes"])})
               for r in resume.meta["records"]]
    return (resume.arrays["active"].astype(np.int64), resume.arrays["batch"],
            int(resume.meta["leader"]), int(resume.meta["next_pass"]),
            float(resume.meta["seconds"]), records)


def _chunks(group: np.ndarray, m: int, settings: AdaptiveSettings) -> list[np.ndarray]:
    """``group``'s pixel ids in chunks of at most ``max_lanes // m`` pixels (one
    wavefront each)."""
    per_chunk = max(1, settings.max_lanes // m)
    return [group[lo:lo + per_chunk] for lo in range(0, group.size, per_chunk)]


def _next_pass(acc: _Accumulator, leader: int, ladder: tuple[int, ...],
               settings: AdaptiveSettings,
               shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Error test over the whole image, dilation, and the next pass's batches:
    ``(failing, batch, active_next)``; ``leader`` counts the samples of a pixel
    that was active in every pass so far, this one included."""
    mean_y, se_y = luminance_error(acc.stats())
    ratio = error_ratio(mean_y, se_y, acc.count, settings)
    failing = ratio > 1.0
    # Every active pixel gets the pass's batch size (less only where the
    # budget is nearly spent): one wavefront per pass, and a pixel that
    # becomes active late - typically a neighbour of a failing pixel - is
    # refined at the failing pixel's rate at once.
    step = pass_batch_size(leader, ladder, settings)
    batch = np.minimum(step, budget_batches(acc.traced, ladder, settings.max_spp))
    # Only pixels that can still be refined spread activity: a pixel that spent
    # its budget no longer keeps its neighbours busy.
    refinable = batch > 0
    wanted = dilate((failing & refinable).reshape(shape), settings.dilation)
    return failing, batch, np.flatnonzero(wanted.ravel() & refinable)


def _result(film, acc, width, height, s, settings, records, sampler, ladder, has_alpha,
            seconds) -> AdaptiveRender:
    """Develop the accumulated samples into an :class:`AdaptiveRender`."""
    mean_y, se_y = luminance_error(acc.stats())
    ratio = error_ratio(mean_y, se_y, acc.count, settings)
    image, spp, stats, crop = _develop(film, acc, width, height, s)
    se_y = se_y.reshape(height, width)[crop]
    converged = (ratio <= 1.0).reshape(height, width)[crop]
    nonfinite = int(stats.nonfinite.sum())
    if nonfinite:
        empty = int((stats.count == 0).sum())
        log.warning("adaptive: %d NaN/Inf samples left out (%d pixels had no finite sample "
                    "and are 0)", nonfinite, empty)
    image, names = in_film_format(film, image, has_alpha)  # luminance or XYZ films too
    return AdaptiveRender(image=image.astype(np.float32), channels=names, stats=stats,
                          spp=spp, passes=records, seconds=seconds, settings=settings,
                          sampler=_sampler_label(sampler), batch_ladder=ladder,
                          luminance_stderr=se_y, converged=converged)


class _Wavefront:
    """Accumulator of one compacted wavefront (``m`` lanes per pixel of ``ids``):
    per-pixel moments and sub-pixel sums, each pixel's lanes summed in order
    (deterministic, no atomics), merged into ``acc`` on commit."""

    def __init__(self, staged: list[tuple], ids: np.ndarray, s: int, on_samples: Any,
                 k: int) -> None:
        self.staged, self.ids, self.s, self.on_samples, self.k = staged, ids, s, on_samples, k
        self.pending: tuple | None = None
        self.bad = 0

    def add(self, samples: CameraSamples, values: list[mi.Float], group: int) -> None:
        s, m, ids = self.s, group, self.ids
        lane = dr.arange(mi.UInt32, ids.size * m)
        inside = samples.position - mi.Vector2f(samples.pixel)
        sub = mi.Vector2u(dr.clip(dr.floor(inside * s), 0, s - 1))
        finite = dr.isfinite(values[0]) & dr.isfinite(values[1]) & dr.isfinite(values[2])
        # Sub-pixel of every lane among the wavefront's ids.size * s^2 sub-pixels.
        key = (lane // m) * (s * s) + sub.y * s + sub.x
        dr.eval(values, finite, key, inside if self.on_samples is not None else None)
        s2, n_values = s * s, len(values)

        def contributions(lane: mi.UInt32) -> list[mi.Float]:
            cell = dr.gather(mi.UInt32, key, lane) % s2
            keep = dr.gather(mi.Bool, finite, lane)
            vals = [dr.gather(mi.Float, v, lane) for v in values]
            out: list[Any] = []
            for j in range(s2):
                hit = keep & (cell == j)
                out += [dr.select(hit, v, 0.0) for v in vals] + [dr.select(hit, 1.0, 0.0)]
            return out

        sums = sequential_block_sums(ids.size, m, contributions, s2 * (n_values + 1))
        per_cell = [sums[j * (n_values + 1):(j + 1) * (n_values + 1)] for j in range(s2)]
        # Cell-major like the Accumulator's (pixel, sub-pixel) layout.
        sub_count = np.stack([np.array(c[-1], dtype=np.float64) for c in per_cell], -1)
        sub_sums = [np.stack([np.array(c[i], dtype=np.float64) for c in per_cell], -1)
                    for i in range(n_values)]
        count, means, m2, bad = block_moments([mi.Float64(v) for v in values[:3]], m)
        dr.eval(count, means, m2, bad)
        self.pending = (ids, m, count, means, m2, bad, sub_count, sub_sums)
        self.bad = int(np.asarray(bad, dtype=np.float64).sum())
        if self.on_samples is not None:
            self.on_samples(self.k, np.repeat(ids, m), np.array(inside, dtype=np.float64).T,
                            np.array(mi.Color3f(*values[:3]), dtype=np.float64).T)

    def commit(self) -> None:
        if self.pending is not None:
            self.staged.append(self.pending)
            self.pending = None


def _rgb_alpha(film: mi.Film, samples: CameraSamples) -> list[Any]:
    values: list[Any] = [samples.rgb.x, samples.rgb.y, samples.rgb.z]
    if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
        values.append(dr.select(samples.valid, mi.Float(1.0), mi.Float(0.0)))
    return values


def _trace_wavefront(scene, sensor, sampler, integrator, film, ids: np.ndarray, m: int,
                     k: int, wave_seed: int, ours: bool, differential_spp: int, s: int,
                     acc: _Accumulator, staged: list[tuple], on_samples) -> int:
    """Trace ``m`` new samples of each pixel in ``ids`` (one compacted wavefront)
    with the engine's pass step, its sums appended to ``staged`` (merged into
    ``acc`` by the caller at the end of the pass: a pixel is in one wavefront per
    pass, so ``acc`` already holds its earlier passes); returns the non-finite
    samples found."""
    lanes = ids.size * m
    if (k + 1) * m >= 1 << 32:
        raise McrtError("adaptive: too many passes for 32-bit sample indices; raise growth")
    # Lanes: m consecutive lanes per active pixel, built in the kernel from the ids.
    lane = dr.arange(mi.UInt32, lanes)
    pixel_index = dr.gather(mi.UInt32, mi.UInt32(ids.astype(np.uint32)), lane // m)
    sampler.set_sample_count(m)
    if ours and getattr(sampler, "progressive", False):
        # One sequence per pixel (sobol): this batch continues it where the pixel's
        # previous batches stopped, so its samples so far are always a prefix.
        start = dr.gather(mi.UInt32, mi.UInt32(acc.traced[ids].astype(np.uint32)), lane // m)
        sampler.seed_lanes(wave_seed, pixel_index, lane % m + start)
    elif ours:
        # Epoch k of the pixel's sequence at sample count m: a fresh pattern.
        sampler.seed_lanes(wave_seed, pixel_index, lane % m + dr.opaque(mi.UInt32, k * m))
    else:
        sampler.set_samples_per_wavefront(m)
        sampler.seed(wave_seed, lanes)
    wavefront = _Wavefront(staged, ids, s, on_samples, k)
    # Ray differentials are scaled for the first pass's count in every pass,
    # which keeps one kernel for all passes.
    trace_pass(scene, sensor, integrator, sampler, pixel_of_index(film, pixel_index),
               differential_spp, wavefront, m, _rgb_alpha)
    return wavefront.bad


def _develop(film: mi.Film, acc: _Accumulator, width: int, height: int,
             s: int) -> tuple[np.ndarray, np.ndarray, PixelStats, tuple[slice, slice]]:
    """Reconstruct the crop window; crop per-pixel arrays to it."""
    channels = acc.sub_sum.shape[-1]
    sums = acc.sub_sum.reshape(height, width, s, s, channels)
    counts = acc.sub_count.reshape(height, width, s, s)
    image, _ = reconstruct(sums, counts, subpixel_filter(film.rfilter(), s))
    b = int(film.rfilter().border_size()) if film.sample_border() else 0
    crop = (slice(b, height - b), slice(b, width - b))
    stats = PixelStats(count=acc.count.reshape(height, width)[crop],
                       mean=acc.mean.reshape(height, width, 3)[crop],
                       m2=acc.m2.reshape(height, width, 3)[crop],
                       nonfinite=acc.nonfinite.reshape(height, width)[crop])
    return image[crop], acc.traced.reshape(height, width)[crop], stats, crop


__all__ = ["render_adaptive"]
