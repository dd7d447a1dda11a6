"""Planning a scene: read it once, decide its effects, edit and build it.

The description is read once and, in the common case, instantiated once: the
decisions that need no geometry come first and their edits go into the
description; the scene built from it measures depth of field and motion. Only
a thin lens found negligible or area lights switched off build it again.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import mitsuba as mi

from ...core.engine import check_rfilter, sampling_integrator
from ...core.sampling import sampler_name
from ...errors import SceneError
from ..motion import SUBFRAME_STEP_PX
from ..scene import SceneDescription, read_scene
from .edits import bake_pose, edit_built, edit_description, name_area_lights, rendered_camera
from .effects import ScanFacts, SceneFacts, decide_described, decide_measured
from .integrator import choose_integrator, cut_out_caveat, delta_weight_caveat
from .model import RenderPlan, check_overrides
from .nodes import integer
from .planned import PlannedScene
from .scan import AuthoredIntegrator, scan_scene


def plan_scene(path: str | Path, params: dict[str, str] | None = None,
               overrides: dict[str, bool] | None = None,
               step_px: float = SUBFRAME_STEP_PX, wrap: str | None = None) -> PlannedScene:
    """Analyse the scene at ``path`` and build the scene its plan renders.

    ``params`` substitutes the scene's ``$key`` parameters; ``overrides``
    (``{"dof": False, "motion": True}``) switches effects off or forces them on.
    The ``distribution`` integrator a plan may choose is registered by
    ``import mcrt`` (:func:`mcrt.register`). ``wrap`` nests the planned
    integrator in that integrator plugin (``"multisample"``: ``mcrt render
    --multisample``).
    """
    overrides = check_overrides(overrides)
    desc = read_scene(path, params)
    scan = scan_scene(desc)  # also strips the motion properties
    if scan.sensor < 0:  # Mitsuba's own error first (a plugin it cannot find, ...)
        _instantiate(desc)
        raise SceneError(f"{path} has no sensor to render from")
    name_area_lights(desc, scan)
    described = ScanFacts.of(desc, scan)
    author = AuthoredIntegrator.of(desc, scan)
    decisions = decide_described(described, author, overrides)
    integrator, integrator_reason = choose_integrator(described, author, decisions)
    edit_description(described, decisions, integrator if author.replannable else None)
    if wrap is not None:
        from ..multisample import wrap_integrator  # only for --multisample

        wrap_integrator(desc, wrap)
    facts = SceneFacts.built(described, _instantiate(desc))
    decide_measured(decisions, facts)
    scene = _instantiate(desc) if edit_built(facts, decisions) else facts.scene
    sampling_integrator(scene)  # one the engine drives (not ptracer, stokes, ...), or say so
    _check_film(scene, path)
    bake_pose(scene, decisions, facts.shutter[0])

    sampler = scene.sensors()[0].sampler()
    spp = sampler.sample_count()
    notes = decisions.notes + _rounding_note(desc, sampler)
    streak = decisions.streak_px
    plan = RenderPlan(
        scene=str(path), effects=decisions.effects, camera=rendered_camera(facts),
        scene_camera=facts.scene_camera, integrator=integrator,
        integrator_reason=integrator_reason, scene_integrator=author.label,
        shutter=facts.shutter, sampler=sampler_name(sampler), spp=spp,
        motions=decisions.motions,
        streak_px=streak if math.isfinite(streak) else float(spp) * step_px,
        coc_px=decisions.coc_px, notes=notes,
        caveats=(cut_out_caveat(facts, integrator, author)
                 + delta_weight_caveat(scene, integrator, author)),
        aperture_sample=bool(scene.sensors()[0].needs_aperture_sample()),
        wavelength_sample=bool(mi.is_spectral))
    planned = PlannedScene(plan, scene, decisions.motions, step_px)
    planned.plan.subframes = planned.subframes_for(plan.spp)
    return planned


def _check_film(scene: mi.Scene, path: str | Path) -> None:
    """A film with no pixels (``-D res=0``, ``width = 0``) is refused up front, in
    one line, before any command would fail on it deep inside a render."""
    film = scene.sensors()[0].film()
    width, height = (int(v) for v in film.crop_size())
    if width < 1 or height < 1:
        raise SceneError(f"{path}: the film has {width}x{height} pixels; an image needs at "
                         f"least 1x1 (check the film's width and height, or the $parameters "
                         f"that set them)")
    check_rfilter(film, f"{path}: ")


def _instantiate(desc: SceneDescription) -> mi.Scene:
    """Build the scene; mcrt's samplers keep quiet about rounding the scene's
    sample count, which a render may never use (:func:`_rounding_note` says it)."""
    logger = logging.getLogger("mcrt.samplers")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        return desc.instantiate()
    finally:
        logger.setLevel(level)


def _rounding_note(desc: SceneDescription, sampler: mi.Sampler) -> list[str]:
    """A note when the scene's sampler does not take the sample count it is given."""
    for node in desc.nodes:
        if node.type == mi.ObjectType.Sampler and "sample_count" in node.props:
            asked = integer(node.props, "sample_count")
            if asked != sampler.sample_count():
                return [f"the scene's {sampler_name(sampler)} sampler takes sample_count "
                        f"{asked} as {sampler.sample_count()}"]
    return []
