"""Render a scene into a developed film or into exact per-pixel statistics.

Both are the pass engine (:func:`~mcrt.core.engine.run_passes`) with one
accumulator each: :class:`~mcrt.core.accumulators.FilmAccumulator` develops
the scene's film (reconstruction filter and all) and
:class:`~mcrt.core.accumulators.MomentsAccumulator` keeps float64 moments
``(n, mean, M2)`` per pixel (box-binned). Ctrl-C raises
:class:`~mcrt.core.job.Interrupted` carrying the passes finished so far and a
:class:`~mcrt.core.job.Checkpoint` to resume from; mcrt's samplers resume
bit-identically.
"""

from __future__ import annotations

import functools
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from . import pass_replay, replay
from .accumulators import FilmAccumulator, MomentsAccumulator, release_cached_memory
from .colour import SRGB_TO_XYZ, XYZ_TO_SRGB
from .engine import (
    MAX_LANES_PER_PASS,
    Accumulator,
    PassRun,
    fitted_shape,
    grid_pixels,
    keeps_lane_state,
    pass_shape,
    run_passes,
    sampling_integrator,
    supported_film,
)
from .executor import Executor, cluster_status, task_memory
from .inputs import check_max_lanes, check_sampler, check_scene, check_seed, check_sensor, check_spp
from .job import Checkpoint, Checkpointing, CheckpointPacer, Interrupted, Job, run_job
from .memory import STATS_BYTES_PER_LANE, film_bytes, moments_bytes, require_memory
from .pass_replay import PassReplay
from .progress import Progress
from .sampling import make_sampler

if TYPE_CHECKING:  # the statistics' types: imported by render_stats when it runs
    from .filtered import FilteredMomentsAccumulator, FilteredStats
    from .stats import PixelStats


@dataclass
class FilmRender:
    """A developed image and how it was made."""

    image: np.ndarray  # (height, width, channels), float32
    channels: list[str]
    spp: int
    passes: int
    seconds: float  # wall time of the passes, synchronised (kernel compilation included)
    pixels: int
    nonfinite: np.ndarray  # (grid height, grid width) samples left out
    state: Callable[[], Checkpoint] | None = None  # makes the checkpoint (on demand)
    aov_count: int = 0  # trailing channels that are the integrator's AOVs

    @property
    def checkpoint(self) -> Checkpoint | None:
        """The film's sums, to resume or develop again later (built when asked for:
        a render that writes its files never pays for a copy of its sums)."""
        return self.state() if self.state is not None else None

    @property
    def nonfinite_samples(self) -> int:
        """NaN/Inf samples detected and left out of the image (a sampled border's
        included: :attr:`nonfinite` covers the film's grid)."""
        return int(self.nonfinite.sum())

    @property
    def image_nonfinite(self) -> np.ndarray:
        """:attr:`nonfinite` of the image's pixels, (H, W): the grid without a
        sampled border's ring (the image is the grid's centre)."""
        h, w = (self.nonfinite.shape[i] - self.image.shape[i] for i in (0, 1))
        return self.nonfinite[h // 2:self.nonfinite.shape[0] - h + h // 2,
                              w // 2:self.nonfinite.shape[1] - w + w // 2]

    @property
    def samples(self) -> int:
        return self.pixels * self.spp

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")

    @property
    def base_channels(self) -> list[str]:
        """The film's own channels (``R G B [A]``, ``Y [A]`` or ``X Y Z [A]``)."""
        return self.channels[:len(self.channels) - self.aov_count]

    @property
    def aovs(self) -> dict[str, np.ndarray]:
        """The integrator's AOV channels by Mitsuba's names, (H, W) each."""
        first = len(self.channels) - self.aov_count
        return {name: self.image[..., first + i]
                for i, name in enumerate(self.channels[first:])}

    @property
    def rgb(self) -> np.ndarray:
        """The image as linear sRGB (H, W, 3), whatever the film's pixel format:
        XYZ converted back with the inverse of Mitsuba's matrix, luminance grey."""
        return linear_srgb(self.image, self.channels)


def srgb_to_xyz_matrix() -> np.ndarray:
    """Mitsuba's linear sRGB -> CIE XYZ matrix (``mi.srgb_to_xyz``), float64: a
    copy of :data:`mcrt.core.colour.SRGB_TO_XYZ`."""
    return SRGB_TO_XYZ.copy()  # [row, column]


def linear_srgb(image: np.ndarray, channels: list[str]) -> np.ndarray:
    """Linear sRGB (H, W, 3) of a developed film whose channels are labelled
    ``channels`` (Mitsuba's labels): ``R G B`` as they are, ``X Y Z`` through
    the inverse of :func:`srgb_to_xyz_matrix`, a luminance ``Y`` as grey."""
    head = channels[:3]
    if head == ["R", "G", "B"]:
        return image[..., :3]
    if head == ["X", "Y", "Z"]:
        return (image[..., :3].astype(np.float64) @ XYZ_TO_SRGB.T).astype(image.dtype)
    if channels[:1] == ["Y"]:
        return np.repeat(image[..., :1], 3, axis=-1)
    raise McrtError(f"cannot show a film with channels {', '.join(channels)} as RGB")


def film_base_channels(film: mi.Film) -> list[str]:
    """The channels an ``hdrfilm`` develops besides AOVs, by its ``pixel_format``
    (Mitsuba's labels: ``R G B [A]``, ``Y [A]``, ``X Y Z [A]``); empty if unknown."""
    match = re.search(r"pixel_format = (\w+)", str(film))  # Mitsuba prints "y", "ya", ...
    return list(_FORMAT_CHANNELS.get(match.group(1), "")) if match else []


def in_film_format(film: mi.Film, image: np.ndarray, alpha: bool) -> tuple[np.ndarray, list[str]]:
    """Linear sRGB pixels (H, W, 3, then an alpha channel if ``alpha``) in the
    channels ``film`` develops, as Mitsuba's ``hdrfilm`` forms them: luminance as
    ``Y`` (the Y row of :func:`srgb_to_xyz_matrix`), XYZ through that matrix,
    RGB as it is; the alpha kept where the format has one."""
    names = film_base_channels(film) or ["R", "G", "B", "A"]
    rgb = image[..., :3].astype(np.float64)
    if names[0] == "X":
        rgb = rgb @ SRGB_TO_XYZ.T
    elif names[0] == "Y":
        rgb = rgb @ SRGB_TO_XYZ[1][:, None]
    out = rgb.astype(image.dtype)
    if alpha:
        out = np.concatenate([out, image[..., 3:4]], axis=-1)
    return out, names[:out.shape[-1]]


@dataclass
class StatsRender:
    """Per-pixel sample statistics of a render and how they were made."""

    # PixelStats: box-binned over the film's sampled grid (crop window [+ border]);
    # FilteredStats: developed with the film's filter over its crop window.
    stats: PixelStats | FilteredStats
    spp: int
    passes: int
    seconds: float

    @property
    def samples(self) -> int:
        return self.stats.samples + int(self.stats.nonfinite.sum())


#: Channels of a developed film by its ``pixel_format`` (Mitsuba's labels).
_FORMAT_CHANNELS = {"rgb": "RGB", "rgba": "RGBA", "luminance": "Y", "luminance_alpha": "YA",
                    "y": "Y", "ya": "YA", "xyz": "XYZ", "xyza": "XYZA"}


def channel_names(film: mi.Film, count: int, aovs: list[str] | None = None) -> list[str]:
    """Names of the developed film's channels (as Mitsuba's bitmap labels them),
    read from the film's pixel format and the integrator's AOVs (asking the
    film for a bitmap would develop it once more)."""
    base = film_base_channels(film)
    if base and len(base) + len(aovs or []) == count:
        return base + list(aovs or [])
    try:
        bitmap: Any = film.bitmap()  # struct_() is missing from Mitsuba's stubs
        names = [f.name for f in bitmap.struct_()]
    except Exception:  # films without a bitmap view: generic names
        names = []
    if len(names) != count:
        names = (["R", "G", "B", "A"] + [f"C{i}" for i in range(4, count)])[:count]
    return names


def _arguments(who: str, scene: mi.Scene, sampler: mi.Sampler | str | None, spp: int | None,
               seed: int, sensor: int) -> tuple[mi.Sampler, int | None, int, int]:
    """A caller's arguments checked (:mod:`mcrt.core.inputs`), a sampler's name
    made into the sampler (at ``spp``, else the scene's sample count)."""
    check_scene(scene, who)
    spp, seed, sensor = check_spp(spp, who), check_seed(seed, who), check_sensor(scene, sensor, who)
    chosen = check_sampler(sampler, who)
    if chosen is None:
        chosen = scene.sensors()[sensor].sampler()
    elif isinstance(chosen, str):
        chosen = make_sampler(chosen, spp or scene.sensors()[sensor].sampler().sample_count())
    return chosen, spp, seed, sensor


def _prepare(scene: mi.Scene, sampler: mi.Sampler, spp: int | None,
             sensor: int) -> tuple[mi.Film, mi.Sampler, int]:
    sensor_obj = scene.sensors()[sensor]
    integrator = sampling_integrator(scene)
    film = supported_film(sensor_obj.film())
    # A clone renders: the caller's (or the scene's) sampler keeps its count, seed state
    # and film width, so a second render with it is the first's bits.
    sampler = sampler.clone()
    if spp is not None and spp != sampler.sample_count():
        sampler.set_sample_count(spp)
    film.prepare(integrator.aov_names())
    return film, sampler, sampler.sample_count()


def _restore_scene(on_pass: Callable[[int, int], None] | None) -> None:
    """Let a sub-frame hook put the scene back as the render found it: its
    ``restore()``, if it has one (motion blur's moves shapes), run after the
    passes, also when they stopped on an error or Ctrl-C."""
    restore = getattr(on_pass, "restore", None)
    if callable(restore):
        restore()


def _run(scene: mi.Scene, sampler: mi.Sampler, accumulator: Accumulator, run: PassRun,
         seed: int, sensor: int, progress: bool,
         on_pass: Callable[[int, int], None] | None,
         replayer: PassReplay | None = None) -> None:
    shape = run.shape
    bar = Progress(shape.passes, enabled=progress and shape.passes > 1, initial=run.done)
    bar.postfix(f"{shape.lanes} samples/pass")
    try:
        run_passes(scene, sampler, accumulator, run, seed, sensor=sensor, on_pass=on_pass,
                   progress=bar, replayer=replayer)
    finally:
        bar.close()


@dataclass(frozen=True)
class PassTasks:
    """A render's passes as the tasks of a job run by ``executor`` (a Dask
    cluster, say): ``task(index, passes=count, **shared)`` returns the sums of
    pass ``index`` of ``count`` alone, as :func:`render_film_pass` makes them,
    wherever it runs; they are added in pass order: the same bits as in-process."""

    task: Callable[..., Any]
    shared: dict[str, Any] = field(default_factory=dict)
    executor: Executor | None = None


def render_film(scene: mi.Scene, sampler: mi.Sampler | str | None = None,
                spp: int | None = None,
                seed: int = 0, sensor: int = 0, progress: bool = False,
                max_lanes: int | None = None, passes: int | None = None,
                on_pass: Callable[[int, int], None] | None = None,
                checkpoints: Checkpointing | None = None,
                tasks: PassTasks | None = None) -> FilmRender:
    """Render ``scene`` with ``sampler`` (default: the sensor's; a name such as
    ``"jittered"`` makes that sampler) at ``spp`` (default: the sampler's count).

    Returns the developed film (bit-identical across runs and thread counts),
    the effective sample count (samplers may round it), passes, wall time and
    the per-pixel count of non-finite samples (left out of the image).
    ``max_lanes`` (a positive int; None: no limit but the memory's) caps the
    samples of one pass; ``passes`` forces the number of passes (it must divide
    the sample count); ``on_pass(index, count)`` runs before each pass is traced
    (motion-blur sub-frames; its ``restore()``, if it has one, after the passes, also
    when they stop on an error or Ctrl-C). ``checkpoints``
    (:class:`~mcrt.core.job.Checkpointing`) resumes an interrupted render and
    saves the finished passes while it runs; ``tasks`` (:class:`PassTasks`)
    runs the passes elsewhere.

    A render without checkpoints, sub-frames, tasks or a progress bar over several
    passes is recorded the second time its (scene, sampler, pass shape) is rendered
    and replayed afterwards with each new seed (:mod:`mcrt.core.replay`): the same
    bits, without tracing; ``MCRT_REPLAY=0`` switches that off.

    The sampler given (or the scene's) is cloned, not changed: a second call with the
    same objects renders the same bits as a call with fresh ones.
    """
    sampler, spp, seed, sensor = _arguments("render_film", scene, sampler, spp, seed, sensor)
    max_lanes = check_max_lanes(max_lanes, "render_film")
    kept = checkpoints or Checkpointing()
    resume, save, save_every = kept.resume, kept.save, kept.every
    film, sampler, spp = _prepare(scene, sampler, spp, sensor)
    width, height = grid_pixels(film)
    channels = film.create_block().channel_count()
    if resume is not None and passes is None and max_lanes is None:
        passes = int(resume.meta.get("settings", [0, 0])[1]) or None  # its own pass size
    accumulator = FilmAccumulator(film, channels)
    # A sampler with per-lane state keeps folded passes to the usual size.
    fold_lanes = (max_lanes or MAX_LANES_PER_PASS) if keeps_lane_state(sampler) else None
    workers = task_memory(tasks.executor) if tasks is not None else None  # passes run there
    if workers is not None:  # (this process's own memory was checked by the command)
        require_memory(width * height, film_bytes(width * height, channels),
                       f"a {width}x{height} render", available=workers, where=" on a Dask worker")
    run = PassRun(fitted_shape(width * height, spp, max_lanes, passes,
                               fixed_bytes=film_bytes(width * height, channels),
                               fold=accumulator.fold, fold_lanes=fold_lanes, available=workers))
    if resume is not None:
        if resume.meta.get("settings") != [spp, run.shape.passes, seed]:
            raise McrtError("the saved partial render was made with other settings")
        accumulator.restore(resume.arrays)
        run.done, run.seconds = int(resume.meta["done"]), float(resume.meta["seconds"])

    def checkpoint(done: int = 0, seconds: float = 0.0) -> Checkpoint:
        return Checkpoint({"settings": [spp, run.shape.passes, seed], "done": done,
                           "seconds": seconds}, accumulator.state())

    def result(developed: Any = None) -> FilmRender:
        release_cached_memory(width * height)  # the passes' buffers
        developed = accumulator.develop() if developed is None else developed
        array = np.array(developed, dtype=np.float32)
        del developed
        release_cached_memory(width * height)
        done, seconds = run.done, run.seconds
        nonfinite = np.array(accumulator.nonfinite, dtype=np.uint32).reshape(height, width)
        aovs = list(sampling_integrator(scene).aov_names())
        names = channel_names(film, array.shape[-1], aovs)
        return FilmRender(image=array, channels=names,
                          spp=done * run.shape.group, passes=done, seconds=seconds,
                          pixels=width * height, nonfinite=nonfinite,
                          state=lambda: checkpoint(done, seconds), aov_count=len(aovs))

    pacer = CheckpointPacer(save_every, state_bytes=accumulator.state_bytes())
    started = run.done

    def before_pass(index: int, count: int) -> None:
        if save is not None and index > started:  # the passes before `index` are committed
            pacer.maybe(save, lambda: checkpoint(run.done, run.seconds))
        if on_pass is not None:
            on_pass(index, count)

    why = replay.why_not(scene, run.shape, progress, checkpoints=save, resume=resume,
                         subframes=on_pass, tasks=tasks)
    if why is None and run.done == 0:
        replayed = replay.render(scene, sampler, run.shape, seed, sensor, channels)
        if replayed is not None:  # the same bits as the passes below would give
            accumulator.sums, accumulator.nonfinite = replayed.sums, replayed.nonfinite
            run.done, run.seconds = run.shape.passes, replayed.seconds
            return result(replayed.image)
    elif why is not None:
        replay.note(why)
    try:
        if tasks is None:
            _run(scene, sampler, accumulator, run, seed, sensor, progress,
                 before_pass if save is not None else on_pass,
                 _pass_replay(scene, sampler, run, seed, sensor, accumulator, on_pass))
        else:
            task = functools.partial(tasks.task, passes=run.shape.passes)
            _run_tasks(run, accumulator, Job("film", run.shape.passes, task, _add_sums,
                                             shared=dict(tasks.shared)),
                       tasks.executor, progress, pacer if save is not None else None,
                       lambda state: save(Checkpoint(  # type: ignore[misc]
                           {"settings": [spp, run.shape.passes, seed], "done": run.done,
                            "seconds": run.seconds}, state)))
    except KeyboardInterrupt:
        partial = result()
        raise Interrupted(partial if run.done else None, run.done, run.shape.passes,
                          state=partial.checkpoint) from None
    finally:
        _restore_scene(on_pass)
    return result()


def render_film_pass(scene: mi.Scene, sampler: mi.Sampler, index: int, passes: int,
                     seed: int = 0, sensor: int = 0,
                     on_pass: Callable[[int, int], None] | None = None
                     ) -> dict[str, np.ndarray]:
    """The film sums of pass ``index`` alone (of ``passes``) of the render
    :func:`render_film` makes with the same arguments: what a task of a
    distributed render returns. The sampler continues exactly to that pass
    (mcrt's samplers are counter-based; Mitsuba's cannot, see
    :func:`~mcrt.core.engine.resume_seed`)."""
    film, sampler, spp = _prepare(scene, sampler, None, sensor)
    channels = film.create_block().channel_count()
    width, height = grid_pixels(film)
    run = PassRun(pass_shape(width * height, spp, passes=passes), done=index)
    accumulator = FilmAccumulator(film, channels)
    try:
        run_passes(scene, sampler, accumulator, run, seed, sensor=sensor, on_pass=on_pass,
                   stop=index + 1, replayer=_pass_replay(scene, sampler, run, seed, sensor,
                                                         accumulator, on_pass, eager=False))
    finally:
        _restore_scene(on_pass)
    return accumulator.state()


def _pass_replay(scene: mi.Scene, sampler: mi.Sampler, run: PassRun, seed: int, sensor: int,
                 accumulator: FilmAccumulator, subframes: Callable[[int, int], None] | None,
                 eager: bool | None = None) -> PassReplay | None:
    """The replayer of a film render's passes, or None (said why, once).
    Recording at the first pass pays off when a few more passes follow."""
    sums = accumulator.ext[0] * accumulator.ext[1] * accumulator.channels
    why = pass_replay.why_not(scene, sampler, subframes, sums)
    if why is not None:
        replay.note(f"passes: {why}")
        return None
    if eager is None:
        eager = run.shape.passes - run.done >= 3
    return PassReplay(scene, sampler, run.shape, seed, sensor, accumulator.channels, eager)


def _add_sums(total: dict[str, np.ndarray] | None,
              part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Fold of pass sums in pass order: float64 adds, as the device adds them."""
    if total is None:
        return {name: value.copy() for name, value in part.items()}
    return {name: total[name] + part[name] for name in total}


def _run_tasks(run: PassRun, accumulator: FilmAccumulator, job: Job,
               executor: Executor | None,
               progress: bool, pacer: CheckpointPacer | None,
               save: Callable[[dict[str, np.ndarray]], object]) -> None:
    """Run the passes ``run.done ..`` as the tasks of ``job`` and fold their sums
    into ``accumulator`` (also when interrupted: the folded passes are kept)."""
    shape = run.shape
    bar = Progress(shape.passes, enabled=progress and shape.passes > 1, initial=run.done)
    start, before = time.perf_counter(), run.seconds

    def on_fold(count: int, total: dict[str, np.ndarray]) -> None:
        run.done, run.seconds = count, before + time.perf_counter() - start
        bar.postfix(cluster_status(executor).strip(", "))
        bar.update(1)
        if pacer is not None:
            pacer.maybe(save, lambda: total)

    try:
        total = run_job(job, executor, done=run.done, total=accumulator.state(),
                        on_fold=on_fold)
    except Interrupted as stop:
        if stop.partial is not None:
            accumulator.restore(stop.partial)
        raise KeyboardInterrupt from None
    finally:
        bar.close()
    if total is not None:
        accumulator.restore(total)


def render_stats(scene: mi.Scene, sampler: mi.Sampler | str | None = None,
                 spp: int | None = None, seed: int = 0,
                 sensor: int = 0, progress: bool = False, max_lanes: int | None = None,
                 passes: int | None = None,
                 on_pass: Callable[[int, int], None] | None = None,
                 filtered: bool = False) -> StatsRender:
    """Render ``scene`` and return exact per-pixel sample moments (float64).

    The pixel grid is the film's sampled grid; a sample belongs to the pixel it
    was drawn in (box filter), whatever the scene's reconstruction filter.
    With ``filtered`` and a film whose filter is not a box, the statistics are
    instead :class:`~mcrt.core.filtered.FilteredStats` of the film's developed
    pixels (its own filter, float64). ``sampler``, ``max_lanes``, ``passes`` and
    ``on_pass`` as in :func:`render_film`.
    """
    sampler, spp, seed, sensor = _arguments("render_stats", scene, sampler, spp, seed, sensor)
    max_lanes = check_max_lanes(max_lanes, "render_stats")
    film, sampler, spp = _prepare(scene, sampler, spp, sensor)
    width, height = grid_pixels(film)
    run = PassRun(fitted_shape(width * height, spp, max_lanes, passes, STATS_BYTES_PER_LANE,
                               moments_bytes(width * height)))
    accumulator: MomentsAccumulator | FilteredMomentsAccumulator = MomentsAccumulator(film)
    if filtered and not film.rfilter().is_box_filter():
        from .filtered import FilteredMomentsAccumulator

        accumulator = FilteredMomentsAccumulator(film)
    start = time.perf_counter()
    try:
        _run(scene, sampler, accumulator, run, seed, sensor, progress, on_pass)
    finally:
        _restore_scene(on_pass)
    dr.sync_thread()
    return StatsRender(stats=accumulator.stats(), spp=spp, passes=run.done,
                       seconds=time.perf_counter() - start)


__all__ = ["FilmRender", "PassTasks", "StatsRender", "channel_names", "film_base_channels",
           "in_film_format", "linear_srgb", "render_film", "render_stats", "srgb_to_xyz_matrix"]
