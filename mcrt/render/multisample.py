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
   in sample order (``first``). Each lane scans its pixel's lanes in one
   kernel, so the cost is ``O(lanes x samples per pixel)``.
3. :func:`shade_groups`: only representatives are shaded, packed at the front
   of the wavefront (masked lanes would cost as much as shaded ones in Dr.Jit;
   packets of slots without one skip the shading), by the nested integrator;
   every lane then takes its group's value (a gather).
   The film, its reconstruction filter and mcrt's accumulators see ordinary
   samples, one per lane, at each sample's own film position: with a box
   filter a pixel is ``sum over groups of coverage x shaded value``.

The representatives' shading dimensions (light samples, BSDF samples, ...)
come from an ``independent`` sampler seeded per wavefront from the scene
sampler's stream (deterministic for a given seed): the scene sampler's strata
belong to the pixel's N visibility samples, not to its few shading points.

Nothing here reads a device value on the host (the counts of what was shaded
stay on the device until :attr:`MultisampleIntegrator.counts` is read), so a
film render replays it from a recording (:mod:`mcrt.core.replay`) with the
bits of an unfrozen render, whatever the number of representatives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from ..core.trace import film_grid_size, integrator_sample
from ..errors import McrtError
from ..samplers.kit import hash_keys

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

    A lane's group is the active lanes of its pixel (its block of ``group``
    lanes) whose keys all equal its own; its representative is the member of
    least ``(distance, lane)`` (all distances equal when ``distance`` is None:
    the first member). Three steps, in symbolic loops (nothing is read back on
    the host, so a frozen render, :func:`drjit.freeze`, replays them):

    1. each lane walks its block from the start to its first member, the
       group's *lead* (one step for most lanes: a pixel has few groups);
    2. each lead walks its whole block for the member of least distance (lanes
       that lead nothing stop at once, and so do SIMD packets without a lead);
    3. each lane takes its lead's choice.

    Constant keys (width 1: the primitive under ``group_by="shape"``) are left
    out: they are equal for every lane.
    """
    lanes = dr.width(keys[0])
    lane = dr.arange(mi.UInt32, lanes)
    on = mi.Bool(active) | dr.zeros(mi.Bool, lanes)  # a literal mask has width 1
    if group == 1:
        return dr.select(on, lane, _NONE)
    keys = tuple(k for k in keys if dr.width(k) != 1)
    dist = dr.zeros(mi.Float, lanes) + (distance if distance is not None else 0.0)
    dr.eval(on, dist, keys)  # gathered in the loops
    mine = [mi.UInt32(k) for k in keys]
    start = (lane // group) * group

    def same(other: mi.UInt32) -> mi.Bool:
        """Whether lane ``other`` is an active lane with this lane's keys."""
        member = dr.gather(mi.Bool, on, other)
        for key, own in zip(keys, mine, strict=True):
            member &= dr.gather(mi.UInt32, key, other) == own
        return member

    def seek(j: mi.UInt32, lead: mi.UInt32) -> tuple[mi.UInt32, mi.UInt32]:
        other = start + j
        return j + 1, dr.select(same(other), other, lead)

    _, lead = dr.while_loop(  # the lane itself is a member: every active lane finds one
        (dr.zeros(mi.UInt32, lanes), dr.select(on, _NONE, lane)),
        lambda j, lead: lead == _NONE, seek, mode="symbolic", labels=("j", "lead"),
        label="multisample_lead")

    def scan(j: mi.UInt32, best: mi.UInt32, best_dist: mi.Float
             ) -> tuple[mi.UInt32, mi.UInt32, mi.Float]:
        other = start + j
        d = dr.gather(mi.Float, dist, other)
        # The block is walked in lane order: ties keep the lower lane, and the
        # first member (the lead) is taken whatever its distance (NaN too).
        better = same(other) & ((best == _NONE) | (d < best_dist))
        return j + 1, dr.select(better, other, best), dr.select(better, d, best_dist)

    leads = on & (lead == lane)
    _, choice, _ = dr.while_loop(
        (dr.select(leads, lane - start, group), dr.full(mi.UInt32, _NONE, lanes),
         dr.full(mi.Float, dr.inf, lanes)),
        lambda j, best, best_dist: j < group, scan, mode="symbolic",
        labels=("j", "best", "best_dist"), label="multisample_representatives")
    rep = dr.gather(mi.UInt32, choice, dr.minimum(lead, lanes - 1))
    return dr.select(on, rep, _NONE)


@dataclass
class Shaded:
    """Per-lane results of :func:`shade_groups` and what they cost."""

    spectrum: Any
    valid: mi.Bool
    aovs: list[Any]
    #: Representatives (shading evaluations) of each pixel of the wavefront, on
    #: the device: their sum is the wavefront's evaluations.
    per_pixel: mi.UInt32


def shading_seed(sampler: mi.Sampler, active: Any = True) -> mi.UInt32:
    """A seed for the representatives' shading sampler, drawn from the scene
    sampler's next dimension (so it changes with the render seed and pass):
    a hash of the sum of that dimension's bits over the wavefront, computed on
    the device (one opaque value: no kernel per seed, nothing read back)."""
    u = sampler.next_1d(active)
    total = dr.sum(mi.UInt64(dr.reinterpret_array(mi.UInt32, mi.Float(u))))
    low, high = mi.UInt32(total & 0xFFFFFFFF), mi.UInt32(total >> 32)
    seed = hash_keys(low, high, 0x3C5)
    dr.eval(seed)  # evaluated, so opaque: the shading kernels take it as an input
    return seed


def shade_groups(scene: mi.Scene, nested: mi.SamplingIntegrator, shading: mi.Sampler,
                 seed: mi.UInt32, ray: mi.RayDifferential3f, rep: mi.UInt32, group: int,
                 medium: Any = None) -> Shaded:
    """Shade the representatives, packed at the front of the wavefront, and
    give every lane its representative's value (lanes with ``rep ==
    0xFFFFFFFF`` get 0). ``shading`` (an ``independent`` sampler) is cloned
    and seeded with ``seed`` for the representatives' shading dimensions.

    The shading wavefront keeps the width of the visibility wavefront, so that
    nothing depends on how many representatives there are: a frozen render
    (:func:`drjit.freeze`) replays it whatever their number. The nested
    integrator runs in a symbolic ``if`` on "this slot holds a representative":
    the slots past the last representative (whole SIMD packets on the CPU,
    whole warps on the GPU) skip the shading, so it costs about what a
    compacted wavefront (``dr.compress``) would: masked lanes alone would cost
    as much as shaded ones, and ``dr.compress`` makes Dr.Jit record a frozen
    render again at every call on the CPU (with the film's scatter-adds).
    """
    lanes = dr.width(rep)
    lane = dr.arange(mi.UInt32, lanes)
    is_rep = rep == lane
    per_pixel = dr.block_sum(mi.UInt32(is_rep), group)
    slot = dr.prefix_sum(mi.UInt32(is_rep))  # a representative's slot in the packed wavefront
    order = dr.zeros(mi.UInt32, lanes)  # the lane shaded in each slot
    busy = dr.zeros(mi.Bool, lanes)  # the slot holds a representative
    dr.scatter(order, lane, slot, is_rep)
    dr.scatter(busy, True, slot, is_rep)
    shade_ray = dr.gather(type(ray), ray, order)
    shading = shading.clone()  # its state, made in the symbolic ``if``, dies with it
    shading.seed(seed, lanes)  # type: ignore[arg-type]  # the stub wants a UInt array
    spec, valid, aovs = _shade_where(busy, scene, nested, shading, shade_ray, medium)
    dr.eval(spec, valid, aovs)  # one shading kernel (a gather evaluates its source per component)
    # Every active lane's representative is a representative; inactive lanes
    # (rep == _NONE) take nothing.
    has = rep != _NONE
    at = dr.gather(mi.UInt32, slot, dr.minimum(rep, lanes - 1))
    out_spec = dr.gather(type(spec), spec, at, has)
    out_valid = dr.gather(mi.Bool, valid, at, has)
    out_aovs = [dr.gather(type(a), a, at, has) for a in aovs]
    return Shaded(out_spec, out_valid, out_aovs, per_pixel)


def _shade_where(busy: mi.Bool, scene: mi.Scene, nested: mi.SamplingIntegrator,
                 shading: mi.Sampler, ray: mi.RayDifferential3f,
                 medium: Any) -> tuple[Any, mi.Bool, list[Any]]:
    """``integrator_sample`` of ``nested`` in the ``busy`` lanes (zeros elsewhere),
    in a symbolic ``if`` that packets without a busy lane skip."""
    made: list[Any] = []

    def shade(ray: Any, shading: Any) -> tuple[Any, Any, list[Any], Any]:
        spec, valid, aovs = integrator_sample(nested, scene, shading, ray, medium, True)
        made[:] = [type(spec), [type(a) for a in aovs]]
        return spec, mi.Bool(valid), list(aovs), shading

    def skip(ray: Any, shading: Any) -> tuple[Any, Any, list[Any], Any]:
        spec_type, aov_types = made  # the true branch is traced first
        return dr.zeros(spec_type), mi.Bool(False), [dr.zeros(t) for t in aov_types], shading

    spec, valid, aovs, _ = dr.if_stmt((ray, shading), busy, shade, skip, mode="symbolic",
                                      label="multisample_shade")
    return spec, valid, list(aovs)


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
