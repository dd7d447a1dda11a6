"""Planned scenes kept per process, so that a job's tasks load each scene once.

A job's tasks receive their scene as a :class:`~mcrt.core.scene_files.SceneSource`
(in this process) or a :class:`~mcrt.core.scene_files.SceneBundle` (on a
cluster worker); :func:`planned_scene` plans it (:func:`~mcrt.render.plan.plan_scene`)
the first time and returns the same :class:`~mcrt.render.plan.PlannedScene` to
the job's later tasks, keyed by the scene's content digest and parameters (a
changed file is a new scene) and the Mitsuba variant (a scene of another variant
is another scene: its objects are that variant's classes). The few most recent
scenes are kept.

It is also the one place a client plans a scene it was given by path (the study's
checks, its references, its cells and its report's headers all ask it), so a
study of up to :data:`KEPT` scenes plans each once (with more, a scene the later
ones pushed out is planned again for its cells, and for the report's headers).

:func:`film_pass` is a pass of ``mcrt render`` as such a task (``--cluster``).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mitsuba as mi
import numpy as np

from ..core.render import render_film_pass
from ..core.sampling import make_sampler, quiet_sampler_warnings, sampler_params
from ..core.scene_files import SceneBundle, SceneSource, local_scene
from .plan import PlannedScene, plan_scene

#: Scenes kept per process (a study renders its scenes one after the other).
KEPT = 4

_planned: OrderedDict[tuple, PlannedScene] = OrderedDict()


def _key(path: str | Path, digest: str, params: dict[str, str] | None,
         overrides: dict[str, bool] | None = None, wrap: str | None = None) -> tuple:
    return (mi.variant(), digest, str(path), tuple(sorted((params or {}).items())),
            tuple(sorted((overrides or {}).items())), wrap)


def _keep(key: tuple, planned: PlannedScene) -> None:
    _planned[key] = planned
    _planned.move_to_end(key)
    while len(_planned) > KEPT:
        _planned.popitem(last=False)


def remember_planned(source: SceneSource, params: dict[str, str] | None,
                     planned: PlannedScene, overrides: dict[str, bool] | None = None,
                     wrap: str | None = None) -> None:
    """Keep a scene planned by the caller for this process's tasks."""
    _keep(_key(source.path, source.digest, params, overrides, wrap), planned)


def planned_scene(scene: SceneSource | SceneBundle | str | Path,
                  params: dict[str, str] | None = None,
                  overrides: dict[str, bool] | None = None,
                  wrap: str | None = None) -> PlannedScene:
    """The scene planned as ``mcrt render`` plans it (with its ``--effect``
    overrides and integrator ``wrap``), loaded once per process. A path is
    the scene's XML file (its digest read now: an edited file is planned again)."""
    if isinstance(scene, (str, Path)):
        given = scene
        try:
            scene = SceneSource.of(given, params)
        except OSError:  # unreadable: the planner says so as it says it for `mcrt render`
            return plan_scene(given, dict(params or {}), dict(overrides or {}), wrap=wrap)
    path, digest = local_scene(scene)
    key = _key(path, digest, params, overrides, wrap)
    planned = _planned.get(key)
    if planned is None:
        planned = plan_scene(path, dict(params or {}), dict(overrides or {}), wrap=wrap)
    _keep(key, planned)
    return planned


@dataclass(frozen=True)
class FilmPassTask:
    """What every pass of an ``mcrt render`` needs besides its scene and index,
    for :func:`film_pass` (``mcrt render --cluster``)."""

    params: tuple[tuple[str, str], ...]
    overrides: tuple[tuple[str, bool], ...]
    wrap: str | None
    sampler: str
    sampler_params: tuple[tuple[str, Any], ...]
    spp: int
    seed: int
    base_seed: int = 0  # the sampler's own seed property (a scene may author one)
    #: the scene's own sampler (no ``--sampler``): its parameters are read from the
    #: scene as the task loaded it, so that a file it names (a ``pointset``'s
    #: ``filename``) is the scene bundle's copy, not the client's path
    scene_sampler: bool = False


def film_pass(task: FilmPassTask, index: int, *, passes: int,
              scene: SceneSource | SceneBundle) -> dict[str, np.ndarray]:
    """The film sums of pass ``index`` (of ``passes``) of the render, alone, as
    :func:`~mcrt.core.render.render_film_pass` makes them, with the scene planned
    as ``mcrt render`` plans it (its motion sub-frames too)."""
    planned = planned_scene(scene, dict(task.params), dict(task.overrides), task.wrap)
    params = dict(task.sampler_params)
    if task.scene_sampler:  # the same scene, its files where this machine has them
        params = sampler_params(planned.scene.sensors()[0].sampler())
    with quiet_sampler_warnings():  # (the client has said it once)
        sampler = make_sampler(task.sampler, task.spp, task.base_seed, **params)
    _, on_pass = planned.schedule(sampler, task.spp, task.seed)
    return render_film_pass(planned.scene, sampler, index, passes, seed=task.seed,
                            on_pass=on_pass)
