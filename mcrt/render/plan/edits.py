"""Edits that make a scene render its plan.

The plan instantiates a scene once: :func:`edit_description` makes the edits
that need no geometry before that (shutter, smooth BSDFs, the integrator, a
pinhole asked for); :func:`edit_built` those that do (a thin lens whose blur is
negligible, area lights switched off), which then need a second instantiation;
:func:`bake_pose` moves shapes in place (``mi.traverse``). Node property
references dangle once a node is appended (:func:`.nodes.add_node`), so every
edit looks its node up afresh.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ...errors import McrtError
from ..motion import MotionDriver
from ..scene import SceneDescription
from .camera import auto_float
from .effects import Decisions, ScanFacts, SceneFacts
from .model import IntegratorSpec
from .nodes import add_node, children, rgb, shapes_by_id
from .scan import ROUGH_ONLY_PROPS, ROUGH_TO_SMOOTH, RoughBSDF, Scan

#: Area light -> delta light: sample positions per axis measuring the shape,
#: and how far the mean normal may be from 1 (flat) or 0 (closed) for either.
SHAPE_SAMPLES = 64
FLATNESS_TOLERANCE = 1e-3
#: The spot light standing in for a flat area light: full intensity up to
#: ``SPOT_BEAM_DEG`` off the normal, falling linearly (in angle) to 0 at 90
#: degrees; 32 degrees fits ``cos`` best (least squares over the hemisphere,
#: weighted by solid angle: residual 0.0008 against 0.083 for a constant).
SPOT_BEAM_DEG = 32.0
SPOT_CUTOFF_DEG = 90.0


def name_area_lights(desc: SceneDescription, scan: Scan) -> None:
    """Give emitting shapes ids, so that the instantiated scene can name them."""
    for k, (shape, _) in enumerate(scan.area_lights):
        props = desc.nodes[shape].props
        if not props.id():
            props.set_id(f"mcrt_area_light_{k}")


def edit_description(facts: ScanFacts, d: Decisions, integrator: IntegratorSpec | None) -> None:
    """Before instantiation: the edits that need no geometry, with
    ``integrator`` (None: keep the scene's)."""
    sensor = facts.desc.nodes[facts.scan.sensor].props
    if facts.scene_camera == "thinlens" and d.overrides.get("dof") is False:
        to_pinhole(sensor)
    if facts.shutter_is_open:  # mcrt renders time by sub-frames, never per path
        sensor["shutter_close"] = facts.shutter[0]
    make_smooth(facts, d.to_smooth)
    if integrator is not None:
        set_integrator(facts, integrator)
    if facts.scan.moving:
        facts.desc.config.merge_meshes = False  # moving meshes must stay separate shapes


def edit_built(facts: SceneFacts, d: Decisions) -> bool:
    """After instantiation: the edits that need geometry; True when the scene
    must be instantiated again."""
    sensor = facts.desc.nodes[facts.scan.sensor].props
    rebuild = False
    if sensor.plugin_name() == "thinlens" and not d.on("dof"):  # blur found negligible
        to_pinhole(sensor)
        rebuild = True
    if facts.scan.area_lights and d.effects["soft_shadows"].forced is False:
        area_to_delta(facts)  # soft shadows are only ever off by request
        d.notes.append("soft_shadows off: each area light is a delta light of the same power "
                       "(a spot along the normal of a flat shape, a point light for a closed "
                       "one); the light's shape no longer shows in the image")
        rebuild = True
    return rebuild


def rendered_camera(facts: ScanFacts) -> str:
    return facts.desc.nodes[facts.scan.sensor].props.plugin_name()


def to_pinhole(sensor: mi.Properties) -> None:
    """``thinlens`` -> ``perspective`` (same fov, pose, clip, film)."""
    sensor.set_plugin_name("perspective")
    for key in ("aperture_radius", "focus_distance"):
        if key in sensor:
            del sensor[key]


def make_smooth(facts: ScanFacts, bsdfs: list[RoughBSDF]) -> None:
    """Turn rough BSDFs into their smooth counterparts."""
    for bsdf in bsdfs:
        if bsdf.plugin not in ROUGH_TO_SMOOTH:
            raise McrtError(f"glossy=off: cannot make the '{bsdf.plugin}' BSDF smooth")
        props = facts.desc.nodes[bsdf.node].props
        props.set_plugin_name(ROUGH_TO_SMOOTH[bsdf.plugin])
        for key in ROUGH_ONLY_PROPS:
            if key in props:
                del props[key]


def set_integrator(facts: ScanFacts, integrator: IntegratorSpec) -> None:
    props = mi.Properties(str(integrator["type"]))
    for key, value in integrator.items():
        if key != "type":
            props[key] = value
    if facts.scan.integrator is None:
        add_node(facts.desc, mi.ObjectType.Integrator, props, 0, "_mcrt_integrator")
    else:
        facts.desc.nodes[facts.scan.integrator].props = props


def area_to_delta(facts: SceneFacts) -> None:
    """Replace every area-lit shape by a delta light of the same power at its
    centroid (see :mod:`mcrt.render.plan`): a spot along the normal for a flat
    shape, a point light for a closed one; refuse any other shape."""
    desc = facts.desc
    shapes = shapes_by_id(facts.scene)
    for k, (shape, emitter) in enumerate(facts.scan.area_lights):
        sprops = desc.nodes[shape].props  # valid until the append below
        where = f"soft_shadows=off: the area light on '{sprops.id()}'"
        radiance = rgb(desc.nodes[emitter].props, "radiance")
        if radiance is None:
            raise McrtError(f"{where} has a textured or spectral radiance; only rgb/float "
                            f"radiance converts to a delta light")
        keys = [key for key, i in children(desc, desc.nodes[0].props) if i == shape]
        if not keys:
            raise McrtError(f"{where} is not on a top-level shape")
        light = delta_light(shapes[sprops.id()], radiance, where)
        for key in keys:
            del desc.nodes[0].props[key]
        add_node(desc, mi.ObjectType.Emitter, light, 0, f"_mcrt_delta_light_{k}")


def delta_light(shape: mi.Shape, radiance: np.ndarray, where: str) -> mi.Properties:
    """The delta light emitting the power ``pi L A`` of a Lambertian area light
    of radiance ``L`` on ``shape``: from a flat shape all into the front
    hemisphere, as a spot of intensity ``L A / (2 F)`` with ``F`` its falloff
    integrated over the hemisphere; from a closed shape, as a point of ``L A / 4``
    (its far-field intensity, exact for a sphere)."""
    area = float(np.array(shape.surface_area()).ravel()[0])
    centroid, normal = _centroid_and_mean_normal(shape)
    flatness = float(np.linalg.norm(normal))
    if flatness > 1 - FLATNESS_TOLERANCE:
        beam, cutoff = np.radians(SPOT_BEAM_DEG), np.radians(SPOT_CUTOFF_DEG)
        falloff = 1 + (np.sin(beam) - np.sin(cutoff)) / (cutoff - beam)  # int f sin
        light = mi.Properties("spot")
        light["intensity"] = mi.ScalarColor3d(*(radiance * area / (2 * falloff)))
        light["cutoff_angle"], light["beam_width"] = SPOT_CUTOFF_DEG, SPOT_BEAM_DEG
        up = np.eye(3)[int(np.argmin(np.abs(normal)))]
        light["to_world"] = mi.ScalarTransform4d().look_at(
            origin=centroid.tolist(), target=(centroid + normal).tolist(), up=up.tolist())
    elif flatness < FLATNESS_TOLERANCE:
        light = mi.Properties("point")
        light["position"] = dr.scalar.Array3f64(*centroid)
        light["intensity"] = mi.ScalarColor3d(*(radiance * area / 4))
    else:
        raise McrtError(f"{where} is neither flat nor closed (its normals average to "
                        f"{flatness:.2f} of flat): no point or spot light emits like it")
    return light


def _centroid_and_mean_normal(shape: mi.Shape) -> tuple[np.ndarray, np.ndarray]:
    """The centroid of ``shape``'s surface and its mean normal (vector area / A):
    exact from a mesh's triangles, else from a grid of uniform area samples. A
    mesh chooses the triangle of a sample from its area CDF, so a grid leaves
    whole faces under- or over-sampled: a cube's normals averaged to 0.02, not
    0, and it was refused as "neither flat nor closed"."""
    u = (np.arange(SHAPE_SAMPLES) + 0.5) / SHAPE_SAMPLES
    x, y = (mi.Float(a.ravel().astype(np.float32)) for a in np.meshgrid(u, u))
    ps = shape.sample_position(auto_float(0.0), mi.Point2f(x, y))  # uniform over the area
    centroid = np.array(ps.p, dtype=np.float64).mean(axis=1)
    normal = np.array(ps.n, dtype=np.float64).mean(axis=1)
    if not isinstance(shape, mi.Mesh):
        return centroid, normal
    v = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    a, b, c = (v[i] for i in np.array(shape.faces_buffer()).reshape(-1, 3).T)
    vector_areas = np.cross(b - a, c - a) / 2
    areas = np.linalg.norm(vector_areas, axis=1)
    exact = vector_areas.sum(axis=0) / areas.sum()
    if exact @ normal < 0:  # the sampled normals know which side emits (flipped normals)
        exact = -exact
    return (areas @ (a + b + c) / 3) / areas.sum(), exact


def bake_pose(scene: mi.Scene, d: Decisions, t: float) -> None:
    """Motion off with the shutter opening at ``t != 0``: put the moving shapes
    at their pose at ``t``, in place."""
    if not d.on("motion") and d.motions and t != 0.0:
        MotionDriver(scene, d.motions).set_time(t)
