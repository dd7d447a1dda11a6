"""Moving shapes: mcrt's motion format and motion blur by time-stratified sub-frames.

Released Mitsuba 3 has a camera shutter (rays carry a time) but no moving
geometry. mcrt adds it:

* **Format.** A shape moves when it carries one of the ``mcrt_*`` properties
  below (the shape needs an ``id``). Its ``to_world`` is its pose at time 0; the
  shutter is the sensor's own ``shutter_open`` / ``shutter_close``. mcrt removes
  the ``mcrt_*`` properties before Mitsuba instantiates the scene (plain
  ``mi.load_file`` rejects them as unreferenced properties)::

      <sensor type="perspective">
          <float name="shutter_open" value="0"/>
          <float name="shutter_close" value="1"/>
          ...
      </sensor>
      <shape type="sphere" id="ball">
          <transform name="to_world"> <translate x="-1"/> </transform>  <!-- pose at t = 0 -->
          <!-- world units per unit time -->
          <vector name="mcrt_velocity" value="2, 0, 0"/>
          <!-- rotation axis times degrees per unit time -->
          <vector name="mcrt_angular_velocity" value="0, 90, 0"/>
          <!-- what it turns about; default: the bounding-box centre at t = 0 -->
          <point name="mcrt_pivot" value="-1, 0, 0"/>
      </shape>

  The pose at time ``t`` is ``T(v t) . T(c) . R(w, |w| t) . T(-c) . to_world``:
  a rigid motion in world space (constant linear and angular velocity) applied
  on top of the authored pose.

* **Sub-frames.** Geometry cannot follow each ray's time, so a render is split
  into ``n`` passes (sub-frames); before pass ``k`` every moving shape is put at
  time ``t_k`` through ``mi.traverse`` + ``params.update()`` (``to_world`` of
  analytic shapes, ``vertex_positions``/``vertex_normals`` of meshes). The times
  are stratified over the shutter, one per stratum of width ``T / n``:
  ``t_k = open + (close - open) (k + xi) / n``, a lattice shifted by one offset
  ``xi`` that the render's own sampler draws (uniform for ``jittered``, the cell
  centre 0.5 for ``uniform_grid``), so every sub-frame time is uniform over the
  shutter (unbiased over seeds) and the sub-frames are evenly spaced (the least
  strobing; a separate jitter per stratum is available as ``mode="jittered"``
  and strobes 2.5-5x more, see BENCHMARKS.md). Each pass traces
  ``spp / n`` samples of every pixel and the sampler advances between passes,
  so the film, lens, light and BSDF dimensions stay one stratified pattern per
  pixel across the sub-frames.

* **Strobing.** ``n`` sub-frames show a moving edge as ``n`` copies; they blend
  into a continuous streak once consecutive copies are at most
  :data:`SUBFRAME_STEP_PX` pixels apart, so the default ``n`` is the smallest
  divisor of ``spp`` with ``streak / n <= SUBFRAME_STEP_PX`` (see
  :func:`subframe_count` and the measurements in BENCHMARKS.md).
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Iterable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.sampling import quiet_sampler_warnings
from ..errors import SceneError

VELOCITY = "mcrt_velocity"
ANGULAR_VELOCITY = "mcrt_angular_velocity"
PIVOT = "mcrt_pivot"
#: The motion properties a shape may carry (any other ``mcrt_*`` name is an error).
MOTION_PROPERTIES = (VELOCITY, ANGULAR_VELOCITY, PIVOT)

#: Largest distance in pixels between consecutive sub-frames by default. At this
#: spacing a moving edge's profile deviates from a 256-sub-frame reference by
#: 0.7% of its peak brightness (1.6% at 1 px, 3% at 2 px, 9% at 4 px; noise
#: floor of the measurement 0.4%), well under the ~2% of a just-visible
#: luminance step: see BENCHMARKS.md, "What each effect costs".
SUBFRAME_STEP_PX = 0.5

#: A shape moving less than this many pixels over the shutter is not blurred.
NEGLIGIBLE_STREAK_PX = 0.25


@dataclass(frozen=True)
class Motion:
    """Constant linear and angular velocity of one shape (see the module docstring)."""

    shape: str
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Rotation axis times rate, in degrees per unit time (world space).
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: World-space point the rotation turns about; None: the shape's
    #: bounding-box centre at time 0.
    pivot: tuple[float, float, float] | None = None

    @property
    def is_static(self) -> bool:
        return not any(self.velocity) and not any(self.angular_velocity)

    def matrix(self, t: float, pivot: Iterable[float] | None = None) -> np.ndarray:
        """World-space rigid motion (4x4) from time 0 to time ``t``."""
        centre = np.asarray(self.pivot if self.pivot is not None else
                            (pivot if pivot is not None else (0.0, 0.0, 0.0)), dtype=np.float64)
        m = np.eye(4)
        w = np.asarray(self.angular_velocity, dtype=np.float64)
        rate = float(np.linalg.norm(w))
        if rate > 0:
            m[:3, :3] = _rotation(w / rate, math.radians(rate * t))
            m[:3, 3] = centre - m[:3, :3] @ centre
        m[:3, 3] += np.asarray(self.velocity, dtype=np.float64) * t
        return m

    def to_dict(self) -> dict:
        out = {"shape": self.shape, "velocity": list(self.velocity),
               "angular_velocity": list(self.angular_velocity)}
        if self.pivot is not None:
            out["pivot"] = list(self.pivot)
        return out


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about unit ``axis`` by ``angle`` radians (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _vector3(props: mi.Properties, name: str, where: str) -> tuple[float, float, float]:
    value = props[name]
    if props.type(name) != mi.Properties.Type.Vector or not isinstance(value, dr.scalar.Array3f64):
        raise SceneError(f"{where}: '{name}' must be a <vector> or <point> with three "
                         f"components, e.g. <vector name=\"{name}\" value=\"1, 0, 0\"/>")
    vector = (float(value[0]), float(value[1]), float(value[2]))
    if not all(math.isfinite(c) for c in vector):
        raise SceneError(f"{where}: '{name}' must be finite, got {vector}")
    return vector


def take_motion(props: mi.Properties, where: str) -> Motion | None:
    """Read and remove the ``mcrt_*`` motion properties of a shape's properties.

    Returns None when the shape has none. ``where`` names the shape in errors.
    """
    names = [k for k in props.keys() if k.startswith("mcrt_")]
    if not names:
        return None
    unknown = [k for k in names if k not in MOTION_PROPERTIES]
    if unknown:
        raise SceneError(f"{where}: unknown property '{unknown[0]}' (mcrt's motion properties "
                         f"are {', '.join(MOTION_PROPERTIES)})")
    shape_id = props.id()
    if not shape_id:
        raise SceneError(f"{where}: a moving shape needs an id (e.g. <shape ... id=\"ball\">)")
    values = {name: _vector3(props, name, where) for name in names}
    for name in names:
        del props[name]
    return Motion(shape=shape_id, velocity=values.get(VELOCITY, (0.0, 0.0, 0.0)),
                  angular_velocity=values.get(ANGULAR_VELOCITY, (0.0, 0.0, 0.0)),
                  pivot=values.get(PIVOT))


def sample_times(t_open: float, t_close: float, count: int = 9) -> np.ndarray:
    """Evenly spaced times over the shutter (for streak-length estimates)."""
    return np.linspace(t_open, t_close, max(count, 2))


def subframe_count(streak_px: float, spp: int, step_px: float = SUBFRAME_STEP_PX) -> int:
    """Sub-frames for a streak of ``streak_px`` pixels at ``spp`` samples per pixel.

    The smallest divisor ``n`` of ``spp`` with ``streak_px / n <= step_px`` (every
    pass is one sub-frame, so ``n`` must divide the sample count); ``spp`` if none
    is large enough (then consecutive sub-frames are further apart than
    ``step_px``: raise the sample count for a smoother streak).
    """
    if streak_px < NEGLIGIBLE_STREAK_PX:
        return 1
    needed = math.ceil(streak_px / step_px)
    for n in range(needed, spp + 1):
        if spp % n == 0:
            return n
    return spp


def subframe_times(count: int, t_open: float, t_close: float,
                   sampler: str | mi.Sampler = "independent", seed: int = 0,
                   mode: str = "shifted") -> np.ndarray:
    """Stratified sub-frame times over the shutter, one per stratum of width ``T / count``.

    ``mode="shifted"`` (default): ``t_k = open + T (k + xi) / count`` with one
    offset ``xi`` for all strata (a randomly shifted lattice: evenly spaced
    sub-frames, so the least strobing, and every time is uniform over the
    shutter, so the render is unbiased over seeds). ``mode="jittered"``: an
    offset ``xi_k`` per stratum. The offsets come from ``sampler``'s 1D points
    of one virtual pixel (seed derived from ``seed``): ``xi_k = frac(count u_k)``,
    which is the in-cell jitter of ``jittered``, the cell centre of
    ``uniform_grid`` and uniform for ``independent``.
    """
    from ..samplers.points import point_sets

    if count < 1:
        raise ValueError("count must be >= 1")
    if mode not in ("shifted", "jittered"):
        raise ValueError(f"unknown sub-frame time mode {mode!r}")
    draws = 1 if mode == "shifted" else count
    with quiet_sampler_warnings():  # they may round ``draws`` up and say so: nobody asked
        u = point_sets(sampler, pixels=[0], spp=draws, dimension=0, ndim=1,
                       seed=(int(seed) ^ 0x6D6F7469) & 0xFFFFFFFF)[0, :draws, 0]
    xi = np.mod(u.astype(np.float64) * draws, 1.0)
    return t_open + (t_close - t_open) * (np.arange(count) + xi) / count


def strobing_index(profile: np.ndarray, reference: np.ndarray, shift_px: float = 0.0) -> float:
    """How far a motion streak's profile is from a many-sub-frame reference.

    ``max |profile(x) - reference(x - shift_px)| / max(reference)``: the largest
    deviation, relative to the streak's peak, of a 1D profile across the streak
    (e.g. the mean over the rows it covers) from the profile of a render with
    many more sub-frames. ``shift_px`` (screen speed x (mean sub-frame time -
    shutter mid-time)) removes the sub-step offset of the sub-frames' mean time,
    which moves the whole streak by less than one step, is zero on average over
    seeds, and is not strobing. The reference is linearly interpolated.
    """
    profile = np.asarray(profile, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if profile.shape != reference.shape or profile.ndim != 1:
        raise ValueError("profile and reference must be 1D arrays of the same length")
    x = np.arange(reference.size, dtype=np.float64)
    shifted = np.interp(x - shift_px, x, reference)
    peak = float(np.max(np.abs(reference)))
    return float(np.max(np.abs(profile - shifted)) / peak) if peak > 0 else 0.0


@dataclass(frozen=True)
class _RigidShape:
    """A shape moved through its ``to_world`` parameter."""

    motion: Motion
    centre: np.ndarray           # default pivot: bounding-box centre at time 0
    transform: type              # the parameter's transform class
    to_world: np.ndarray         # 4x4 pose at time 0


@dataclass(frozen=True)
class _MeshShape:
    """A mesh moved through its world-space vertex positions (and normals)."""

    motion: Motion
    centre: np.ndarray
    positions: np.ndarray        # (n, 3) at time 0
    normals: np.ndarray | None


class MotionDriver:
    """Puts the moving shapes of an instantiated scene at any time of the shutter.

    Shapes with a ``to_world`` parameter (sphere, rectangle, disk, cylinder, ...)
    get ``to_world(t) = M(t) to_world(0)``; meshes get their world-space vertex
    positions (and normals) moved by ``M(t)``. :meth:`on_pass` is the
    ``on_pass(index, count)`` of :func:`mcrt.core.render.render_film`, wrapped in a
    :class:`SubframeHook` by :meth:`mcrt.render.plan.PlannedScene.schedule`.
    """

    def __init__(self, scene: mi.Scene, motions: Iterable[Motion],
                 times: np.ndarray | None = None) -> None:
        self.motions = [m for m in motions if not m.is_static]
        self.times = None if times is None else np.asarray(times, dtype=np.float64)
        self._initial: list[_RigidShape | _MeshShape] = []
        self._shapes: dict[str, mi.Shape] = {}
        self.time: float | None = None
        #: The moving shapes' parameters before the first move (None: not moved since
        #: made or restored): what :meth:`restore` puts back.
        self._before: dict[str, object] | None = None
        if not self.motions:  # nothing to move: no traversal of a large scene
            return
        self.params = mi.traverse(scene)
        shapes = self._shapes = {s.id(): s for s in scene.shapes()}
        for motion in self.motions:
            if motion.shape not in shapes:
                raise SceneError(f"moving shape '{motion.shape}' is not a shape of the scene")
            self._initial.append(self._initial_pose(motion, shapes[motion.shape]))

    def _initial_pose(self, motion: Motion, shape: mi.Shape) -> _RigidShape | _MeshShape:
        bbox = shape.bbox()
        centre = 0.5 * (np.array(bbox.min, dtype=np.float64).ravel()
                        + np.array(bbox.max, dtype=np.float64).ravel())
        key = f"{motion.shape}.to_world"
        if key in self.params:
            value = self.params[key]
            return _RigidShape(motion, centre, type(value), _matrix(value))
        key = f"{motion.shape}.vertex_positions"
        if key not in self.params:
            raise SceneError(f"shape '{motion.shape}' cannot move: it exposes neither "
                             f"to_world nor vertex_positions to mi.traverse")
        positions = np.array(self.params[key], dtype=np.float64).reshape(-1, 3)
        nkey = f"{motion.shape}.vertex_normals"
        normals = (np.array(self.params[nkey], dtype=np.float64).reshape(-1, 3)
                   if nkey in self.params and dr.width(self.params[nkey]) else None)
        return _MeshShape(motion, centre, positions, normals)

    @property
    def moving(self) -> bool:
        return bool(self.motions)

    def set_time(self, t: float) -> None:
        """Move every moving shape to its pose at time ``t`` and update the scene."""
        if not self._initial:
            return
        if self._before is None:
            self._before = self._current()
        for shape in self._initial:
            m = shape.motion.matrix(t, shape.centre)
            name = shape.motion.shape
            if isinstance(shape, _RigidShape):
                self.params[f"{name}.to_world"] = shape.transform(mi.Matrix4f(m @ shape.to_world))
                continue
            self._write(f"{name}.vertex_positions", shape.positions @ m[:3, :3].T + m[:3, 3])
            if shape.normals is not None:
                self._write(f"{name}.vertex_normals", shape.normals @ m[:3, :3].T)
        self.params.update()
        self.time = t

    def _current(self) -> dict[str, object]:
        """Copies of the parameters :meth:`set_time` writes, as they are now (a
        parameter's object changes when the parameter is set)."""
        now: dict[str, object] = {}
        for shape in self._initial:
            name = shape.motion.shape
            if isinstance(shape, _RigidShape):
                value = self.params[f"{name}.to_world"]
                now[f"{name}.to_world"] = type(value)(value)
                continue
            arrays = ["vertex_positions"] + (["vertex_normals"] if shape.normals is not None
                                             else [])
            for key in (f"{name}.{array}" for array in arrays):
                now[key] = np.array(self.params[key], dtype=np.float32)
        return now

    def restore(self) -> None:
        """Put the moving shapes back as they were before the first :meth:`set_time`
        since the driver was made or last restored (their arrays in place, as
        sub-frames write them: a replay's recording stays valid)."""
        before, self._before = self._before, None
        if before is None:
            return
        for key, value in before.items():
            if isinstance(value, np.ndarray):
                self._write(key, value)
            else:
                self.params[key] = value
        self.params.update()
        self.time = None

    def _write(self, key: str, values: np.ndarray) -> None:
        """Set the mesh array ``key`` to ``values``: on the CPU over its own memory,
        so that the array keeps its address (see :meth:`replayable`)."""
        flat = values.astype(np.float32).ravel()
        current = self.params[key]
        if dr.backend_v(current) != dr.JitBackend.LLVM:
            self.params[key] = type(current)(flat)
            return
        dr.eval(current)
        dr.sync_thread()  # no kernel still reads it
        view = np.from_dlpack(current)  # the array's memory (read-only to numpy)
        src = np.ascontiguousarray(flat, dtype=view.dtype)
        if view.size != src.size:
            raise SceneError(f"motion: {key} has {view.size} values, the pose {src.size}")
        ctypes.memmove(view.__array_interface__["data"][0], src.ctypes.data, src.nbytes)
        self.params.set_dirty(key)

    @property
    def replayable(self) -> bool | str:
        """True where passes replayed by Dr.Jit's frozen functions see each
        sub-frame's scene (else why not). A replayed kernel reads the arrays
        that shapes' methods use at the addresses they had when it was recorded,
        so an update must keep them where they are: moving meshes are written in
        place (on the CPU) and rigid shapes change only single values; an
        emitting mesh rebuilds its area distribution into new arrays."""
        for shape in self._initial:
            if isinstance(shape, _MeshShape):
                key = f"{shape.motion.shape}.vertex_positions"
                if dr.backend_v(self.params[key]) != dr.JitBackend.LLVM:
                    return "moving meshes are updated in place on the CPU only"
                if self._shapes[shape.motion.shape].is_emitter():
                    return f"the moving mesh '{shape.motion.shape}' emits light"
        return True

    def on_pass(self, index: int, count: int) -> None:
        """``render_film``'s hook: sub-frame ``index`` of ``count`` shows time ``times[index]``."""
        if self.times is None or len(self.times) != count:
            raise SceneError(f"motion: {count} passes but "
                             f"{0 if self.times is None else len(self.times)} sub-frame times")
        self.set_time(float(self.times[index]))


class SubframeHook:
    """``render_film``'s ``on_pass(index, count)`` for a moving scene; its
    ``replayable`` says whether the passes may be replayed (see
    :attr:`MotionDriver.replayable`)."""

    def __init__(self, driver: MotionDriver) -> None:
        self.driver = driver
        self.replayable = driver.replayable

    def __call__(self, index: int, count: int) -> None:
        self.driver.on_pass(index, count)

    def restore(self) -> None:
        """Put the scene back as the render found it (``render_film`` calls this
        after the passes, also when they stop on an error or Ctrl-C)."""
        self.driver.restore()


def _matrix(transform: mi.ScalarTransform4f | mi.Transform4f) -> np.ndarray:
    """4x4 float64 matrix of a (width-1) Mitsuba transform."""
    m = np.array(transform.matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0].reshape(4, 4)
