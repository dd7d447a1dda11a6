"""Planning a scene: read it once, decide its effects, edit and build it."""

from __future__ import annotations

import math
from pathlib import Path

from ...core.sampling import sampler_name
from ..motion import SUBFRAME_STEP_PX
from ..scene import read_scene
from .edits import apply_plan, name_area_lights
from .effects import SceneFacts, decide_effects
from .integrator import choose_integrator
from .model import RenderPlan, check_overrides
from .planned import PlannedScene
from .scan import AuthoredIntegrator, scan_scene


def plan_scene(path: str | Path, params: dict[str, str] | None = None,
               overrides: dict[str, bool] | None = None,
               step_px: float = SUBFRAME_STEP_PX) -> PlannedScene:
    """Analyse the scene at ``path`` and build the scene its plan renders.

    ``params`` substitutes the scene's ``$key`` parameters; ``overrides``
    (``{"dof": False, "motion": True}``) switches effects off or forces them on.
    The ``distribution`` integrator a plan may choose is registered by
    ``import mcrt`` (:func:`mcrt.register`).
    """
    overrides = check_overrides(overrides)
    desc = read_scene(path, params)
    scan = scan_scene(desc)  # also strips the motion properties
    name_area_lights(desc, scan)
    facts = SceneFacts.of(desc, scan, desc.instantiate())
    author = AuthoredIntegrator.of(desc, scan)
    decisions = decide_effects(facts, author, overrides)
    integrator, integrator_reason = choose_integrator(facts, author, decisions)
    camera = apply_plan(facts, decisions, integrator if author.replannable else None)
    scene = desc.instantiate()

    sampler = scene.sensors()[0].sampler()
    spp = sampler.sample_count()
    streak = decisions.streak_px
    plan = RenderPlan(
        scene=str(path), effects=decisions.effects, camera=camera,
        scene_camera=facts.scene_camera, integrator=integrator,
        integrator_reason=integrator_reason, scene_integrator=author.label,
        shutter=facts.shutter, sampler=sampler_name(sampler), spp=spp,
        motions=decisions.motions,
        streak_px=streak if math.isfinite(streak) else float(spp) * step_px,
        coc_px=decisions.coc_px, notes=decisions.notes)
    planned = PlannedScene(plan, scene, decisions.motions, step_px)
    planned.plan.subframes = planned.subframes_for(plan.spp)
    return planned
