"""Render plans: effect detection, overrides, sample-dimension layouts (counted),
the motion format, sub-frames, and the ``mcrt plan`` / ``mcrt render`` CLI."""

from __future__ import annotations

import json
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt.core.trace import pixel_of_index, trace
from mcrt.errors import McrtError, SceneError
from mcrt.io import read_exr
from mcrt.render.motion import Motion, strobing_index, subframe_count, subframe_times
from mcrt.render.plan import EFFECTS, parse_effect_overrides, plan_scene
from mcrt.samplers import JitteredSampler
from tests.conftest import CHECKERBOARD, ROOT, run_cli, scene_xml

EFFECT_SCENES = ROOT / "scenes" / "effects"
CORNELL = ROOT / "scenes" / "cornell_box.xml"


# ----------------------------------------------------------------------------
# Effects of the shipped scenes
# ----------------------------------------------------------------------------
@pytest.mark.parametrize("scene, effects, integrator", [
    (EFFECT_SCENES / "aa.xml", {"aa"}, "direct"),
    (EFFECT_SCENES / "soft_shadows.xml", {"aa", "soft_shadows"}, "direct"),
    (EFFECT_SCENES / "glossy.xml", {"aa", "glossy"}, "distribution"),
    (EFFECT_SCENES / "dof.xml", {"aa", "dof"}, "direct"),
    (EFFECT_SCENES / "motion.xml", {"aa", "motion"}, "direct"),
    (EFFECT_SCENES / "combined.xml", {"aa", "soft_shadows", "glossy", "dof", "motion"},
     "distribution"),
    (CORNELL, {"aa", "soft_shadows", "indirect"}, "path"),
    (CHECKERBOARD, {"aa"}, "direct"),
])
def test_plan_lists_exactly_the_effects_of_each_shipped_scene(scene, effects, integrator):
    plan = plan_scene(scene).plan
    assert set(plan.effects_on) == effects
    assert set(plan.effects) == set(EFFECTS)
    assert plan.integrator["type"] == integrator
    assert plan.camera == ("thinlens" if "dof" in effects else plan.scene_camera)
    assert (plan.subframes > 1) == ("motion" in effects)
    text = plan.describe()
    for name in EFFECTS:
        assert f"{name} " in text


def test_every_effect_scene_is_shipped():
    names = {p.stem for p in EFFECT_SCENES.glob("*.xml")}
    assert {"aa", "soft_shadows", "glossy", "dof", "motion", "combined"} <= names


# ----------------------------------------------------------------------------
# Dimension layout: the plan's list against counted sampler calls
# ----------------------------------------------------------------------------
CALLS: list[int] = []  # ndim of each sampler call as it is traced (outside loop state)


def counting_sampler(base: type) -> type:
    """``base`` (``jittered`` of the active variant) counting its calls per lane
    (n1, n2 are Dr.Jit loop state)."""

    class CountingSampler(base):  # type: ignore[misc, valid-type]
        plugin_name = "counting_jittered"

        def _configure(self, props: mi.Properties) -> None:
            super()._configure(props)
            self.n1 = mi.UInt32(0)
            self.n2 = mi.UInt32(0)

        def next_1d(self, active=True):
            CALLS.append(1)
            self.n1 = self.n1 + 1
            return super().next_1d(active)

        def next_2d(self, active=True):
            CALLS.append(2)
            self.n2 = self.n2 + 1
            return super().next_2d(active)

    return CountingSampler


CountingSampler = counting_sampler(JitteredSampler)


def count_calls(scene: mi.Scene, spp: int = 4,
                counting: type = CountingSampler) -> tuple[list[int], int, int]:
    """Trace one wavefront of every pixel; return the traced call order and the
    largest per-lane numbers of 1D and 2D calls."""
    mi.register_sampler("counting_jittered", lambda props: counting(props))
    sampler = mi.load_dict({"type": "counting_jittered", "sample_count": spp})
    sensor = scene.sensors()[0]
    size = sensor.film().crop_size()
    lanes = int(size[0]) * int(size[1]) * spp
    sampler.set_samples_per_wavefront(spp)
    sampler.seed(0, lanes)
    pixel = pixel_of_index(sensor.film(), dr.arange(mi.UInt32, lanes) // spp)
    CALLS.clear()
    result = trace(scene, sensor, sampler, scene.integrator(), pixel, spp)
    dr.eval(result.rgb, sampler.n1, sampler.n2)
    return list(CALLS), int(dr.max(sampler.n1)[0]), int(dr.max(sampler.n2)[0])


@pytest.mark.slow
@pytest.mark.parametrize("scene, params, spp", [
    (CHECKERBOARD, {"width": "16", "height": "12"}, 4),
    (EFFECT_SCENES / "soft_shadows.xml", {"width": "16", "height": "12"}, 4),
    (EFFECT_SCENES / "dof.xml", {"width": "16", "height": "12"}, 4),
    (EFFECT_SCENES / "motion.xml", {"width": "16", "height": "12"}, 4),
    (EFFECT_SCENES / "glossy.xml", {"width": "24", "height": "18"}, 4),
    (EFFECT_SCENES / "combined.xml", {"width": "24", "height": "18"}, 4),
    (CORNELL, {"res": "16", "max_depth": "4"}, 4),
    # an irradiance meter: film and aperture samples, one pixel (so many lanes, for
    # some path to reach its third vertex)
    (ROOT / "scenes" / "foreign" / "irradiance_meter.xml", {}, 1024),
])
def test_dimension_layout_matches_counted_sampler_calls(scene, params, spp):
    """The first traced calls are the camera's then one integrator step's, in the
    plan's order; the busiest lane makes exactly the plan's maximum number of
    1D and 2D calls (every bounded path here reaches its last step)."""
    plan = plan_scene(scene, params).plan
    camera = [d.ndim for d in plan.camera_dimensions()]
    per_step, steps = plan.bounce_dimensions()
    per_step = [d.ndim for d in per_step]
    calls, n1, n2 = count_calls(plan_scene(scene, params).scene, spp)
    assert calls[:len(camera) + len(per_step)] == camera + per_step
    if plan.integrator["type"] == "direct":
        assert calls == camera + per_step
    assert steps is not None
    assert n1 == per_step.count(1) * steps + camera.count(1)
    assert n2 == per_step.count(2) * steps + camera.count(2)
    if plan.on("motion"):  # time comes from sub-frames, never from a per-path dimension
        assert plan_scene(scene, params).scene.sensors()[0].shutter_open_time() == 0


@pytest.mark.parametrize("scene, params", [
    (CHECKERBOARD, {"width": "16", "height": "12"}),
    (EFFECT_SCENES / "dof.xml", {"width": "16", "height": "12"}),
])
def test_spectral_plan_lists_the_wavelength_sample(scene, params):
    """A spectral variant's camera draws the wavelengths (1D) after the film and
    lens samples (mcrt.core.trace): the plan lists them there, and its layout and
    maximum counts match the calls traced (counted, no statistics involved)."""
    mi.set_variant("llvm_ad_spectral")
    mcrt.register()
    from mcrt.samplers import PLUGINS

    planned = plan_scene(scene, params)
    labels = [d.label for d in planned.plan.camera_dimensions()]
    assert labels[-1] == "wavelength" and labels[0] == "film"
    assert "wavelength 1D" in planned.plan.describe()
    camera = [d.ndim for d in planned.plan.camera_dimensions()]
    per_step, steps = planned.plan.bounce_dimensions()
    per_step = [d.ndim for d in per_step]
    calls, n1, n2 = count_calls(planned.scene, 4, counting_sampler(PLUGINS["jittered"]))
    assert calls == camera + per_step  # both scenes: the direct integrator, one step
    assert steps == 1
    assert n1 == per_step.count(1) + camera.count(1)
    assert n2 == per_step.count(2) + camera.count(2)


# ----------------------------------------------------------------------------
# Overrides
# ----------------------------------------------------------------------------
def test_parse_effect_overrides():
    assert parse_effect_overrides(["dof=off,motion=on", "glossy=OFF", "soft-shadows=on"]) == {
        "dof": False, "motion": True, "glossy": False, "soft_shadows": True}
    assert parse_effect_overrides(None) == {}
    for bad, message in [("dof", "NAME=on|off"), ("dof=maybe", "NAME=on|off"),
                         ("blur=off", "unknown effect 'blur'"), ("aa=off", "cannot be switched")]:
        with pytest.raises(McrtError, match=message):
            parse_effect_overrides([bad])


def test_dof_off_renders_a_pinhole_without_lens_dimension():
    plan = plan_scene(EFFECT_SCENES / "dof.xml", overrides={"dof": False}).plan
    assert not plan.on("dof") and plan.effects["dof"].forced is False
    assert plan.camera == "perspective" and plan.scene_camera == "thinlens"
    assert [d.label for d in plan.camera_dimensions()] == ["film"]


def test_negligible_depth_of_field_is_off_unless_forced():
    """An aperture whose circle of confusion stays under half a pixel at every
    visible depth renders as a pinhole; forcing dof on keeps the thin lens."""
    params = {"aperture": "0.0005"}
    plan = plan_scene(EFFECT_SCENES / "dof.xml", params).plan
    assert not plan.on("dof") and plan.camera == "perspective"
    assert plan.coc_px[1] < 0.5 and "negligible" in plan.effects["dof"].reason
    forced = plan_scene(EFFECT_SCENES / "dof.xml", params, {"dof": True}).plan
    assert forced.on("dof") and forced.camera == "thinlens"


def test_soft_shadows_off_replaces_area_lights_by_spot_lights():
    planned = plan_scene(EFFECT_SCENES / "soft_shadows.xml", overrides={"soft_shadows": False})
    emitters = planned.scene.emitters()
    assert len(emitters) == 1 and emitters[0].class_name() == "SpotLight"
    m = np.array(emitters[0].world_transform().matrix).reshape(4, 4)
    assert np.allclose(m[:3, 3], [-1.8, 3, 0.6], atol=1e-5)  # the light's centre
    assert np.allclose(m[:3, 2], [0, -1, 0], atol=1e-5)      # along its normal
    area = 1.6 * 0.8  # the light's rectangle
    falloff = 0.535626858795831  # the spot's falloff integrated (x sin) over the hemisphere
    assert np.allclose(np.array(mi.traverse(emitters[0])["intensity.value"]).ravel(),
                       np.array([9, 8.5, 8]) * area / (2 * falloff), rtol=1e-5)  # same power
    assert "light" not in {s.id() for s in planned.scene.shapes()}
    assert planned.plan.integrator == {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}


def test_glossy_off_makes_rough_bsdfs_smooth_and_keeps_their_reflections():
    planned = plan_scene(EFFECT_SCENES / "glossy.xml", overrides={"glossy": False})
    kinds = {type(s.bsdf()).__name__ + s.bsdf().class_name() for s in planned.scene.shapes()}
    assert not any("Rough" in k for k in kinds)
    assert any("SmoothConductor" in k for k in kinds) and any("SmoothPlastic" in k for k in kinds)
    # Mirrors still show other objects: the path continues through delta lobes.
    assert planned.plan.integrator == {"type": "distribution", "max_depth": 3}


def test_indirect_switches_between_path_and_direct():
    off = plan_scene(CORNELL, overrides={"indirect": False}).plan
    assert off.integrator["type"] == "direct" and off.integrator["bsdf_samples"] == 1
    on = plan_scene(EFFECT_SCENES / "aa.xml", overrides={"indirect": True}).plan
    assert on.integrator == {"type": "path", "max_depth": 8}


def test_motion_off_is_one_subframe_at_the_shutter_open_pose():
    planned = plan_scene(EFFECT_SCENES / "motion.xml", overrides={"motion": False})
    assert planned.plan.subframes == 1 and planned.schedule() == (None, None)
    assert not planned.driver.moving


def test_plan_reads_the_scene_once_and_registers_no_plugin(monkeypatch):
    """One parse of the XML per plan (the analysis and the rendered scene are
    both built from it), and no plugin registration as a side effect: that is
    ``mcrt.register()``'s job."""
    parses = []
    parse_file = mi.parser.parse_file

    def counting_parse(*args, **kwargs):
        parses.append(args[1])
        return parse_file(*args, **kwargs)

    def refuse(*args, **kwargs):
        raise AssertionError("plan_scene registered a plugin")

    monkeypatch.setattr(mi.parser, "parse_file", counting_parse)
    monkeypatch.setattr(mi, "register_integrator", refuse)
    monkeypatch.setattr(mi, "register_sampler", refuse)
    planned = plan_scene(EFFECT_SCENES / "glossy.xml", {"width": "16", "height": "12"})
    assert planned.plan.integrator["type"] == "distribution"
    assert parses == [str(EFFECT_SCENES / "glossy.xml")]


@pytest.mark.parametrize("scene, effect, message", [
    (EFFECT_SCENES / "aa.xml", "dof", "not a thinlens"),
    (EFFECT_SCENES / "aa.xml", "motion", "no moving shape"),
    (EFFECT_SCENES / "aa.xml", "glossy", "no rough BSDF"),
    (EFFECT_SCENES / "aa.xml", "soft_shadows", "no area emitter"),
])
def test_forcing_on_an_absent_effect_is_an_error(scene, effect, message):
    with pytest.raises(McrtError, match=message):
        plan_scene(scene, overrides={effect: True})


# ----------------------------------------------------------------------------
# Motion format, sub-frames, driver
# ----------------------------------------------------------------------------
MOVING = """<scene version="3.0.0">
  <integrator type="direct"/>
  <sensor type="perspective">
    <float name="shutter_open" value="0"/><float name="shutter_close" value="{close}"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
  </sensor>
  <emitter type="point"><point name="position" value="0,0,5"/><rgb name="intensity" value="5"/></emitter>
  <shape type="sphere" {id}><transform name="to_world"><scale value="0.3"/><translate x="-1"/></transform>
    {motion}
  </shape>
  <shape type="cube" id="box"><transform name="to_world"><scale value="0.2"/><translate x="1"/></transform>
    <vector name="mcrt_angular_velocity" value="0, 0, 90"/>
  </shape>
</scene>"""


def write_moving(tmp_path, close="1", id='id="ball"',
                 motion='<vector name="mcrt_velocity" value="2, 0, 0"/>') -> Path:
    path = tmp_path / "moving.xml"
    path.write_text(MOVING.format(close=close, id=id, motion=motion))
    return path


@pytest.mark.parametrize("kwargs, message", [
    ({"id": ""}, "needs an id"),
    ({"motion": '<float name="mcrt_velocity" value="2"/>'}, "must be a <vector>"),
    ({"motion": '<vector name="mcrt_speed" value="2, 0, 0"/>'}, "unknown property 'mcrt_speed'"),
])
def test_motion_format_errors(tmp_path, kwargs, message):
    with pytest.raises(SceneError, match=message):
        plan_scene(write_moving(tmp_path, **kwargs))


def test_plain_mitsuba_rejects_the_motion_properties(tmp_path):
    """Documented behaviour: the mcrt_* properties are for mcrt's loader only."""
    with pytest.raises(Exception, match="unreferenced propert"):
        mi.load_file(str(write_moving(tmp_path)))


def test_closed_shutter_means_no_motion_blur(tmp_path):
    path = write_moving(tmp_path, close="0")
    plan = plan_scene(path).plan
    assert not plan.on("motion") and "shutter is closed" in plan.effects["motion"].reason
    with pytest.raises(McrtError, match="shutter"):
        plan_scene(path, overrides={"motion": True})


def test_motion_driver_moves_analytic_shapes_and_meshes(tmp_path):
    """A sphere translated by v t and a cube turned by w t about its centre."""
    planned = plan_scene(write_moving(tmp_path))
    scene, driver = planned.scene, planned.driver
    shapes = {s.id(): s for s in scene.shapes()}
    box0 = np.array(mi.traverse(scene)["box.vertex_positions"]).reshape(-1, 3)
    driver.set_time(0.5)
    ball = shapes["ball"].bbox()
    centre = (np.array(ball.min).ravel() + np.array(ball.max).ravel()) / 2
    assert np.allclose(centre, [-1 + 2 * 0.5, 0, 0], atol=1e-5)
    box = np.array(mi.traverse(scene)["box.vertex_positions"]).reshape(-1, 3)
    c = np.array([1.0, 0.0, 0.0])
    angle = np.radians(90 * 0.5)  # 90 degrees per unit time about z, at t = 0.5
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                     [0, 0, 1]])
    assert np.allclose(box, (box0 - c) @ turn.T + c, atol=1e-5)
    driver.set_time(0.0)
    assert np.allclose(np.array(mi.traverse(scene)["box.vertex_positions"]).reshape(-1, 3), box0,
                       atol=1e-6)


def test_motion_matrix_composes_rotation_about_pivot_and_translation():
    m = Motion("s", velocity=(1, 0, 0), angular_velocity=(0, 0, 180), pivot=(1, 1, 0))
    a = m.matrix(0.5)  # 90 degrees about z through (1, 1, 0), then +0.5 x
    p = np.array([2.0, 1.0, 0.0, 1.0])
    assert np.allclose(a @ p, [1.5, 2.0, 0.0, 1.0])
    assert np.allclose(m.matrix(0.0), np.eye(4))
    assert Motion("s").is_static


def test_subframe_count_rule():
    assert subframe_count(0.1, 64) == 1          # negligible streak
    assert subframe_count(10.0, 64) == 32        # 20 needed -> next divisor of 64
    assert subframe_count(29.1, 64) == 64
    assert subframe_count(29.1, 256) == 64
    assert subframe_count(500.0, 64) == 64       # capped at one sample per sub-frame
    assert subframe_count(10.0, 64, step_px=5.0) == 2


@pytest.mark.parametrize("mode", ["shifted", "jittered"])
def test_subframe_times_are_stratified(mode):
    for n in (1, 7, 16):
        t = subframe_times(n, 2.0, 4.0, "independent", seed=3, mode=mode)
        assert np.all(np.floor((t - 2.0) / 2.0 * n) == np.arange(n))
    t = subframe_times(8, 0.0, 1.0, "independent", seed=5, mode="shifted")
    assert np.allclose(np.diff(t), 1 / 8)  # one shared offset: evenly spaced
    assert np.allclose(subframe_times(4, 0.0, 1.0, "uniform_grid"), [0.125, 0.375, 0.625, 0.875])


def test_subframe_offsets_are_uniform_over_seeds():
    """Unbiased time sampling: the shared offset xi is U(0, 1) over seeds. With
    64 seeds a Kolmogorov-Smirnov p-value below 1e-3 would reject it."""
    from scipy.stats import kstest

    xi = [subframe_times(4, 0.0, 1.0, "jittered", seed=s)[0] * 4 for s in range(64)]
    assert kstest(xi, "uniform").pvalue > 1e-3


def test_strobing_index():
    ref = np.array([0, 0.5, 1, 1, 0.5, 0])
    assert strobing_index(ref, ref) == 0
    assert strobing_index(ref + np.array([0, 0, 0.1, 0, 0, 0]), ref) == pytest.approx(0.1)
    shifted = np.interp(np.arange(6) - 0.5, np.arange(6), ref)
    assert strobing_index(shifted, ref, shift_px=0.5) == pytest.approx(0)


# ----------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------

def test_plan_command_prints_the_plan(capsys):
    code, out, _ = run_cli(capsys, "plan", str(EFFECT_SCENES / "combined.xml"), "--spp", "256")
    assert code == 0
    assert "integrator:   distribution (max_depth 3)" in out
    assert "film 2D, lens 2D, then per path vertex (up to 3)" in out
    assert "in 64 time-stratified sub-frames of 4 spp" in out
    code, out, _ = run_cli(capsys, "plan", str(EFFECT_SCENES / "combined.xml"), "--json",
                           "--effect", "dof=off,motion=off")
    plan = json.loads(out)
    assert plan["effects_on"] == ["aa", "soft_shadows", "glossy"]
    assert plan["camera"] == "perspective" and plan["subframes"] == 1
    assert plan["effects"]["dof"]["forced"] == "off"


@pytest.mark.parametrize("argv, message", [
    (["--effect", "dof"], "NAME=on|off"),
    (["--effect", "aa=off"], "cannot be switched off"),
    (["--effect", "dof=on"], "not a thinlens"),
])
def test_effect_flag_errors_are_one_line(capsys, argv, message):
    for command in ("plan", "render"):
        code, _, err = run_cli(capsys, command, str(EFFECT_SCENES / "aa.xml"), *argv)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_render_follows_the_plan_and_records_it(tmp_path, capsys):
    out = tmp_path / "m"
    code, _, _ = run_cli(capsys, "-q", "render", str(EFFECT_SCENES / "motion.xml"),
                         "-D", "width=24", "-D", "height=18", "--spp", "16", "-o", str(out))
    assert code == 0
    _, meta = read_exr(out.with_suffix(".exr"))
    plan = json.loads(meta["plan"])
    assert meta["effects"] == "aa,motion" and plan["subframes"] == meta["passes"] > 1
    assert len(plan["subframe_times"]) == plan["subframes"] and plan["spp"] == 16
    code, _, _ = run_cli(capsys, "-q", "render", str(EFFECT_SCENES / "motion.xml"),
                         "-D", "width=24", "-D", "height=18", "--spp", "16",
                         "--effect", "motion=off", "-o", str(out))
    _, meta = read_exr(out.with_suffix(".exr"))
    assert meta["effects"] == "aa" and meta["passes"] == 1


@pytest.mark.parametrize("integrator", [
    '<integrator type="path"><integer name="max_depth" value="2"/></integrator>',
    '<integrator type="path"><integer name="maxDepth" value="2"/></integrator>',  # Mitsuba 0.6
])
def test_an_authored_depth_limit_is_an_upper_bound(tmp_path, integrator):
    """glossy.xml wants max_depth 3 for reflections of other objects; a scene that
    says max_depth 2 (direct light only) keeps 2, and the plan says what that
    leaves out; forcing indirect light on such a scene is refused."""
    text = (EFFECT_SCENES / "glossy.xml").read_text()
    text = text.replace('<integrator type="direct"/>', integrator)
    if "maxDepth" in integrator:
        text = text.replace('version="3.0.0"', 'version="0.6.0"')
    path = tmp_path / "glossy_depth2.xml"
    path.write_text(text)
    plan = plan_scene(path).plan
    assert plan.integrator["max_depth"] == 2
    assert "capped at the scene's max_depth 2" in plan.integrator_reason
    with pytest.raises(McrtError, match="indirect=on: the scene's integrator sets max_depth 2"):
        plan_scene(path, overrides={"indirect": True})
    deeper = tmp_path / "glossy_depth5.xml"
    deeper.write_text(text.replace('value="2"', 'value="5"'))
    assert plan_scene(deeper).plan.integrator["max_depth"] == 5  # a bound, not a target


# ----------------------------------------------------------------------------
# Indirect light of a scene with one reflecting shape
# ----------------------------------------------------------------------------
def one_shape_scene(tmp_path: Path, shape: str) -> Path:
    """A ``path`` scene (max_depth 8) of one reflecting ``shape`` (XML) and a point
    light at (0, 0.5, 0), seen from (0, 0, 0.5) towards -z."""
    path = tmp_path / "one_shape.xml"
    path.write_text(scene_xml(
        shape + '<emitter type="point"><point name="position" x="0" y="0.5" z="0"/>'
        '<rgb name="intensity" value="5"/></emitter>',
        '<integrator type="path"><integer name="max_depth" value="8"/></integrator>',
        origin="0, 0, 0.5", target="0, 0, -1", fov=60))
    return path


DIFFUSE_08 = '<bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf>'
FLIPPED = '<boolean name="flip_normals" value="true"/>'


@pytest.mark.parametrize("shape, indirect", [
    (f'<shape type="sphere"><float name="radius" value="2"/>{FLIPPED}{DIFFUSE_08}</shape>', True),
    (f'<shape type="cube"><transform name="to_world"><scale value="2"/></transform>{FLIPPED}'
     f'{DIFFUSE_08}</shape>', True),
    (f'<shape type="sphere"><float name="radius" value="2"/><bsdf type="twosided">{DIFFUSE_08}'
     '</bsdf></shape>', True),
    (f'<shape type="cylinder"><float name="radius" value="2"/>{DIFFUSE_08}</shape>', True),
    (f'<shape type="sphere"><point name="center" x="0" y="0" z="-3"/>{DIFFUSE_08}</shape>',
     False),
    (f'<shape type="cube"><transform name="to_world"><translate z="-3"/></transform>'
     f'{DIFFUSE_08}</shape>', False),
    ('<shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform>'
     '<bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>', False),
])
def test_one_shape_gets_indirect_light_unless_it_cannot_light_itself(tmp_path, shape, indirect):
    """A single shape lights itself unless it is flat or closed, convex, with
    outward normals and a one-sided opaque BSDF (the inside of a flipped sphere,
    a room, was rendered with direct light only: 0.30 against Mitsuba's 1.24)."""
    plan = plan_scene(one_shape_scene(tmp_path, shape)).plan
    assert plan.on("indirect") is indirect
    assert plan.integrator["type"] == ("path" if indirect else "direct")
    if indirect:
        assert "can light itself" in plan.effects["indirect"].reason


def test_the_inside_of_a_sphere_renders_what_mitsubas_path_tracer_renders(tmp_path):
    """The planned scene against the authored one (loaded as written): pixel means
    of independent renders differ by z ~ N(0, 1) if the plan keeps every bounce;
    the mean z over the 256 pixels must lie within 4/sqrt(n) of 0 (4 standard
    errors) and the rms z below 1.3. With direct light only, z is ~ -47."""
    from mcrt.core.render import render_stats
    from mcrt.core.sampling import make_sampler
    from mcrt.render.scene import load_scene

    path = one_shape_scene(
        tmp_path, f'<shape type="sphere"><float name="radius" value="2"/>{FLIPPED}{DIFFUSE_08}'
                  '</shape>')
    planned = render_stats(plan_scene(path).scene, make_sampler("independent", 256), seed=1)
    authored = render_stats(load_scene(path), make_sampler("independent", 256), seed=2)
    a, b = planned.stats, authored.stats
    se = np.sqrt(a.variance_of_mean + b.variance_of_mean)[..., 0]
    z = ((a.mean - b.mean)[..., 0] / se).ravel()
    assert z.size == 256 and np.all(se > 0)
    assert abs(z.mean()) < 4 / np.sqrt(z.size)
    assert np.sqrt(np.mean(z ** 2)) < 1.3
