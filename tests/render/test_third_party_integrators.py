"""Scenes written by others use integrators and films
mcrt must handle: AOV wrappers (``aov``, ``moment``), Mitsuba's differentiable
integrators (``prb``, ``prb_basic``, ``direct_projective``, ``prbvolpath``) and
film pixel formats other than RGB. The scenes are ours (``scenes/foreign``)."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film, render_stats, srgb_to_xyz_matrix
from mcrt.io import read_exr
from tests.conftest import ROOT, run_cli

FOREIGN = ROOT / "scenes" / "foreign"
SPHERE = FOREIGN / "sphere.xml"
MEDIUM = FOREIGN / "medium.xml"


def _load(path, **params) -> mi.Scene:
    return mi.load_file(str(path), **{k: str(v) for k, v in params.items()})


# ----------------------------------------------------------------- class 2


@pytest.mark.slow
@pytest.mark.parametrize("scene_path, integrator", [
    (SPHERE, "prb"), (SPHERE, "prb_basic"), (SPHERE, "direct_projective"),
    (MEDIUM, "prbvolpath")])
def test_differentiable_integrators_agree_with_mitsuba(scene_path, integrator):
    """mcrt's engine drives the AD integrators (their sample() takes a mode and
    state) and its image mean agrees with ``mi.render`` of the same scene.

    Margin: the two means are independent estimates (different seeds) of the
    same quantity; each has variance sum_p var_p / n / P^2 (var_p from mcrt's
    exact per-pixel moments), so the difference must lie within 5 SE of 0
    (a false failure has probability < 1e-6)."""
    scene = _load(scene_path, integrator=integrator, width=16, height=12, spp=64)
    stats = render_stats(scene, mi.load_dict({"type": "independent"}), spp=64, seed=3).stats
    ours = stats.mean.mean()
    se_ours = np.sqrt(stats.variance_of_mean.mean(axis=-1).sum()) / stats.count.size
    theirs = float(np.asarray(mi.render(scene, seed=11, spp=64), np.float64)[..., :3].mean())
    assert stats.nonfinite.sum() == 0
    assert ours > 0.05  # a lit image, not a black one
    assert abs(ours - theirs) < 5 * np.sqrt(2) * se_ours, (ours, theirs, se_ours)
    # The developed film of the same engine agrees with its moments (box filter).
    film = render_film(scene, mi.load_dict({"type": "independent"}), spp=64, seed=3)
    np.testing.assert_allclose(film.rgb, stats.mean, rtol=1e-5, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["render", "adaptive", "reference"])
def test_prb_works_in_every_command(tmp_path, capsys, mode):
    """``prb`` renders in ``render``, ``render --adaptive`` and ``reference``."""
    out = tmp_path / "out"
    args = {"render": ["render", str(SPHERE), "-D", "integrator=prb", "-o", str(out)],
            "adaptive": ["render", str(SPHERE), "-D", "integrator=prb", "--adaptive",
                         "--min-spp", "4", "--max-spp", "16", "-o", str(out)],
            "reference": ["reference", str(SPHERE), "-D", "integrator=prb", "--spp", "16",
                          "--no-cache", "-o", str(out)]}[mode]
    code, stdout, stderr = run_cli(capsys, "-q", *args)
    assert code == 0, stderr
    layers, _ = read_exr(out.with_suffix(".exr"))
    assert layers["rgb"].shape == (6, 8, 3)
    assert np.isfinite(layers["rgb"]).all() and layers["rgb"].mean() > 0.05


# ----------------------------------------------------------------- class 1


def test_aov_integrator_writes_image_and_named_aovs(tmp_path, capsys):
    """An ``aov`` wrapper: the EXR holds the image (R G B) and every AOV channel
    under Mitsuba's name; the AOVs hold what Mitsuba's film holds."""
    out = tmp_path / "aov"
    code, _, stderr = run_cli(capsys, "-q", "render", str(FOREIGN / "aov.xml"), "-o", str(out))
    assert code == 0, stderr
    layers, meta = read_exr(out.with_suffix(".exr"))
    scene = _load(FOREIGN / "aov.xml")
    names = list(scene.integrator().aov_names())
    assert meta["image_channels"] == "R G B" and meta["aov_channels"] == " ".join(names)
    assert set(layers) == {"rgb", "_arg_0", "dd.y.T", "nn"}
    assert layers["_arg_0"].shape == (6, 8, 4) and layers["nn"].shape == (6, 8, 3)
    # The nested integrator's image is the image itself (same samples), its alpha 1
    # where the sphere covers the pixel; depth is the camera distance to the sphere
    # (3 at the centre, background 0) and normals are unit length on the sphere.
    np.testing.assert_allclose(layers["_arg_0"][..., :3], layers["rgb"], rtol=1e-5)
    depth = layers["dd.y.T"]
    assert 2.9 < depth[3, 4] < 3.2 and depth[0, 0] == 0.0
    norm = np.linalg.norm(layers["nn"], axis=-1)  # the 2x2 centre pixels lie on the sphere
    np.testing.assert_allclose(norm[2:4, 3:5], 1.0, atol=0.02)
    # Our channels match Mitsuba's film (same names, same order).
    mi.render(scene)
    bitmap = scene.sensors()[0].film().bitmap()
    assert [f.name for f in bitmap.struct_()] == ["R", "G", "B", *names]


def test_moment_integrator_writes_its_moments(tmp_path, capsys):
    """A ``moment`` wrapper: image plus first and second moments, named as
    Mitsuba names them; the second moment is at least the squared first."""
    out = tmp_path / "moment"
    code, _, stderr = run_cli(capsys, "-q", "render", str(FOREIGN / "moment.xml"), "-D",
                              "spp=16", "-o", str(out))
    assert code == 0, stderr
    layers, _ = read_exr(out.with_suffix(".exr"))
    assert set(layers) == {"rgb", "_arg_0", "m2__arg_0"}
    first, second = layers["_arg_0"], layers["m2__arg_0"]
    assert first.mean() > 0.05
    assert np.all(second >= first ** 2 * (1 - 1e-5) - 1e-7)  # E[x^2] >= E[x]^2


def test_failure_writing_keeps_the_render(tmp_path, capsys, monkeypatch):
    """Any failure while writing the outputs (here a bug-like ValueError) keeps
    the finished render in its checkpoint; the next run writes it without
    rendering again."""
    from mcrt.cli import render_cmd

    out = tmp_path / "kept"
    real = render_cmd.write_exr

    def broken(*args, **kwargs):
        raise ValueError("simulated failure after the render")

    monkeypatch.setattr(render_cmd, "write_exr", broken)
    code, _, stderr = run_cli(capsys, "-q", "render", str(FOREIGN / "aov.xml"), "-o", str(out))
    assert code != 0 and "kept in" in stderr and "simulated failure" in stderr
    assert not out.with_suffix(".exr").exists()
    monkeypatch.setattr(render_cmd, "write_exr", real)
    calls: list = []

    def recorded(*args, **kwargs):
        calls.append(kwargs["checkpoints"].resume)
        return render_film(*args, **kwargs)

    monkeypatch.setattr(render_cmd, "render_film", recorded)
    code, _, stderr = run_cli(capsys, "-q", "render", str(FOREIGN / "aov.xml"), "-o", str(out))
    assert code == 0, stderr
    assert calls and calls[0] is not None  # resumed from the kept render
    layers, _ = read_exr(out.with_suffix(".exr"))
    assert "nn" in layers


# ----------------------------------------------------------------- class 3


@pytest.mark.slow
@pytest.mark.parametrize("mode", [[], ["--adaptive", "--spp", "64"]], ids=["fixed", "adaptive"])
@pytest.mark.parametrize("pixel_format, labels", [
    ("luminance", ["Y"]), ("luminance_alpha", ["Y", "A"]), ("xyz", ["X", "Y", "Z"]),
    ("xyza", ["X", "Y", "Z", "A"]), ("rgba", ["R", "G", "B", "A"])])
def test_pixel_formats_written_as_mitsuba_labels_them(tmp_path, capsys, pixel_format, labels,
                                                      mode):
    """The EXR holds what the film holds, under Mitsuba's labels; converting it
    back gives the RGB render of the same samples; the PNG preview is the
    preview of that RGB (XYZ is never encoded as if it were sRGB). Adaptive
    renders too: their samples do not depend on the pixel format."""
    from PIL import Image

    rgb_out, out = tmp_path / "rgb", tmp_path / pixel_format
    for target, fmt in ((rgb_out, "rgb"), (out, pixel_format)):
        code, _, stderr = run_cli(capsys, "-q", "render", str(SPHERE), "-D",
                                  f"pixel_format={fmt}", *mode, "-o", str(target))
        assert code == 0, stderr
    rgb = read_exr(rgb_out.with_suffix(".exr"))[0]["rgb"].astype(np.float64)
    layers, meta = read_exr(out.with_suffix(".exr"))
    assert meta["image_channels"] == " ".join(labels)
    unprefixed = {k: v for k, v in layers.items() if k in ("rgb", "X", "Y", "Z", "A")}
    matrix = srgb_to_xyz_matrix()
    if labels[0] == "X":
        assert set(unprefixed) == set(labels)
        xyz = np.stack([layers[c] for c in "XYZ"], -1).astype(np.float64)
        np.testing.assert_allclose(xyz, rgb @ matrix.T, rtol=1e-4, atol=1e-6)
    elif labels[0] == "Y":
        luminance = layers["Y"] if "A" in labels else layers["rgb"]
        np.testing.assert_allclose(luminance, rgb @ matrix[1], rtol=1e-4, atol=1e-6)
    else:
        np.testing.assert_allclose(layers["rgb"][..., :3], rgb, rtol=1e-6)
    if "A" in labels:
        alpha = layers["A"] if "A" in layers else layers["rgb"][..., 3]
        assert alpha.max() == 1.0 and alpha.min() >= 0.0
    png = np.asarray(Image.open(out.with_suffix(".png")).convert("RGB"), np.int16)
    reference_png = np.asarray(Image.open(rgb_out.with_suffix(".png")).convert("RGB"), np.int16)
    if labels[0] == "Y":  # grey: all three channels equal
        assert np.array_equal(png[..., 0], png[..., 2])
    else:  # the same colours as the RGB render's preview (within rounding)
        assert np.abs(png - reference_png).max() <= 1


def test_study_refuses_luminance_films_in_one_line(tmp_path):
    from mcrt.analysis.study.config import ConfigError, load_config

    toml = tmp_path / "study.toml"
    toml.write_text(f'spp = [4, 16]\nseeds = 2\nsamplers = ["independent"]\n[reference]\nspp = 64\n'
                    f'[[scenes]]\npath = "{SPHERE}"\n'
                    f'params = {{ pixel_format = "luminance", width = 32, height = 32 }}\n')
    with pytest.raises(ConfigError, match="luminance") as info:
        load_config(toml)
    assert "\n" not in str(info.value)


_CAMERA = """<sensor type="perspective">
  <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
</sensor>"""


@pytest.mark.parametrize("body, cause, hint", [
    ('<shape type="sphere"><emitter type="area"><spectrum type="blackbody" name="radiance">'
     '<float name="temperature" value="3000"/></spectrum></emitter></shape>',
     "BlackBodySpectrum: Not implemented for non-spectral modes", "--variant llvm_ad_spectral"),
    ('<shape type="rectangle"><bsdf type="bumpmap"><texture type="checkerboard" '
     'name="arbitrary"/><bsdf type="diffuse"/></bsdf></shape>'
     '<emitter type="constant"/>',
     "Texture: Texture::eval_1_grad(): not implemented!", None)])
def test_a_plugin_mitsuba_cannot_evaluate_is_a_one_line_scene_error(tmp_path, capsys, body,
                                                                    cause, hint):
    """Scenes that load but that Mitsuba cannot render in this variant (mi.render
    raises too): one line naming the plugin's own message, exit status 2, for a
    fixed and an adaptive render; with a hint where a spectral variant would do."""
    scene = tmp_path / "scene.xml"
    scene.write_text(f'<scene version="3.0.0"><integrator type="path"/>{_CAMERA}{body}</scene>')
    with pytest.raises(RuntimeError):
        mi.render(mi.load_file(str(scene)), spp=1)
    for extra in ([], ["--adaptive"]):
        code, _, err = run_cli(capsys, "render", str(scene), "--spp", "16", "-q",
                               "-o", str(tmp_path / "out"), *extra)
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith("mcrt: error: Mitsuba cannot render this scene") and cause in err
        assert (hint in err) if hint else "variant" not in err


def test_other_runtime_errors_while_tracing_keep_their_traceback():
    """Only a Mitsuba plugin's refusal ('[Class] message') becomes a scene error:
    anything else raised inside an integrator is a bug and propagates as is."""
    from mcrt.core.trace import integrator_sample

    class Broken(mi.SamplingIntegrator):
        def sample(self, scene, sampler, ray, medium, active):
            raise RuntimeError("an integrator bug")

    scene = _load(SPHERE, width=4, height=4, spp=1)
    ray = mi.RayDifferential3f(mi.Point3f(0, 0, 0), mi.Vector3f(0, 0, 1))
    with pytest.raises(RuntimeError, match="an integrator bug"):
        integrator_sample(Broken(mi.Properties()), scene, mi.load_dict({"type": "independent"}),
                          ray)


def test_an_adjoint_integrator_is_refused_by_plan_and_render_in_one_line(tmp_path, capsys):
    """ptracer traces from the lights and splats onto the film: the engine cannot
    drive it, and ``mcrt plan`` says so too instead of describing a render that
    would then fail (it listed 'film 2D, then whatever ptracer draws')."""
    scene = tmp_path / "ptracer.xml"
    scene.write_text(f'<scene version="3.0.0"><integrator type="ptracer"/>{_CAMERA}'
                     f'<shape type="sphere"><emitter type="area"/></shape></scene>')
    for argv in (["plan", str(scene)], ["render", str(scene), "-q", "-o", str(tmp_path / "o")]):
        code, out, err = run_cli(capsys, *argv)
        assert code == 2 and err.count("\n") == 1 and out == "", (argv, err)
        assert "ParticleTracerIntegrator (an adjoint integrator" in err
        assert "render it with mi.render" in err
    assert not list(tmp_path.glob("o*"))
