"""The ``multisample`` integrator: shading shared by the samples that see one surface.

Every check here is exact or bounded by the strata, never statistical:
flat (emissive) surfaces have one bitwise-constant radiance, so a multisampled
pixel must equal the supersampled one *exactly*, whatever the sampler and
filter; the coverage of a vertical edge by n x n jittered strata is known to
within one stratum column (1/n); and what the integrator shades is compared with
counts derived from the geometry.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.errors import McrtError
from mcrt.render import multisample as ms
from tests.conftest import run_cli

LEFT, RIGHT = (0.8, 0.2, 0.1), (0.1, 0.3, 0.9)


def _sensor(width, height, sampler="jittered", spp=16, rfilter="box", **sampler_props):
    return {"type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]),
            "sampler": {"type": sampler, "sample_count": spp, **sampler_props},
            "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb",
                     "component_format": "float32", "rfilter": {"type": rfilter}}}


def _emissive_rect(x0, x1, colour):
    return {"type": "rectangle",
            "to_world": mi.ScalarTransform4f().translate([(x0 + x1) / 2, 0, 0])
            .scale([(x1 - x0) / 2, 2, 1]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": colour}}}


def _two_surfaces(integrator, edge, width=16, height=8, **sensor):
    """Two flat emissive rectangles meeting at the vertical line x = ``edge``
    (orthographic view of x in [-1, 1]: pixel column ``(edge + 1) / 2 * width``)."""
    return mi.load_dict({"type": "scene", "integrator": integrator,
                         "sensor": _sensor(width, height, **sensor),
                         "a": _emissive_rect(-1.5, edge, LEFT),
                         "b": _emissive_rect(edge, 1.5, RIGHT)})


def _pair(edge, **sensor):
    flat = {"type": "path", "max_depth": 1}
    return (_two_surfaces(flat, edge, **sensor),
            _two_surfaces({"type": "multisample", "nested": flat}, edge, **sensor))


@pytest.mark.slow
@pytest.mark.parametrize("sampler,spp,rfilter", [
    ("independent", 16, "box"), ("stratified", 16, "gaussian"), ("jittered", 16, "box"),
    ("poisson_disk", 9, "tent"), ("ldsampler", 16, "mitchell")])
def test_flat_surfaces_give_exactly_the_supersampled_image(sampler, spp, rfilter):
    # edge=1.4 lies outside the view: one flat surface per pixel (two triangles,
    # same radiance); edge=-0.2125 adds an edge through column 6.3.
    for edge in (1.4, -0.2125):
        ss, msa = _pair(edge, sampler=sampler, spp=spp, rfilter=rfilter)
        expected = render_film(ss, seed=5).image
        got = render_film(msa, seed=5).image
        assert np.array_equal(got, expected), (sampler, edge)
        counts = msa.integrator().counts
        assert counts.samples == 16 * 8 * spp
        assert counts.evaluations < counts.samples / 4  # shading was shared


def test_mitsuba_render_drives_it_too():
    ss, msa = _pair(-0.2125, sampler="stratified", spp=16)
    expected = np.array(mi.render(ss, seed=2))
    got = np.array(mi.render(msa, seed=2))
    assert np.array_equal(got, expected)


def test_edge_pixels_get_the_coverage_weighted_colour():
    # Edge at pixel column 6.3 (fraction 0.3 of pixel 6 on the left side). With
    # 4 x 4 jittered strata each row of strata misjudges the coverage by at most
    # one stratum column: |estimate - 0.3| <= 1/4 in every pixel of column 6.
    n = 4
    _, msa = _pair(-0.2125, sampler="jittered", spp=n * n)
    image = render_film(msa, seed=1).image
    left, right = np.array(LEFT), np.array(RIGHT)
    expected = 0.3 * left + 0.7 * right
    bound = np.abs(left - right) / n + 1e-6
    assert np.all(np.abs(image[:, 6] - expected) <= bound)
    assert np.all(image[:, :6] == left.astype(np.float32))
    assert np.all(image[:, 7:] == right.astype(np.float32))
    # and the estimate is not stuck at one colour: coverage in (0, 1)
    assert np.all(np.abs(image[:, 6] - left) > 0) and np.all(np.abs(image[:, 6] - right) > 0)


def _diagonal_quad(integrator, size=16, spp=16):
    """One mesh of two triangles whose shared diagonal runs corner to corner
    through the film (orthographic view of [-1, 1]^2 on a square film)."""
    mesh = mi.Mesh("quad", 4, 2)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f([-2, 2, 2, -2], [-2, -2, 2, 2], 0))
    params["faces"] = dr.ravel(mi.Vector3u([0, 0], [1, 2], [2, 3]))
    params.update()
    mesh.set_bsdf(mi.load_dict({"type": "diffuse"}))  # type: ignore[attr-defined]
    return mi.load_dict({"type": "scene", "integrator": integrator,
                         "sensor": _sensor(size, size, spp=spp), "quad": mesh,
                         "light": {"type": "directional", "direction": [0, 0, -1]}})


@pytest.mark.parametrize("group_by", ["primitive", "shape"])
def test_shading_evaluations_are_the_distinct_surfaces_per_pixel(group_by):
    # The diagonal crosses pixels (i, i) through their corners: 4 x 4 strata put
    # samples on both triangles there (strata off the diagonal lie wholly on one
    # side), one triangle everywhere else.
    scene = _diagonal_quad({"type": "multisample", "group_by": group_by,
                            "nested": {"type": "direct"}})
    render_film(scene, seed=0)
    counts = scene.integrator().counts
    eye = np.eye(16, dtype=np.int64)
    if group_by == "primitive":
        assert np.array_equal(counts.per_pixel, 1 + eye) or \
            np.array_equal(counts.per_pixel, 1 + eye[::-1])
    else:
        assert np.array_equal(counts.per_pixel, np.ones((16, 16), np.int64))
    assert counts.evaluations == counts.per_pixel.sum()
    assert counts.samples_per_pixel == [16]
    scene.integrator().reset_counts()
    assert scene.integrator().counts.evaluations == 0


def _checker_plane(integrator, sampler, spp, scale=13.7):
    """A flat, sun-lit plane with a checkerboard finer than the pixels."""
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": _sensor(32, 32, sampler=sampler, spp=spp),
        "light": {"type": "directional", "direction": [0, 0, -1]},
        "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(2),
                  "bsdf": {"type": "diffuse", "reflectance": {
                      "type": "checkerboard", "color0": 0.9, "color1": 0.1,
                      "to_uv": mi.ScalarTransform4f().scale(scale)}}}})


def test_texture_is_shaded_once_per_surface():
    # Supersampling averages the fine checks into greys; multisampling shades one
    # sample per triangle per pixel, so (with a box filter) every pixel that sees
    # one triangle is exactly one of the two check colours.
    ss = render_film(_checker_plane({"type": "direct"}, "jittered", 16), seed=0).image
    msa_scene = _checker_plane({"type": "multisample", "group_by": "shape",
                                "nested": {"type": "direct"}}, "jittered", 16)
    msa = render_film(msa_scene, seed=0).image[..., 0]
    checks = np.array([0.9, 0.1]) / np.pi  # diffuse albedo / pi, unit irradiance
    nearest = np.abs(msa[..., None] - checks).min(axis=-1)
    assert np.all(nearest <= 1e-6 * checks[0])  # float32 rounding of the shading only
    assert np.mean(np.abs(ss[..., 0, None] - checks).min(axis=-1) > 1e-3) > 0.5


def test_centre_representative_shades_the_pixel_centre():
    # uniform_grid with 3 x 3 samples puts one sample at the pixel centre: the
    # multisampled checkerboard must then equal a 1-spp render at pixel centres.
    centre = render_film(_checker_plane({"type": "direct"}, "uniform_grid", 1), seed=0).image
    scene = _checker_plane({"type": "multisample", "group_by": "shape",
                            "nested": {"type": "direct"}}, "uniform_grid", 9)
    assert np.array_equal(render_film(scene, seed=0).image, centre)
    first = _checker_plane({"type": "multisample", "group_by": "shape",
                            "representative": "first", "nested": {"type": "direct"}},
                           "uniform_grid", 9)
    assert not np.array_equal(render_film(first, seed=0).image, centre)


def test_loads_from_xml_and_checks_its_parameters():
    scene = mi.load_string("""<scene version="3.0.0">
        <integrator type="multisample">
            <string name="representative" value="first"/>
            <integrator type="direct"/>
        </integrator>
        <sensor type="perspective"><film type="hdrfilm">
            <integer name="width" value="8"/><integer name="height" value="8"/>
        </film></sensor>
        <shape type="sphere"/><emitter type="constant"/>
    </scene>""")
    integrator = scene.integrator()
    assert integrator.representative == "first" and integrator.group_by == "primitive"
    assert "direct" in str(integrator.nested).lower()
    assert np.isfinite(np.array(mi.render(scene, spp=4))).all()
    with pytest.raises((McrtError, RuntimeError), match="representative"):
        mi.load_dict({"type": "multisample", "representative": "middle"})
    with pytest.raises((McrtError, RuntimeError), match="unknown parameter"):
        mi.load_dict({"type": "multisample", "shading_rate": 2})
    assert "representative" in type(integrator).__doc__


def test_layout_must_be_whole_pixels():
    scene = _two_surfaces({"type": "direct"}, 0.0)
    with pytest.raises(McrtError, match="whole number"):
        ms.wavefront_layout(scene, 16 * 8 * 4 + 1)
    assert ms.wavefront_layout(scene, 16 * 8 * 4).group == 4


def test_cli_multisample(tmp_path, capsys):
    scene = tmp_path / "s.xml"
    scene.write_text("""<scene version="3.0.0">
        <integrator type="direct"/>
        <sensor type="perspective">
            <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/>
            </transform>
            <sampler type="jittered"><integer name="sample_count" value="4"/></sampler>
            <film type="hdrfilm"><integer name="width" value="16"/>
                <integer name="height" value="16"/><rfilter type="box"/></film>
        </sensor>
        <emitter type="directional"><vector name="direction" value="0,0,-1"/></emitter>
        <shape type="sphere"><bsdf type="diffuse"/></shape>
    </scene>""")
    code, out, err = run_cli(capsys, "render", str(scene), "--multisample", "-q",
                             "-o", str(tmp_path / "out"))
    assert code == 0, err
    assert "multisample:" in out and "shading evaluations" in out
    assert (tmp_path / "out.exr").exists()
    code, out, err = run_cli(capsys, "render", str(scene), "--multisample", "--adaptive",
                             "-q", "-o", str(tmp_path / "out2"))
    assert code != 0 and "cannot be combined" in err


def test_a_radiance_meter_is_multisampled_and_counted_lane_by_lane(tmp_path, capsys):
    """A radiance meter traces one ray for every sample (Dr.Jit keeps it one
    lane wide): nothing to share, each sample shaded, counted as such (it said
    '1 shading evaluations for 1 samples' at 16 spp) and the same pixel as
    without --multisample, bit for bit."""
    scene = tmp_path / "meter.xml"
    scene.write_text("""<scene version="3.0.0">
        <integrator type="path"><integer name="max_depth" value="3"/></integrator>
        <sensor type="radiancemeter">
            <point name="origin" x="0" y="0" z="4"/><vector name="direction" x="0" y="0" z="-1"/>
            <film type="hdrfilm"><integer name="width" value="1"/>
                <integer name="height" value="1"/><rfilter type="box"/></film>
        </sensor>
        <emitter type="constant"/>
        <shape type="sphere"><bsdf type="diffuse"/></shape>
    </scene>""")
    code, out, err = run_cli(capsys, "render", str(scene), "--multisample", "--spp", "16", "-q",
                             "-o", str(tmp_path / "ms"))
    assert code == 0, err
    assert "multisample: 16 shading evaluations for 16 samples" in out
    code, _, err = run_cli(capsys, "render", str(scene), "--spp", "16", "-q",
                           "-o", str(tmp_path / "plain"))
    assert code == 0, err
    from mcrt.io import read_exr

    ms_pixel, plain = (read_exr(tmp_path / f"{n}.exr")[0]["rgb"] for n in ("ms", "plain"))
    assert np.array_equal(ms_pixel.view(np.uint32), plain.view(np.uint32))


def test_multisampling_a_scene_with_shading_noise_says_what_it_costs(tmp_path, capsys):
    """Soft shadows and indirect light are sampled at the shading rate under
    --multisample: the command says so; over noise-free shading (the checker
    scene: textures under a constant light) it says nothing."""
    from tests.conftest import ROOT

    cornell = ROOT / "scenes" / "cornell_box.xml"
    code, _, err = run_cli(capsys, "render", str(cornell), "-D", "res=16", "--spp", "4",
                           "--multisample", "-o", str(tmp_path / "c"))
    assert code == 0 and "far noisier than supersampling" in err
    assert "soft_shadows, indirect noise" in err
    checker = ROOT / "scenes" / "multisample" / "checker.xml"
    code, _, err = run_cli(capsys, "render", str(checker), "-D", "width=16", "-D", "height=12",
                           "--spp", "4", "--multisample", "-o", str(tmp_path / "k"))
    assert code == 0 and "noisier" not in err


def test_a_radiance_meter_with_shading_noise_gets_no_note_about_it(tmp_path, capsys):
    """On a radiance meter every lane is shaded (no surfaces to share), so its
    soft-shadow noise is sampled at the full rate: no note that the image is
    'far noisier than supersampling' (it printed one, while the counts line
    said 1.0000 evaluations per sample)."""
    scene = tmp_path / "meter.xml"
    scene.write_text("""<scene version="3.0.0">
        <integrator type="path"/>
        <sensor type="radiancemeter">
            <point name="origin" x="0" y="0" z="3"/><vector name="direction" x="0" y="0" z="-1"/>
            <film type="hdrfilm"><integer name="width" value="1"/>
                <integer name="height" value="1"/><rfilter type="box"/></film>
        </sensor>
        <shape type="rectangle"><bsdf type="diffuse"/></shape>
        <shape type="rectangle">
            <transform name="to_world"><rotate x="1" angle="180"/><translate z="2"/>
                <scale value="0.3"/></transform>
            <emitter type="area"><rgb name="radiance" value="10"/></emitter>
        </shape>
    </scene>""")
    code, out, err = run_cli(capsys, "render", str(scene), "--multisample", "--spp", "16",
                             "-o", str(tmp_path / "m"))
    assert code == 0, err
    assert "plan: aa, soft_shadows" in err  # the effect the note is about is there
    assert "multisample: 16 shading evaluations for 16 samples" in out
    assert "noisier" not in err


def _representatives_reference(keys, distance, group, active):
    """Brute force: the lowest-(distance, lane) active lane of the block with all keys equal."""
    lanes = len(active)
    rep = np.full(lanes, 0xFFFFFFFF, np.uint32)
    for i in np.flatnonzero(active):
        block = range(i - i % group, i - i % group + group)
        members = [j for j in block if active[j] and all(k[j] == k[i] for k in keys)]
        rep[i] = min(members, key=lambda j: (distance[j], j))
    return rep


@pytest.mark.parametrize("with_distance", [True, False])
def test_representatives_are_the_nearest_member_of_each_group(with_distance):
    """The device-only election (one symbolic loop per lane) against brute force:
    random keys of few values, distances with ties, a partial active mask, a
    constant (width 1) key; and no representative at all where no lane is active."""
    rng = np.random.default_rng(3)
    lanes, group = 64 * 9, 9
    keys = [rng.integers(0, 3, lanes).astype(np.uint32) for _ in range(2)]
    distance = rng.integers(0, 4, lanes).astype(np.float32)  # many ties
    active = rng.random(lanes) < 0.8
    got = ms.representatives(
        (mi.UInt32(keys[0]), mi.UInt32(0), mi.UInt32(keys[1])),
        mi.Float(distance) if with_distance else None, group, mi.Bool(active))
    expected = _representatives_reference(
        keys, distance if with_distance else np.zeros(lanes), group, active)
    assert np.array_equal(np.array(got), expected)
    none = ms.representatives((mi.UInt32(keys[0]),), None, group, dr.zeros(mi.Bool, lanes))
    assert np.all(np.array(none) == 0xFFFFFFFF)


def test_a_wavefront_without_representatives_shades_nothing_and_gives_zeros():
    """No active lane: no representative, the shading ``if`` skips every slot,
    every lane gets 0 (no host check of the count, so a replay handles it too)."""
    scene = _two_surfaces({"type": "direct"}, 0.0)
    lanes = 32
    ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(0.5, 0, 5), mi.Vector3f(0, 0, -1)))
    ray = dr.gather(mi.RayDifferential3f, ray, dr.zeros(mi.UInt32, lanes))
    rep = dr.full(mi.UInt32, 0xFFFFFFFF, lanes)
    shaded = ms.shade_groups(scene, scene.integrator(),
                             mi.load_dict({"type": "independent"}), mi.UInt32(1), ray, rep, 4)
    assert np.all(np.array(shaded.spectrum) == 0) and not np.any(np.array(shaded.valid))
    assert np.all(np.array(shaded.per_pixel) == 0)
    # and with every lane active, each lane gets its representative's colour
    rep = dr.arange(mi.UInt32, lanes) // 4 * 4
    shaded = ms.shade_groups(scene, scene.integrator(),
                             mi.load_dict({"type": "independent"}), mi.UInt32(1), ray, rep, 4)
    assert np.allclose(np.array(shaded.spectrum).T, RIGHT) and np.all(np.array(shaded.valid))
    assert np.all(np.array(shaded.per_pixel) == 1)
