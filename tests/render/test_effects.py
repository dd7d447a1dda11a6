"""Distribution effects checked against geometry, and switched off against the
scene authored without them.

Geometry tests render small analytic set-ups (self-luminous rectangles on a
black background, an orthographic view of a floor) whose blur can be computed
from first principles, fit the analytic profile to the rendered one and require
the fitted size within 10% of the prediction (the issue's margin; the measured
errors are ~0.1-0.5%, limited by noise and by the model, so a wrong formula, a
missing sample dimension or a radius/diameter mix-up fails by far).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

import mcrt  # noqa: F401  (registers the distribution integrator)
from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.render.motion import strobing_index
from mcrt.render.plan import plan_scene
from mcrt.render.scene import load_scene

EFFECT_SCENES = Path(__file__).resolve().parents[2] / "scenes" / "effects"
CORNELL = Path(__file__).resolve().parents[2] / "scenes" / "cornell_box.xml"


def render(path, params=None, overrides=None, spp=None, seed=0, sampler=None,
           subframes=None):
    """Render as ``mcrt render`` does (plan, sub-frames); returns (rgb, planned)."""
    planned = plan_scene(path, params, overrides)
    sampler = make_sampler(sampler, spp or 16) if sampler else \
        planned.scene.sensors()[0].sampler()
    passes, on_pass = planned.schedule(sampler, spp, seed, subframes=subframes)
    result = render_film(planned.scene, sampler, spp=spp, seed=seed, passes=passes,
                         on_pass=on_pass)
    return result.rgb, planned


def pixel_average(f, x: np.ndarray, *args) -> np.ndarray:
    """Mean of ``f`` over each unit pixel around ``x`` (the box filter)."""
    sub = (np.arange(16) + 0.5) / 16 - 0.5
    return f(x[:, None] + sub[None, :], *args).mean(axis=1)


# ----------------------------------------------------------------------------
# Depth of field: the blur of an edge is the thin lens's circle of confusion
# ----------------------------------------------------------------------------
DOF_W, DOF_FOV, DOF_FOCUS, DOF_R = 128, 30.0, 4.0, 0.2
DOF_F_PX = 0.5 * DOF_W / math.tan(math.radians(DOF_FOV) / 2)  # pixels per unit tangent


def dof_scene(depth: float) -> str:
    """Two self-luminous planes facing a thin-lens camera (looking down -z):
    one at the focus distance filling the image left of -32 px, one at
    ``depth`` filling it right of +32 px. On a black background the image of
    each is its silhouette convolved with its circle of confusion."""
    left = -32 / DOF_F_PX * DOF_FOCUS
    right = 32 / DOF_F_PX * depth
    return f"""<scene version="3.0.0">
      <integrator type="direct"/>
      <sensor type="thinlens">
        <float name="fov" value="{DOF_FOV}"/><string name="fov_axis" value="x"/>
        <float name="aperture_radius" value="{DOF_R}"/>
        <float name="focus_distance" value="{DOF_FOCUS}"/>
        <transform name="to_world"><lookat origin="0,0,0" target="0,0,-1" up="0,1,0"/></transform>
        <sampler type="jittered"><integer name="sample_count" value="256"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{DOF_W}"/>
          <integer name="height" value="12"/>
          <string name="component_format" value="float32"/><rfilter type="box"/></film>
      </sensor>
      <shape type="rectangle" id="in_focus">
        <transform name="to_world"><scale x="5" y="5"/>
          <translate x="{left - 5}" z="{-DOF_FOCUS}"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
      </shape>
      <shape type="rectangle" id="out_of_focus">
        <transform name="to_world"><scale x="10" y="10"/>
          <translate x="{right + 10}" z="{-depth}"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
      </shape>
    </scene>"""


def disk_edge(x: np.ndarray, radius: float) -> np.ndarray:
    """Fraction of a uniform disk of ``radius`` on the negative side of a line
    at signed distance ``x`` from its centre (the edge-spread function)."""
    if radius < 1e-6:
        return (x > 0).astype(np.float64)
    t = np.clip(x / radius, -1.0, 1.0)
    return 0.5 + (t * np.sqrt(1 - t * t) + np.arcsin(t)) / np.pi


def fit_disk_edge(profile: np.ndarray, lo: int, hi: int) -> tuple[float, float]:
    """Least-squares (edge position, disk radius) of a blurred step in profile[lo:hi]."""
    x = np.arange(lo, hi) + 0.5
    y = profile[lo:hi]
    sign = 1.0 if y[-1] > y[0] else -1.0

    def model(p):
        x0, r, level = p
        return level * pixel_average(lambda s: disk_edge(sign * (s - x0), r), x)

    start = [x[np.argmin(np.abs(y - 0.5 * y.max()))], 2.0, y.max()]
    fit = least_squares(lambda p: model(p) - y, start, bounds=([lo, 0, 0], [hi, 60, 2]))
    return float(fit.x[0]), float(fit.x[1])


@pytest.mark.parametrize("depth", [8.0, 2.5])
def test_out_of_focus_edge_blurs_by_the_circle_of_confusion(tmp_path, depth):
    """Mitsuba's thinlens aims the ray from lens point a (|a| <= R) at the point
    of the focal plane z = d_f that the film position names, so a point at depth
    z lands at tangent P/z + a (1/d_f - 1/z): a disk of diameter
    c = 2 R |1/d_f - 1/z| in tangent units, times f_px = (W/2)/tan(fov_x/2) in
    pixels. The in-focus edge must stay sharp (fitted radius < 0.25 px)."""
    path = tmp_path / "dof.xml"
    path.write_text(dof_scene(depth))
    rgb, planned = render(path)
    assert planned.plan.on("dof") and planned.plan.camera == "thinlens"
    profile = rgb[..., 0].mean(axis=0)
    _, r_focus = fit_disk_edge(profile, 8, 56)
    _, r_blur = fit_disk_edge(profile, 72, 124)
    expected = 2 * DOF_R * DOF_F_PX * abs(1 / DOF_FOCUS - 1 / depth)
    assert r_focus < 0.25
    assert abs(2 * r_blur / expected - 1) < 0.10, (2 * r_blur, expected)


# ----------------------------------------------------------------------------
# Soft shadows: penumbra width from similar triangles
# ----------------------------------------------------------------------------
def penumbra_scene(light: float, occluder: float, height: float, x_light: float,
                   view: tuple[float, float], with_occluder: bool, width: int = 128) -> str:
    """An orthographic camera looks straight down at the floor y = 0 over
    x in ``view``. A ``light`` x 3 area light faces down at ``height`` centred
    on x = ``x_light``; a plate at height ``occluder`` covers x < 0."""
    half = (view[1] - view[0]) / 2
    mid = (view[0] + view[1]) / 2
    plate = f"""<shape type="rectangle" id="plate">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale x="2.5" z="5"/>
          <translate x="-2.5" y="{occluder}"/></transform>
      </shape>""" if with_occluder else ""
    return f"""<scene version="3.0.0">
      <integrator type="direct"/>
      <sensor type="orthographic">
        <transform name="to_world"><scale x="{half}" y="{half}" z="1"/>
          <lookat origin="{mid},5,0" target="{mid},0,0" up="0,0,-1"/></transform>
        <sampler type="jittered"><integer name="sample_count" value="256"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{width}"/>
          <integer name="height" value="8"/>
          <string name="component_format" value="float32"/><rfilter type="box"/></film>
      </sensor>
      <shape type="rectangle" id="light">
        <transform name="to_world"><scale x="{light / 2}" y="1.5"/><rotate x="1" angle="90"/>
          <translate x="{x_light}" y="{height}"/></transform>
        <emitter type="area"><rgb name="radiance" value="10"/></emitter>
      </shape>
      <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale x="10" z="10"/></transform>
      </shape>
      {plate}
    </scene>"""


def fit_ramp_width(profile: np.ndarray) -> float:
    """Width of the clamped linear ramp that best fits a monotone step profile."""
    x = np.arange(profile.size) + 0.5
    sign = 1.0 if profile[-1] > profile[0] else -1.0

    def model(p):
        x1, w, lo, hi = p
        return lo + (hi - lo) * np.clip((sign * x - x1) / w, 0, 1)

    start = [sign * x[profile.size // 4], profile.size / 2, profile.min(), profile.max()]
    return float(least_squares(lambda p: model(p) - profile, start).x[1])


@pytest.mark.parametrize("light, occluder", [(0.6, 1.0), (0.4, 1.5)])
def test_penumbra_width_matches_light_size_and_distances(tmp_path, light, occluder):
    """Similar triangles: a light of width L at height h_L behind an edge at
    height h_o casts a penumbra of width L h_o / (h_L - h_o) on the floor,
    centred on the edge's projection from the light's centre. We divide the
    render by the same scene without the plate (visible fraction of the light),
    and fit a clamped ramp; the cosine and distance falloff across the light
    bend the ramp slightly (a ramp fit to the exact integral is 0.4% narrower)."""
    height, x_light = 3.0, -1.0
    width_world = light * occluder / (height - occluder)
    centre = x_light + (0.0 - x_light) * height / (height - occluder)
    view = (centre - 1.25 * width_world, centre + 1.25 * width_world)
    profiles = []
    for with_occluder in (True, False):
        path = tmp_path / f"penumbra_{with_occluder}.xml"
        path.write_text(penumbra_scene(light, occluder, height, x_light, view, with_occluder))
        rgb, planned = render(path)
        assert planned.plan.on("soft_shadows")
        profiles.append(rgb[..., 0].mean(axis=0))
    visible = profiles[0] / profiles[1]
    px_per_unit = 128 / (view[1] - view[0])
    expected = width_world * px_per_unit
    assert abs(fit_ramp_width(visible) / expected - 1) < 0.10


# ----------------------------------------------------------------------------
# Motion blur: streak length = speed x shutter; no strobing at default settings
# ----------------------------------------------------------------------------
STREAK_XML = """<scene version="3.0.0">
  <default name="spp" value="64"/>
  <default name="speed" value="1"/>
  <default name="close" value="1"/>
  <integrator type="direct"/>
  <sensor type="orthographic">
    <float name="shutter_open" value="0"/><float name="shutter_close" value="$close"/>
    <transform name="to_world"><scale x="2" y="2" z="1"/>
      <lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="jittered"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="128"/><integer name="height" value="4"/>
      <string name="component_format" value="float32"/><rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle" id="bar">
    <transform name="to_world"><scale x="0.25" y="2"/><translate x="-1"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    <vector name="mcrt_velocity" value="$speed, 0, 0"/>
  </shape>
</scene>"""
#: The orthographic view is 4 units across 128 pixels; the bar is 0.5 units wide.
STREAK_PX_PER_UNIT = 32.0


def fit_streak(profile: np.ndarray) -> tuple[float, float]:
    """(streak length, bar width) in pixels: a box of width w swept uniformly
    over S pixels gives a trapezoid; fit it, pixel-averaged, to the profile."""
    x = np.arange(profile.size) + 0.5

    def swept(s, a, length, w):
        lo = np.maximum(s - a - w, 0.0)
        hi = np.minimum(s - a, length)
        return np.clip(hi - lo, 0, None) / length

    def model(p):
        a, length, w, level = p
        return level * pixel_average(swept, x, a, length, w)

    start = [x[profile > 0.01 * profile.max()][0], 20.0, 10.0, 1.0]
    fit = least_squares(lambda p: model(p) - profile, start,
                        bounds=([0, 0.1, 0.1, 0], [128, 128, 128, 2]))
    return float(fit.x[1]), float(fit.x[2])


@pytest.mark.parametrize("speed, close", [(1.0, 1.0), (1.5, 0.5)])
def test_streak_length_is_speed_times_shutter(tmp_path, speed, close):
    path = tmp_path / "streak.xml"
    path.write_text(STREAK_XML)
    rgb, planned = render(path, {"speed": str(speed), "close": str(close)})
    assert planned.plan.on("motion") and planned.plan.subframes > 1
    length, width = fit_streak(rgb[..., 0].mean(axis=0))
    expected = speed * close * STREAK_PX_PER_UNIT
    assert abs(length / expected - 1) < 0.10, (length, expected)
    assert abs(width / (0.5 * STREAK_PX_PER_UNIT) - 1) < 0.10


@pytest.mark.slow
def test_default_subframes_show_no_strobing(tmp_path):
    """The streak profile with the plan's default sub-frame count stays within
    2% of a 256-sub-frame reference (strobing_index; 2% is about the smallest
    visible luminance step), while 8 sub-frames (4 px apart) strobe visibly.
    The renders use 1024 spp so that noise (about 0.4% of the peak for the
    profile of the reference) does not hide or fake a ripple."""
    path = tmp_path / "streak.xml"
    path.write_text(STREAK_XML)
    params = {"spp": "1024"}
    default = plan_scene(path, {"spp": "64"}).plan.subframes  # at the scene's own spp
    assert default == 64  # 32 px streak, sub-frames at most 0.5 px apart
    reference, _ = render(path, params, subframes=256, seed=1)
    reference = reference[..., 0].mean(axis=0)
    indices = {}
    for n in (default, 8):
        rgb, planned = render(path, params, subframes=n, seed=2)
        times = np.array(planned.plan.subframe_times)
        assert len(times) == n and np.all(np.floor(times * n) == np.arange(n))  # stratified
        shift = STREAK_PX_PER_UNIT * (times.mean() - 0.5)
        indices[n] = strobing_index(rgb[..., 0].mean(axis=0), reference, shift)
    assert indices[default] < 0.02, indices
    assert indices[8] > 0.05, indices


# ----------------------------------------------------------------------------
# Glossy reflection: the distribution integrator is direct lighting at diffuse
# vertices and a path through glossy ones
# ----------------------------------------------------------------------------
def glossy_test_scene(tmp_path, integrator: str, floor: str, ball: str) -> Path:
    path = tmp_path / f"g_{abs(hash((integrator, floor, ball)))}.xml"
    path.write_text(f"""<scene version="3.0.0">
      {integrator}
      <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0,1.5,4" target="0,0.3,0" up="0,1,0"/></transform>
        <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="14"/>
          <string name="component_format" value="float32"/><rfilter type="box"/></film>
      </sensor>
      <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale x="5" z="5"/></transform>
        {floor}
      </shape>
      <shape type="sphere" id="ball"><point name="center" value="0,0.5,0"/>
        <float name="radius" value="0.5"/>{ball}</shape>
      <shape type="rectangle" id="light">
        <transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/>
          <translate x="0.5" y="2.5" z="1"/></transform>
        <emitter type="area"><rgb name="radiance" value="20"/></emitter>
      </shape>
      <emitter type="point"><point name="position" value="-1,2,1"/>
        <rgb name="intensity" value="3"/></emitter>
    </scene>""")
    return path


DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf>'
ROUGH = '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>'


def z_scores(scene_a, scene_b, spp: int = 256) -> np.ndarray:
    """Per-pixel z of the difference of two independent renders' means."""
    a = render_stats(scene_a, make_sampler("independent", spp), seed=1).stats
    b = render_stats(scene_b, make_sampler("independent", spp), seed=2).stats
    se = np.sqrt(a.variance_of_mean + b.variance_of_mean)[..., 0]  # grey scene: one channel
    z = (a.mean - b.mean)[..., 0] / np.where(se > 0, se, np.inf)
    return z[se > 0]


@pytest.mark.parametrize("floor, ball, reference", [
    (DIFFUSE, DIFFUSE, '<integrator type="direct"/>'),
    (ROUGH, ROUGH, '<integrator type="path"><integer name="max_depth" value="3"/></integrator>'),
])
def test_distribution_integrator_limits(tmp_path, floor, ball, reference):
    """On diffuse-only scenes the ``distribution`` integrator must estimate what
    ``direct`` does, on glossy-only scenes what ``path`` does at the same depth
    (the scenes are loaded as written, not re-planned). Pixel means of
    independent renders differ by z ~ N(0, 1) if both are unbiased: the mean z
    over the ~220 lit pixels (channel R) must be within 4/sqrt(n) of 0 and the rms z below
    1.3 (a bias of a fraction of the noise in every pixel fails it)."""
    ours = '<integrator type="distribution"><integer name="max_depth" value="3"/></integrator>'
    a = load_scene(glossy_test_scene(tmp_path, ours, floor, ball))
    b = load_scene(glossy_test_scene(tmp_path, reference, floor, ball))
    z = z_scores(a, b)
    assert z.size > 100
    assert abs(z.mean()) < 4 / math.sqrt(z.size)
    assert np.sqrt(np.mean(z ** 2)) < 1.3


# ----------------------------------------------------------------------------
# An effect switched off renders the scene authored without it
# ----------------------------------------------------------------------------
def _edit(text: str, replacements: list[tuple[str, str]]) -> str:
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    return text


def _drop_block(text: str, start: str, end: str) -> str:
    i = text.index(start)
    j = text.index(end, i) + len(end)
    return text[:i] + text[j:]


def _authored_without(effect: str, tmp_path: Path) -> tuple[Path, Path]:
    """(shipped scene, the same scene authored without ``effect``)."""
    if effect == "indirect":
        source = CORNELL
        text = _edit(source.read_text(), [(
            '<integrator type="path">\n        <integer name="max_depth" value="$max_depth"/>\n'
            '    </integrator>', '<integrator type="direct"/>'),
            ('<default name="max_depth" value="8"/>', '')])
    else:
        source = EFFECT_SCENES / f"{effect}.xml"
        text = source.read_text()
    if effect == "dof":
        text = _edit(text, [('<sensor type="thinlens">', '<sensor type="perspective">'),
                            ('<float name="aperture_radius" value="$aperture"/>', ''),
                            ('<float name="focus_distance" value="6"/>', '')])
    elif effect == "soft_shadows":
        # The 1.6 x 0.8 light of radiance L becomes a spot light along its normal
        # at its centre, keeping its power (the plan's documented conversion).
        text = _drop_block(text, '<shape type="rectangle" id="light">', "</shape>")
        text = _edit(text, [('<shape type="rectangle" id="floor">',
                             '<emitter type="spot"><transform name="to_world"><lookat '
                             'origin="-1.8, 3, 0.6" target="-1.8, 2, 0.6" up="1, 0, 0"/>'
                             '</transform><float name="cutoff_angle" value="90"/>'
                             '<float name="beam_width" value="32"/><rgb name="intensity" '
                             'value="10.75375498, 10.15632415, 9.55889332"/></emitter>\n'
                             '    <shape type="rectangle" id="floor">')])
    elif effect == "glossy":
        text = _edit(text, [('type="roughconductor"', 'type="conductor"'),
                            ('<float name="alpha" value="$alpha"/>', ''),
                            ('type="roughplastic"', 'type="plastic"'),
                            ('<float name="alpha" value="0.15"/>', '')])
    elif effect == "motion":
        text = _edit(text, [('<vector name="mcrt_velocity" value="$speed, 0, 0"/>', ''),
                            ('<vector name="mcrt_angular_velocity" value="0, $spin, 0"/>', ''),
                            ('<float name="shutter_close" value="1"/>', '')])
    path = tmp_path / f"{effect}_without.xml"
    path.write_text(text)
    return source, path


@pytest.mark.parametrize("effect", ["dof", "soft_shadows", "glossy", "motion", "indirect"])
def test_effect_off_equals_the_scene_authored_without_it(tmp_path, effect):
    """Same seed, same sampler, same dimension layout: mcrt's counter-based
    samplers give both renders the same numbers, so the images agree to float
    rounding. We require the mean absolute difference below 1% of the
    per-pixel noise (the standard error of a pixel at this spp is ~10% of
    its value), so "within noise" holds with a wide margin and any change in
    the layout (which reshuffles every sample) fails."""
    source, without = _authored_without(effect, tmp_path)
    small = {"width": "40", "height": "30"} if effect != "indirect" else {"res": "24"}
    spp = 16
    off, plan_off = render(source, {**small, "spp": str(spp)}, overrides={effect: False},
                           seed=3)
    ref, plan_ref = render(without, {**small, "spp": str(spp)}, seed=3)
    assert not plan_off.plan.on(effect) and not plan_ref.plan.on(effect)
    assert plan_off.plan.effects_on == plan_ref.plan.effects_on
    assert plan_off.plan.integrator == plan_ref.plan.integrator
    stats = render_stats(plan_ref.scene, make_sampler("jittered", spp), seed=3).stats
    noise = float(np.sqrt(stats.variance_of_mean).mean())
    assert np.abs(off - ref).mean() < 0.01 * noise, (np.abs(off - ref).mean(), noise)
