"""Multisampling: visibility at every sample, shading once per surface per pixel.

The lecture's multisampling ("sample visibility at a higher rate than
shading"), in Dr.Jit's wavefront style, for a wavefront laid out pixel-major
(``G`` consecutive lanes per pixel, as Mitsuba's ``render`` and mcrt's pass
engine lay it out):

1. :func:`surface_keys`: one preliminary intersection per lane gives its *group
   key*: (shape, instance, primitive) of the primary hit, or "miss". Two
   triangles of one mesh are two groups (``group_by="primitive"``), so both
   sides of an edge stay apart even inside one mesh.
2. :func:`representatives`: within each pixel, lanes with equal keys form a
   group; each group elects one *representative*: the member whose ray
   direction is closest to the mean direction of the pixel's rays
   (``centre``: the covered sample nearest the centre of the pixel's pattern,
   as hardware MSAA shades at the pixel centre, or at a covered sample when the
   centre is not covered), ties to the lower sample index; or the first member
   in sample order (``first``). Rounds of block reductions peel off one group
   per pixel at a time, so the cost is ``O(lanes x groups per pixel)``.
3. :func:`shade_groups`: only representatives are shaded, in a *compacted*
   wavefront (masked lanes would cost as much as shaded ones in Dr.Jit), by
   the nested integrator; every lane then takes its group's value (a gather).
   The film, its reconstruction filter and mcrt's accumulators see ordinary
   samples, one per lane, at each sample's own film position: with a box
   filter a pixel is ``sum over groups of coverage x shaded value``.

The representatives' shading dimensions (light samples, BSDF samples, ...)
come from an ``independent`` sampler seeded per wavefront from the scene
sampler's stream (deterministic for a given seed): the scene sampler's strata
belong to the pixel's N visibility samples, not to its few shading points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from ..core.trace import film_grid_size, integrator_sample
from ..errors import McrtError
from ..samplers.kit import hash_keys_int

#: Representative choices (``representative`` parameter).
REPRESENTATIVES = ("centre", "first")
#: Grouping choices (``group_by`` parameter).
GROUPINGS = ("primitive", "shape")

_NONE = 0xFFFFFFFF


@dataclass
class Wavefront:
    """How a wavefront of ``lanes`` splits into pixels of ``group`` lanes."""

    lanes: int
    group: int  # lanes (samples) per pixel in this wavefront
    pixels: int
    grid: tuple[int, int]  # (width, height) of the sampled pixel grid


def wavefront_layout(scene: mi.Scene, lanes: int) -> Wavefront:
    """The pixel-major layout of a wavefront of ``lanes`` lanes: the first
    sensor whose sampled pixel grid divides ``lanes`` gives the pixels."""
    for sensor in scene.sensors():
        size = film_grid_size(sensor.film())
        pixels = int(size[0]) * int(size[1])
        if pixels and lanes % pixels == 0:
            return Wavefront(lanes, lanes // pixels, pixels, (int(size[0]), int(size[1])))
    raise McrtError(f"multisample: a wavefront of {lanes} samples is not a whole number of "
                    f"samples for every pixel of the film; multisample renders whole-film "
                    f"pixel-major wavefronts (mi.render, mcrt render), not adaptive ones")


def surface_keys(scene: mi.Scene, ray: mi.Ray3f, group_by: str,
                 active: Any = True) -> tuple[mi.UInt32, mi.UInt32, mi.UInt32]:
    """(shape, instance, primitive) of each lane's primary hit; zeros for a miss.

    Shapes and instances are Dr.Jit pointer registry ids (0 is no object);
    ``group_by="shape"`` leaves the primitive out (a smooth mesh is one group).
    """
    intersect: Any = scene.ray_intersect_preliminary  # the stubs' Bool is not mi.Bool
    pi = intersect(mi.Ray3f(ray), coherent=True, active=mi.Bool(active))
    hit = pi.is_valid()
    shape = dr.select(hit, dr.reinterpret_array(mi.UInt32, pi.shape), 0)
    instance = dr.select(hit, dr.reinterpret_array(mi.UInt32, pi.instance), 0)
    prim = dr.select(hit, pi.prim_index, 0) if group_by == "primitive" else mi.UInt32(0)
    return mi.UInt32(shape), mi.UInt32(instance), mi.UInt32(prim)


def centre_distance(ray: mi.Ray3f, group: int) -> mi.Float:
    """Squared distance of each lane's point ``o + d/|d|`` (one unit along its
    ray: the direction for a pinhole, the origin for an orthographic camera) to
    the mean of its pixel's points, a proxy for the distance to the centre of
    the pixel's sample pattern that needs no film position."""
    lanes = dr.width(ray.o)
    origin: Any = ray.o  # the stubs add no Vector3f to a Point3f
    point = [dr.zeros(mi.Float, lanes) + c  # a constant (literal) has width 1
             for c in origin + dr.normalize(ray.d)]
    dr.eval(point)
    block = dr.arange(mi.UInt32, lanes) // group
    total = mi.Float(0.0)
    for c in point:
        mean = dr.gather(mi.Float, dr.block_sum(c, group), block) / group
        total += dr.square(c - mean)
    return total


def representatives(keys: tuple[mi.UInt32, ...], distance: mi.Float | None, group: int,
                    active: Any = True) -> mi.UInt32:
    """Lane of each lane's representative (``0xFFFFFFFF`` for inactive lanes).

    Each round finds, per pixel, the first lane not yet assigned, takes every
    unassigned lane with its key as one group, and elects the member of least
    ``distance`` (all equal when ``distance`` is None: the first member).
    """
    lanes = dr.width(keys[0])
    lane = dr.arange(mi.UInt32, lanes)
    if group == 1:
        return dr.select(mi.Bool(active), lane, _NONE)
    block = lane // group
    keys = tuple(dr.zeros(mi.UInt32, lanes) + k for k in keys)  # literals have width 1
    todo = mi.Bool(active) & (lane == lane)
    rep = dr.full(mi.UInt32, _NONE, lanes)
    dist = dr.zeros(mi.Float, lanes) + (distance if distance is not None else 0.0)
    while True:
        first = dr.gather(mi.UInt32, dr.block_reduce(
            dr.ReduceOp.Min, dr.select(todo, lane, _NONE), group), block)
        lead = dr.minimum(first, lanes - 1)
        member = todo & (first != _NONE)
        for key in keys:
            member &= key == dr.gather(mi.UInt32, key, lead)
        best = dr.gather(mi.Float, dr.block_reduce(
            dr.ReduceOp.Min, dr.select(member, dist, dr.inf), group), block)
        chosen = dr.gather(mi.UInt32, dr.block_reduce(
            dr.ReduceOp.Min, dr.select(member & (dist == best), lane, _NONE), group), block)
        rep = dr.select(member, chosen, rep)
        todo &= ~member
        dr.eval(rep, todo)
        if not dr.any(todo):
            return rep


@dataclass
class Shaded:
    """Per-lane results of :func:`shade_groups` and what they cost."""

    spectrum: Any
    valid: mi.Bool
    aovs: list[Any]
    evaluations: int  # shading evaluations (representatives) in the wavefront
    per_pixel: mi.UInt32  # representatives of each pixel of the wavefront


def shading_seed(sampler: mi.Sampler, active: Any = True) -> int:
    """A seed for the representatives' shading sampler, drawn from the scene
    sampler's next dimension (so it changes with the render seed and pass)."""
    u = sampler.next_1d(active)
    total = dr.sum(mi.UInt64(dr.reinterpret_array(mi.UInt32, mi.Float(u))))
    return hash_keys_int(int(total[0]) & 0xFFFFFFFF, int(total[0]) >> 32, 0x3C5)


def shade_groups(scene: mi.Scene, nested: mi.SamplingIntegrator, shading: mi.Sampler,
                 seed: int, ray: mi.RayDifferential3f, rep: mi.UInt32, group: int,
                 medium: Any = None) -> Shaded:
    """Shade the representatives in one compacted wavefront and give every
    lane its representative's value (lanes with ``rep == 0xFFFFFFFF`` get 0)."""
    lanes = dr.width(rep)
    lane = dr.arange(mi.UInt32, lanes)
    is_rep = rep == lane
    index: Any = dr.compress(is_rep)
    count = dr.width(index)
    per_pixel = dr.block_sum(mi.UInt32(is_rep), group)
    shade_ray = dr.gather(type(ray), ray, index)
    seed_value: Any = mi.UInt32(seed)  # opaque: a literal seed would compile a kernel per pass
    dr.make_opaque(seed_value)
    shading.seed(seed_value, max(count, 1))
    spec, valid, aovs = integrator_sample(nested, scene, shading, shade_ray, medium, True)
    valid = mi.Bool(valid)
    dr.eval(spec, valid, aovs)  # one shading kernel (a gather evaluates its source per component)
    has = rep != _NONE
    slot = dr.gather(mi.UInt32, dr.prefix_sum(mi.UInt32(is_rep)), dr.minimum(rep, lanes - 1))
    take = has & (count > 0)
    out_spec = dr.gather(type(spec), spec, slot, take)
    out_valid = dr.gather(mi.Bool, valid, slot, take)
    out_aovs = [dr.gather(type(a), a, slot, take) for a in aovs]
    return Shaded(out_spec, out_valid, out_aovs, count, per_pixel)


def wrap_integrator(desc: Any, plugin: str = "multisample") -> None:
    """Edit a parsed scene description (``mi.parser`` state) so that its
    integrator is nested in a ``plugin`` integrator (``path`` if it has none)."""
    scene_props = desc.nodes[0].props
    for key in scene_props.keys():
        value = scene_props[key]
        if isinstance(value, mi.Properties.ResolvedReference) and \
                desc.nodes[value.index()].type == mi.ObjectType.Integrator:
            index = value.index()
            inner = mi.parser.SceneNode()
            inner.type = mi.ObjectType.Integrator
            inner.props = desc.nodes[index].props
            desc.nodes.append(inner)
            outer = mi.Properties(plugin)
            outer["nested"] = mi.Properties.ResolvedReference(len(desc.nodes) - 1)
            desc.nodes[index].props = outer
            return
    node = mi.parser.SceneNode()
    node.type = mi.ObjectType.Integrator
    node.props = mi.Properties(plugin)
    desc.nodes.append(node)
    desc.nodes[0].props["_mcrt_multisample"] = mi.Properties.ResolvedReference(
        len(desc.nodes) - 1)


__all__ = ["GROUPINGS", "REPRESENTATIVES", "Shaded", "Wavefront", "centre_distance",
           "representatives", "shade_groups", "shading_seed", "surface_keys",
           "wavefront_layout", "wrap_integrator"]
