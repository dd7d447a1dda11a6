"""The integrator a plan renders with (see the module docstring of
:mod:`mcrt.render.plan`): the author's when mcrt cannot re-plan it, else
``path`` for indirect light, ``distribution`` for reflections of other
objects, ``direct`` for everything else."""

from __future__ import annotations

import mitsuba as mi

from .effects import Decisions, ScanFacts
from .model import IntegratorSpec, listing
from .nodes import integer, scalar, scalars
from .scan import AuthoredIntegrator, environment_emitters

#: ``max_depth`` of ``path`` when indirect light is forced on in a scene whose
#: own integrator sets none deeper than direct lighting.
DEFAULT_INDIRECT_DEPTH = 8


def choose_integrator(facts: ScanFacts, author: AuthoredIntegrator,
                      d: Decisions) -> tuple[IntegratorSpec, str]:
    """(integrator, why) for the decided effects."""
    if not author.replannable:
        return {"type": author.kind, **scalars(author.props)}, "kept as authored"
    bounce = reflection_bounces(facts, d)
    if facts.scan.cut_outs and author.kind == "path" and not d.on("indirect"):
        spec, reason = _cut_out_path(facts, author)
    elif d.on("indirect"):
        spec, reason = _indirect(author)
    elif bounce:
        spec, reason = _distribution(facts, d, bounce)
    else:
        spec, reason = _direct(facts, author, d)
    if "hide_emitters" in author.props:
        spec["hide_emitters"] = bool(scalar(author.props, "hide_emitters"))
    return _capped(spec, reason, author.depth_limit)


def _capped(spec: IntegratorSpec, reason: str, limit: int | None) -> tuple[IntegratorSpec, str]:
    """The plan's integrator within the author's ``max_depth`` (an upper bound):
    a deeper plan is cut to it, and the reason says what that leaves out."""
    depth = int(spec.get("max_depth", 2))  # direct lighting: depth 2
    if limit is None or 0 <= depth <= limit:
        return spec, reason
    capped: IntegratorSpec = {**spec, "max_depth": limit}
    lost = ("reflected objects are not rendered, only direct light" if limit <= 2 else
            f"paths end after {limit - 1} bounces")
    return capped, f"{reason}; capped at the scene's max_depth {limit}: {lost}"


def reflection_bounces(facts: ScanFacts, d: Decisions) -> int:
    """Bounces past direct light that glossy or specular surfaces need to show
    other objects: 1, 2 with dielectrics (in and out), 0 without such surfaces."""
    specular = bool(facts.scan.specular) or bool(d.to_smooth)
    if not (d.on("glossy") or specular):
        return 0
    return 2 if facts.scan.dielectric else 1


def _indirect(author: AuthoredIntegrator) -> tuple[IntegratorSpec, str]:
    depth = author.max_depth if author.deep else DEFAULT_INDIRECT_DEPTH
    spec: IntegratorSpec = {"type": "path", "max_depth": depth}
    if author.kind == "path" and "rr_depth" in author.props:
        spec["rr_depth"] = integer(author.props, "rr_depth")
    return spec, "indirect light"


def _cut_out_path(facts: ScanFacts, author: AuthoredIntegrator) -> tuple[IntegratorSpec, str]:
    """The scene's ``path``, at its depth: Mitsuba 3.9's ``path`` weights the light
    a cut-out (``mask``) reflects from a sampled emitter by its opacity twice, a
    bias (``direct``, ``prb`` and ``distribution`` weight it once, the analytic
    value: docs/mask-path-bias.md), so no shorter integrator renders the image
    ``mi.render`` gives; :func:`cut_out_caveat` says so."""
    spec: IntegratorSpec = {"type": "path", "max_depth": author.max_depth}
    if "rr_depth" in author.props:
        spec["rr_depth"] = integer(author.props, "rr_depth")
    return spec, (f"the scene's path is kept for its cut-out BSDFs "
                  f"({listing(facts.scan.cut_outs)}): no other integrator gives mi.render's image")


def cut_out_caveat(facts: ScanFacts, integrator: IntegratorSpec,
                   author: AuthoredIntegrator) -> list[str]:
    """Where ``path`` renders a scene with cut-out BSDFs (``mask``), planned or as
    authored: Mitsuba 3.9's ``path`` makes the sampled light they reflect too dark
    (docs/mask-path-bias.md), in ``mi.render`` too; the plan keeps that image and
    says so in a caveat (a render's plan line included, not only ``mcrt plan``)."""
    if not facts.scan.cut_outs:
        return []
    if author.replannable:
        lit = integrator["type"] == "path"
    else:  # (a path of max_depth 0 or 1 samples no light: no bias)
        lit = any(leaf.kind == "path" and not 0 <= leaf.max_depth <= 1
                  for leaf in author.leaves())
    if not lit:
        return []
    return [f"Mitsuba 3.9's path renders the sampled light that cut-out BSDFs "
            f"({listing(facts.scan.cut_outs)}) reflect too dark (opacity^2 in place of "
            f"opacity); mi.render gives the same image, prb (or direct, for direct light) "
            f"the right one (docs/mask-path-bias.md)"]


def _distribution(facts: ScanFacts, d: Decisions, bounce: int) -> tuple[IntegratorSpec, str]:
    what = "glossy" if d.on("glossy") else "specular"
    reason = (f"{what} surfaces show other objects: {bounce} bounce"
              f"{'s' if bounce > 1 else ''} past direct light"
              + (" (dielectrics: in and out)" if facts.scan.dielectric else ""))
    return {"type": "distribution", "max_depth": 2 + bounce}, reason


def _direct(facts: ScanFacts, author: AuthoredIntegrator,
            d: Decisions) -> tuple[IntegratorSpec, str]:
    """Direct lighting: one emitter sample, and a BSDF sample only when MIS
    needs one (emitters with area; glossy and specular surfaces never get
    here: they need :func:`_distribution`)."""
    extended = environment_emitters(facts.scan)
    if d.on("soft_shadows") and facts.scan.area_lights:
        extended = ["area", *extended]
    spec: IntegratorSpec = {"type": "direct", "emitter_samples": 1,
                            "bsdf_samples": 1 if extended else 0}
    reason = (f"direct lighting is all the scene needs; BSDF sample for MIS with the "
              f"{', '.join(extended)} emitter{'s' if len(extended) > 1 else ''}"
              if extended else
              "direct lighting is all the scene needs; delta lights only, so no BSDF sample")
    if author.kind == "direct":
        keys = ("emitter_samples", "bsdf_samples", "shading_samples")
        explicit = {k: integer(author.props, k) for k in keys if k in author.props}
        if "shading_samples" in explicit:
            s = explicit.pop("shading_samples")
            explicit = {"emitter_samples": s, "bsdf_samples": s}
        if explicit:
            spec.update(explicit)
            reason = "direct lighting, sample counts as authored"
    return spec, reason


def delta_weight_caveat(scene: mi.Scene, integrator: IntegratorSpec,
                        author: AuthoredIntegrator) -> list[str]:
    """Mitsuba 3.9.1's ``direct`` weights each of its ``emitter_samples`` n samples
    of a point, spot, directional or projector light by 1, not 1/n (mitsuba3
    #1861), so such lights render n times too bright, in ``mi.render`` too. The
    plan keeps the sample counts (its image is ``mi.render``'s) and says so:
    the caveat names the lights, the count and the fix."""
    if author.replannable:
        counts = [int(integrator.get("emitter_samples", 1))] \
            if integrator["type"] == "direct" else []
    else:
        counts = [integer(leaf.props, key) for leaf in author.leaves() if leaf.kind == "direct"
                  for key in ("emitter_samples", "shading_samples") if key in leaf.props]
    n = max(counts, default=1)
    if n <= 1:
        return []
    delta = sorted({e.class_name() for e in scene.emitters()
                    if mi.has_flag(e.flags(), mi.EmitterFlags.Delta)})
    if not delta:
        return []
    return [f"Mitsuba 3.9.1's direct integrator renders delta lights ({listing(delta)}) "
            f"{n} times too bright with emitter_samples {n}: it weights each of their "
            f"samples 1, not 1/{n} (mitsuba3 #1861); mi.render gives the same image, "
            f"emitter_samples 1 the right one (docs/effects-and-plan.md)"]
