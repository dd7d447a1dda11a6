"""One render of a study's group of cells: the task a process (or a cluster worker) runs.

:class:`SeedTask` says what the group's renders need, :func:`render_seed` renders
task ``i`` (warming its cell up first in each process), times it by the protocol
of :mod:`mcrt.core.timing` and, for a seed's render, scores it against the
reference (:func:`score_seed`) where it was rendered: the client only folds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.timing import Sample, timed
from ...errors import McrtError
from ..aliasing import AliasingScore, aliasing_score, measurable
from ..metrics import delta_e_2000, error_map, mse, rel_mse, srgb_to_lab
from .config import WARMUP_SEED, SamplerSpec

if TYPE_CHECKING:
    from ...core.render import FilmRender
    from ...core.scene_files import SceneBundle, SceneSource


@dataclass(frozen=True)
class SeedTask:
    """What the renders of one group of a scene's cells (every pending sampler at
    one sample count) need besides the scene and the task's index.

    The group's renders come in rounds (:mod:`mcrt.core.timing`): round ``r``
    renders every cell once, in the order ``orders[r]``, so task ``i`` is cell
    ``orders[i // n][i % n]`` (``n`` cells) in round ``i // n``. Rounds before
    ``scored`` render the study's seeds (round ``r``: ``seeds[r]``) and are scored;
    later rounds (or all, for ``mcrt compare --retime``) are timed only."""

    params: tuple[tuple[str, str], ...]
    cells: tuple[tuple[SamplerSpec, int], ...]  # (sampler, spp) of each cell, in order
    seeds: tuple[int, ...]
    run: str  # the study run: each process warms a cell up once per run
    aliasing_draws: int
    correlation: np.ndarray  # the film filter's pixel correlation (aliasing null model)
    orders: tuple[tuple[int, ...], ...] = ()  # the cells' order in every round
    scored: int = 0  # rounds whose renders are scored (the seeds')

    @property
    def tasks(self) -> int:
        return len(self.cells) * len(self.orders)

    def slot(self, index: int) -> tuple[int, int]:
        """(cell, round) of task ``index``."""
        r, position = divmod(index, len(self.cells))
        return self.orders[r][position], r


@dataclass
class SeedRender:
    """One render of a cell, as a task returns it: its time, and for a seed's
    render its metrics and image (scored where it was rendered: the client only
    folds)."""

    cell: int  # index into the task's cells
    round: int
    time: Sample
    values: dict[str, Any] | None = None  # the per-seed values of the study's cell fields
    rgb: np.ndarray | None = None  # (H, W, 3) float32, linear sRGB


#: (run, scene digest, scene parameters, sampler label, spp) of the cells this
#: process warmed up (two scenes of one file differ by their parameters).
_warmed: set[tuple[str, str, tuple[tuple[str, str], ...], str, int]] = set()


def render_seed(task: SeedTask, index: int, scene: SceneSource | SceneBundle,
                reference: np.ndarray) -> SeedRender:
    """Task ``index`` of a group: one render of a cell, rendered as ``mcrt render``
    renders it, timed by :func:`mcrt.core.timing.timed`, and (in a scored round)
    scored against ``reference`` (the mean image). The first task of a cell in a
    process first renders an untimed warm-up (kernels compiled and cached, the
    render recorded for replay), so every timed render is warm."""
    import drjit as dr

    from ...core import render, replay  # looked up now: tests wrap render_film
    from ...core.sampling import make_sampler, quiet_sampler_warnings
    from ...render.loaded import planned_scene

    planned = planned_scene(scene, dict(task.params))
    cell_index, r = task.slot(index)
    spec, spp = task.cells[cell_index]
    cell = (task.run, getattr(scene, "digest", ""), task.params, spec.label, spp)

    def run(seed: int) -> FilmRender:
        with quiet_sampler_warnings():
            sampler = make_sampler(spec.name, spp, **spec.params)
        subframes, move = planned.schedule(sampler, None, seed)
        return render.render_film(planned.scene, sampler, seed=seed, passes=subframes,
                                  on_pass=move)

    if cell not in _warmed:
        with replay.warming_up():  # recorded now: every timed render replays
            run(WARMUP_SEED)  # untimed
        _warmed.add(cell)
    seed = task.seeds[r % len(task.seeds)]
    rendered, sample = timed(lambda: run(seed), dr.sync_thread)
    if r >= task.scored:
        return SeedRender(cell_index, r, sample)
    rgb = np.asarray(rendered.rgb, np.float32)
    values = score_seed(rgb, reference, seed, rendered.spp, sample.wall, task.aliasing_draws,
                        task.correlation)
    values["cpu_seconds"] = sample.cpu
    return SeedRender(cell_index, r, sample, values, rgb)


#: (reference, its CIELAB) of the last references this process scored against: a
#: study scores every render of a scene against one reference array.
_reference_labs: list[tuple[np.ndarray, np.ndarray]] = []


def _reference_lab(reference: np.ndarray) -> np.ndarray:
    """:func:`~mcrt.analysis.metrics.srgb_to_lab` of ``reference``, computed once
    per reference array (held here, so its identity is not reused)."""
    for held, lab in _reference_labs:
        if held is reference:
            return lab
    lab = srgb_to_lab(reference)
    _reference_labs[:] = [(reference, lab), *_reference_labs[:3]]
    return lab


def score_seed(rgb32: np.ndarray, reference: np.ndarray, seed: int, spp: int, seconds: float,
               draws: int, correlation: np.ndarray | None) -> dict[str, Any]:
    """A seed's metrics against the reference mean: NaN/Inf pixels are counted
    (``nonfinite``) and measured as zero error; ``correlation`` (the film
    filter's) shapes the aliasing score's null model."""
    rgb = np.asarray(rgb32, dtype=np.float64)
    if rgb.shape != reference.shape:
        raise McrtError(f"render shape {rgb.shape} differs from the reference's "
                        f"{reference.shape}")
    bad = np.logical_not(np.all(np.isfinite(rgb), axis=-1))
    clean = np.where(bad[..., None], reference, rgb) if bad.any() else rgb
    # An image under 32 pixels on a side has no aliasing score (n/a), only errors.
    score = aliasing_score(error_map(clean, reference), null_draws=draws, seed=seed,
                           correlation=correlation) if measurable(rgb.shape) \
        else AliasingScore.unmeasured(null_draws=draws)
    return {"seed": seed, "spp": int(spp), "seconds": seconds,
            "mean_error": float(np.mean(clean - reference)),
            "mse": mse(clean, reference), "rel_mse": rel_mse(clean, reference),
            "delta_e": delta_e_2000(clean, reference, reference_lab=_reference_lab(reference)),
            "nonfinite": int(bad.sum()), "aliasing": score.as_dict()}


def collect(total: list[Any] | None, result: Any) -> list[Any]:
    """Fold of the seeds' results: their list, in task order (a finished cell's
    are taken out by the study as it records the cell)."""
    return [*(total or []), result]


__all__ = ["SeedRender", "SeedTask", "collect", "render_seed", "score_seed"]
