"""What a scene description contains, as far as the plan is concerned.

:func:`scan_scene` walks the parse state once: the sensor and integrator
nodes, the emitters (area lights with their shapes), the BSDFs by roughness,
the shapes that reflect light, and the shapes' ``mcrt_*`` motion (which it
removes from the description, so that Mitsuba can instantiate it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import mitsuba as mi

from ..motion import Motion, take_motion
from ..scene import SceneDescription
from .nodes import children, integer

#: Rough BSDFs and the smooth plugins they become when glossy is off.
ROUGH_TO_SMOOTH = {"roughconductor": "conductor", "roughplastic": "plastic",
                   "roughdielectric": "dielectric"}
#: Properties only the rough plugins take (removed when one turns smooth).
ROUGH_ONLY_PROPS = ("alpha", "alpha_u", "alpha_v", "distribution", "sample_visible")
#: Mitsuba's ``alpha`` when a rough BSDF sets none.
DEFAULT_ALPHA = 0.1
#: BSDFs that are glossy whatever their parameters.
ALWAYS_GLOSSY = {"principled", "principledthinfilm", "measured", "hair"}
SPECULAR = {"conductor", "dielectric", "thindielectric", "plastic", "polarizer", "retarder"}
DIELECTRIC = {"dielectric", "roughdielectric", "thindielectric"}
#: Emitters that light from an area (a BSDF sample helps them through MIS).
EXTENDED_EMITTERS = {"area", "constant", "envmap", "sunsky", "directionalarea"}
MESH_SHAPES = {"obj", "ply", "serialized", "mesh", "merge", "shapegroup", "instance"}
#: Integrators the plan may replace; any other is rendered as authored.
REPLANNABLE = {"path", "direct"}


class RoughBSDF(NamedTuple):
    """A BSDF node with glossy lobes and its roughness (None: not a number,
    for BSDFs glossy by nature; inf: a textured roughness)."""

    node: int
    plugin: str
    alpha: float | None


@dataclass
class Scan:
    """What the parse state says about the scene."""

    sensor: int = -1                    # node index (-1: none; instantiating says so)
    integrator: int | None = None
    area_lights: list[tuple[int, int]] = field(default_factory=list)  # (shape, emitter)
    emitter_kinds: list[str] = field(default_factory=list)
    rough: list[RoughBSDF] = field(default_factory=list)
    specular: list[str] = field(default_factory=list)
    dielectric: bool = False
    reflecting_shapes: int = 0
    mesh_shapes: int = 0
    motions: dict[int, Motion] = field(default_factory=dict)  # shape node -> motion

    @property
    def moving(self) -> list[Motion]:
        """Motions that move something."""
        return [m for m in self.motions.values() if not m.is_static]


def scan_scene(desc: SceneDescription) -> Scan:
    """Scan the description (and strip its shapes' motion properties)."""
    nodes = desc.nodes
    scan = Scan()
    top = [i for _, i in children(desc, nodes[0].props)]
    sensors = [i for i in top if nodes[i].type == mi.ObjectType.Sensor]
    integrators = [i for i in top if nodes[i].type == mi.ObjectType.Integrator]
    scan.sensor = sensors[0] if sensors else -1
    scan.integrator = integrators[0] if integrators else None
    for i, node in enumerate(nodes):
        if node.type == mi.ObjectType.Emitter:
            scan.emitter_kinds.append(node.props.plugin_name())
        elif node.type == mi.ObjectType.BSDF:
            _scan_bsdf(scan, i, node.props)
        elif node.type == mi.ObjectType.Shape:
            _scan_shape(scan, desc, i, node.props)
    return scan


def _roughness(props: mi.Properties) -> float:
    """Largest alpha of a rough BSDF; inf for a textured one."""
    alpha: float | None = None
    for key in ("alpha", "alpha_u", "alpha_v"):
        if key in props:
            value = props[key]
            if not isinstance(value, float):
                return math.inf  # a texture: treat as rough
            alpha = max(alpha or 0.0, value)
    return DEFAULT_ALPHA if alpha is None else alpha


def _scan_bsdf(scan: Scan, node: int, props: mi.Properties) -> None:
    name = props.plugin_name()
    if name in ROUGH_TO_SMOOTH:
        scan.rough.append(RoughBSDF(node, name, _roughness(props)))
    elif name in ALWAYS_GLOSSY:
        scan.rough.append(RoughBSDF(node, name, None))
    elif name in SPECULAR:
        scan.specular.append(name)
    scan.dielectric |= name in DIELECTRIC


def _scan_shape(scan: Scan, desc: SceneDescription, node: int, props: mi.Properties) -> None:
    name = props.plugin_name()
    motion = take_motion(props, f"shape '{props.id() or name}'")
    if motion is not None:
        scan.motions[node] = motion
    emitters = [j for _, j in children(desc, props)
                if desc.nodes[j].type == mi.ObjectType.Emitter]
    for j in emitters:
        if desc.nodes[j].props.plugin_name() == "area":
            scan.area_lights.append((node, j))
    if not emitters:
        scan.reflecting_shapes += 1
        scan.mesh_shapes += name in MESH_SHAPES


def environment_emitters(scan: Scan) -> list[str]:
    """Kinds of the scene's extended emitters other than area lights (sorted)."""
    return sorted({k for k in scan.emitter_kinds if k in EXTENDED_EMITTERS - {"area"}})


@dataclass
class AuthoredIntegrator:
    """The scene's own integrator (``path`` when it names none)."""

    label: str                 # as plans report it, e.g. "path (default)"
    props: mi.Properties       # a copy: the description's may be edited

    @classmethod
    def of(cls, desc: SceneDescription, scan: Scan) -> AuthoredIntegrator:
        if scan.integrator is None:
            return cls("path (default)", mi.Properties("path"))
        props = mi.Properties(desc.nodes[scan.integrator].props)
        return cls(props.plugin_name(), props)

    @property
    def kind(self) -> str:
        return self.props.plugin_name()

    @property
    def max_depth(self) -> int:
        """The authored ``max_depth``; -1 (unbounded) when unset."""
        return integer(self.props, "max_depth") if "max_depth" in self.props else -1

    @property
    def replannable(self) -> bool:
        return self.kind in REPLANNABLE

    @property
    def deep(self) -> bool:
        """A ``path`` integrator that goes past direct lighting."""
        return self.kind == "path" and (self.max_depth < 0 or self.max_depth > 2)
