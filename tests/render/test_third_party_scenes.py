"""Scenes written by others: old-format scenes, wrapper integrators,
participating media, one instantiation per plan, and the plan's messages.

Statistical comparisons use the image mean of ``K`` renders with fixed seeds
and its standard error from the per-pixel spread across those seeds: with a
box filter, pixel estimates are independent, so ``Var(image mean) =
sum_i Var(pixel_i) / (K P^2)``, estimated with ``P (K - 1)`` degrees of
freedom (thousands: the SE itself is known to a few percent), and a
difference of 5 SE has probability below 1e-6 under the null hypothesis.
"""

from __future__ import annotations

import logging
import re
import shutil
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.errors import McrtError
from mcrt.io import read_exr
from mcrt.render.plan import plan_scene
from mcrt.render.plan.edits import SPOT_BEAM_DEG
from tests.conftest import ROOT, run_cli, scene_xml

FOREIGN = ROOT / "scenes" / "foreign"
OLD = FOREIGN / "old_format.xml"
MEDIUM = FOREIGN / "medium_in_dielectric.xml"
MESH_LIGHT = FOREIGN / "mesh_light.xml"
ENV = FOREIGN / "env_lit.xml"
METER = FOREIGN / "irradiance_meter.xml"
SEEDS = 4


def mean_and_se(images: list[np.ndarray]) -> tuple[float, float]:
    """Image mean over ``K`` renders and its standard error (see the module doc)."""
    stack = np.stack([im[..., :3].mean(axis=-1) for im in images]).astype(np.float64)
    k, pixels = stack.shape[0], stack[0].size
    return float(stack.mean()), float(np.sqrt(stack.var(axis=0, ddof=1).sum() / k) / pixels)


def z_score(a: tuple[float, float], b: tuple[float, float]) -> float:
    return abs(a[0] - b[0]) / float(np.hypot(a[1], b[1]))


def planned_mean(path: Path, params: dict[str, str] | None = None,
                 overrides: dict[str, bool] | None = None, spp: int = 16
                 ) -> tuple[float, float]:
    scene = plan_scene(path, params, overrides).scene
    return mean_and_se([render_film(scene, spp=spp, seed=s).image for s in range(SEEDS)])


def mitsuba_mean(path: Path, spp: int = 16) -> tuple[float, float]:
    """``mi.render`` of ``mi.load_file`` (seeds apart from the planned renders')."""
    scene = mi.load_file(str(path))
    return mean_and_se([np.array(mi.render(scene, spp=spp, seed=100 + s))
                        for s in range(SEEDS)])


def variant(tmp_path: Path, source: Path, old: str, new: str, name: str = "v.xml") -> Path:
    """A copy of ``source`` with ``old`` replaced by ``new`` (next to its meshes)."""
    text = source.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new).replace('value="meshes/',
                                                    f'value="{source.parent}/meshes/'))
    return path


# ----------------------------------------------------------------------------
# Class 4: the plan sees an old-format scene as Mitsuba does
# ----------------------------------------------------------------------------
def test_old_format_scene_is_planned_with_mitsubas_upgraded_names():
    planned = plan_scene(OLD)
    plan = planned.plan
    assert plan.integrator == {"type": "path", "max_depth": 3, "rr_depth": 2,
                               "hide_emitters": True}
    assert plan.spp == 16  # sampleCount
    reference = mi.load_file(str(OLD))
    ours, theirs = (np.array(s.sensors()[0].world_transform().matrix)
                    for s in (planned.scene, reference))
    assert np.allclose(ours, theirs)  # toWorld of the sensor
    bsdfs = {s.bsdf().class_name() for s in planned.scene.shapes()}
    assert "SmoothDielectric" in bsdfs
    assert "1.8" in str([s.bsdf() for s in planned.scene.shapes()
                         if s.bsdf().class_name() == "SmoothDielectric"][0])  # intIOR


@pytest.mark.slow
def test_old_format_scene_renders_as_mi_render_does(tmp_path):
    """The planned render agrees with ``mi.render`` of the same file, and the
    comparison is sharp enough to see the old failure (``maxDepth`` ignored:
    an unbounded path)."""
    ours, theirs = planned_mean(OLD), mitsuba_mean(OLD)
    assert z_score(ours, theirs) < 5
    unbounded = variant(tmp_path, OLD, '<integer name="maxDepth" value="3"/>', "")
    assert plan_scene(unbounded).plan.integrator["max_depth"] == -1
    assert z_score(planned_mean(unbounded), theirs) > 5


# ----------------------------------------------------------------------------
# Class 5: wrappers and media
# ----------------------------------------------------------------------------
def wrapped(tmp_path: Path, inner: str, outer: str = "moment") -> Path:
    """The old-format scene (two facing walls: interreflection) with its
    integrator replaced by ``inner`` inside an ``outer`` wrapper (if any)."""
    text = OLD.read_text()
    start, end = text.index("<integrator"), text.index("</integrator>") + len("</integrator>")
    integrator = f'<integrator type="{outer}">{inner}</integrator>' if outer else inner
    path = tmp_path / "wrapped.xml"
    path.write_text(text[:start] + integrator + text[end:])
    return path


@pytest.mark.parametrize("inner, outer, indirect", [
    ('<integrator type="path"><integer name="max_depth" value="16"/></integrator>', "moment", True),
    ('<integrator type="path"><integer name="max_depth" value="2"/></integrator>', "moment", False),
    ('<integrator type="volpath"/>', "aov", True),
    ('<integrator type="path"><integer name="max_depth" value="5"/></integrator>', "adaptive",
     True),
    ('<integrator type="prb"/>', "", True),                 # Mitsuba's default max_depth 6
    ('<integrator type="direct_projective"/>', "", False),  # default max_depth 2
])
def test_indirect_light_is_what_the_wrapped_integrators_trace(tmp_path, inner, outer, indirect):
    if outer == "aov":
        inner = '<string name="aovs" value="dd.y:depth"/>' + inner
    plan = plan_scene(wrapped(tmp_path, inner, outer)).plan
    assert plan.on("indirect") == indirect and plan.effects["indirect"].present == indirect
    assert plan.integrator_reason == "kept as authored"
    if outer:
        assert plan.scene_integrator.startswith(f"{outer}(")
    with pytest.raises(McrtError, match="re-plans path and direct integrators only"):
        plan_scene(wrapped(tmp_path, inner, outer), overrides={"indirect": not indirect})


def test_a_user_plugin_holding_an_integrator_is_looked_into(tmp_path):
    class Holder(mi.SamplingIntegrator):
        def __init__(self, props: mi.Properties) -> None:
            super().__init__(props)
            self.inner = props["inner"]

    mi.register_integrator("test_holder", Holder)
    inner = '<integrator type="path" name="inner"><integer name="max_depth" value="7"/></integrator>'
    plan = plan_scene(wrapped(tmp_path, inner, "test_holder")).plan
    assert plan.on("indirect") and "path max_depth 7" in plan.effects["indirect"].reason


def test_a_medium_inside_a_dielectric_scatters_indirect_light(tmp_path):
    plan = plan_scene(MEDIUM).plan
    assert set(plan.effects_on) == {"aa", "indirect"}
    note = next(n for n in plan.notes if n.startswith("participating media"))
    assert "homogeneous (interior of 'glass')" in note and "rendered by volpath" in note
    # Without the floor only the medium can scatter light again: still indirect.
    text = MEDIUM.read_text()
    alone = tmp_path / "alone.xml"
    alone.write_text(text[:text.index('<shape type="rectangle">')] + "</scene>\n")
    assert plan_scene(alone).plan.on("indirect")
    clear = tmp_path / "clear.xml"  # ... without the medium, light reflects inside the glass
    text = alone.read_text()
    clear.write_text(text[:text.index("<medium")] + text[text.index("</medium>") + 9:])
    assert plan_scene(clear).plan.on("indirect")
    opaque = tmp_path / "opaque.xml"  # ... and a diffuse ball alone lights nothing again
    opaque.write_text(re.sub(r'<bsdf type="dielectric">.*?</bsdf>', '<bsdf type="diffuse"/>',
                             clear.read_text()))
    assert not plan_scene(opaque).plan.on("indirect")
    # path ignores media, and mcrt says so.
    path = variant(tmp_path, MEDIUM, 'type="volpath"', 'type="path"', "path.xml")
    assert any("ignores them" in n for n in plan_scene(path).plan.notes)


@pytest.mark.slow
def test_a_medium_inside_a_dielectric_renders_as_mi_render_does():
    assert z_score(planned_mean(MEDIUM, spp=8), mitsuba_mean(MEDIUM, spp=8)) < 5


@pytest.mark.slow
def test_a_sensor_attached_to_a_shape_is_rendered_from(capsys, tmp_path):
    """The scene's only sensor is an irradiance meter inside a shape: mcrt plans and
    renders it as ``mi.render`` does (a 1x1 film), instead of finding no sensor.

    The meter's variance is high (the light is reached by a cosine-weighted
    direction), so the means are over 32 seeds: the SE estimate has 31 degrees of
    freedom, and P(|t_31| > 5) is about 2e-5."""
    planned = plan_scene(METER, {"spp": "256"})
    assert planned.plan.on("soft_shadows") and planned.plan.on("indirect")
    ours = mean_and_se([render_film(planned.scene, spp=256, seed=s).image for s in range(32)])
    scene = mi.load_file(str(METER))
    theirs = mean_and_se([np.array(mi.render(scene, spp=256, seed=100 + s)) for s in range(32)])
    assert ours[0] > 1.0 and z_score(ours, theirs) < 5, (ours, theirs)
    code, out, err = run_cli(capsys, "-q", "render", str(METER), "--spp", "16",
                             "--sampler", "sobol", "-o", str(tmp_path / "meter"))
    assert code == 0, err
    layers, _ = read_exr(tmp_path / "meter.exr")
    assert layers["rgb"].shape == (1, 1, 3) and np.all(layers["rgb"] > 0)


def test_a_scenes_search_paths_find_its_files(tmp_path, monkeypatch):
    """``<path value="..."/>`` adds a folder where the scene's files are looked for (here
    a relative one, resolved against the scene's folder, with the working directory
    elsewhere). mcrt parses and builds a scene in two steps: the folders the parse
    added must still be searched when it builds the mesh (they once were not)."""
    folder = tmp_path / "scene" / "lights"
    folder.mkdir(parents=True)
    shutil.copy(FOREIGN / "meshes" / "quad_light.obj", folder)
    text = MESH_LIGHT.read_text().replace("<default name=\"res\"", '<path value="lights"/>'
                                          '<default name="res"', 1)
    path = tmp_path / "scene" / "search.xml"
    path.write_text(text)
    monkeypatch.chdir(tmp_path)
    params = {"light": "quad_light.obj"}
    planned = plan_scene(path, params)
    assert planned.plan.on("soft_shadows")
    ours = mean_and_se([render_film(planned.scene, spp=16, seed=s).image for s in range(SEEDS)])
    scene = mi.load_file(str(path), **params)
    theirs = mean_and_se([np.array(mi.render(scene, spp=16, seed=100 + s))
                          for s in range(SEEDS)])
    assert ours[0] > 0.05 and z_score(ours, theirs) < 5, (ours, theirs)


SHALLOW = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="{depth}"/></integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,2,6" target="0,1,0" up="0,1,0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="roughconductor"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><translate y="3" z="-2"/></transform>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
</scene>"""


@pytest.mark.slow
@pytest.mark.parametrize("depth", [0, 1])
def test_a_path_that_stops_before_any_lighting_is_rendered_as_authored(tmp_path, depth):
    """``path`` with max_depth 0 renders nothing and with 1 only the emitters the
    camera sees: mcrt keeps it (``direct`` would light the floor), and plans no
    soft shadows or glossy reflections, which need lighting (forcing one is an
    error). The image mean agrees with ``mi.render`` (see the module doc)."""
    path = tmp_path / "shallow.xml"
    path.write_text(SHALLOW.format(depth=depth))
    planned = plan_scene(path)
    assert planned.plan.integrator == {"type": "path", "max_depth": depth}
    assert planned.plan.effects_on == ["aa"]
    ours, theirs = planned_mean(path), mitsuba_mean(path)
    if depth == 0:
        assert ours == theirs == (0.0, 0.0)
    else:
        assert ours[0] > 0.05 and z_score(ours, theirs) < 5, (ours, theirs)
    with pytest.raises(McrtError, match="renders no lighting"):
        plan_scene(path, overrides={"soft_shadows": True})


THIN_LENS = """<sensor type="thinlens">
    <float name="aperture_radius" value="0.1"/><float name="focus_distance" value="3"/>
    <transform name="to_world"><lookat origin="0,2,6" target="0,0.5,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
</sensor>"""


@pytest.mark.parametrize("camera_first", [True, False])
def test_the_plan_is_made_for_the_sensor_mitsuba_renders_from(tmp_path, camera_first):
    """With a camera and a shape's sensor in one scene, ``mi.render`` (and mcrt) render
    from the first in document order; the plan must describe that one (the thin
    lens's depth of field only when the camera is first)."""
    text = METER.read_text()
    text = (text.replace('<bsdf type="diffuse" id="white">', THIN_LENS + '<bsdf type="diffuse" id="white">')
            if camera_first else text.replace("</scene>", THIN_LENS + "</scene>"))
    path = tmp_path / "both.xml"
    path.write_text(text)
    planned = plan_scene(path)
    size = tuple(planned.scene.sensors()[0].film().size())
    assert size == ((8, 6) if camera_first else (1, 1))
    assert planned.plan.on("dof") == camera_first


# ----------------------------------------------------------------------------
# "Done when": plan lists exactly the effects of each scene of this file
# ----------------------------------------------------------------------------
@pytest.mark.parametrize("scene, effects", [
    (OLD, {"aa", "indirect"}),
    (MEDIUM, {"aa", "indirect"}),
    (MESH_LIGHT, {"aa", "soft_shadows"}),
    (ENV, {"aa"}),
])
def test_plan_lists_exactly_the_effects_of_each_foreign_scene(scene, effects):
    assert set(plan_scene(scene).plan.effects_on) == effects


# ----------------------------------------------------------------------------
# Class 7: read once, instantiate once
# ----------------------------------------------------------------------------
def many_meshes(folder: Path, count: int) -> Path:
    shapes = []
    for i in range(count):
        (folder / f"m{i}.obj").write_text(
            f"v {i} 0 0\nv {i + 0.5} 0 0\nv {i} 0.5 0\nf 1 2 3\n")
        shapes.append(f'<shape type="obj"><string name="filename" value="m{i}.obj"/></shape>')
    path = folder / "many.xml"
    path.write_text(OLD.read_text().replace("</scene>", "\n".join(shapes) + "</scene>"))
    return path


@pytest.mark.parametrize("scene, overrides, builds", [
    ("many", None, 1),
    (ROOT / "scenes" / "effects" / "dof.xml", {"dof": False}, 1),
    (ROOT / "scenes" / "effects" / "motion.xml", {"motion": False}, 1),
    (ROOT / "scenes" / "effects" / "glossy.xml", {"glossy": False}, 1),
    (ROOT / "scenes" / "effects" / "soft_shadows.xml", {"soft_shadows": False}, 2),
])
def test_a_plan_instantiates_the_scene_once(tmp_path, monkeypatch, scene, overrides, builds):
    path = many_meshes(tmp_path, 60) if scene == "many" else scene
    calls = []
    instantiate = mi.parser.instantiate

    def counting(*args, **kwargs):
        calls.append(1)
        return instantiate(*args, **kwargs)

    monkeypatch.setattr(mi.parser, "instantiate", counting)
    planned = plan_scene(path, overrides=overrides)
    assert len(calls) == builds
    if scene == "many":
        assert len(planned.scene.shapes()) >= 1 and planned.plan.on("indirect")


# ----------------------------------------------------------------------------
# Class 9: messages
# ----------------------------------------------------------------------------
def test_the_scene_sample_count_rounding_is_a_note_not_a_warning(tmp_path, caplog):
    path = variant(tmp_path, ENV, '<sampler type="independent">',
                   '<sampler type="jittered">')
    with caplog.at_level(logging.INFO):
        plan = plan_scene(path, {"spp": "128"}).plan
    assert not [r for r in caplog.records if "rounding" in r.getMessage()]
    assert plan.spp == 144
    assert any("sample_count 128 as 144" in n for n in plan.notes)


@pytest.mark.slow
def test_soft_shadows_off_keeps_the_power_of_a_flat_mesh_light():
    """A flat quad mesh becomes a spot along its normal emitting the area light's
    power ``pi L A``; the lighting then stays within 10% (measured +4%; the old
    isotropic point light gave 30%)."""
    planned = plan_scene(MESH_LIGHT, overrides={"soft_shadows": False})
    (light,) = planned.scene.emitters()
    assert light.class_name() == "SpotLight"
    beam, cutoff = np.radians(SPOT_BEAM_DEG), np.pi / 2
    theta = np.linspace(0, cutoff, 200001)
    falloff = np.where(theta < beam, 1.0, (cutoff - theta) / (cutoff - beam))
    intensity = float(np.array(mi.traverse(light)["intensity.value"]).ravel()[0])
    power = 2 * np.pi * intensity * np.trapezoid(falloff * np.sin(theta), theta)
    assert power == pytest.approx(np.pi * 20 * 0.25, rel=1e-4)
    axis = np.array(light.world_transform().matrix)[:3, 2].ravel()
    assert np.allclose(axis, [0, -1, 0], atol=1e-5)  # the quad faces down
    on, off = planned_mean(MESH_LIGHT, spp=32), planned_mean(
        MESH_LIGHT, overrides={"soft_shadows": False}, spp=32)
    assert 0.9 < off[0] / on[0] < 1.1
    assert any("same power" in n for n in planned.plan.notes)


def test_soft_shadows_off_makes_a_closed_light_a_point_and_refuses_other_shapes(tmp_path):
    sphere = variant(tmp_path, MESH_LIGHT, '<string name="filename" value="$light"/>', "")
    sphere.write_text(sphere.read_text().replace('type="obj"', 'type="sphere"'))
    (light,) = plan_scene(sphere, overrides={"soft_shadows": False}).scene.emitters()
    assert light.class_name() == "PointLight"
    intensity = float(np.array(mi.traverse(light)["intensity.value"]).ravel()[0])
    assert intensity == pytest.approx(20 * 4 * np.pi / 4, rel=1e-4)  # L A / 4, unit sphere
    with pytest.raises(McrtError, match="neither flat nor closed"):
        plan_scene(MESH_LIGHT, {"light": "meshes/open_box.obj"}, {"soft_shadows": False})


def test_indirect_off_names_the_emitters_that_need_a_bsdf_sample(tmp_path):
    path = variant(tmp_path, ENV, '<integrator type="direct"/>', '<integrator type="path"/>')
    assert plan_scene(path).plan.on("indirect")
    plan = plan_scene(path, overrides={"indirect": False}).plan
    assert plan.integrator["type"] == "direct" and plan.integrator["bsdf_samples"] == 1
    assert "constant emitter" in plan.integrator_reason
    assert "area" not in plan.integrator_reason


def test_a_plan_names_a_scenes_many_objects_in_a_line(tmp_path):
    """A scene of many objects (40 area-lit tiles, 30 spheres of one rough plastic
    each, 12 of them in fog): the reasons name repeated objects once with their
    count and count what is past the first six, so ``mcrt plan`` prints a line per
    effect; they listed every one (about 1500 characters for the BSDFs alone)."""
    tiles = "".join(
        f'<shape type="rectangle"><transform name="to_world"><scale value="0.05"/>'
        f'<translate x="{i / 20 - 1:g}" y="2"/></transform><emitter type="area">'
        f'<rgb name="radiance" value="1"/></emitter></shape>' for i in range(40))
    fog = '<medium type="homogeneous" name="interior"><float name="sigma_t" value="1"/></medium>'
    balls = "".join(
        f'<shape type="sphere"><float name="radius" value="0.02"/>'
        f'<point name="center" x="{i / 15 - 1:g}" y="0" z="0"/>'
        f'<bsdf type="roughplastic"/>{fog if i < 12 else ""}</shape>' for i in range(30))
    path = tmp_path / "many.xml"
    path.write_text(scene_xml(tiles + balls, '<integrator type="direct"/>'))
    plan = plan_scene(path).plan
    glossy = plan.effects["glossy"].reason
    assert glossy == "rough BSDFs: roughplastic (roughplastic, alpha 0.1) x30"
    shadows = plan.effects["soft_shadows"].reason
    assert shadows.startswith("40 area emitters (") and shadows.endswith(", and 34 more)")
    assert shadows.count(",") == 6
    media = next(note for note in plan.notes if note.startswith("participating media"))
    assert media.startswith("participating media: homogeneous (interior of 'sphere') x12;")
    assert max(len(line) for line in plan.describe().splitlines()) < 250


GROUPED = """<shape type="shapegroup" id="grp">{group_motion}
    <shape type="sphere" id="member"><float name="radius" value="0.3"/>{member_motion}</shape>
</shape>
<shape type="instance" id="copy"><ref id="grp"/>{instance_motion}
    <transform name="to_world"><translate x="-1"/></transform></shape>
<emitter type="point"><point name="position" value="0, 0, 5"/><rgb name="intensity" value="5"/></emitter>"""
VELOCITY = '<vector name="mcrt_velocity" value="2, 0, 0"/>'
SHUTTER = '<float name="fov" value="40"/><float name="shutter_close" value="1"/>'


@pytest.mark.parametrize("where, message", [
    ("member_motion", "shape 'member' cannot move: it is in the shapegroup 'grp'"),
    ("group_motion", "shapegroup 'grp' cannot move"),
])
def test_motion_of_a_shapegroups_shapes_is_refused_and_instances_move(tmp_path, where,
                                                                       message):
    """mcrt's motion properties on a shape inside a ``shapegroup`` (or on the
    group) are refused in one line that says to move the instances; they ended in
    a KeyError traceback (the plan looked the shape up among the scene's shapes,
    where only the instances are). An instance itself moves."""
    def write(**motion: str) -> Path:
        body = GROUPED.format(**{"group_motion": "", "member_motion": "",
                                 "instance_motion": "", **motion})
        path = tmp_path / "grouped.xml"
        path.write_text(scene_xml(body, '<integrator type="direct"/>')
                        .replace('<float name="fov" value="40"/>', SHUTTER))
        return path

    with pytest.raises(McrtError, match=re.escape(message)):
        plan_scene(write(**{where: VELOCITY}))
    planned = plan_scene(write(instance_motion=VELOCITY), {}, None)
    assert planned.plan.on("motion")
    planned.driver.set_time(0.5)
    (copy,) = planned.scene.shapes()
    centre = (np.array(copy.bbox().min).ravel() + np.array(copy.bbox().max).ravel()) / 2
    assert np.allclose(centre, [-1 + 2 * 0.5, 0, 0], atol=1e-5)
