"""The ``distribution`` integrator: Cook-style paths through glossy and specular lobes only.

Distribution ray tracing (Cook, Porter and Carpenter 1984) traces reflection
rays from glossy and mirror surfaces but lights every other surface directly.
Mitsuba's ``path`` integrator continues every path at every vertex, so a glossy
floor that must reflect the objects standing on it (``max_depth`` 3) also gives
every *diffuse* surface a bounce of indirect light, with the noise of the
caustic paths diffuse -> glossy -> light. This integrator is ``path`` with one
rule added: a path continues past a vertex only if the BSDF lobe it sampled
there is glossy or delta. After a diffuse lobe the sampled ray still collects
the emitter it hits (so light sampling and BSDF sampling stay combined by
multiple importance sampling, exactly as in ``path``), and the path ends.

Hence: on diffuse-only scenes it estimates what ``direct`` does; on scenes
without diffuse lobes it estimates what ``path`` does at the same
``max_depth``; in between it renders glossy and mirror reflections of directly
lit objects and no diffuse interreflection. ``mcrt plan`` chooses it when
glossy or specular surfaces must show other objects and nothing in the scene
calls for indirect light.

Per path vertex it draws, in this order: emitter 2D, BSDF lobe 1D, BSDF
direction 2D (no Russian roulette: ``max_depth`` bounds the path)::

    <integrator type="distribution">
        <integer name="max_depth" value="3"/>
    </integrator>
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..errors import SceneError
from .plugins import register_integrator

#: Variant whose ``mi.SamplingIntegrator`` the plugin class derives from.
_classes_variant = mi.variant()


def _mis_weight(pdf_a, pdf_b):
    """Power heuristic, 0 where it is undefined (as Mitsuba's integrators)."""
    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.detach(dr.select(dr.isfinite(w), w, 0.0))


class DistributionIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-distribution:

    Distribution ray tracing (:monosp:`distribution`)
    -------------------------------------------------

    .. pluginparameters::

     * - max_depth
       - |int|
       - Longest path in vertices, as ``path``'s ``max_depth`` (2: direct
         lighting; 3: one glossy or mirror reflection of lit objects).
         (Default: 3)
     * - hide_emitters
       - |bool|
       - Hide directly visible emitters. (Default: false)
    """

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        max_depth = props.get("max_depth", 3)
        if not isinstance(max_depth, (int, float, str)):
            raise SceneError("distribution: max_depth must be an integer")
        self.max_depth = int(max_depth)
        if self.max_depth < 1:
            raise SceneError(f"distribution: max_depth must be >= 1, got {self.max_depth}")
        self.hide = bool(props.get("hide_emitters", False))

    def aov_names(self) -> list[str]:
        return []

    def to_string(self) -> str:
        return f"DistributionIntegrator[max_depth={self.max_depth}]"

    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium | None = None, active: dr.auto.ad.Bool | bool = True):
        ctx = mi.BSDFContext()
        max_depth = self.max_depth
        hide = self.hide

        path_ray = mi.Ray3f(ray)
        depth = mi.UInt32(0)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        alive = mi.Bool(active)
        valid = mi.Bool(False)
        prev_si = dr.zeros(mi.SurfaceInteraction3f)
        prev_pdf = mi.Float(1.0)
        prev_delta = mi.Bool(True)
        last = mi.Bool(False)  # the previous vertex sampled a diffuse lobe

        def cond(sampler, ray, depth, L, beta, active, valid, prev_si, prev_pdf, prev_delta,
                 last):
            return active

        def body(sampler, ray, depth, L, beta, active, valid, prev_si, prev_pdf, prev_delta,
                 last):
            si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                     active=active)
            valid |= active & (depth == 0) & si.is_valid()

            # Emitter hit by the ray, weighted against light sampling at the
            # previous vertex (multiple importance sampling).
            ds = mi.DirectionSample3f(scene, si, prev_si)
            em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_delta)
            weight = dr.select(prev_delta | (depth == 0), 1.0, _mis_weight(prev_pdf, em_pdf))
            show = active & ~(hide & (depth == 0))
            L = dr.select(show, L + beta * weight * ds.emitter.eval(si, show), L)

            active_next = active & si.is_valid() & (depth + 1 < max_depth) & ~last
            bsdf = si.bsdf(ray)

            # Light sampling.
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds_em, em_val = scene.sample_emitter_direction(si, sampler.next_2d(active_em), True,
                                                           active_em)
            active_em &= ds_em.pdf != 0.0
            wo = si.to_local(ds_em.d)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
            em_weight = dr.select(ds_em.delta, 1.0, _mis_weight(ds_em.pdf, bsdf_pdf))
            L = dr.select(active_em, L + beta * em_weight * bsdf_val * em_val, L)

            # BSDF sampling: the path goes on through glossy and delta lobes only.
            bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(active_next),
                                          sampler.next_2d(active_next), active_next)
            beta = dr.select(active_next, beta * bsdf_weight, beta)
            ray = dr.select(active_next, si.spawn_ray(si.to_world(bs.wo)), ray)
            prev_si = dr.select(active_next, si, prev_si)
            prev_pdf = dr.select(active_next, bs.pdf, prev_pdf)
            prev_delta = dr.select(active_next, mi.has_flag(bs.sampled_type,
                                                            mi.BSDFFlags.Delta), prev_delta)
            last = dr.select(active_next,
                             mi.has_flag(bs.sampled_type, mi.BSDFFlags.Diffuse), last)
            depth = dr.select(active, depth + 1, depth)
            active = active_next & dr.any(beta != 0.0)
            return (sampler, ray, depth, L, beta, active, valid, prev_si, prev_pdf, prev_delta,
                    last)

        state = dr.while_loop(
            state=(sampler, path_ray, depth, L, beta, alive, valid, prev_si, prev_pdf, prev_delta,
                   last),
            cond=cond, body=body, labels=("sampler", "ray", "depth", "L", "beta", "active",
                                          "valid", "prev_si", "prev_pdf", "prev_delta", "last"),
            label="distribution")
        return state[3], state[6], []


def register() -> None:
    """Register the ``distribution`` integrator with the active Mitsuba variant."""
    register_integrator("distribution", __name__, "DistributionIntegrator")


__all__ = ["DistributionIntegrator", "register"]
