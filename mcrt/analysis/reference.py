"""High-spp reference images with exact per-pixel statistics, cached and resumable.

A reference is rendered in *passes*. Pass ``i`` is one :func:`render_stats` call
with its own seed :func:`pass_seed` ``(seed, i)``, so passes are independent
patterns; each pass's per-pixel moments ``(n, mean, M2)`` are Chan-merged in
float64 into the running total (:mod:`mcrt.core.stats`). Counts are
int64 and the moments are merged pairwise, so the estimate, the per-sample
variance and the standard error stay exact however many samples are taken
(beyond 2^32 in total; Mitsuba alone renders at most 2^32 samples per call and
stores float16 films by default).

Samples per pass
    Some samplers round their sample count (``jittered``/``uniform_grid``/
    ``stratified`` to squares, ``orthogonal`` to prime squares, ``ldsampler`` to
    powers of 4, ``multijitter`` to products of near-equal factors). The pass
    plan (:func:`plan_passes`) only uses counts the sampler accepts *unchanged*:
    ``k`` passes of the largest accepted count not above the target (256, or
    fewer so that a pass has at most :data:`LANE_BUDGET` lanes), then the
    remainder split greedily into accepted counts. Only when the sampler accepts
    no count small enough for the last remainder (``orthogonal`` below 4, or
    ``ldsampler`` below 4) is the total rounded up; :attr:`PassPlan.spp` is then
    the effective total, reported by :attr:`Reference.spp` and logged. Nothing
    is ever rendered at a count other than the plan's (checked every pass).

Cache and resume
    The result is cached under ``<cache>/reference`` (:func:`mcrt.cache.cache_dir`)
    by :func:`reference_key`, a SHA-256 of the scene's content (the XML, the
    files it includes and the files it names with ``filename``), the ``-D``
    parameters, sampler and its plugin parameters (a point file's content too),
    seed, requested spp, the pass plan, the lane budget, the Mitsuba / Dr.Jit /
    mcrt versions, the variant and :data:`CACHE_FORMAT`.
    After every finished pass the running state (count, mean, M2, nonfinite,
    passes done, seconds, key) is written atomically to ``<key>.partial.npz``;
    the finished reference goes to ``<key>.npz``. A later call with the same
    key returns a finished reference without rendering, or continues a partial
    one from its next pass; because passes are seeded by index and merged in
    order from bit-exact float64 state, the result is bit-identical to an
    uninterrupted run. Files are validated on load (format, key, role, shapes,
    dtypes, and that every pixel has exactly the samples of the passes done), so
    a partial state is never taken for a finished one and a damaged file is
    ignored, never trusted.

Reconstruction filters
    A scene whose film filters with anything but a box gets a reference
    developed with that filter, as its film develops a render: per pixel the
    float64 ratio of filter-weighted sums over every sample within the filter's
    reach, with the delta-method variance of that ratio (every weight counted;
    see :mod:`mcrt.core.filtered`). Its arrays cover the film's crop window,
    ``variance`` is the weighted per-sample variance and the EXR gains an
    ``effective_count`` layer (Kish's ``(sum w)^2 / sum w^2``). Box films keep
    the box-binned moments below.

Standard error
    ``standard_error = sqrt(variance / n)`` (NaN, unknown, for a pixel with fewer
    than two finite samples; with none its mean is 0 by convention) assumes independent
    samples, which holds exactly for the default ``independent`` sampler. For stratified or
    low-discrepancy samplers the samples of one pass are negatively correlated,
    so the true error of the mean is usually smaller: the reported value is then
    a (typically conservative) estimate.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import check_free_space, remove_stale_temporaries
from ..core.executor import Executor, cluster_status, task_memory
from ..core.filtered import FilteredStats
from ..core.job import Interrupted, Job, content_key, run_job
from ..core.progress import Progress
from ..core.provenance import FILE_PARAMS, absolute
from ..core.render import StatsRender, render_stats
from ..core.sampling import check_sampler_name, make_sampler, sampler_fingerprint
from ..core.scene_files import SceneBundle, SceneSource, scene_digest
from ..core.stats import PixelStats
from ..core.trace import film_grid_size
from ..errors import McrtError, SamplerError, whole_number
from ..render.loaded import planned_scene
from ..render.scene import check_scene_file, scene_params
from ..samplers.kit import hash_keys_int
from .pass_plan import DEFAULT_PASS_SPP, LANE_BUDGET, PassPlan, plan_passes
from .reference_cache import (
    CACHE_FORMAT,
    STATE_BYTES_PER_PIXEL,
    StateSaver,
    cache_paths,
    load_state,
    reference_lock,
)
from .reference_exr import reference_layers as reference_layers  # its EXR file, named here too
from .reference_exr import reference_metadata as reference_metadata

log = logging.getLogger("mcrt.reference")

#: Default total samples per pixel of a reference.
DEFAULT_REFERENCE_SPP = 4096

# --------------------------------------------------------------------------- keys


def pass_seed(seed: int, index: int) -> int:
    """Seed of reference pass ``index``: hashed, so nearby user seeds never
    share passes. For a fixed ``seed`` it is a bijection of ``index`` (a chain of
    32-bit bijections), so no two passes of one reference share a seed."""
    return hash_keys_int(seed, index, 0x5EF)


def key_payload(scene_path: str | Path, params: dict[str, str] | None, sampler: str, seed: int,
                plan: PassPlan, filtered: bool = False,
                sampler_params: dict[str, Any] | None = None) -> dict:
    """Everything a reference's bits depend on (see :func:`reference_key`)."""
    # Keys without a filter or sampler parameters stay as they were.
    extra: dict[str, Any] = {"estimator": "filtered"} if filtered else {}
    if sampler_params:
        extra["sampler_params"] = sorted([k, v] for k, v in sampler_params.items())
    return {**extra,
        "format": CACHE_FORMAT,
        "scene": scene_digest(scene_path, params),
        "params": sorted((str(k), str(v)) for k, v in (params or {}).items()),
        "sampler": sampler,
        "seed": int(seed),
        "spp": plan.requested_spp,
        "plan": [plan.pass_spp, plan.full_passes, list(plan.tail)],
        "lane_budget": LANE_BUDGET,
        **({"sampler_code": code} if (code := sampler_fingerprint(sampler, sampler_params))
           else {}),
    }


def reference_key(scene_path: str | Path, params: dict[str, str] | None, sampler: str,
                  seed: int, plan: PassPlan, filtered: bool = False,
                  sampler_params: dict[str, Any] | None = None) -> str:
    """Cache key: :func:`~mcrt.core.job.content_key` of :func:`key_payload`."""
    return content_key(key_payload(scene_path, params, sampler, seed, plan, filtered,
                                   sampler_params))


# --------------------------------------------------------------------------- result


@dataclass
class Reference:
    """A reference image: per-pixel estimate and its statistics (float64).

    ``spp`` is the effective total samples per pixel (see :class:`PassPlan`);
    ``seconds`` the wall time, on the process that merges them, from the start of
    the passes to the last one merged (summed over the sessions of a resumed or
    cached reference; passes of a cluster that run at the same time count once);
    ``cached`` whether it came from the cache without rendering;
    ``resumed_passes`` how many passes a partial state provided;
    ``pass_seconds`` the passes' own render times added up, for the passes this
    call rendered only (0 for a cached reference): on a cluster, the workers'
    summed time, more than ``seconds`` when they ran at once.
    """

    stats: PixelStats | FilteredStats  # FilteredStats: developed with the film's filter
    spp: int
    sampler: str
    seed: int
    passes: int
    seconds: float
    key: str = ""
    cached: bool = False
    resumed_passes: int = 0
    plan: PassPlan | None = None
    pass_seconds: float = 0.0
    sampler_params: dict[str, Any] = field(default_factory=dict)

    @property
    def mean(self) -> np.ndarray:
        return self.stats.mean

    @property
    def variance(self) -> np.ndarray:
        return self.stats.variance

    @property
    def standard_error(self) -> np.ndarray:
        return self.stats.standard_error

    @property
    def samples(self) -> int:
        """Finite samples merged into the estimate (exact Python int)."""
        return self.stats.samples

    @property
    def drawn_samples(self) -> int:
        """All samples traced, non-finite ones included (exact Python int)."""
        return self.stats.samples + int(self.stats.nonfinite.sum())

    @property
    def samples_per_second(self) -> float:
        return self.drawn_samples / self.seconds if self.seconds > 0 else float("inf")


# --------------------------------------------------------------------------- rendering


@dataclass(frozen=True)
class ReferenceRequest:
    """Which reference: a scene (its ``$key`` parameters, the CLI's ``-D``) at
    ``spp`` samples per pixel of ``sampler`` (with its plugin parameters
    ``sampler_params``, e.g. a ``pointset``'s ``filename``) from ``seed``, in
    passes of ``spp_per_pass`` (None: as many as fit). With the software it is
    what the reference's bits, and so its cache key, depend on."""

    scene_path: str | Path
    params: dict[str, str] | None = None
    spp: int = DEFAULT_REFERENCE_SPP
    sampler: str = "independent"
    seed: int = 0
    spp_per_pass: int | None = None
    sampler_params: dict[str, Any] | None = None


@dataclass(frozen=True)
class ReferenceHooks:
    """What a caller sees of a reference being made: a progress bar;
    ``on_pass(index, passes)`` after pass ``index`` is merged and its state saved
    (a test hook; raising there interrupts the reference, which the next call
    resumes); ``before_work(width, height)`` once the scene is planned, before
    the cache is read or a pass rendered (e.g. the command's own checks: free
    space for its output)."""

    progress: bool = False
    on_pass: Callable[[int, int], None] | None = None
    before_work: Callable[[int, int], None] | None = None


def get_reference(scene_path: str | Path, params: dict[str, str] | None = None,
                  spp: int = DEFAULT_REFERENCE_SPP, sampler: str = "independent",
                  seed: int = 0, spp_per_pass: int | None = None,
                  progress: bool = False, *, cache: bool = True,
                  on_pass: Callable[[int, int], None] | None = None,
                  executor: Executor | None = None,
                  before_work: Callable[[int, int], None] | None = None,
                  sampler_params: dict[str, Any] | None = None) -> Reference:
    """Render (or fetch from the cache) a reference of ``scene_path`` at ``spp``:
    the :class:`ReferenceRequest` of the arguments before ``progress`` and of
    ``sampler_params``, seen
    through the :class:`ReferenceHooks` ``progress``, ``on_pass``, ``before_work``.

    A :class:`~mcrt.core.job.Job` whose tasks are the passes (each a pure
    function of its index), folded in order with Chan's merge, on ``executor``
    (default: this process). ``cache`` False neither reads nor writes the cache.
    Ctrl-C raises :class:`~mcrt.core.job.Interrupted` with the partial
    :class:`Reference`. Raises :class:`~mcrt.errors.McrtError` for bad arguments
    or scenes, before rendering.
    """
    hooks = ReferenceHooks(progress, on_pass, before_work)
    setup = _setup(ReferenceRequest(scene_path, params, spp, sampler, seed, spp_per_pass,
                                    sampler_params), executor)
    height, width = setup.shape
    if cache:  # room for the partial and the finished state (and a temporary copy)
        remove_stale_temporaries(setup.finished.parent)
        check_free_space(setup.finished.parent, 3 * STATE_BYTES_PER_PIXEL * width * height,
                         "the reference cache files", STATE_BYTES_PER_PIXEL * width * height)
    if hooks.before_work is not None:
        hooks.before_work(width, height)
    if not cache:
        return _render(setup, None, 0, 0.0, False, hooks, executor)
    with reference_lock(setup.key):  # another process rendering it: wait, then read it here
        found = load_state(setup.finished, setup.key, setup.plan, setup.shape, complete=True,
                           filtered=setup.filtered)
        if found is not None:
            return setup.result(found[0], found[2], cached=True)
        start: StatsRender | None = None
        done, seconds = 0, 0.0
        found = load_state(setup.partial, setup.key, setup.plan, setup.shape, complete=False,
                           filtered=setup.filtered)
        if found is not None:
            start = StatsRender(found[0], 0, 0, 0.0)
            done, seconds = found[1], found[2]
            log.info("resuming reference %s after pass %d of %d", setup.key, done,
                     setup.plan.passes)
        return _render(setup, start, done, seconds, True, hooks, executor)


@dataclass
class _Setup:
    """A reference's settings, checked, with its scene planned and its pass plan."""

    params: dict[str, str]
    sampler: str
    seed: int
    source: SceneSource
    filtered: bool
    plan: PassPlan
    key: str
    shape: tuple[int, int]  # (height, width) of the reference's pixels
    sampler_params: dict[str, Any]

    @property
    def finished(self) -> Path:
        return cache_paths(self.key)[0]

    @property
    def partial(self) -> Path:
        return cache_paths(self.key)[1]

    def result(self, stats: PixelStats | FilteredStats, seconds: float, cached: bool = False,
               resumed: int = 0, pass_seconds: float = 0.0) -> Reference:
        return Reference(stats=stats, spp=self.plan.spp, sampler=self.sampler, seed=self.seed,
                         passes=self.plan.passes, seconds=seconds, key=self.key, cached=cached,
                         resumed_passes=resumed, plan=self.plan, pass_seconds=pass_seconds,
                         sampler_params=dict(self.sampler_params))


def _setup(request: ReferenceRequest, executor: Executor | None = None) -> _Setup:
    """Check the request, plan the scene (kept for this process's tasks) and its
    passes (to fit the memory where ``executor`` runs them): every user error
    surfaces here, before any pass."""
    scene_path, spp, sampler, seed = request.scene_path, request.spp, request.sampler, request.seed
    params, spp_per_pass = scene_params(request.params), request.spp_per_pass
    check_scene_file(scene_path)  # (a path: the cache keys the file's content)
    if isinstance(spp, int | np.integer) and not isinstance(spp, bool) and spp < 1:
        raise McrtError(f"a reference needs at least 1 sample per pixel, got {spp}")
    spp = whole_number(spp, "a reference's spp (samples per pixel)")
    seed = whole_number(seed, "a reference's seed", 0, 2 ** 32)
    check_sampler_name(sampler)
    # A point-set file by absolute path: the key, the header and the passes on any
    # worker name the same file, whatever the working directory.
    sampler_params = {k: absolute(v) if k in FILE_PARAMS and isinstance(v, str) and v else v
                      for k, v in (request.sampler_params or {}).items()}
    # The scene `mcrt render` renders (motion too), kept for this process's tasks.
    planned = planned_scene(scene_path, params)
    source = SceneSource.of(scene_path, params)
    film = planned.scene.sensors()[0].film()
    grid = film_grid_size(film)
    width, height = int(grid[0]), int(grid[1])
    filtered = not film.rfilter().is_box_filter()
    if filtered:
        log.info("the reference is developed with the film's %s filter (float64; standard "
                 "errors count every filter weight)", film.rfilter().class_name())
    if spp_per_pass is None:
        spp_per_pass = memory_pass_spp(width * height, spp, executor)
    plan = plan_passes(sampler, spp, width * height, spp_per_pass, sampler_params)
    key = reference_key(scene_path, params, sampler, seed, plan, filtered, sampler_params)
    if filtered:  # the developed pixels: the crop window
        width, height = (int(v) for v in film.crop_size())
    return _Setup(params, sampler, seed, source, filtered, plan, key, (height, width),
                  sampler_params)


def _render(setup: _Setup, start: StatsRender | None, done: int, seconds: float, cache: bool,
            hooks: ReferenceHooks, executor: Executor | None) -> Reference:
    """Run the passes ``done ..`` as a job (folded onto ``start``), saving the
    state after each, and return the reference."""
    plan = setup.plan
    task = ReferencePass(tuple(sorted(setup.params.items())), setup.sampler, plan, setup.seed,
                         setup.filtered, tuple(sorted(setup.sampler_params.items())))
    job = Job(setup.key, plan.passes, functools.partial(reference_pass, task), _merge,
              shared={"scene": setup.source})
    saver = StateSaver(setup.key, plan, setup.finished, setup.partial, cache)
    bar = Progress(plan.passes, enabled=hooks.progress, desc="reference", initial=done)
    before = start.samples if start is not None else 0
    # Wall time on this process: passes that run at once on a cluster's workers
    # count once, not once per worker (their own times add up to more).
    clock = time.perf_counter()
    folded = [0.0]  # the wall time when the last pass was merged (what the cache keeps)

    def on_fold(count: int, merged: StatsRender) -> None:
        elapsed = folded[0] = time.perf_counter() - clock
        saver.save(count, merged, seconds + elapsed)
        if elapsed > 0:
            bar.postfix(f"{(merged.samples - before) / elapsed / 1e6:.2f} M samples/s"
                        + cluster_status(executor))
        bar.update(1)
        if hooks.on_pass is not None:
            hooks.on_pass(count - 1, plan.passes)

    try:
        merged = run_job(job, executor, done=done, total=start, on_fold=on_fold)
    except Interrupted as stop:
        if stop.partial is None:
            raise KeyboardInterrupt from None
        raise Interrupted(setup.result(stop.partial.stats, seconds + folded[0],
                                       resumed=done), stop.done, plan.passes) from None
    finally:
        bar.close()
    assert merged is not None
    return setup.result(merged.stats, seconds + folded[0], resumed=done,
                        pass_seconds=merged.seconds)


@dataclass(frozen=True)
class ReferencePass:
    """What every pass of a reference needs besides its scene and index."""

    params: tuple[tuple[str, str], ...]
    sampler: str
    plan: PassPlan
    seed: int
    filtered: bool
    sampler_params: tuple[tuple[str, Any], ...] = ()


def reference_pass(task: ReferencePass, index: int,
                   scene: SceneSource | SceneBundle) -> StatsRender:
    """Pass ``index`` of a reference: a pure function of its arguments, run in
    this process or on a cluster worker (the scene loaded once per process)."""
    planned = planned_scene(scene, dict(task.params))
    count = task.plan.spp_of(index)
    pass_sampler = make_sampler(task.sampler, count, **dict(task.sampler_params))
    subframes, move = planned.schedule(pass_sampler, count, pass_seed(task.seed, index))
    part = render_stats(planned.scene, pass_sampler, seed=pass_seed(task.seed, index),
                        max_lanes=LANE_BUDGET, passes=subframes, on_pass=move,
                        filtered=task.filtered)
    if part.spp != count:  # the plan only uses counts the sampler keeps
        raise SamplerError(f"{task.sampler} rendered {part.spp} samples per pixel in pass "
                           f"{index}, planned {count}")
    return part


def memory_pass_spp(pixels: int, spp: int, executor: Executor | None = None) -> int | None:
    """Samples per pixel of a pass that fits the memory available, when the
    default pass (:func:`plan_passes`) would not; None when it fits (or no limit
    is known). A one-line :class:`McrtError` if even 1 sample per pixel cannot.
    With an ``executor`` that runs the passes elsewhere (a Dask cluster), the
    memory is its workers' (the least of theirs, their memory limits included)."""
    from ..core.memory import STATS_BYTES_PER_LANE, moments_bytes, require_memory

    available = task_memory(executor)
    budget = require_memory(pixels, moments_bytes(pixels), "this reference",
                            STATS_BYTES_PER_LANE, available,
                            " on a Dask worker")
    default = min(spp, DEFAULT_PASS_SPP, max(1, LANE_BUDGET // max(1, pixels)))
    if budget is None or budget >= pixels * default:
        return None
    fitting = max(1, budget // pixels)
    log.info("passes of %d samples per pixel fit in the memory available%s (%d lanes of about "
             "%d bytes); the default %d would not", fitting,
             "" if available is None else " on the Dask workers", budget, STATS_BYTES_PER_LANE,
             default)
    return fitting


def _merge(merged: StatsRender | None, part: StatsRender) -> StatsRender:
    """Fold one pass into the running total (Chan's merge, or the sums of
    filtered statistics added; seconds add up)."""
    if merged is None:
        return part
    total, more = merged.stats, part.stats
    stats: PixelStats | FilteredStats
    # The same call twice: each branch narrows both types for the type checker.
    if isinstance(total, FilteredStats) and isinstance(more, FilteredStats):  # noqa: SIM114
        stats = total.merge(more)
    elif isinstance(total, PixelStats) and isinstance(more, PixelStats):
        stats = total.merge(more)
    else:
        raise McrtError("cannot merge box-binned and filtered reference passes")
    return StatsRender(stats, part.spp, part.passes, merged.seconds + part.seconds)
