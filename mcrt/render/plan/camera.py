"""Camera geometry: how far things blur in pixels (depth of field, motion)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import drjit as dr
import mitsuba as mi
import numpy as np

from ..motion import Motion, sample_times
from .nodes import shapes_by_id

#: Times at which a moving shape is projected to measure its streak.
STREAK_TIMES = 17


def first_value(params: mi.SceneParameters, key: str) -> float:
    """A traversed scalar parameter (e.g. ``x_fov``) as a float."""
    return float(np.array(params[key]).ravel()[0])


@dataclass
class CameraModel:
    """Pixel projection of a sensor (perspective/thinlens/orthographic)."""

    kind: str                    # "projective", "orthographic" or "unknown"
    world_to_camera: np.ndarray
    f_px: float                  # pixels per unit tangent (projective) or camera unit
    near: float

    @classmethod
    def of(cls, sensor: mi.Sensor) -> CameraModel:
        to_world = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        width = float(sensor.film().size()[0])
        name = sensor.class_name()
        params = mi.traverse(sensor)
        if name in ("PerspectiveCamera", "ThinLensCamera") and "x_fov" in params:
            x_fov = first_value(params, "x_fov")
            f_px = 0.5 * width / math.tan(math.radians(x_fov) / 2)
            kind = "projective"
        elif name == "OrthographicCamera":
            f_px, kind = 0.5 * width, "orthographic"
        else:
            f_px, kind = 0.0, "unknown"
        near = float(sensor.near_clip()) if isinstance(sensor, mi.ProjectiveCamera) else 0.0
        return cls(kind, np.linalg.inv(to_world), f_px, near)

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


def auto_float(value: float | mi.Float) -> dr.auto.ad.Float:
    # Mitsuba's stubs type variant arrays as drjit.auto.ad's; mi.Float is the
    # active variant's Float, which is what the bindings take.
    return cast(dr.auto.ad.Float, mi.Float(value))


def visible_depths(scene: mi.Scene, sensor: mi.Sensor, grid: int = 48) -> np.ndarray:
    """Camera-space depths of the surfaces seen through a grid of pixel centres
    (pinhole rays through the lens centre)."""
    u = (np.arange(grid) + 0.5) / grid
    x, y = np.meshgrid(u, u)
    pos = mi.Point2f(mi.Float(x.ravel().astype(np.float32)), mi.Float(y.ravel().astype(np.float32)))
    ray, _ = sensor.sample_ray(auto_float(sensor.shutter_open()), auto_float(0.0), pos,
                               mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    points = np.array(si.p, dtype=np.float64).T
    valid = np.array(si.is_valid(), dtype=bool)
    dr.sync_thread()
    if not valid.any():
        return np.zeros(0)
    return CameraModel.of(sensor).to_camera(points[valid])[:, 2]


def circle_of_confusion(scene: mi.Scene, sensor: mi.Sensor, camera: CameraModel,
                        radius: float, focus: float
                        ) -> tuple[tuple[float, float] | None, np.ndarray]:
    """(smallest, largest) thin-lens blur diameter in pixels over the visible
    depths (None if nothing is visible or the camera does not project), and
    those depths."""
    depths = visible_depths(scene, sensor)
    if not depths.size or camera.kind != "projective":
        return None, depths
    blur = 2 * radius * camera.f_px * np.abs(1 / focus - 1 / np.maximum(depths, 1e-6))
    return (float(blur.min()), float(blur.max())), depths


def _corners(shape: mi.Shape) -> tuple[np.ndarray, np.ndarray]:
    """The 8 corners of a shape's bounding box and its centre."""
    bbox = shape.bbox()
    lo = np.array(bbox.min, dtype=np.float64).ravel()
    hi = np.array(bbox.max, dtype=np.float64).ravel()
    corners = np.array([[(lo, hi)[(c >> k) & 1][k] for k in range(3)] for c in range(8)])
    return corners, 0.5 * (lo + hi)


def streak_px(scene: mi.Scene, camera: CameraModel, motions: list[Motion],
              t0: float, t1: float) -> float:
    """Longest screen-space path (pixels) of a moving shape's bounding-box
    corners over the shutter (inf when the camera model is unknown)."""
    if camera.kind == "unknown":
        return math.inf
    shapes = shapes_by_id(scene)
    times = sample_times(t0, t1, STREAK_TIMES)
    longest = 0.0
    for motion in motions:
        corners, centre = _corners(shapes[motion.shape])
        tracks = []
        for t in times:
            m = motion.matrix(t, centre)
            tracks.append(camera.project(corners @ m[:3, :3].T + m[:3, 3]))
        steps = np.linalg.norm(np.diff(np.array(tracks), axis=0), axis=-1)  # (times-1, 8)
        length = np.nansum(steps, axis=0)
        if length.size:
            longest = max(longest, float(np.nanmax(length)))
    return longest
