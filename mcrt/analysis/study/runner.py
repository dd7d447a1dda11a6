"""Running a study: every (scene, sampler, spp) cell, rendered per seed after a warm-up.

See :mod:`mcrt.analysis.study` for what is measured and how time is taken.
"""

from __future__ import annotations

import datetime
import functools
import logging
import os
import platform
import time
import uuid
import zlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ... import __version__
from ...core.executor import Executor, cluster_status
from ...core.job import Interrupted, Job, run_job
from ...core.machine import machine
from ...core.progress import Progress
from ...core.provenance import source_digest
from ...core.stats import PixelStats
from ...core.timing import Sample, round_orders
from ...errors import McrtError
from ..filter_noise import filter_correlation, variance_factor
from ..metrics import REL_MSE_EPSILON, reference_noise_floor
from . import summary
from .checks import check_config
from .conclude import conclude, timing_verdict
from .config import SamplerSpec, SceneSpec, StudyConfig, cell_keys
from .fields import Cell
from .seeds import SeedRender, SeedTask, collect, render_seed
from .store import StudyState, reference_fingerprint
from .summary import CellImages, CellRenders, CellScores, ReferenceImage

if TYPE_CHECKING:
    from ...core.scene_files import SceneSource
    from ...render.plan import PlannedScene

log = logging.getLogger("mcrt.compare")


@dataclass
class ReferenceInfo:
    """What a scene's reference is and what its noise adds to every MSE."""

    scene: str
    spp: int
    sampler: str
    seconds: float
    noise_floor: float           # mean squared standard error (adds to every MSE)
    rel_noise_floor: float       # the same, weighted like relMSE
    width: int
    height: int
    cached: bool = False         # taken from mcrt's reference cache, not rendered now


@dataclass
class StudyResult:
    """What a study measured; ``partial`` when it was interrupted (see ``progress``)."""

    config: StudyConfig
    references: dict[str, ReferenceInfo]
    cells: list[Cell]
    fits: list[dict[str, Any]]
    reference_images: dict[str, np.ndarray]
    images: dict[tuple[str, str], CellImages]
    environment: dict[str, Any]
    seconds: float
    #: the cell being rendered when the study was interrupted, with its seeds done
    #: (``{"scene", "sampler", "spp", "seeds_done", "seeds_total"}``), else None
    interrupted: dict[str, Any] | None = None
    #: cells taken from an earlier run's saved state instead of being rendered
    resumed_cells: int = 0
    #: how to resume a partial study (set by the command line)
    resume_command: str | None = None
    #: the command line that runs the study again from any folder (set by the
    #: command line; results.json records it)
    command: str | None = None
    #: every measured cell's images (mean, first seed, variance), keyed like
    #: :meth:`cell`: (scene, sampler label, spp requested)
    renders: dict[tuple[str, str, int], CellRenders] = field(default_factory=dict)
    #: how time was taken and whether it held (:func:`~.conclude.timing_verdict`)
    timing: dict[str, Any] = field(default_factory=dict)

    @property
    def biased(self) -> list[Cell]:
        """The cells whose bias is significant (Holm-corrected over the study)."""
        return [c for c in self.cells if c["biased"]]

    @property
    def partial(self) -> bool:
        """True when some cells of the configuration were not measured."""
        return len(self.cells) < self.config.cells

    @property
    def scenes(self) -> list[str]:
        """Scenes with a reference (all of them unless the study was interrupted)."""
        return [s.name for s in self.config.scenes if s.name in self.references]

    def pending(self) -> list[tuple[str, str, int]]:
        """(scene, sampler label, spp) of every cell not measured, in study order."""
        done = {(c["scene"], c["sampler"], c["spp_requested"]) for c in self.cells}
        return [key for key in cell_keys(self.config) if key not in done]

    def progress(self) -> dict[str, Any]:
        """Cells done / total, the interrupted cell, the pending cells (JSON-ready)."""
        return {"partial": self.partial, "cells_done": len(self.cells),
                "cells_total": self.config.cells, "cells_resumed": self.resumed_cells,
                "seeds_per_cell": len(self.config.seeds), "interrupted": self.interrupted,
                "pending": [{"scene": a, "sampler": b, "spp": c} for a, b, c in self.pending()],
                "resume": self.resume_command if self.partial else None}

    def cell(self, scene: str, sampler: str, spp: int) -> Cell:
        for c in self.cells:
            if (c["scene"], c["sampler"], c["spp_requested"]) == (scene, sampler, spp):
                return c
        raise KeyError((scene, sampler, spp))

    def fit(self, scene: str, sampler: str) -> dict[str, Any]:
        for f in self.fits:
            if (f["scene"], f["sampler"]) == (scene, sampler):
                return f
        raise KeyError((scene, sampler))


def environment() -> dict[str, Any]:
    """Versions and machine facts recorded with every study."""
    import drjit as dr
    import mitsuba as mi


    drjit_version = dr.__version__  # type: ignore[attr-defined]  # not in drjit's stubs
    return {"mcrt": __version__, "mcrt_source": source_digest(), "mitsuba": mi.__version__,
            "drjit": drjit_version, "variant": mi.variant(), "python": platform.python_version(),
            "platform": platform.platform(), "cpus": os.cpu_count(), "machine": machine(),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}


def run_study(config: StudyConfig, progress: bool = False,
              state: StudyState | None = None, executor: Executor | None = None,
              retime: bool = False) -> StudyResult:
    """Run every cell of a validated study; see :mod:`mcrt.analysis.study` for
    what is measured.

    With ``state``, cells saved there are taken instead of rendered and every
    cell finished now is added to it. With ``retime`` the cells saved in
    ``state`` are timed again (the timing protocol's rounds, timing-only renders)
    and keep their errors; cells not saved are left out. Ctrl-C raises the one
    :class:`~mcrt.core.job.Interrupted` with ``partial`` the result of the
    cells finished so far (``done`` of ``total`` cells).
    """
    if not config.effective_spp:
        check_config(config)
    if retime and (state is None or not state.cells):
        raise McrtError("nothing to retime: no measured cells are saved for this study; "
                        "run it without --retime first")
    bar = Progress(config.renders, progress, unit="render", desc="study", leave=True)
    run = _Run(config, state, bar)
    _warn_if_busy(run.env["machine"])
    run.executor = executor
    run.retiming = retime
    try:
        for spec in config.scenes:
            run.scene(spec)
    except KeyboardInterrupt:  # a render's own Interrupted is one too
        partial = run.result(run.current)
        raise Interrupted(partial, len(partial.cells), config.cells) from None
    finally:
        run.bar.close()
    return run.result()


def _warn_if_busy(facts: dict[str, Any]) -> None:
    """pyperf's "the system load is high" before a study times anything: other
    processes runnable now (the load average also counts this process's own
    recent work, so it only goes into the message)."""
    load, cpus = facts.get("loadavg") or [0.0], facts.get("cpus_usable") or 1
    others = facts.get("others_running") or 0
    if others >= 1:
        log.warning("the system load is high (load average %.2f on %d CPUs, %d other "
                    "processes running): times will be noisy; ratios pair renders of one "
                    "round, and the report names the cells whose timing was disturbed",
                    load[0], cpus, others)


# --------------------------------------------------------------------------- the steps


class _Scene:
    """Renders one scene as ``mcrt render`` does (planned once, when first needed)."""

    def __init__(self, spec: SceneSpec):
        self.spec = spec
        self._planned: PlannedScene | None = None
        self._source: SceneSource | None = None
        self._correlation: np.ndarray | None = None

    def pixel_correlation(self) -> np.ndarray:
        """Per-axis correlation of neighbouring pixels' noise from the film's
        reconstruction filter (``[1]``: box; :mod:`mcrt.analysis.filter_noise`)."""
        if self._correlation is None:
            film = self.planned().scene.sensors()[0].film()
            self._correlation = filter_correlation(film.rfilter())
        return self._correlation

    def planned(self) -> PlannedScene:
        """Planned as the study's checks planned it (this process's one plan of it)."""
        from ...render.loaded import planned_scene

        if self._planned is None:
            self._planned = planned_scene(self.source(), self.spec.params)
        return self._planned

    def source(self) -> SceneSource:
        """The scene as its seed tasks receive it."""
        from ...core.scene_files import SceneSource

        if self._source is None:
            self._source = SceneSource.of(self.spec.path, self.spec.params)
        return self._source


class _Run:
    """One run of a study: what is measured so far, and the steps that measure it."""

    def __init__(self, config: StudyConfig, state: StudyState | None, bar: Progress):
        self.config = config
        self.state = state
        self.bar = bar
        self.start = time.perf_counter()
        self.before = state.seconds if state is not None else 0.0
        self.env = environment()
        if state is not None and state.cells:
            self.env["resumed"] = True
        self.references: dict[str, ReferenceInfo] = {}
        self.reference_images: dict[str, np.ndarray] = {}
        self.cells: list[Cell] = []
        self.images: dict[tuple[str, str], CellImages] = {}
        self.renders: dict[tuple[str, str, int], CellRenders] = {}
        #: runs the seeds of a cell (:mod:`mcrt.core.executor`; in-process by default)
        self.executor: Executor | None = None
        #: time the saved cells again instead of measuring pending ones
        self.retiming = False
        #: this run's name for its tasks (each process warms a cell up once per run)
        self.token = uuid.uuid4().hex
        #: the cell being rendered (see StudyResult.interrupted)
        self.current: dict[str, Any] | None = None
        self.resumed = 0

    def seconds(self) -> float:
        """Study time so far, earlier runs included."""
        return self.before + time.perf_counter() - self.start

    def result(self, interrupted: dict[str, Any] | None = None) -> StudyResult:
        pixels = {name: ref.width * ref.height for name, ref in self.references.items()}
        fits = [summary.fit_sampler(scene, sampler.label, self.cells, pixels[scene])
                for scene in self.references for sampler in self.config.samplers]
        order = {key: i for i, key in enumerate(cell_keys(self.config))}
        measured = sorted(self.cells, key=lambda c: order[(c["scene"], c["sampler"],
                                                           c["spp_requested"])])
        cells = conclude(measured, fits, self.config.baseline, pixels)
        env = {**self.env, "machine_end": machine()}
        return StudyResult(config=self.config, references=self.references, cells=cells,
                           fits=fits, reference_images=self.reference_images,
                           images=self.images, environment=env, seconds=self.seconds(),
                           interrupted=interrupted, resumed_cells=self.resumed,
                           renders=self.renders, timing=timing_verdict(cells, env))

    def scene(self, spec: SceneSpec) -> None:
        """Every cell of one scene, against its reference: one group of cells per
        sample count (every sampler at that spp, timed in interleaved rounds)."""
        ref = self.reference(spec)
        scene = _Scene(spec)
        for spp in self.config.spp:
            if self.retiming:
                group = tuple((sampler, spp) for sampler in self.config.samplers
                              if self.resume(spec.name, sampler.label, spp))
            else:
                group = tuple((sampler, spp) for sampler in self.config.samplers
                              if not self.resume(spec.name, sampler.label, spp))
            if group:
                self.measure(scene, group, ref)

    def reference(self, spec: SceneSpec) -> ReferenceImage:
        """Render (or take from the cache) the reference of a scene and record it."""
        from ..reference import get_reference  # looked up now: tests replace it

        config = self.config.reference
        self.bar.describe(f"{spec.name}: reference")
        self.bar.note(f"[{spec.name}] reference: {config.sampler_text()}, {config.spp} spp")

        def on_pass(index: int, passes: int) -> None:
            self.bar.describe(f"{spec.name}: reference pass {index + 1}/{passes}")

        ref = get_reference(spec.path, spec.params, spp=config.spp, sampler=config.sampler,
                            seed=config.seed, spp_per_pass=config.spp_per_pass, on_pass=on_pass,
                            executor=self.executor, sampler_params=config.params)
        mean = np.asarray(ref.mean, dtype=np.float64)
        se = np.asarray(ref.standard_error, dtype=np.float64)
        var = se ** 2
        floor = reference_noise_floor(se)
        height, width = mean.shape[:2]
        self.references[spec.name] = ReferenceInfo(
            scene=spec.name, spp=int(ref.spp), sampler=config.sampler,
            seconds=float(ref.seconds), noise_floor=floor,
            rel_noise_floor=float(np.nanmean(var / (mean ** 2 + REL_MSE_EPSILON))
                                  if np.isfinite(var).any() else 0.0),
            width=int(width), height=int(height), cached=bool(getattr(ref, "cached", False)))
        self.reference_images[spec.name] = mean
        if self.state is not None:
            self.state.check_reference(spec.name, reference_fingerprint(mean, se))
        return ReferenceImage(mean=mean, var=var, floor=floor)

    def resume(self, scene: str, label: str, spp: int) -> bool:
        """Take the cell from the saved state, if it is there (with its images
        when the report shows them); False: it must be measured."""
        if self.state is None:
            return False
        saved = self.state.cells.get((scene, label, spp))
        if saved is None:
            return False
        saved_images = None
        if spp == self.config.image_spp:
            saved_images = self.state.images(scene, label)
            if saved_images is None:
                return False
            self.images[(scene, label)] = saved_images
        saved_renders = self.state.renders(scene, label, spp)
        if saved_renders is None:
            return False
        self.renders[(scene, label, spp)] = saved_renders
        self.cells.append(saved)
        self.resumed += 1
        self.bar.update(len(self.config.seeds) + 1)
        return True

    def measure(self, scene: _Scene, cells: tuple[tuple[SamplerSpec, int], ...],
                ref: ReferenceImage) -> None:
        """Render one group of a scene's cells (every pending sampler at one spp):
        each cell's warm-up, then :attr:`StudyConfig.rounds` rounds that render
        every cell once in a shuffled order (the seeds' renders first, scored,
        then timing-only ones); record each cell once its rounds are in.

        The group's renders are the tasks of one job, folded in task order; each
        task renders on whichever process (or cluster worker) runs it. With
        :attr:`retiming` every round is timing-only and the saved cells get new
        times (their errors are kept)."""
        name, seeds, rounds = scene.spec.name, self.config.seeds, self.config.rounds
        k, spp = len(seeds), cells[0][1]
        scene.planned()
        orders = round_orders(len(cells), rounds, zlib.crc32(f"{name}\0{spp}".encode()))
        task = SeedTask(tuple(sorted(scene.spec.params.items())), cells, tuple(seeds),
                        self.token, self.config.aliasing_draws, scene.pixel_correlation(),
                        tuple(tuple(o) for o in orders), 0 if self.retiming else k)

        def on_fold(done: int, folded: list[SeedRender]) -> None:
            cell, r = task.slot(done - 1)
            self.current = {"scene": name, "sampler": cells[cell][0].label, "spp": spp,
                            "seeds_done": min(r + 1, k), "seeds_total": k}
            self.bar.describe(f"{name}: {spp} spp, round {r + 1}/{rounds}")
            if self.executor is not None:
                self.bar.postfix(cluster_status(self.executor).strip(", "))
            self.bar.update(2 if r == 0 else 1)  # a cell's first task warmed it up too

        self.current = {"scene": name, "sampler": cells[0][0].label, "spp": spp,
                        "seeds_done": 0, "seeds_total": k}
        self.bar.describe(f"{name}: {spp} spp")
        job: Job[SeedRender, list[SeedRender]] = Job(
            f"{name}/{spp}spp", task.tasks, functools.partial(render_seed, task), collect,
            shared={"scene": scene.source(), "reference": ref.mean},
            groups=lambda index: task.slot(index)[0])  # a cell's renders share its warm-up
        folded = run_job(job, self.executor, on_fold=on_fold) or []
        by_cell: list[list[SeedRender]] = [[] for _ in cells]
        for rendered in folded:  # in task order: every cell's renders in round order
            by_cell[rendered.cell].append(rendered)
        for (sampler, _), renders in zip(cells, by_cell, strict=True):
            if self.retiming:
                self.retime(name, sampler, spp, [r.time for r in renders])
            else:
                self.record(scene, sampler, spp, ref, renders)
        self.current = None

    def retime(self, scene: str, sampler: SamplerSpec, spp: int, times: list[Sample]) -> None:
        """Give a saved cell the times of this run (``mcrt compare --retime``)."""
        index = next(i for i, c in enumerate(self.cells)
                     if (c["scene"], c["sampler"], c["spp_requested"]) == (scene, sampler.label,
                                                                            spp))
        cell = self.cells[index] = summary.retime_cell(self.cells[index], times)
        if self.state is not None:
            self.state.add(cell, None, self.seconds())

    def record(self, scene: _Scene, sampler: SamplerSpec, spp: int, ref: ReferenceImage,
               rendered: list[SeedRender]) -> None:
        """Score a cell's seeds, summarise the cell and record it (and save it)."""
        name, correlation = scene.spec.name, scene.pixel_correlation()
        scored = [r for r in rendered if r.values is not None]
        per_seed = [r.values for r in scored if r.values is not None]
        for values in per_seed:
            if values["nonfinite"]:  # counted and reported; metrics see zero error there
                log.warning("%s/%s/%d spp seed %d: %d pixels are NaN/Inf", name,
                            sampler.label, spp, values["seed"], values["nonfinite"])
        renders = [np.asarray(r.rgb, dtype=np.float64) for r in scored]
        stats = PixelStats.from_images(renders)
        cell = summary.summarise_cell(CellScores(name, sampler, spp, per_seed, stats,
                                         rfilter=scene.spec.rfilter,
                                         variance_factor=variance_factor(correlation),
                                         times=[r.time for r in rendered]), ref)
        images = None
        if spp == self.config.image_spp:
            images = summary.cell_images(renders, stats, ref.mean)
            self.images[(name, sampler.label)] = images
        views = self.renders[(name, sampler.label, spp)] = summary.cell_renders(renders, stats)
        self.cells.append(cell)
        self.current = None
        if self.state is not None:
            self.state.add(cell, images, self.seconds(), renders=views)
