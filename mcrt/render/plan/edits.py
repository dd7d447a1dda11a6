"""Edits of the scene description that make it render its plan.

Node property references dangle once a node is appended (:func:`.nodes.add_node`),
so :func:`apply_plan` makes every edit through existing nodes first.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ...errors import McrtError
from ..scene import SceneDescription
from .effects import Decisions, SceneFacts
from .model import IntegratorSpec
from .nodes import add_node, bbox_centre, children, matrix, rgb, shapes_by_id
from .scan import ROUGH_ONLY_PROPS, ROUGH_TO_SMOOTH, RoughBSDF, Scan

#: Shapes whose point light shines along their normal with intensity ``L * A``.
PLANAR_SHAPES = {"rectangle", "disk"}


def name_area_lights(desc: SceneDescription, scan: Scan) -> None:
    """Give emitting shapes ids, so that the instantiated scene can name them."""
    for k, (shape, _) in enumerate(scan.area_lights):
        props = desc.nodes[shape].props
        if not props.id():
            props.set_id(f"mcrt_area_light_{k}")


def apply_plan(facts: SceneFacts, d: Decisions, integrator: IntegratorSpec | None) -> str:
    """Edit the description to render the decided effects with ``integrator``
    (None: keep the scene's); returns the camera plugin it now renders with."""
    sensor = facts.desc.nodes[facts.scan.sensor].props
    if facts.scene_camera == "thinlens" and not d.on("dof"):
        to_pinhole(sensor)
    t_open, _ = facts.shutter
    if facts.shutter_is_open:  # mcrt renders time by sub-frames, never per path
        sensor["shutter_close"] = t_open
    make_smooth(facts, d.to_smooth)
    camera = sensor.plugin_name()
    # Appending nodes from here on.
    if facts.scan.area_lights and d.effects["soft_shadows"].forced is False:
        area_to_point(facts)  # soft shadows are only ever off by request
    if not d.on("motion") and d.motions and t_open != 0.0:
        bake_pose(facts, t_open)
    if integrator is not None:
        set_integrator(facts, integrator)
    if d.on("motion"):
        facts.desc.config.merge_meshes = False  # moving meshes must stay separate shapes
    return camera


def to_pinhole(sensor: mi.Properties) -> None:
    """``thinlens`` -> ``perspective`` (same fov, pose, clip, film)."""
    sensor.set_plugin_name("perspective")
    for key in ("aperture_radius", "focus_distance"):
        if key in sensor:
            del sensor[key]


def make_smooth(facts: SceneFacts, bsdfs: list[RoughBSDF]) -> None:
    """Turn rough BSDFs into their smooth counterparts."""
    for bsdf in bsdfs:
        if bsdf.plugin not in ROUGH_TO_SMOOTH:
            raise McrtError(f"glossy=off: cannot make the '{bsdf.plugin}' BSDF smooth")
        props = facts.desc.nodes[bsdf.node].props
        props.set_plugin_name(ROUGH_TO_SMOOTH[bsdf.plugin])
        for key in ROUGH_ONLY_PROPS:
            if key in props:
                del props[key]


def set_integrator(facts: SceneFacts, integrator: IntegratorSpec) -> None:
    props = mi.Properties(str(integrator["type"]))
    for key, value in integrator.items():
        if key != "type":
            props[key] = value
    if facts.scan.integrator is None:
        add_node(facts.desc, mi.ObjectType.Integrator, props, 0, "_mcrt_integrator")
    else:
        facts.desc.nodes[facts.scan.integrator].props = props


def area_to_point(facts: SceneFacts) -> None:
    """Replace every area-lit shape by a point light at the centre of its
    bounding box, of intensity ``L * A`` for planar shapes and ``L * A / 4``
    otherwise (see :mod:`mcrt.render.plan`)."""
    desc = facts.desc
    shapes = shapes_by_id(facts.scene)
    for k, (shape, emitter) in enumerate(facts.scan.area_lights):
        sprops = desc.nodes[shape].props  # valid until the append below
        radiance = rgb(desc.nodes[emitter].props, "radiance")
        if radiance is None:
            raise McrtError(f"soft_shadows=off: the area light on '{sprops.id()}' has a textured "
                            f"or spectral radiance; only rgb/float radiance converts to a point")
        obj = shapes[sprops.id()]
        area = float(np.array(obj.surface_area()).ravel()[0])
        factor = 1.0 if sprops.plugin_name() in PLANAR_SHAPES else 0.25
        keys = [key for key, i in children(desc, desc.nodes[0].props) if i == shape]
        if not keys:
            raise McrtError(f"soft_shadows=off: the area-lit shape '{sprops.id()}' is not a "
                            f"top-level shape")
        for key in keys:
            del desc.nodes[0].props[key]
        point = mi.Properties("point")
        point["position"] = dr.scalar.Array3f64(*[float(c) for c in bbox_centre(obj)])
        point["intensity"] = mi.ScalarColor3d(*[float(c) for c in radiance * area * factor])
        add_node(desc, mi.ObjectType.Emitter, point, 0, f"_mcrt_point_light_{k}")


def bake_pose(facts: SceneFacts, t: float) -> None:
    """Put moving shapes at their pose at time ``t`` (motion off, shutter open at t != 0)."""
    shapes = shapes_by_id(facts.scene)
    for node, motion in facts.scan.motions.items():
        props = facts.desc.nodes[node].props
        centre = bbox_centre(shapes[motion.shape])
        props["to_world"] = mi.ScalarTransform4d(motion.matrix(t, centre)
                                                 @ matrix(props, "to_world"))
