"""The per-effect decisions: does the scene have the effect, does it render, why.

Each ``decide_*`` function looks at the scene as authored and records one
:class:`~.model.Effect` in :class:`Decisions`, honouring the user's overrides;
see the table in :mod:`mcrt.render.plan`. Most decisions read the description
only (:class:`ScanFacts`), so the plan can edit it before the one
instantiation; depth of field and motion measure the instantiated scene
(:class:`SceneFacts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mitsuba as mi

from ...errors import McrtError
from ..motion import NEGLIGIBLE_STREAK_PX, Motion
from ..scene import SceneDescription
from .camera import CameraModel, circle_of_confusion, streak_px
from .model import EFFECTS, Effect, listing
from .nodes import children, scalar
from .scan import (
    DELTA_EMITTERS,
    NO_LIGHTING,
    VOLUMETRIC,
    AuthoredIntegrator,
    RoughBSDF,
    Scan,
    environment_emitters,
)

#: Depth of field is negligible when no visible depth blurs by this many pixels.
DOF_NEGLIGIBLE_PX = 0.5
#: A rough BSDF whose alpha is below this is rendered as its smooth counterpart.
GLOSSY_MIN_ALPHA = 1e-3


@dataclass
class ScanFacts:
    """The scene as authored, as its description says it (before any edit)."""

    desc: SceneDescription
    scan: Scan
    scene_camera: str                   # the sensor's plugin
    shutter: tuple[float, float]        # (open, close)
    lens: tuple[float, float] | None    # thinlens (aperture radius, focus distance)

    @classmethod
    def of(cls, desc: SceneDescription, scan: Scan) -> ScanFacts:
        props = desc.nodes[scan.sensor].props
        t_open = float(scalar(props, "shutter_open")) if "shutter_open" in props else 0.0
        t_close = float(scalar(props, "shutter_close")) if "shutter_close" in props else 0.0
        lens = None
        if props.plugin_name() == "thinlens":  # both are required: Mitsuba says so if absent
            radius, focus = (float(scalar(props, k)) if k in props else math.nan
                             for k in ("aperture_radius", "focus_distance"))
            lens = (radius, focus)
        return cls(desc, scan, props.plugin_name(), (t_open, max(t_open, t_close)), lens)

    @property
    def shutter_is_open(self) -> bool:
        return self.shutter[1] > self.shutter[0]

    def node_id(self, node: int) -> str:
        return self.desc.nodes[node].props.id()


@dataclass
class SceneFacts(ScanFacts):
    """The scene as authored and instantiated (after the edits that need no
    geometry: its shutter is closed, its integrator may be the plan's)."""

    scene: mi.Scene
    sensor: mi.Sensor
    camera: CameraModel

    @classmethod
    def built(cls, facts: ScanFacts, scene: mi.Scene) -> SceneFacts:
        sensor = scene.sensors()[0]
        return cls(facts.desc, facts.scan, facts.scene_camera, facts.shutter, facts.lens,
                   scene, sensor, CameraModel.of(sensor))


@dataclass
class Decisions:
    """The effects decided so far, with what the later steps need of them."""

    overrides: dict[str, bool]
    effects: dict[str, Effect] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    to_smooth: list[RoughBSDF] = field(default_factory=list)  # rough BSDFs rendered smooth
    coc_px: tuple[float, float] | None = None
    motions: list[Motion] = field(default_factory=list)       # the shapes that move
    streak_px: float = 0.0

    def decide(self, name: str, present: bool, reason: str,
               can_force: str | None = None) -> Effect:
        """Record effect ``name``; ``can_force`` is why forcing it on fails
        when it is absent (None: forcing on keeps it)."""
        forced = self.overrides.get(name)
        on = present if forced is None else forced
        if forced and not present and can_force is not None:
            raise McrtError(f"{name}=on: {can_force}")
        self.effects[name] = Effect(name, present, on, reason, forced)
        return self.effects[name]

    def on(self, name: str) -> bool:
        return self.effects[name].on


def decide_described(facts: ScanFacts, author: AuthoredIntegrator,
                     overrides: dict[str, bool]) -> Decisions:
    """The effects the description decides (all but dof and motion)."""
    d = Decisions(overrides)
    decide_aa(d)
    if author.unlit:
        decide_unlit(d, author)
    else:
        decide_soft_shadows(d, facts)
        decide_glossy(d, facts)
    decide_indirect(d, facts, author)
    note_media(d, facts.scan, author)
    return d


def decide_measured(d: Decisions, facts: SceneFacts) -> None:
    """The effects measured on the instantiated scene (dof, motion); then every
    effect in the order plans list them."""
    decide_dof(d, facts)
    decide_motion(d, facts)
    d.effects = {name: d.effects[name] for name in EFFECTS}


def decide_aa(d: Decisions) -> None:
    d.decide("aa", True, "film position sampled over the pixel area (film 2D)")


def unlit_reason(author: AuthoredIntegrator) -> str:
    leaves = author.leaves()
    why = [f"{kind} renders {NO_LIGHTING[kind]}, no lighting"
           for kind in sorted({leaf.kind for leaf in leaves if leaf.kind in NO_LIGHTING})]
    depths = sorted({leaf.max_depth for leaf in leaves if leaf.kind not in NO_LIGHTING})
    if depths:
        what = "nothing" if depths == [0] else "only the emitters the camera sees"
        why.append(f"max_depth {', '.join(map(str, depths))} renders no lighting ({what})")
    return f"{author.label} as authored: {'; '.join(why)}"


def decide_unlit(d: Decisions, author: AuthoredIntegrator) -> None:
    """Soft shadows and glossy reflections need lighting, which the integrator
    does not render; the BSDFs are left as they are (never evaluated)."""
    reason = unlit_reason(author)
    for name in ("soft_shadows", "glossy"):
        d.decide(name, False, reason, reason)
    d.to_smooth = []


def decide_soft_shadows(d: Decisions, facts: ScanFacts) -> None:
    area = facts.scan.area_lights
    names = listing(facts.node_id(s) for s, _ in area)
    lit = facts.scan.reflecting_shapes > 0
    reason = (f"{len(area)} area emitter{'s' if len(area) != 1 else ''}"
              + (f" ({names})" if names else "")
              + ("" if lit or not area else " but nothing to light"))
    d.decide("soft_shadows", bool(area) and lit, reason,
             "the scene has no area emitter" if not area else "nothing in the scene to shadow")
    env = environment_emitters(facts.scan)
    if env:
        d.notes.append(f"environment emitters ({listing(env)}) light with area too; "
                       f"soft_shadows does not switch them")


def _describe_rough(facts: ScanFacts, bsdf: RoughBSDF) -> str:
    alpha = (f", alpha {bsdf.alpha:g}" if bsdf.alpha is not None and math.isfinite(bsdf.alpha)
             else "")
    return f"{facts.node_id(bsdf.node) or bsdf.plugin} ({bsdf.plugin}{alpha})"


def decide_glossy(d: Decisions, facts: ScanFacts) -> None:
    rough = facts.scan.rough
    # Under a point, spot or directional light a nearly smooth BSDF still shows the
    # light's highlight, a tiny bright spot a smooth one cannot (delta meets delta).
    delta = sorted({k for k in facts.scan.emitter_kinds if k in DELTA_EMITTERS})
    smooth = [] if delta else [b for b in rough
                               if b.alpha is not None and b.alpha < GLOSSY_MIN_ALPHA]
    glossy = any(b.alpha is None or b.alpha >= GLOSSY_MIN_ALPHA for b in rough)
    desc = listing(_describe_rough(facts, b) for b in rough)
    if glossy:
        reason = f"rough BSDFs: {desc}"
    elif rough and delta:
        glossy = True
        reason = (f"roughness below {GLOSSY_MIN_ALPHA:g}, kept rough: {', '.join(delta)} "
                  f"lights make a highlight a smooth BSDF loses: {desc}")
    elif rough:
        reason = f"roughness below {GLOSSY_MIN_ALPHA:g}: {desc}"
    else:
        reason = "no rough BSDF"
    effect = d.decide("glossy", glossy, reason, None if rough else "the scene has no rough BSDF")
    # Rough BSDFs rendered smooth: all when glossy is off, the negligibly rough
    # ones unless glossy was forced on.
    if not effect.on:
        d.to_smooth = list(rough)
    else:
        d.to_smooth = [] if effect.forced else smooth


def batch_thin_lenses(facts: ScanFacts) -> int:
    """How many of a ``batch`` sensor's sensors are thin lenses (0 for any other)."""
    props = facts.desc.nodes[facts.scan.sensor].props
    if props.plugin_name() != "batch":
        return 0
    nodes = facts.desc.nodes
    return sum(1 for _, j in children(facts.desc, props)
               if nodes[j].type == mi.ObjectType.Sensor
               and nodes[j].props.plugin_name() == "thinlens")


def decide_dof(d: Decisions, facts: SceneFacts) -> None:
    lenses = batch_thin_lenses(facts)
    if lenses:  # their blur is the batch's own: not measured, never switched off
        reason = (f"batch sensor with {lenses} thin lens{'es' if lenses > 1 else ''}, "
                  f"rendered as authored")
        if d.overrides.get("dof") is False:
            raise McrtError(f"dof=off: {reason}; mcrt cannot switch a batch's lenses to "
                            f"pinholes (give the scene a perspective sensor instead)")
        d.decide("dof", True, reason)
        return
    if facts.lens is None:
        d.decide("dof", False, f"pinhole camera ({facts.scene_camera})",
                 "the camera is not a thinlens (give it aperture_radius and focus_distance)")
        return
    # The instantiated sensor may be the pinhole the plan made of the thin lens:
    # its rays are those through the centre of the lens, all the depths need.
    radius, focus = facts.lens
    coc, depths = circle_of_confusion(facts.scene, facts.sensor, facts.camera, radius, focus)
    reason = f"thin lens, aperture radius {radius:g}, focus distance {focus:g}"
    if coc is not None:
        reason += (f"; circle of confusion {coc[0]:.2f}..{coc[1]:.2f} px over the visible "
                   f"depths {depths.min():.3g}..{depths.max():.3g}")
    present = coc is None or coc[1] >= DOF_NEGLIGIBLE_PX
    if not present:
        reason += f" (below {DOF_NEGLIGIBLE_PX} px: negligible)"
    d.coc_px = coc
    d.decide("dof", present, reason)


def decide_motion(d: Decisions, facts: SceneFacts) -> None:
    motions = facts.scan.moving
    t_open, t_close = facts.shutter
    d.motions = motions
    ids = listing(m.shape for m in motions)
    if not motions:
        d.decide("motion", False, "no moving shape", "the scene has no moving shape")
        return
    if not facts.shutter_is_open:
        d.decide("motion", False, f"moving shapes ({ids}) but the shutter is closed",
                 "the sensor's shutter is closed (set shutter_open < shutter_close)")
        return
    d.streak_px = streak_px(facts.scene, facts.camera, motions, t_open, t_close)
    reason = (f"{len(motions)} moving shape{'s' if len(motions) != 1 else ''} ({ids}); "
              f"streak up to {d.streak_px:.1f} px over the shutter [{t_open:g}, {t_close:g}]")
    present = d.streak_px >= NEGLIGIBLE_STREAK_PX
    if not present:
        reason += f" (below {NEGLIGIBLE_STREAK_PX} px: negligible)"
    if facts.camera.kind == "unknown":
        d.notes.append(f"cannot project motion through a '{facts.scene_camera}' camera: "
                       f"one sub-frame per sample")
    d.decide("motion", present, reason)


def decide_indirect(d: Decisions, facts: ScanFacts, author: AuthoredIntegrator) -> None:
    kind, depth, scan = author.kind, author.max_depth, facts.scan
    interreflect = scan.reflecting_shapes >= 2 or bool(scan.self_lighting)
    if not author.replannable:
        _decide_authored_indirect(d, scan, author, interreflect)
        return
    if not author.deep:
        reason = f"the scene's integrator is {kind}" + (
            f" with max_depth {depth}" if kind == "path" else "")
    elif not interreflect:
        reason = ("no surface can light another (fewer than two reflecting shapes, "
                  "none that can light itself)")
    elif scan.reflecting_shapes < 2:
        reason = (f"{scan.self_lighting[0]} can light itself, and a path integrator of "
                  f"max_depth {depth}")
    else:
        reason = f"{scan.reflecting_shapes} reflecting shapes and a path integrator of " \
                 f"max_depth {depth}"
    limit = author.depth_limit
    d.decide("indirect", author.deep and interreflect, reason,
             None if limit is None or limit > 2 else
             f"the scene's integrator sets max_depth {limit}, which stops at direct light; "
             f"give it a larger max_depth to render indirect light")


def _decide_authored_indirect(d: Decisions, scan: Scan, author: AuthoredIntegrator,
                              interreflect: bool) -> None:
    """Indirect light of an integrator rendered as authored: what the
    integrators it wraps trace (``moment(volpath)`` renders indirect light),
    with media scattering light again where a volumetric integrator sees them."""
    leaves = author.leaves()
    volumetric = [leaf.kind for leaf in leaves if leaf.kind in VOLUMETRIC]
    scatter = interreflect or bool(volumetric and scan.media)
    deep = [leaf for leaf in leaves if leaf.traces_indirect()]
    unknown = [leaf.kind for leaf in leaves if leaf.traces_indirect() is None]
    present = bool(deep) and scatter
    if deep:
        depths = ", ".join(f"{leaf.kind} max_depth {leaf.max_depth}" for leaf in deep)
        reason = (f"{author.label} as authored: {depths}"
                  + ("" if scatter else "; but no surface or medium can light another"))
    elif unknown:
        reason = f"{author.label} as authored: mcrt cannot tell what '{unknown[0]}' traces"
    elif author.unlit:
        reason = unlit_reason(author)
    else:
        reason = f"{author.label} as authored: direct lighting only"
    forced = d.overrides.get("indirect")
    if forced is not None and forced != present:
        raise McrtError(f"indirect={'on' if forced else 'off'}: mcrt re-plans path and direct "
                        f"integrators only; {reason}")
    d.decide("indirect", present, reason)


def note_media(d: Decisions, scan: Scan, author: AuthoredIntegrator) -> None:
    """Say which participating media the scene has and whether they render."""
    if not scan.media:
        return
    volumetric = [leaf.kind for leaf in author.leaves() if leaf.kind in VOLUMETRIC]
    d.notes.append(f"participating media: {listing(scan.media)}; "
                   + (f"rendered by {', '.join(volumetric)}" if volumetric else
                      f"'{author.kind}' ignores them (only volpath, volpathmis and prbvolpath "
                      f"render media)"))
