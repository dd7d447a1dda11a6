"""Render plans: simulate only the distribution effects a scene calls for.

:func:`plan_scene` reads a Mitsuba XML scene (through ``mi.parser``, so
``$key`` parameters work as in ``mi.load_file``), finds which distribution
ray-tracing effects it contains, and builds the scene that renders exactly
those:

============  =====================================  ===================================
effect        on when the scene has                  switched off by
============  =====================================  ===================================
aa            always (the film position sample)      cannot be switched off
soft_shadows  an ``area`` emitter                    each area-lit shape -> a ``point``
                                                     light at its centre (see below)
glossy        a rough BSDF (``roughconductor``,      rough -> smooth counterpart
              ``roughplastic``, ``roughdielectric``  (``conductor``, ``plastic``,
              with alpha >= 1e-3, ``principled``)    ``dielectric``)
dof           a ``thinlens`` camera whose circle of  ``thinlens`` -> ``perspective``
              confusion reaches 0.5 px somewhere in  (same fov, pose, clip, film)
              the visible depth range
motion        a moving shape (``mcrt_velocity`` ...) one sub-frame, shapes at their
              and an open shutter, streak >= 0.25 px shutter-open pose
indirect      a ``path`` integrator deeper than 2    the shortest path the remaining
              and at least two reflecting shapes     effects need
              (or a mesh, which may see itself)
============  =====================================  ===================================

Then the plan chooses:

* **integrator**: ``path`` at the author's depth when indirect light is on;
  else ``path`` at ``max_depth = 2 + k`` when glossy or specular surfaces must
  show other objects (``k = 1``, ``2`` with dielectrics: in and out); else
  ``direct`` with one emitter sample and a BSDF sample only when MIS needs one
  (glossy surfaces or emitters with area), so a scene lit by point lights
  draws film 2D + emitter 2D and nothing else;
* **camera**: as authored, or ``perspective`` when depth of field is off;
* **shutter**: always closed in the rendered scene (Mitsuba's shapes ignore ray
  time, so a per-path time sample would be wasted); motion blur is rendered by
  time-stratified sub-frames (:mod:`mcrt.render.motion`).

``overrides`` (``{"dof": False, "motion": True}``) switch effects off or force
them on; forcing on an effect the scene does not have is an error, forcing on
one the plan found negligible keeps it. The plan lists the sample dimensions a
camera path consumes, in the order Mitsuba's integrators draw them (checked
against counted ``next_1d``/``next_2d`` calls in ``tests/test_plan.py``).

An area light switched off becomes a ``point`` light at the centre of its
shape's bounding box with intensity ``L * A`` for planar shapes (``rectangle``,
``disk``: their intensity along the normal) and ``L * A / 4`` otherwise (exact
for spheres; the mean projected area of any convex shape is ``A / 4``); the
light's shape is removed from the scene.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError, SceneError
from . import distribution
from .motion import (
    NEGLIGIBLE_STREAK_PX,
    SUBFRAME_STEP_PX,
    Motion,
    MotionDriver,
    sample_times,
    subframe_count,
    subframe_times,
    take_motion,
)
from .scene import check_scene_file, mitsuba_message, quiet_sampler_warnings, sampler_name

#: Effect names in the order plans list them, with a one-line description.
EFFECTS: dict[str, str] = {
    "aa": "antialiasing: samples over the pixel area",
    "soft_shadows": "soft shadows: samples over area lights",
    "glossy": "glossy reflection: samples over rough BSDF lobes",
    "dof": "depth of field: samples over the thin lens",
    "motion": "motion blur: time-stratified sub-frames",
    "indirect": "indirect light: paths longer than direct lighting",
}

#: Depth of field is negligible when no visible depth blurs by this many pixels.
DOF_NEGLIGIBLE_PX = 0.5
#: A rough BSDF whose alpha is below this is rendered as its smooth counterpart.
GLOSSY_MIN_ALPHA = 1e-3
#: ``max_depth`` of ``path`` when indirect light is forced on in a scene whose
#: own integrator sets none deeper than direct lighting.
DEFAULT_INDIRECT_DEPTH = 8

_ROUGH_TO_SMOOTH = {"roughconductor": "conductor", "roughplastic": "plastic",
                    "roughdielectric": "dielectric"}
_ROUGH_ONLY_PROPS = ("alpha", "alpha_u", "alpha_v", "distribution", "sample_visible")
_ALWAYS_GLOSSY = {"principled", "principledthinfilm", "measured", "hair"}
_SPECULAR = {"conductor", "dielectric", "thindielectric", "plastic", "polarizer", "retarder"}
_DIELECTRIC = {"dielectric", "roughdielectric", "thindielectric"}
_EXTENDED_EMITTERS = {"area", "constant", "envmap", "sunsky", "directionalarea"}
_PLANAR_SHAPES = {"rectangle", "disk"}
_MESH_SHAPES = {"obj", "ply", "serialized", "mesh", "merge", "shapegroup", "instance"}
_REPLANNABLE = {"path", "direct"}

_T = mi.Properties.Type


# ----------------------------------------------------------------------------
# The plan
# ----------------------------------------------------------------------------
@dataclass
class Effect:
    """One effect's decision: whether the scene has it, whether it renders, why."""

    name: str
    present: bool
    on: bool
    reason: str
    forced: bool | None = None  # the user's override, if any

    def to_dict(self) -> dict:
        out = {"on": self.on, "present": self.present, "reason": self.reason}
        if self.forced is not None:
            out["forced"] = "on" if self.forced else "off"
        return out


@dataclass
class Dimension:
    """A group of sampler calls of one camera path: ``label`` drawn ``ndim``-D."""

    label: str
    ndim: int


@dataclass
class RenderPlan:
    """What mcrt renders for a scene (see the module docstring)."""

    scene: str
    effects: dict[str, Effect]
    camera: str                 # sensor plugin rendered with
    scene_camera: str           # sensor plugin of the scene as authored
    integrator: dict            # plugin name under "type" + its properties
    integrator_reason: str
    scene_integrator: str
    shutter: tuple[float, float]        # the scene's shutter (open, close)
    sampler: str
    spp: int
    motions: list[Motion] = field(default_factory=list)
    streak_px: float = 0.0              # longest screen-space motion over the shutter
    coc_px: tuple[float, float] | None = None   # circle of confusion over visible depths
    subframes: int = 1
    subframe_times: list[float] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    # -- queries --------------------------------------------------------------
    def on(self, effect: str) -> bool:
        return self.effects[effect].on

    @property
    def effects_on(self) -> list[str]:
        return [name for name, e in self.effects.items() if e.on]

    def camera_dimensions(self) -> list[Dimension]:
        """Sampler calls a camera sample makes before the integrator runs."""
        dims = [Dimension("film", 2)]
        if self.camera == "thinlens":
            dims.append(Dimension("lens", 2))
        return dims  # the rendered shutter is closed: no per-path time sample

    def bounce_dimensions(self) -> tuple[list[Dimension], int | None]:
        """Sampler calls per integrator step and the number of steps (None:
        unbounded). Orders as Mitsuba 3.9.1 draws them (``direct`` passes
        ``next_1d(), next_2d()`` as arguments of one call, which this build
        evaluates right to left)."""
        kind = self.integrator["type"]
        if kind == "direct":
            e = int(self.integrator.get("emitter_samples", 1))
            b = int(self.integrator.get("bsdf_samples", 1))
            return ([Dimension("emitter", 2)] * e
                    + [Dimension("BSDF direction", 2), Dimension("BSDF lobe", 1)] * b), 1
        if kind == "distribution":
            return ([Dimension("emitter", 2), Dimension("BSDF lobe", 1),
                     Dimension("BSDF direction", 2)], int(self.integrator["max_depth"]))
        if kind == "path":
            depth = int(self.integrator.get("max_depth", -1))
            return ([Dimension("emitter", 2), Dimension("BSDF lobe", 1),
                     Dimension("BSDF direction", 2),
                     Dimension("roulette", 1)], None if depth < 0 else depth)
        return [], None

    def max_calls(self) -> tuple[int, int] | None:
        """(sampler calls, scalar dimensions) of the longest camera path, or
        None when unbounded or unknown."""
        per, steps = self.bounce_dimensions()
        if steps is None:
            return None
        dims = self.camera_dimensions() + per * steps
        return len(dims), sum(d.ndim for d in dims)

    # -- output ---------------------------------------------------------------
    def to_dict(self) -> dict:
        per, steps = self.bounce_dimensions()
        out = {
            "scene": self.scene,
            "effects": {name: e.to_dict() for name, e in self.effects.items()},
            "effects_on": self.effects_on,
            "camera": self.camera, "scene_camera": self.scene_camera,
            "integrator": self.integrator, "integrator_reason": self.integrator_reason,
            "scene_integrator": self.scene_integrator,
            "shutter": list(self.shutter), "subframes": self.subframes,
            "subframe_times": [round(t, 9) for t in self.subframe_times],
            "sampler": self.sampler, "spp": self.spp,
            "dimensions": {"camera": [[d.label, d.ndim] for d in self.camera_dimensions()],
                           "per_step": [[d.label, d.ndim] for d in per],
                           "steps": steps},
            "streak_px": round(self.streak_px, 4),
            "motions": [m.to_dict() for m in self.motions],
            "notes": self.notes,
        }
        if self.coc_px is not None:
            out["coc_px"] = [round(c, 4) for c in self.coc_px]
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))

    def describe(self) -> str:
        """The plan as ``mcrt plan`` prints it."""
        lines = [f"plan for {self.scene}", "effects:"]
        for name, e in self.effects.items():
            state = "on " if e.on else "off"
            forced = f" (forced {'on' if e.forced else 'off'})" if e.forced is not None else ""
            lines.append(f"  {name:13s} {state}  {e.reason}{forced}")
        integ = ", ".join(f"{k} {v}" for k, v in self.integrator.items() if k != "type")
        lines.append(f"integrator:   {self.integrator['type']}"
                     f"{f' ({integ})' if integ else ''} - {self.integrator_reason}"
                     f" [scene: {self.scene_integrator}]")
        lines.append(f"camera:       {self.camera} [scene: {self.scene_camera}]")
        t0, t1 = self.shutter
        if self.on("motion"):
            per = self.spp // self.subframes
            lines.append(f"shutter:      [{t0:g}, {t1:g}] in {self.subframes} time-stratified "
                         f"sub-frames of {per} spp (streak up to {self.streak_px:.1f} px)")
        else:
            lines.append(f"shutter:      closed (instant {t0:g}); one sub-frame")
        lines.append(f"sampler:      {self.sampler}, {self.spp} spp")
        lines.append("dimensions per camera path (sampler calls in order):")
        camera = ", ".join(f"{d.label} {d.ndim}D" for d in self.camera_dimensions())
        per, steps = self.bounce_dimensions()
        if self.integrator["type"] == "direct":
            lines.append(f"  {camera}, " + ", ".join(f"{d.label} {d.ndim}D" for d in per))
        elif per:
            count = "unbounded, until roulette or escape" if steps is None else f"up to {steps}"
            lines.append(f"  {camera}, then per path vertex ({count}): "
                         + ", ".join(f"{d.label} {d.ndim}D" for d in per))
        else:
            lines.append(f"  {camera}, then whatever '{self.integrator['type']}' draws")
        calls = self.max_calls()
        if calls is not None:
            lines.append(f"  = at most {calls[0]} calls, {calls[1]} scalar dimensions")
        if self.on("motion"):
            lines.append(f"  + per sub-frame: time 1D ({self.subframes} stratified values, "
                         f"not a per-path dimension)")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


# ----------------------------------------------------------------------------
# Overrides from the command line
# ----------------------------------------------------------------------------
def parse_effect_overrides(items: Iterable[str] | None) -> dict[str, bool]:
    """``["dof=off,motion=on", "glossy=off"]`` -> ``{"dof": False, ...}``."""
    out: dict[str, bool] = {}
    for item in items or []:
        for part in item.split(","):
            part = part.strip()
            if not part:
                continue
            name, sep, value = part.partition("=")
            name, value = name.strip().replace("-", "_"), value.strip().lower()
            if not sep or value not in ("on", "off"):
                raise McrtError(f"--effect expects NAME=on|off, got {part!r}")
            if name not in EFFECTS:
                raise McrtError(f"unknown effect {name!r}; effects: {', '.join(EFFECTS)}")
            if name == "aa" and value == "off":
                raise McrtError("antialiasing cannot be switched off: every camera sample "
                                "draws its position in the pixel (film 2D)")
            out[name] = value == "on"
    return out


# ----------------------------------------------------------------------------
# Parse state helpers
# ----------------------------------------------------------------------------
def _children(state: mi.parser.ParserState, props: mi.Properties) -> list[tuple[str, int]]:
    """(property name, node index) of every child object of a node."""
    out = []
    for key in props.keys():
        kind = props.type(key)
        if kind == _T.ResolvedReference:
            out.append((key, props[key].index()))
        elif kind == _T.Reference:
            ref = str(props[key])
            ref = ref[len("Reference["):-1] if ref.startswith("Reference[") else ref
            if ref in state.id_to_index:
                out.append((key, state.id_to_index[ref]))
    return out


def _add_node(state: mi.parser.ParserState, kind, props: mi.Properties, parent: int,
              key: str) -> int:
    """Append a node and reference it from node ``parent`` as ``key``.

    Appending may reallocate the node list: every ``state.nodes[i].props``
    obtained before is then dangling, so the parent is looked up afterwards.
    """
    node = mi.parser.SceneNode()
    node.type = kind
    node.props = props
    state.nodes.append(node)
    index = len(state.nodes) - 1
    state.nodes[parent].props[key] = mi.Properties.ResolvedReference(index)
    return index


def _float(props: mi.Properties, name: str, default: float) -> float:
    if name not in props:
        return default
    try:
        return float(props[name])
    except (TypeError, ValueError):
        return default


def _rgb(props: mi.Properties, name: str) -> np.ndarray | None:
    if name not in props:
        return None
    kind = props.type(name)
    if kind == _T.Color:
        return np.array([float(c) for c in props[name]], dtype=np.float64)
    if kind == _T.Float:
        return np.full(3, float(props[name]))
    return None


def _parse(path: str | Path, params: dict[str, str] | None):
    path = check_scene_file(path)
    config = mi.parser.ParserConfig(mi.variant())
    try:
        state = mi.parser.parse_file(config, str(path), **(params or {}))
    except Exception as error:
        raise SceneError(f"cannot load scene {path}: {mitsuba_message(error)}") from None
    if state.nodes[0].type != mi.ObjectType.Scene:
        raise SceneError(f"{path} does not describe a scene (its root is not <scene>)")
    return config, state


def _instantiate(config, state, path) -> mi.Scene:
    state = mi.parser.ParserState(state)  # transforms edit the state: keep ours
    # Files a scene names (meshes, textures) are relative to its folder, as with
    # mi.load_file; mi.parser.instantiate does not add that folder itself.
    resolver = mi.file_resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    resolver.prepend(str(Path(path).resolve().parent))
    try:
        mi.parser.transform_all(config, state)
        scene = mi.parser.instantiate(config, state)
    except Exception as error:
        raise SceneError(f"cannot load scene {path}: {mitsuba_message(error)}") from None
    finally:
        resolver.clear()
        for entry in saved:
            resolver.append(entry)
    if not isinstance(scene, mi.Scene):
        raise SceneError(f"{path} does not describe a scene (its root is not <scene>)")
    if not scene.sensors():
        raise SceneError(f"{path} has no sensor to render from")
    return scene


# ----------------------------------------------------------------------------
# Camera geometry
# ----------------------------------------------------------------------------
@dataclass
class _Camera:
    """Pixel projection of a sensor (perspective/thinlens/orthographic)."""

    kind: str                    # "projective", "orthographic" or "unknown"
    world_to_camera: np.ndarray
    f_px: float                  # pixels per unit tangent (projective) or camera unit
    near: float

    @classmethod
    def of(cls, sensor: mi.Sensor) -> _Camera:
        to_world = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        width = float(sensor.film().size()[0])
        name = sensor.class_name()
        params = mi.traverse(sensor)
        if name in ("PerspectiveCamera", "ThinLensCamera") and "x_fov" in params:
            x_fov = float(np.array(params["x_fov"]).ravel()[0])
            f_px = 0.5 * width / math.tan(math.radians(x_fov) / 2)
            kind = "projective"
        elif name == "OrthographicCamera":
            f_px, kind = 0.5 * width, "orthographic"
        else:
            f_px, kind = 0.0, "unknown"
        return cls(kind, np.linalg.inv(to_world), f_px, float(sensor.near_clip()))

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        return points @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (up to an offset and sign) of world points; NaN
        for points behind a projective camera."""
        cam = self.to_camera(points)
        if self.kind == "projective":
            z = np.where(cam[:, 2] > self.near, cam[:, 2], np.nan)
            return cam[:, :2] / z[:, None] * self.f_px
        return cam[:, :2] * self.f_px


def _visible_depths(scene: mi.Scene, sensor: mi.Sensor, grid: int = 48) -> np.ndarray:
    """Camera-space depths of the surfaces seen through a grid of pixel centres
    (pinhole rays through the lens centre)."""
    u = (np.arange(grid) + 0.5) / grid
    x, y = np.meshgrid(u, u)
    pos = mi.Point2f(mi.Float(x.ravel().astype(np.float32)), mi.Float(y.ravel().astype(np.float32)))
    ray, _ = sensor.sample_ray(mi.Float(sensor.shutter_open()), 0.0, pos, mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    points = np.array(si.p, dtype=np.float64).T
    valid = np.array(si.is_valid(), dtype=bool)
    dr.sync_thread()
    if not valid.any():
        return np.zeros(0)
    cam = _Camera.of(sensor)
    return cam.to_camera(points[valid])[:, 2]


# ----------------------------------------------------------------------------
# Analysis
# ----------------------------------------------------------------------------
@dataclass
class _Scan:
    """What the parse state says about the scene."""

    sensor: int
    integrator: int | None
    area_lights: list[tuple[int, int]]          # (shape node, emitter node)
    emitter_kinds: list[str]
    rough: list[tuple[int, str, float | None]]  # (bsdf node, plugin, alpha)
    specular: list[str]
    dielectric: bool
    reflecting_shapes: int
    mesh_shapes: int
    motions: dict[int, Motion]                  # shape node -> motion


def _scan(state: mi.parser.ParserState, path) -> _Scan:
    nodes = state.nodes
    root = nodes[0].props
    top = [i for _, i in _children(state, root)]
    sensors = [i for i in top if nodes[i].type == mi.ObjectType.Sensor]  # none: error later
    integrators = [i for i in top if nodes[i].type == mi.ObjectType.Integrator]
    area, kinds, rough, specular, motions = [], [], [], [], {}
    dielectric, reflecting, meshes = False, 0, 0
    for i, node in enumerate(nodes):
        props = node.props
        name = props.plugin_name()
        if node.type == mi.ObjectType.Emitter:
            kinds.append(name)
        elif node.type == mi.ObjectType.BSDF:
            if name in _ROUGH_TO_SMOOTH:
                alpha = None
                for key in ("alpha", "alpha_u", "alpha_v"):
                    if key in props:
                        if props.type(key) != _T.Float:
                            alpha = math.inf  # a texture: treat as rough
                            break
                        alpha = max(alpha or 0.0, float(props[key]))
                rough.append((i, name, 0.1 if alpha is None else alpha))  # Mitsuba's default
            elif name in _ALWAYS_GLOSSY:
                rough.append((i, name, None))
            elif name in _SPECULAR:
                specular.append(name)
            dielectric |= name in _DIELECTRIC
        elif node.type == mi.ObjectType.Shape:
            where = f"shape '{props.id() or name}'"
            motion = take_motion(props, where)
            if motion is not None:
                motions[i] = motion
            emitters = [j for _, j in _children(state, props)
                        if nodes[j].type == mi.ObjectType.Emitter]
            for j in emitters:
                if nodes[j].props.plugin_name() == "area":
                    area.append((i, j))
            if not emitters:
                reflecting += 1
                meshes += name in _MESH_SHAPES
    return _Scan(sensor=sensors[0] if sensors else -1,
                 integrator=integrators[0] if integrators else None,
                 area_lights=area, emitter_kinds=kinds, rough=rough, specular=specular,
                 dielectric=dielectric, reflecting_shapes=reflecting, mesh_shapes=meshes,
                 motions=motions)


def _streak_px(scene: mi.Scene, camera: _Camera, motions: list[Motion],
               t0: float, t1: float) -> float:
    """Longest screen-space path (pixels) of a moving shape's bounding-box
    corners over the shutter (inf when the camera model is unknown)."""
    if camera.kind == "unknown":
        return math.inf
    shapes = {s.id(): s for s in scene.shapes()}
    times = sample_times(t0, t1, 17)
    longest = 0.0
    for motion in motions:
        bbox = shapes[motion.shape].bbox()
        lo = np.array(bbox.min, dtype=np.float64).ravel()
        hi = np.array(bbox.max, dtype=np.float64).ravel()
        corners = np.array([[(lo, hi)[(c >> k) & 1][k] for k in range(3)] for c in range(8)])
        centre = 0.5 * (lo + hi)
        tracks = []
        for t in times:
            m = motion.matrix(t, centre)
            tracks.append(camera.project(corners @ m[:3, :3].T + m[:3, 3]))
        steps = np.linalg.norm(np.diff(np.array(tracks), axis=0), axis=-1)  # (times-1, 8)
        length = np.nansum(steps, axis=0)
        if length.size:
            longest = max(longest, float(np.nanmax(length)))
    return longest


class PlannedScene:
    """A scene built to follow its plan, ready for :func:`render_film`.

    ``schedule(sampler, spp, seed)`` fixes the sub-frames for a render (it
    fills ``plan.spp``, ``plan.subframes`` and ``plan.subframe_times``) and
    returns the ``passes`` and ``on_pass`` arguments of ``render_film`` /
    ``render_stats``.
    """

    def __init__(self, plan: RenderPlan, scene: mi.Scene, motions: list[Motion],
                 step_px: float) -> None:
        self.plan = plan
        self.scene = scene
        self.step_px = step_px
        self.driver = MotionDriver(scene, motions if plan.on("motion") else [])

    def subframes_for(self, spp: int) -> int:
        if not self.plan.on("motion"):
            return 1
        return subframe_count(self.plan.streak_px, spp, self.step_px)

    def schedule(self, sampler: mi.Sampler | None = None, spp: int | None = None,
                 seed: int = 0, subframes: int | None = None, time_mode: str = "shifted"
                 ) -> tuple[int | None, Callable[[int, int], None] | None]:
        """``(passes, on_pass)`` for rendering this scene with ``sampler`` at ``spp``.

        ``subframes`` forces the sub-frame count (it must divide the sample count);
        ``time_mode`` is :func:`~mcrt.render.motion.subframe_times`' ``mode``.
        """
        sampler = sampler if sampler is not None else self.scene.sensors()[0].sampler()
        if spp is not None:
            with quiet_sampler_warnings():  # the render that follows reports any rounding
                sampler.set_sample_count(spp)
        spp = sampler.sample_count()
        self.plan.spp, self.plan.sampler = spp, sampler_name(sampler)
        if not self.plan.on("motion"):
            if subframes not in (None, 1):
                raise McrtError("sub-frames need motion blur: the plan has motion off")
            self.plan.subframes, self.plan.subframe_times = 1, []
            return None, None
        n = self.subframes_for(spp) if subframes is None else int(subframes)
        if n < 1 or spp % n:
            raise McrtError(f"cannot split {spp} samples per pixel into {n} sub-frames")
        gap = self.plan.streak_px / n
        self.plan.notes = [s for s in self.plan.notes if not s.startswith("sub-frames are")]
        if subframes is None and gap > self.step_px:
            want = math.ceil(self.plan.streak_px / self.step_px)
            self.plan.notes.append(
                f"sub-frames are {gap:.2f} px apart (> {self.step_px} px): {spp} spp allow "
                f"at most {spp} sub-frames; a strobe-free streak needs {want} or more")
        t0, t1 = self.plan.shutter
        times = subframe_times(n, t0, t1, sampler, seed, mode=time_mode)
        self.driver.times = times
        self.plan.subframes, self.plan.subframe_times = n, [float(t) for t in times]
        return n, self.driver.on_pass


def plan_scene(path: str | Path, params: dict[str, str] | None = None,
               overrides: dict[str, bool] | None = None,
               step_px: float = SUBFRAME_STEP_PX) -> PlannedScene:
    """Analyse the scene at ``path`` and build the scene its plan renders."""
    overrides = dict(overrides or {})
    for name in overrides:
        if name not in EFFECTS:
            raise McrtError(f"unknown effect {name!r}; effects: {', '.join(EFFECTS)}")
    if overrides.get("aa") is False:
        raise McrtError("antialiasing cannot be switched off")
    distribution.register()
    config, state = _parse(path, params)
    scan = _scan(state, path)  # also strips the motion properties
    nodes = state.nodes
    # Emitting shapes get ids so that the analysis scene can name them.
    for k, (shape, _) in enumerate(scan.area_lights):
        if not nodes[shape].props.id():
            nodes[shape].props.set_id(f"mcrt_area_light_{k}")
    scene0 = _instantiate(config, state, path)
    sensor0 = scene0.sensors()[0]
    camera = _Camera.of(sensor0)
    # Node property references dangle once a node is appended (_add_node): all
    # edits through them happen before _area_to_point / _set_integrator.
    sensor_props = nodes[scan.sensor].props
    scene_camera = sensor_props.plugin_name()
    t_open = float(sensor0.shutter_open())
    t_close = t_open + float(sensor0.shutter_open_time())
    notes: list[str] = []
    effects: dict[str, Effect] = {}

    def decide(name: str, present: bool, reason: str, can_force: str | None = None) -> Effect:
        forced = overrides.get(name)
        on = present if forced is None else forced
        if forced and not present and can_force is not None:
            raise McrtError(f"{name}=on: {can_force}")
        effects[name] = Effect(name, present, on, reason, forced)
        return effects[name]

    # -- antialiasing -------------------------------------------------------------
    decide("aa", True, "film position sampled over the pixel area (film 2D)")

    # -- soft shadows -------------------------------------------------------------
    n_area = len(scan.area_lights)
    names = ", ".join(nodes[s].props.id() for s, _ in scan.area_lights)
    lit = scan.reflecting_shapes > 0
    decide("soft_shadows", n_area > 0 and lit,
           f"{n_area} area emitter{'s' if n_area != 1 else ''}" + (f" ({names})" if names else "")
           + ("" if lit or not n_area else " but nothing to light"),
           "the scene has no area emitter" if not n_area else "nothing in the scene to shadow")
    env = sorted({k for k in scan.emitter_kinds if k in _EXTENDED_EMITTERS - {"area"}})
    if env:
        notes.append(f"environment emitters ({', '.join(env)}) light with area too; "
                     f"soft_shadows does not switch them")

    # -- glossy -------------------------------------------------------------------
    glossy = [(i, n, a) for i, n, a in scan.rough if a is None or a >= GLOSSY_MIN_ALPHA]
    smooth_rough = [(i, n, a) for i, n, a in scan.rough if a is not None and a < GLOSSY_MIN_ALPHA]
    desc = ", ".join(f"{nodes[i].props.id() or n} ({n}" + (f", alpha {a:g})" if a is not None
                                                            and math.isfinite(a) else ")")
                     for i, n, a in scan.rough)
    decide("glossy", bool(glossy),
           f"rough BSDFs: {desc}" if glossy else
           (f"roughness below {GLOSSY_MIN_ALPHA:g}: {desc}" if scan.rough else "no rough BSDF"),
           None if scan.rough else "the scene has no rough BSDF")
    # Rough BSDFs rendered smooth: all when glossy is off, the negligibly rough
    # ones unless glossy was forced on.
    if not effects["glossy"].on:
        to_smooth = scan.rough
    else:
        to_smooth = [] if effects["glossy"].forced else smooth_rough

    # -- depth of field -------------------------------------------------------------
    coc = None
    if scene_camera == "thinlens":
        params = mi.traverse(sensor0)
        radius = float(np.array(params["aperture_radius"]).ravel()[0])
        focus = float(np.array(params["focus_distance"]).ravel()[0])
        depths = _visible_depths(scene0, sensor0)
        if depths.size and camera.kind == "projective":
            blur = 2 * radius * camera.f_px * np.abs(1 / focus - 1 / np.maximum(depths, 1e-6))
            coc = (float(blur.min()), float(blur.max()))
        present = coc is None or coc[1] >= DOF_NEGLIGIBLE_PX
        reason = (f"thin lens, aperture radius {radius:g}, focus distance {focus:g}"
                  + (f"; circle of confusion {coc[0]:.2f}..{coc[1]:.2f} px over the visible "
                     f"depths {depths.min():.3g}..{depths.max():.3g}" if coc else ""))
        if not present:
            reason += f" (below {DOF_NEGLIGIBLE_PX} px: negligible)"
        decide("dof", present, reason)
    else:
        decide("dof", False, f"pinhole camera ({scene_camera})",
               "the camera is not a thinlens (give it aperture_radius and focus_distance)")

    # -- motion ---------------------------------------------------------------------
    motions = [m for m in scan.motions.values() if not m.is_static]
    streak = 0.0
    if motions and t_close > t_open:
        streak = _streak_px(scene0, camera, motions, t_open, t_close)
    ids = ", ".join(m.shape for m in motions)
    if not motions:
        reason, present, why = "no moving shape", False, "the scene has no moving shape"
    elif t_close <= t_open:
        reason, present = f"moving shapes ({ids}) but the shutter is closed", False
        why = "the sensor's shutter is closed (set shutter_open < shutter_close)"
    else:
        reason = (f"{len(motions)} moving shape{'s' if len(motions) != 1 else ''} ({ids}); "
                  f"streak up to {streak:.1f} px over the shutter [{t_open:g}, {t_close:g}]")
        present, why = streak >= NEGLIGIBLE_STREAK_PX, None
        if not present:
            reason += f" (below {NEGLIGIBLE_STREAK_PX} px: negligible)"
        if camera.kind == "unknown":
            notes.append(f"cannot project motion through a '{scene_camera}' camera: "
                         f"one sub-frame per sample")
    decide("motion", present, reason, why)

    # -- indirect light and the integrator --------------------------------------
    if scan.integrator is None:
        scene_integrator, author = "path (default)", mi.Properties("path")
    else:
        author = nodes[scan.integrator].props
        scene_integrator = author.plugin_name()
    kind = author.plugin_name()
    author_depth = int(author["max_depth"]) if "max_depth" in author else -1
    interreflect = scan.reflecting_shapes >= 2 or scan.mesh_shapes > 0
    if kind not in _REPLANNABLE:
        decide("indirect", False, f"the scene's own integrator '{kind}' decides")
        if "indirect" in overrides:
            raise McrtError(f"indirect: mcrt re-plans path and direct integrators only, "
                            f"not '{kind}'")
    else:
        deep = kind == "path" and (author_depth < 0 or author_depth > 2)
        present = deep and interreflect
        if not deep:
            reason = f"the scene's integrator is {kind}" + (
                f" with max_depth {author_depth}" if kind == "path" else "")
        elif not interreflect:
            reason = "no surface can light another (fewer than two reflecting shapes)"
        else:
            reason = (f"{scan.reflecting_shapes} reflecting shapes and a path integrator of "
                      f"max_depth {author_depth}")
        decide("indirect", present, reason)

    glossy_on = effects["glossy"].on
    specular = bool(scan.specular) or bool(to_smooth)
    bounce = (2 if scan.dielectric else 1) if (glossy_on or specular) else 0
    if kind not in _REPLANNABLE:
        integrator = {"type": kind}
        integrator.update({k: _plain(author[k]) for k in author.keys()
                           if author.type(k) in (_T.Float, _T.Integer, _T.Bool, _T.String)})
        integrator_reason = "kept as authored"
    elif effects["indirect"].on:
        depth = author_depth if kind == "path" and (author_depth < 0 or author_depth > 2) \
            else DEFAULT_INDIRECT_DEPTH
        integrator = {"type": "path", "max_depth": depth}
        if kind == "path" and "rr_depth" in author:
            integrator["rr_depth"] = int(author["rr_depth"])
        integrator_reason = "indirect light"
    elif bounce:
        integrator = {"type": "distribution", "max_depth": 2 + bounce}
        what = "glossy" if glossy_on else "specular"
        integrator_reason = (f"{what} surfaces show other objects: {bounce} bounce"
                             f"{'s' if bounce > 1 else ''} past direct light"
                             + (" (dielectrics: in and out)" if scan.dielectric else ""))
    else:
        extended = (effects["soft_shadows"].on and n_area > 0) or bool(env)
        integrator = {"type": "direct", "emitter_samples": 1,
                      "bsdf_samples": 1 if (extended or glossy_on or specular) else 0}
        integrator_reason = ("direct lighting is all the scene needs; BSDF sample for MIS "
                             "with area emitters" if integrator["bsdf_samples"] else
                             "direct lighting is all the scene needs; delta lights only, "
                             "so no BSDF sample")
        if kind == "direct":
            explicit = {k: int(author[k]) for k in ("emitter_samples", "bsdf_samples",
                                                    "shading_samples")
                        if k in author}
            if "shading_samples" in explicit:
                s = explicit.pop("shading_samples")
                explicit = {"emitter_samples": s, "bsdf_samples": s}
            if explicit:
                integrator.update(explicit)
                integrator_reason = "direct lighting, sample counts as authored"
    if kind in _REPLANNABLE and "hide_emitters" in author:
        integrator["hide_emitters"] = bool(author["hide_emitters"])

    # -- edit the parse state ------------------------------------------------------
    if scene_camera == "thinlens" and not effects["dof"].on:
        sensor_props.set_plugin_name("perspective")
        for key in ("aperture_radius", "focus_distance"):
            if key in sensor_props:
                del sensor_props[key]
    if t_close > t_open:  # mcrt renders time by sub-frames, never per path
        sensor_props["shutter_close"] = float(t_open)
    if to_smooth:
        for i, name, _ in to_smooth:
            if name not in _ROUGH_TO_SMOOTH:
                raise McrtError(f"glossy=off: cannot make the '{name}' BSDF smooth")
            props = nodes[i].props
            props.set_plugin_name(_ROUGH_TO_SMOOTH[name])
            for key in _ROUGH_ONLY_PROPS:
                if key in props:
                    del props[key]
    render_camera = sensor_props.plugin_name()
    if n_area and effects["soft_shadows"].forced is False:  # only ever off by request
        _area_to_point(state, scan, scene0)
    if not effects["motion"].on and motions and t_open != 0.0:
        _bake_pose(state, scan, scene0, t_open)
    if kind in _REPLANNABLE:
        _set_integrator(state, scan, integrator)
    if effects["motion"].on:
        config.merge_meshes = False  # moving meshes must stay separate shapes
    scene = _instantiate(config, state, path)

    sampler = scene.sensors()[0].sampler()
    plan = RenderPlan(
        scene=str(path), effects=effects, camera=render_camera,
        scene_camera=scene_camera, integrator=integrator,
        integrator_reason=integrator_reason, scene_integrator=scene_integrator,
        shutter=(t_open, t_close), sampler=sampler_name(sampler), spp=sampler.sample_count(),
        motions=motions, streak_px=streak if math.isfinite(streak) else float(
            sampler.sample_count()) * step_px, coc_px=coc, notes=notes)
    planned = PlannedScene(plan, scene, motions, step_px)
    planned.plan.subframes = planned.subframes_for(plan.spp)
    return planned


def _plain(value):
    return value if isinstance(value, (bool, int, float, str)) else str(value)


def _set_integrator(state, scan: _Scan, integrator: dict) -> None:
    props = mi.Properties(integrator["type"])
    for key, value in integrator.items():
        if key != "type":
            props[key] = value
    if scan.integrator is None:
        _add_node(state, mi.ObjectType.Integrator, props, 0, "_mcrt_integrator")
    else:
        state.nodes[scan.integrator].props = props


def _area_to_point(state, scan: _Scan, scene0: mi.Scene) -> None:
    """Replace every area-lit shape by a point light (see the module docstring)."""
    nodes = state.nodes
    shapes = {s.id(): s for s in scene0.shapes()}
    for k, (shape, emitter) in enumerate(scan.area_lights):
        sprops, eprops = nodes[shape].props, nodes[emitter].props  # valid until an append
        radiance = _rgb(eprops, "radiance")
        if radiance is None:
            raise McrtError(f"soft_shadows=off: the area light on '{sprops.id()}' has a textured "
                            f"or spectral radiance; only rgb/float radiance converts to a point")
        obj = shapes[sprops.id()]
        area = float(np.array(obj.surface_area()).ravel()[0])
        bbox = obj.bbox()
        centre = 0.5 * (np.array(bbox.min, dtype=np.float64).ravel()
                        + np.array(bbox.max, dtype=np.float64).ravel())
        factor = 1.0 if sprops.plugin_name() in _PLANAR_SHAPES else 0.25
        keys = [key for key, i in _children(state, nodes[0].props) if i == shape]
        if not keys:
            raise McrtError(f"soft_shadows=off: the area-lit shape '{sprops.id()}' is not a "
                            f"top-level shape")
        for key in keys:
            del nodes[0].props[key]
        point = mi.Properties("point")
        point["position"] = dr.scalar.Array3f64(*[float(c) for c in centre])
        point["intensity"] = mi.ScalarColor3d(*[float(c) for c in radiance * area * factor])
        _add_node(state, mi.ObjectType.Emitter, point, 0, f"_mcrt_point_light_{k}")


def _bake_pose(state, scan: _Scan, scene0: mi.Scene, t: float) -> None:
    """Put moving shapes at their pose at time ``t`` (motion off, shutter open at t != 0)."""
    shapes = {s.id(): s for s in scene0.shapes()}
    for node, motion in scan.motions.items():
        props = state.nodes[node].props
        bbox = shapes[motion.shape].bbox()
        centre = 0.5 * (np.array(bbox.min, dtype=np.float64).ravel()
                        + np.array(bbox.max, dtype=np.float64).ravel())
        m0 = (np.array(props["to_world"].matrix, dtype=np.float64).reshape(4, 4)
              if "to_world" in props else np.eye(4))
        props["to_world"] = mi.ScalarTransform4d(motion.matrix(t, centre) @ m0)
