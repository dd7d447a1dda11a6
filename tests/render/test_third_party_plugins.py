"""Mitsuba plugins of third-party scenes beyond the first sweep's
(:mod:`tests.render.test_third_party_features`): BSDFs, shapes, sensors, films
and integrators, planned and rendered as ``mi.render`` renders them.

Statistical comparisons are those of :mod:`tests.render.test_third_party_scenes`
(the image mean of 4 renders with fixed seeds, its standard error from the
per-pixel spread across those seeds with thousands of degrees of freedom; a
difference of 5 SE has probability below 1e-6 under the null hypothesis).
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.errors import McrtError
from mcrt.render.plan import plan_scene
from tests.render.test_third_party_features import scene_file
from tests.render.test_third_party_scenes import mitsuba_mean, planned_mean, z_score

POINT_LIGHT = """<emitter type="point"><point name="position" value="1,-2,3"/>
  <rgb name="intensity" value="20"/></emitter>"""


def sphere(bsdf: str) -> str:
    return f'<shape type="sphere"><float name="radius" value="1"/>{bsdf}</shape>'


def test_a_hair_bsdf_renders(tmp_path: Path):
    """Mitsuba 3.9.1's ``hair`` BSDF lists its unset ``sigma_a`` as a parameter
    whose value is None, which ``mi.traverse``'s parameters cannot read (a
    TypeError): the replay's scan of the scene's arrays crashed on it, so no
    scene with hair rendered at all."""
    path = scene_file(tmp_path, POINT_LIGHT + sphere('<bsdf type="hair"/>'))
    assert plan_scene(path).plan.on("glossy")
    assert z_score(planned_mean(path), mitsuba_mean(path)) < 5


@pytest.mark.parametrize("bsdf", ["principledthin", "pplastic"])
def test_rough_bsdfs_without_a_smooth_counterpart_are_glossy(tmp_path: Path, bsdf: str):
    """The thin principled BSDF (roughness 0.5 unless set; the plan looked for a
    plugin named ``principledthinfilm``, which Mitsuba 3.9 does not have) and the
    polarized plastic (alpha 0.1 unless set) have glossy lobes: the plan said "no
    rough BSDF", and switching glossy off must be refused, not ignored."""
    path = scene_file(tmp_path, POINT_LIGHT + sphere(f'<bsdf type="{bsdf}" id="coat"/>'))
    glossy = plan_scene(path).plan.effects["glossy"]
    assert glossy.on and glossy.reason == f"rough BSDFs: coat ({bsdf})"
    with pytest.raises(McrtError, match=f"cannot make the '{bsdf}' BSDF smooth"):
        plan_scene(path, overrides={"glossy": False})


AREA_LIGHT = """<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/>
  <translate z="3"/></transform><emitter type="area"><rgb name="radiance" value="6"/></emitter>
  </shape>"""


@pytest.mark.parametrize("integrator, reason", [
    ('<integrator type="depth"/>', "depth as authored: depth renders distances, no lighting"),
    ('<integrator type="aov"><string name="aovs" value="dd:depth"/></integrator>',
     "aov as authored: aov renders its AOV channels, no lighting")])
def test_integrators_that_render_no_light_have_no_lighting_effects(tmp_path: Path,
                                                                   integrator: str, reason: str):
    """``depth`` and a bare ``aov`` never sample an emitter or a BSDF: the plan
    claimed soft shadows (and would claim glossy reflections) for their images."""
    path = scene_file(tmp_path, AREA_LIGHT + sphere('<bsdf type="roughplastic"/>'))
    path.write_text(path.read_text().replace('<integrator type="path"/>', integrator))
    plan = plan_scene(path).plan
    assert plan.effects_on == ["aa"]
    for name in ("soft_shadows", "glossy", "indirect"):
        assert plan.effects[name].reason == reason
    with pytest.raises(McrtError, match="soft_shadows=on: .*no lighting"):
        plan_scene(path, overrides={"soft_shadows": True})


def test_soft_shadows_off_makes_a_cube_light_a_point(tmp_path: Path):
    """A ``cube`` is a closed mesh: its light becomes a point light of intensity
    L A / 4 at its centre. Its mean normal was measured from a 64x64 grid of
    area samples, which a mesh maps to triangles through their area CDF, leaving
    faces unevenly sampled: 0.02 of flat, so the cube was refused as "neither
    flat nor closed". From its triangles it is 0 to float rounding."""
    path = scene_file(tmp_path, sphere('<bsdf type="diffuse"/>') + """
      <shape type="cube"><transform name="to_world"><scale value="0.4"/>
        <translate x="0.5" z="2.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>""")
    (light,) = plan_scene(path, overrides={"soft_shadows": False}).scene.emitters()
    assert light.class_name() == "PointLight"
    params = mi.traverse(light)
    intensity = float(np.array(params["intensity.value"]).ravel()[0])
    assert intensity == pytest.approx(5 * 6 * 0.8 ** 2 / 4, rel=1e-5)  # L A / 4
    position = np.array(params["position"], dtype=np.float64).ravel()
    np.testing.assert_allclose(position, [0.5, 0, 2.5], atol=1e-6)


def test_a_batch_sensors_thin_lens_is_depth_of_field(tmp_path: Path):
    """A ``batch`` sensor renders its sensors side by side; a thin lens among them
    blurs as it does alone (its lens 2D is drawn), but the plan read only the
    batch's own plugin and said "pinhole camera (batch)", and dof=off would have
    rendered the blur it claimed to remove."""
    film = ('<film type="hdrfilm"><integer name="width" value="32"/>'
            '<integer name="height" value="16"/><rfilter type="box"/></film>')
    pose = '<transform name="to_world"><lookat origin="0,-6,1" target="0,0,0" up="0,0,1"/>' \
           '</transform>'
    path = tmp_path / "batch.xml"
    path.write_text(f"""<scene version="3.0.0"><sensor type="batch">{film}
      <sensor type="thinlens"><float name="aperture_radius" value="0.3"/>
        <float name="focus_distance" value="3"/>{pose}</sensor>
      <sensor type="perspective">{pose}</sensor></sensor>
      {POINT_LIGHT}{sphere('<bsdf type="diffuse"/>')}</scene>""")
    plan = plan_scene(path).plan
    assert plan.on("dof") and plan.aperture_sample
    assert plan.effects["dof"].reason == "batch sensor with 1 thin lens, rendered as authored"
    with pytest.raises(McrtError, match="dof=off: batch sensor"):
        plan_scene(path, overrides={"dof": False})


def test_a_sensor_in_fog_renders_as_mi_render_does_and_the_note_names_it(tmp_path: Path):
    """A medium given to the sensor (the camera stands in fog, nothing bounds it):
    its rays start in it. The note called it by the parser's placeholder name
    ("_arg_0 of 'perspective'")."""
    path = scene_file(tmp_path, POINT_LIGHT + sphere('<bsdf type="diffuse"/>'))
    path.write_text(path.read_text().replace(
        '<integrator type="path"/>', '<integrator type="volpath"/>').replace(
        '<film type="hdrfilm">', '<medium type="homogeneous"><float name="sigma_t" value="0.15"/>'
        '<rgb name="albedo" value="0.9"/></medium><film type="hdrfilm">'))
    plan = plan_scene(path).plan
    assert plan.notes == ["participating media: homogeneous (medium of 'perspective'); "
                          "rendered by volpath"]
    assert z_score(planned_mean(path), mitsuba_mean(path)) < 5
