"""What a scene description contains, as far as the plan is concerned.

:func:`scan_scene` walks the parse state once: the sensor and integrator
nodes, the emitters (area lights with their shapes), the BSDFs by roughness,
the shapes that reflect light, and the shapes' ``mcrt_*`` motion (which it
removes from the description, so that Mitsuba can instantiate it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import mitsuba as mi

from ...errors import SceneError
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
#: BSDFs that are glossy whatever their parameters (Mitsuba 3.9's plugin names;
#: ``pplastic`` is a rough polarized plastic, alpha 0.1 unless set, with no smooth
#: counterpart to turn into).
ALWAYS_GLOSSY = {"principled", "principledthin", "measured", "hair", "pplastic"}
SPECULAR = {"conductor", "dielectric", "thindielectric", "plastic", "polarizer", "retarder",
            "circular"}
DIELECTRIC = {"dielectric", "roughdielectric", "thindielectric"}
#: BSDFs with a cut-out (a null lobe weighted by an opacity): Mitsuba 3.9's ``path``
#: renders them too dark (docs/mask-path-bias.md; :func:`.integrator.choose_integrator`).
CUT_OUT = {"mask"}
#: Emitters that light from an area (a BSDF sample helps them through MIS).
EXTENDED_EMITTERS = {"area", "constant", "envmap", "sunsky", "directionalarea"}
#: Emitters of a single position or direction: the highlight a nearly smooth rough
#: BSDF shows of one is lost when the BSDF is made smooth (delta meets delta).
DELTA_EMITTERS = {"point", "spot", "directional", "projector"}
#: Shapes that cannot light themselves whatever their BSDF: flat ones.
FLAT_SHAPES = {"rectangle", "disk"}
#: Closed convex shapes: with outward normals and a one-sided opaque BSDF only their
#: outside reflects, and no point of it sees another.
CONVEX_SHAPES = {"sphere", "cube"}
#: BSDFs that reflect on the side of the normal only and transmit nothing.
ONE_SIDED_OPAQUE = {"diffuse", "conductor", "roughconductor", "plastic", "roughplastic",
                    "pplastic"}
#: Integrators the plan may replace; any other is rendered as authored.
REPLANNABLE = {"path", "direct"}
#: ``max_depth`` of Mitsuba 3.9.1's integrators when the scene sets none (-1:
#: unbounded); ``max_depth`` 2 is direct lighting, larger values add indirect light.
DEFAULT_MAX_DEPTH = {"path": -1, "volpath": -1, "volpathmis": -1, "ptracer": -1, "prb": 6,
                     "prb_basic": 6, "prbvolpath": 6, "direct_projective": 2}
#: Integrators that never follow light past one bounce (or trace none at all).
NO_INDIRECT = {"direct", "depth", "aov"}
#: Integrators that render no lighting at all, what they render instead: ``depth``,
#: and an ``aov`` that wraps no integrator (its AOV channels only).
NO_LIGHTING = {"depth": "distances", "aov": "its AOV channels"}
#: Integrators that render participating media (the others ignore them).
VOLUMETRIC = {"volpath", "volpathmis", "prbvolpath"}


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
    cut_outs: list[str] = field(default_factory=list)  # ids (else plugins) of mask BSDFs
    reflecting_shapes: int = 0
    #: Reflecting shapes one point of which may light another of the same shape
    #: (:func:`can_light_itself`), as "plugin (why)".
    self_lighting: list[str] = field(default_factory=list)
    motions: dict[int, Motion] = field(default_factory=dict)  # shape node -> motion
    media: list[str] = field(default_factory=list)  # "homogeneous (interior of 'glass')", ...

    @property
    def moving(self) -> list[Motion]:
        """Motions that move something."""
        return [m for m in self.motions.values() if not m.is_static]


def scan_scene(desc: SceneDescription) -> Scan:
    """Scan the description (and strip its shapes' motion properties)."""
    nodes = desc.nodes
    scan = Scan()
    top = [i for _, i in children(desc, nodes[0].props)]
    sensors = _sensors_in_mitsubas_order(desc, top)
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
        if node.type in (mi.ObjectType.Shape, mi.ObjectType.Sensor):
            _scan_media(scan, desc, node.props)
    _check_motions_move_scene_shapes(desc, scan)
    return scan


def _check_motions_move_scene_shapes(desc: SceneDescription, scan: Scan) -> None:
    """Motion moves what ``scene.shapes()`` holds (shapes and instances): a
    ``shapegroup`` and the shapes in one are not there (every instance of the
    group shares them), so moving them is refused, naming what to move instead."""
    nodes = desc.nodes
    groups = {j: nodes[i].props.id() for i, node in enumerate(nodes)
              if node.type == mi.ObjectType.Shape and node.props.plugin_name() == "shapegroup"
              for _, j in children(desc, node.props)}
    for i, motion in scan.motions.items():
        if nodes[i].props.plugin_name() == "shapegroup":
            raise SceneError(f"shapegroup '{motion.shape}' cannot move: mcrt moves the "
                             f"scene's shapes and instances; give its instances (<shape "
                             f"type=\"instance\">) the mcrt_* motion properties")
        if i in groups:
            raise SceneError(f"shape '{motion.shape}' cannot move: it is in the shapegroup "
                             f"'{groups[i]}', whose shapes every instance shares; give the "
                             f"instances (<shape type=\"instance\">) the mcrt_* motion "
                             f"properties")


def _sensors_in_mitsubas_order(desc: SceneDescription, top: list[int]) -> list[int]:
    """The sensor nodes in the order of ``mi.Scene.sensors()``: the scene's children in
    document order, a shape standing for the sensor attached to it (an irradiance
    meter, say). mcrt renders from the first, as ``mi.render`` does."""
    found = []
    for i in top:
        if desc.nodes[i].type == mi.ObjectType.Sensor:
            found.append(i)
        elif desc.nodes[i].type == mi.ObjectType.Shape:
            found += [j for _, j in children(desc, desc.nodes[i].props)
                      if desc.nodes[j].type == mi.ObjectType.Sensor]
    return found


def _scan_media(scan: Scan, desc: SceneDescription, props: mi.Properties) -> None:
    """The participating media a shape (interior, exterior) or sensor holds."""
    for key, j in children(desc, props):
        if desc.nodes[j].type == mi.ObjectType.Medium:
            owner = props.id() or props.plugin_name()
            role = "medium" if key.startswith("_arg_") else key  # a sensor's has no name
            scan.media.append(f"{desc.nodes[j].props.plugin_name()} ({role} of '{owner}')")


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
    if name in CUT_OUT:
        scan.cut_outs.append(props.id() or name)


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
    # Mitsuba gives an emitting shape without a BSDF a black one; with one (not
    # black itself), it reflects light like any other shape.
    has_bsdf = any(desc.nodes[j].type == mi.ObjectType.BSDF and not _black(desc.nodes[j].props)
                   for _, j in children(desc, props))
    if not emitters or has_bsdf:
        scan.reflecting_shapes += 1
        why = can_light_itself(desc, props)
        if why:
            scan.self_lighting.append(f"{props.id() or name} ({why})")


def _black(bsdf: mi.Properties) -> bool:
    """A ``diffuse`` BSDF of constant reflectance 0 (an emitter's explicit black
    BSDF): it reflects nothing."""
    if bsdf.plugin_name() != "diffuse" or "reflectance" not in bsdf:
        return False
    value: Any = bsdf["reflectance"]
    if isinstance(value, int | float):
        return value == 0
    try:
        return all(float(c) == 0 for c in value)
    except TypeError:  # a texture: not known to be black
        return False


def can_light_itself(desc: SceneDescription, props: mi.Properties) -> str:
    """Why a reflecting shape may light itself (light leaving one of its points
    reaching another), or "" when it cannot: a flat shape, or a closed convex one
    with outward normals and a one-sided opaque BSDF. Any other shape is assumed
    to (a mesh, an open cylinder, a curve, a plugin mcrt does not know), which
    costs indirect bounces but never loses light."""
    name = props.plugin_name()
    if name in FLAT_SHAPES:
        return ""
    if name not in CONVEX_SHAPES:
        return "not known to be flat or convex"
    if "flip_normals" in props and bool(props["flip_normals"]):
        return "normals flipped: its inside reflects"
    bsdfs = [desc.nodes[j].props.plugin_name() for _, j in children(desc, props)
             if desc.nodes[j].type == mi.ObjectType.BSDF]
    other = [b for b in bsdfs if b not in ONE_SIDED_OPAQUE]
    return f"a {other[0]} BSDF may reflect or pass light inside" if other else ""


def environment_emitters(scan: Scan) -> list[str]:
    """Kinds of the scene's extended emitters other than area lights (sorted)."""
    return sorted({k for k in scan.emitter_kinds if k in EXTENDED_EMITTERS - {"area"}})


@dataclass
class AuthoredIntegrator:
    """The scene's own integrator (``path`` when it names none), with the
    integrators it wraps (``moment``, ``aov``, ``adaptive``, a user plugin)."""

    label: str                 # as plans report it, e.g. "path (default)", "moment(path)"
    props: mi.Properties       # a copy: the description's may be edited
    nested: list[AuthoredIntegrator] = field(default_factory=list)

    @classmethod
    def of(cls, desc: SceneDescription, scan: Scan) -> AuthoredIntegrator:
        if scan.integrator is None:
            return cls("path (default)", mi.Properties("path"))
        return cls._read(desc, scan.integrator)

    @classmethod
    def _read(cls, desc: SceneDescription, node: int) -> AuthoredIntegrator:
        props = mi.Properties(desc.nodes[node].props)
        nested = [cls._read(desc, j) for _, j in children(desc, props)
                  if desc.nodes[j].type == mi.ObjectType.Integrator]
        label = props.plugin_name()
        if nested:
            label += f"({', '.join(n.label for n in nested)})"
        return cls(label, props, nested)

    @property
    def kind(self) -> str:
        return self.props.plugin_name()

    @property
    def max_depth(self) -> int:
        """The authored ``max_depth``, else Mitsuba's default (-1: unbounded)."""
        if "max_depth" in self.props:
            return integer(self.props, "max_depth")
        return DEFAULT_MAX_DEPTH.get(self.kind, -1)

    @property
    def depth_limit(self) -> int | None:
        """The smallest ``max_depth`` the author wrote (>= 0) on an integrator that
        traces light, or None: an upper bound the plan never exceeds."""
        written = [leaf.max_depth for leaf in self.leaves()
                   if "max_depth" in leaf.props and leaf.max_depth >= 0]
        return min(written) if written else None

    def leaves(self) -> list[AuthoredIntegrator]:
        """The integrators that trace light: this one, or those it wraps."""
        if not self.nested:
            return [self]
        return [leaf for n in self.nested for leaf in n.leaves()]

    def traces_indirect(self) -> bool | None:
        """Whether this (leaf) integrator follows light past direct lighting;
        None when mcrt cannot tell (a plugin it does not know, no max_depth)."""
        if self.kind in NO_INDIRECT or self.nested:
            return False
        if "max_depth" not in self.props and self.kind not in DEFAULT_MAX_DEPTH:
            return None
        return self.max_depth < 0 or self.max_depth > 2

    @property
    def unlit(self) -> bool:
        """Whether every integrator that traces light stops before any lighting:
        ``max_depth`` 0 renders nothing, 1 only the emitters the camera sees; or
        renders none at all (:data:`NO_LIGHTING`). Such an integrator is rendered
        as authored (``direct`` would light it)."""
        return all(leaf.kind in NO_LIGHTING
                   or ("max_depth" in leaf.props and 0 <= leaf.max_depth <= 1)
                   for leaf in self.leaves())

    @property
    def replannable(self) -> bool:
        return self.kind in REPLANNABLE and not self.unlit

    @property
    def deep(self) -> bool:
        """A ``path`` integrator that goes past direct lighting."""
        return self.kind == "path" and (self.max_depth < 0 or self.max_depth > 2)
