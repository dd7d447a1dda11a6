"""The adaptive render loop: passes over compacted wavefronts of active pixels,
their sums (:mod:`.sums`), Ctrl-C checkpoints, and the developed result (see
:mod:`mcrt.render.adaptive` for the method)."""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, TypeVar

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.engine import deferred_interrupts, sampling_integrator, supported_film
from ...core.inputs import check_sampler, check_scene, check_seed, check_sensor
from ...core.job import Checkpoint, Checkpointing, CheckpointPacer, Interrupted
from ...core.render import in_film_format
from ...core.sampling import bind_film_width, make_sampler
from ...core.stats import PixelStats
from ...core.trace import film_grid_size
from ...errors import ArgumentTypeError, McrtError
from ...samplers.kit import hash_keys_int
from . import frozen
from .criterion import dilate, error_ratio
from .ladder import batch_ladder, budget_batches, pass_batch_size
from .reconstruct import reconstruct_grid, subpixel_filter
from .result import AdaptiveRender, PassRecord
from .settings import AdaptiveSettings
from .sums import Pending, PixelSums
from .wavefront import Target, trace_wavefront

log = logging.getLogger(__name__)


def _sampler_label(sampler: mi.Sampler) -> str:
    from ...core.sampling import sampler_name

    return sampler_name(sampler)


def render_adaptive(scene: mi.Scene, sampler: mi.Sampler | str | None = None,
                    settings: AdaptiveSettings | None = None, seed: int = 0,
                    sensor: int | mi.Sensor = 0,
                    integrator: mi.SamplingIntegrator | None = None,
                    on_pass: Callable[[PassRecord], None] | None = None,
                    on_samples: Callable[..., None] | None = None,
                    checkpoints: Checkpointing | None = None) -> AdaptiveRender:
    """Render ``scene`` adaptively (see :mod:`mcrt.render.adaptive`).

    ``sampler`` defaults to the sensor's (a name makes that sampler; its type and
    parameters are used, not its sample count; it is cloned, never modified);
    ``integrator`` to the scene's (a sampling integrator; for an ``adaptive`` one,
    its nested integrator, and its settings unless ``settings`` is given).
    ``on_pass(record)`` runs after each pass;
    ``on_samples(pass_index, pixel_ids, position, rgb)`` receives every traced
    wavefront as numpy arrays (for tests and visualisation).

    Ctrl-C raises :class:`~mcrt.core.job.Interrupted` with the passes finished
    so far as ``partial`` (a pass in flight is dropped whole) and the
    :class:`~mcrt.core.job.Checkpoint` to resume from as ``state``;
    ``checkpoints`` (:class:`~mcrt.core.job.Checkpointing`) resumes from one and
    saves them while the render runs (paced, like a film render's: a SIGKILL
    loses at most the passes since the last one), and the result's
    :attr:`~.result.AdaptiveRender.checkpoint` makes the finished render's on
    demand (for its caller to keep when writing the outputs fails). Every wavefront's
    samples depend only on (seed, pass, pixel), so a resumed render equals an
    uninterrupted one.
    """
    kept = checkpoints or Checkpointing()
    check_scene(scene, "render_adaptive")
    seed = check_seed(seed, "render_adaptive")
    sensor_obj = sensor if isinstance(sensor, mi.Sensor) else \
        scene.sensors()[check_sensor(scene, sensor, "render_adaptive")]
    if settings is not None and not isinstance(settings, AdaptiveSettings):
        raise ArgumentTypeError(f"render_adaptive: settings must be an AdaptiveSettings(...), "
                                f"got {type(settings).__name__}"
                                + (": use AdaptiveSettings(**settings)"
                                   if isinstance(settings, dict) else ""))
    integrator, settings = _integrator_and_settings(scene, integrator, settings)
    film = supported_film(sensor_obj.film())
    chosen = check_sampler(sampler, "render_adaptive")
    if isinstance(chosen, str):  # (its type and parameters are used, not its count)
        chosen = make_sampler(chosen, settings.min_spp)
    sampler = (chosen if chosen is not None else sensor_obj.sampler()).clone()
    ladder = _ladder(sampler, settings)
    width, height = (int(v) for v in film_grid_size(film))
    bind_film_width(sampler, width)  # zsobol orders pixels along the film
    pixels = width * height
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    acc = PixelSums(pixels, settings.subpixels, 4 if has_alpha else 3)
    target = Target(scene, sensor_obj, integrator, sampler, ladder[0], acc, on_samples)
    loop = _Loop.start(acc, pixels, ladder[0], kept.resume)

    dr.sync_thread()
    start = time.perf_counter()

    def finish() -> AdaptiveRender:
        end = time.perf_counter()
        result = _result(target, settings, ladder, loop.records, start - loop.seconds_before)
        if kept.save is not None:
            result.state = lambda: loop.snapshot(acc, start, end)
        return result

    # The accumulator and the loop state change only together, at the end of a
    # pass and with interrupts held back, so they always describe the passes
    # finished so far: a checkpoint is copied from them only when one is saved.
    pacer = CheckpointPacer(kept.every, state_bytes=acc.nbytes() + loop.nbytes())
    # Largest batch that fits each pixel's remaining budget (0: done).
    budget = budget_batches(acc.traced, ladder, settings.max_spp)
    ended = start  # when the last finished pass ended (a pass in flight is dropped whole)
    try:
        while loop.active.size:
            pass_start = time.perf_counter()
            spent = int(acc.traced.sum())
            k, active = loop.next_pass, loop.active
            batches = loop.batch[active]
            sizes = _sizes(batches)
            lanes, bad_total = 0, 0
            staged: list[Pending] = []
            for m in sizes:
                group = active if len(sizes) == 1 else active[batches == m]
                for c, ids in enumerate(_chunks(group, m, settings)):
                    one_wavefront = k == 0 and ids.size == pixels
                    wave_seed = (seed if target.ours or one_wavefront
                                 else hash_keys_int(seed, k, m, c))
                    pending = frozen.wavefront(target, ids, m, k, wave_seed)
                    if pending is None:  # traced (see .frozen for when)
                        bad_total += trace_wavefront(target, ids, m, k, wave_seed, staged)
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
                leader = loop.leader + sizes[-1]
                failing, batch, active_next = _next_pass(acc, leader, ladder, settings,
                                                         (height, width), budget)
                dr.sync_thread()
                ended = time.perf_counter()
                record = PassRecord(index=k, active_pixels=int(active.size), samples=lanes,
                                    batch_sizes=tuple(sizes), seconds=ended - pass_start,
                                    converged_pixels=int(pixels - failing.sum()),
                                    nonfinite=bad_total)
                loop.advance(record, leader, batch, active_next)
            if on_pass is not None:
                on_pass(record)
            if kept.save is not None and loop.active.size:  # (the last: see finish)
                pacer.maybe(kept.save, lambda: loop.snapshot(acc, start))
    except KeyboardInterrupt:
        k = loop.next_pass
        # The seconds of the passes kept: the time of the pass dropped is not
        # theirs (a resumed render's samples per second count the same work).
        raise Interrupted(finish() if k > 0 else None, k, k + 1,
                          state=loop.snapshot(acc, start, ended)) from None
    return finish()


@dataclass
class _Loop:
    """The adaptive loop's state between passes (saved with the sums in a checkpoint)."""

    active: np.ndarray  # the pixels the next pass refines
    batch: np.ndarray  # each pixel's next batch size
    leader: int  # samples of a pixel that was active in every pass so far
    next_pass: int
    seconds_before: float  # spent by the render before it was resumed
    records: list[PassRecord]

    @classmethod
    def start(cls, acc: PixelSums, pixels: int, first: int,
              resume: Checkpoint | None) -> _Loop:
        """A fresh render's state, or ``resume``'s (its sums restored into ``acc``)."""
        if resume is None:
            return cls(np.arange(pixels, dtype=np.int64),
                       np.full(pixels, first, dtype=np.int64), 0, 0, 0.0, [])
        acc.restore(resume.arrays)
        records = [PassRecord(**{**r, "batch_sizes": tuple(r["batch_sizes"])})
                   for r in resume.meta["records"]]
        return cls(resume.arrays["active"].astype(np.int64), resume.arrays["batch"],
                   int(resume.meta["leader"]), int(resume.meta["next_pass"]),
                   float(resume.meta["seconds"]), records)

    def advance(self, record: PassRecord, leader: int, batch: np.ndarray,
                active: np.ndarray) -> None:
        """A pass is done: its record, and the next pass's pixels and batches."""
        self.records.append(record)
        self.leader, self.batch, self.active = leader, batch, active
        self.next_pass += 1

    def nbytes(self) -> int:
        return int(self.active.nbytes + self.batch.nbytes)

    def snapshot(self, acc: PixelSums, start: float, end: float | None = None) -> Checkpoint:
        """The checkpoint of the passes done (``start``: when this run began;
        ``end``: when its passes ended, if they did)."""
        end = time.perf_counter() if end is None else end
        return Checkpoint(
            meta={"leader": self.leader, "next_pass": self.next_pass,
                  "records": [asdict(r) for r in self.records],
                  "seconds": self.seconds_before + end - start},
            arrays={**acc.arrays(), "active": self.active.copy(), "batch": self.batch.copy()})


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


#: Mitsuba 3.9's ``AOVIntegrator.to_string()`` with no nested integrator (the
#: plugin binds no accessor for them; with one, the list holds its description).
_NO_NESTED = re.compile(r"\bintegrators = \[\s*\]")

IntegratorT = TypeVar("IntegratorT", bound=mi.Integrator)


def check_integrator(integrator: IntegratorT) -> IntegratorT:
    """``integrator``, refused in one line when adaptive sampling has no image to
    adapt to: an ``aov`` integrator without a nested image integrator renders its
    AOVs only, its image is black, and the adaptive renderer keeps no AOVs (it
    would trace every budget's samples into a black image, with a warning that
    ``-q`` hides)."""
    if integrator.class_name() == "AOVIntegrator" and _NO_NESTED.search(str(integrator)):
        raise McrtError("adaptive: the aov integrator has no nested image integrator, so its "
                        "image is black and the adaptive renderer (which keeps no AOVs) has "
                        "nothing to adapt to: nest one (e.g. <integrator type=\"path\"/>) "
                        "inside the aov, or render without --adaptive")
    return integrator


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
    check_integrator(integrator)
    if integrator.aov_names():
        log.warning("adaptive: the nested integrator's AOVs (%s) are not kept",
                    ", ".join(integrator.aov_names()))
    return integrator, settings


def _sizes(batches: np.ndarray) -> list[int]:
    """The distinct batch sizes of a pass's pixels, ascending (usually one: a
    pass gives every active pixel its batch size, less only where a budget is
    nearly spent; np.unique sorts, 0.2 ms at ~13k pixels)."""
    low, high = int(batches.min()), int(batches.max())
    return [low] if low == high else np.unique(batches).tolist()


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


def _result(target: Target, settings: AdaptiveSettings, ladder: tuple[int, ...],
            records: list[PassRecord], clock: float) -> AdaptiveRender:
    """Develop the accumulated samples into an :class:`AdaptiveRender`; its
    ``seconds`` run from ``clock`` (a ``perf_counter`` time) to the developed
    image, as a film render's include its film's development."""
    film, acc, sampler = target.film, target.acc, target.sampler
    width, height = (int(v) for v in film_grid_size(film))
    s, has_alpha = acc.s, mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    ratio = error_ratio(acc.mean_y, acc.se_y, acc.counts(), settings)
    image, spp, stats, crop, traced_bad = _develop(film, acc, width, height, s)
    seconds = time.perf_counter() - clock
    se_y = acc.se_y.reshape(height, width)[crop]
    converged = (ratio <= 1.0).reshape(height, width)[crop]
    if traced_bad:  # every traced one, as the passes count them; the pixels: the image's
        border = traced_bad - int(stats.nonfinite.sum())
        empty = int((stats.count == 0).sum())
        log.warning("adaptive: %d NaN/Inf samples left out (%s%d image pixels had no finite "
                    "sample and are 0)", traced_bad,
                    f"{border} in the film's sampled border; " if border else "", empty)
    image, names = in_film_format(film, image, has_alpha)  # luminance or XYZ films too
    return AdaptiveRender(image=image.astype(np.float32), channels=names, stats=stats,
                          spp=spp, passes=records, seconds=seconds, settings=settings,
                          sampler=_sampler_label(sampler), batch_ladder=ladder,
                          luminance_stderr=se_y, converged=converged,
                          traced_samples=int(acc.traced.sum()), traced_nonfinite=traced_bad)


def _develop(film: mi.Film, acc: PixelSums, width: int, height: int,
             s: int) -> tuple[np.ndarray, np.ndarray, PixelStats, tuple[slice, slice], int]:
    """Reconstruct the crop window; crop per-pixel arrays to it. The last value is
    the NaN/Inf samples of the whole grid (a sampled border's included)."""
    image = reconstruct_grid(acc.grid, (height, width), s, acc.channels,
                             subpixel_filter(film.rfilter(), s))
    b = int(film.rfilter().border_size()) if film.sample_border() else 0
    crop = (slice(b, height - b), slice(b, width - b))
    stats = acc.pixel_stats()
    cropped = PixelStats(count=stats.count.reshape(height, width)[crop],
                       mean=stats.mean.reshape(height, width, 3)[crop],
                       m2=stats.m2.reshape(height, width, 3)[crop],
                       nonfinite=stats.nonfinite.reshape(height, width)[crop])
    return (image[crop], acc.traced.reshape(height, width)[crop], cropped, crop,
            int(stats.nonfinite.sum()))


__all__ = ["check_integrator", "render_adaptive"]
