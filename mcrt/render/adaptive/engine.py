"""The adaptive render loop: passes over compacted wavefronts of active pixels,
their sums (:mod:`.sums`), Ctrl-C checkpoints, and the developed result (see
:mod:`mcrt.render.adaptive` for the method)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.engine import deferred_interrupts, sampling_integrator, supported_film
from ...core.job import Checkpoint, Checkpointing, CheckpointPacer, Interrupted
from ...core.render import in_film_format
from ...core.sampling import bind_film_width
from ...core.stats import PixelStats
from ...core.trace import film_grid_size
from ...errors import McrtError
from ...samplers.base import is_mcrt_sampler
from ...samplers.kit import hash_keys_int
from . import frozen
from .criterion import dilate, error_ratio
from .ladder import batch_ladder, budget_batches, pass_batch_size
from .reconstruct import reconstruct, subpixel_filter
from .result import AdaptiveRender, PassRecord
from .settings import AdaptiveSettings
from .sums import Pending, PixelSums
from .wavefront import trace_wavefront

log = logging.getLogger(__name__)


def _sampler_label(sampler: mi.Sampler) -> str:
    from ...core.sampling import sampler_name

    return sampler_name(sampler)


def render_adaptive(scene: mi.Scene, sampler: mi.Sampler | None = None,
                    settings: AdaptiveSettings | None = None, seed: int = 0,
                    sensor: int | mi.Sensor = 0,
                    integrator: mi.SamplingIntegrator | None = None,
                    on_pass: Callable[[PassRecord], None] | None = None,
                    on_samples: Callable[..., None] | None = None,
                    checkpoints: Checkpointing | None = None) -> AdaptiveRender:
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
    ``checkpoints`` (:class:`~mcrt.core.job.Checkpointing`) resumes from one and
    saves them while the render runs, so that even a SIGKILL keeps the passes
    saved (the last pass is always saved: the caller discards it once the
    result is written). Every wavefront's
    samples depend only on (seed, pass, pixel), so a resumed render equals an
    uninterrupted one.
    """
    kept = checkpoints or Checkpointing()
    resume, save, save_every = kept.resume, kept.save, kept.every
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
    acc = PixelSums(pixels, s, 4 if has_alpha else 3)
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
    # Largest batch that fits each pixel's remaining budget (0: done).
    budget = budget_batches(acc.traced, ladder, settings.max_spp)
    try:
        while active.size:
            pass_start = time.perf_counter()
            spent = int(acc.traced.sum())
            sizes = np.unique(batch[active])
            lanes, bad_total = 0, 0
            staged: list[Pending] = []
            for m in sizes.tolist():
                for c, ids in enumerate(_chunks(active[batch[active] == m], m, settings)):
                    one_wavefront = k == 0 and ids.size == pixels
                    wave_seed = seed if ours or one_wavefront else hash_keys_int(seed, k, m, c)
                    pending = frozen.wavefront(scene, sensor_obj, sampler, integrator, ids, m,
                                               k, wave_seed, first, acc, on_samples)
                    if pending is None:  # traced (see .frozen for when)
                        bad_total += trace_wavefront(scene, sensor_obj, sampler, integrator,
                                                     film, ids, m, k, wave_seed, ours, first,
                                                     acc, staged, on_samples)
                    else:
                        staged.append(pending)
                        bad_total += pending.nonfinite
                    lanes += ids.size * m
            with deferred_interrupts():
                for wavefront in staged:
                    acc.commit(wavefront)
                    # The budget left changed for these pixels only.
                    budget[wavefront.ids] = budget_batches(acc.traced[wavefront.ids], ladder,
                                                           settings.max_spp)
                _check_progress(acc, spent)
                leader += int(sizes.max())
                failing, batch, active_next = _next_pass(acc, leader, ladder, settings,
                                                         (height, width), budget)
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


def _check_progress(acc: PixelSums, spent: int) -> None:
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


def _start(acc: PixelSums, pixels: int, first: int, resume: Checkpoint | None
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


def _next_pass(acc: PixelSums, leader: int, ladder: tuple[int, ...],
               settings: AdaptiveSettings, shape: tuple[int, int],
               budget: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Error test over the whole image, dilation, and the next pass's batches:
    ``(failing, batch, active_next)``; ``leader`` counts the samples of a pixel
    that was active in every pass so far, this one included; ``budget``:
    :func:`~.ladder.budget_batches` of every pixel."""
    ratio = error_ratio(acc.mean_y, acc.se_y, acc.counts(), settings)
    failing = ratio > 1.0
    # Every active pixel gets the pass's batch size (less only where the
    # budget is nearly spent): one wavefront per pass, and a pixel that
    # becomes active late - typically a neighbour of a failing pixel - is
    # refined at the failing pixel's rate at once.
    step = pass_batch_size(leader, ladder, settings)
    batch = np.minimum(step, budget)
    # Only pixels that can still be refined spread activity: a pixel that spent
    # its budget no longer keeps its neighbours busy.
    refinable = batch > 0
    wanted = dilate((failing & refinable).reshape(shape), settings.dilation)
    return failing, batch, np.flatnonzero(wanted.ravel() & refinable)


def _result(film, acc, width, height, s, settings, records, sampler, ladder, has_alpha,
            seconds) -> AdaptiveRender:
    """Develop the accumulated samples into an :class:`AdaptiveRender`."""
    ratio = error_ratio(acc.mean_y, acc.se_y, acc.pixel_stats().count, settings)
    image, spp, stats, crop = _develop(film, acc, width, height, s)
    se_y = acc.se_y.reshape(height, width)[crop]
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


def _develop(film: mi.Film, acc: PixelSums, width: int, height: int,
             s: int) -> tuple[np.ndarray, np.ndarray, PixelStats, tuple[slice, slice]]:
    """Reconstruct the crop window; crop per-pixel arrays to it."""
    sub_sum, sub_count = acc.sub_pixels()
    sums = sub_sum.reshape(height, width, s, s, acc.channels)
    counts = sub_count.reshape(height, width, s, s)
    image, _ = reconstruct(sums, counts, subpixel_filter(film.rfilter(), s))
    b = int(film.rfilter().border_size()) if film.sample_border() else 0
    crop = (slice(b, height - b), slice(b, width - b))
    stats = acc.pixel_stats()
    stats = PixelStats(count=stats.count.reshape(height, width)[crop],
                       mean=stats.mean.reshape(height, width, 3)[crop],
                       m2=stats.m2.reshape(height, width, 3)[crop],
                       nonfinite=stats.nonfinite.reshape(height, width)[crop])
    return image[crop], acc.traced.reshape(height, width)[crop], stats, crop


__all__ = ["render_adaptive"]
