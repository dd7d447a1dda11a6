"""Planned scenes kept per process, so that a job's tasks load each scene once.

A job's tasks receive their scene as a :class:`~mcrt.core.scene_files.SceneSource`
(in this process) or a :class:`~mcrt.core.scene_files.SceneBundle` (on a
cluster worker); :func:`planned_scene` plans it (:func:`~mcrt.render.plan.plan_scene`)
the first time and returns the same :class:`~mcrt.render.plan.PlannedScene` to
the job's later tasks, keyed by the scene's content digest and parameters (a
changed file is a new scene). The few most recent scenes are kept.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

from ..core.scene_files import SceneBundle, SceneSource, local_scene
from .plan import PlannedScene, plan_scene

#: Scenes kept per process (a study renders its scenes one after the other).
KEPT = 4

_planned: OrderedDict[tuple[str, str, tuple[tuple[str, str], ...]], PlannedScene] = \
    OrderedDict()


def _key(path: str | Path, digest: str, params: dict[str, str] | None
         ) -> tuple[str, str, tuple[tuple[str, str], ...]]:
    return digest, str(path), tuple(sorted((params or {}).items()))


def _keep(key: tuple[str, str, tuple[tuple[str, str], ...]], planned: PlannedScene) -> None:
    _planned[key] = planned
    _planned.move_to_end(key)
    while len(_planned) > KEPT:
        _planned.popitem(last=False)


def remember_planned(source: SceneSource, params: dict[str, str] | None,
                     planned: PlannedScene) -> None:
    """Keep a scene planned by the caller for this process's tasks."""
    _keep(_key(source.path, source.digest, params), planned)


def planned_scene(scene: SceneSource | SceneBundle,
                  params: dict[str, str] | None = None) -> PlannedScene:
    """The scene planned as ``mcrt render`` plans it, loaded once per process."""
    path, digest = local_scene(scene)
    key = _key(path, digest, params)
    planned = _planned.get(key)
    if planned is None:
        planned = plan_scene(path, dict(params or {}))
    _keep(key, planned)
    return planned
