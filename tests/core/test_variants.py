"""The render core on Mitsuba's other variants: spectral, monochrome and polarized
(LLVM), CUDA where a GPU exists, and one-line refusals of scalar variants, of a
``specfilm`` and of the ``stokes`` integrator.

Agreement with ``mi.render``: the image means of mcrt's render and of Mitsuba's
own render of the same scene must agree within 5 standard errors. The standard
error of an image mean is ``sqrt(sum_p var_p / n_p) / P`` over the P pixels,
with per-pixel sample variances from ``render_stats`` (independent samples, so
the estimate is exact in expectation; jittered renders have less variance, which
only makes the bound conservative). A 5-SE bound fails by chance with
probability 6e-7; a missing wavelength dimension or an unconverted spectrum
shifts the mean by far more (tens of SE here).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.io import read_exr
from tests.conftest import ROOT, run_cli

CORNELL = str(ROOT / "scenes" / "cornell_box.xml")


def use(variant: str) -> None:
    mi.set_variant(variant)
    mcrt.register()


def image_mean_se(stats) -> np.ndarray:
    n = np.maximum(stats.count, 1)[..., None]
    return np.sqrt((stats.variance / n).sum(axis=(0, 1))) / stats.count.size


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral", "llvm_ad_mono",
                                     "llvm_ad_spectral_polarized"])
def test_core_agrees_with_mi_render(variant):
    use(variant)
    scene = mi.load_file(CORNELL, res="24", sampler="independent")
    ours = render_film(scene, make_sampler("jittered", 64), seed=1)
    again = render_film(scene, make_sampler("jittered", 64), seed=1)
    assert ours.image.tobytes() == again.image.tobytes()  # deterministic in every variant
    theirs = np.array(mi.render(scene, spp=256, seed=5))
    assert ours.image.shape == theirs.shape
    stats = render_stats(scene, make_sampler("independent", 64), seed=2).stats
    se = image_mean_se(stats)
    ours_mean = ours.image.reshape(-1, ours.image.shape[-1]).mean(axis=0)
    theirs_mean = theirs.reshape(-1, theirs.shape[-1]).mean(axis=0)
    if variant == "llvm_ad_mono":  # the film develops luminance; stats hold 3 equal channels
        assert ours.channels == ["Y"]
        se = se[:1]
    else:
        assert ours.channels == ["R", "G", "B"]
    combined = np.sqrt(se ** 2 + (se / 2) ** 2)  # ours at 64 spp, Mitsuba's at 256
    assert np.all(np.abs(ours_mean - theirs_mean) < 5 * combined), (ours_mean, theirs_mean)


@pytest.mark.parametrize("variant", ["llvm_ad_spectral", "llvm_ad_mono"])
def test_cli_renders_with_variant(capsys, tmp_path, variant):
    out = tmp_path / "img"
    code, _, err = run_cli(capsys, "-q", "--variant", variant, "render", CORNELL, "-D", "res=16",
                           "--spp", "4", "-o", str(out))
    assert code == 0, err
    layers, meta = read_exr(out.with_suffix(".exr"))
    assert meta["variant"] == variant
    assert layers["rgb"].shape == ((16, 16) if variant == "llvm_ad_mono" else (16, 16, 3))
    assert (out.with_suffix(".png")).stat().st_size > 0


@pytest.mark.parametrize("variant,message", [
    ("scalar_rgb", "scalar variant"), ("no_such_variant", "unknown variant")])
def test_bad_variants_are_one_line_errors(capsys, variant, message):
    code, _, err = run_cli(capsys, "--variant", variant, "render", CORNELL)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_cuda_variant_without_a_gpu_is_one_line(capsys):
    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("a GPU is present: the CUDA variant renders (see test_cuda_render)")
    code, _, err = run_cli(capsys, "--variant", "cuda_ad_rgb", "render", CORNELL)
    assert code == 2 and "needs an NVIDIA GPU" in err


@pytest.mark.skipif(not dr.has_backend(dr.JitBackend.CUDA), reason="no CUDA GPU here")
def test_cuda_render_is_deterministic_and_agrees():
    use("cuda_ad_rgb")
    scene = mi.load_file(CORNELL, res="24", sampler="independent")
    ours = render_film(scene, make_sampler("jittered", 64), seed=1)
    again = render_film(scene, make_sampler("jittered", 64), seed=1)
    assert ours.image.tobytes() == again.image.tobytes()
    theirs = np.array(mi.render(scene, spp=256, seed=5))
    se = image_mean_se(render_stats(scene, make_sampler("independent", 64), seed=2).stats)
    diff = np.abs(ours.image.mean(axis=(0, 1)) - theirs.mean(axis=(0, 1)))
    assert np.all(diff < 5 * np.sqrt(1.25) * se)


#: A small scene for the refusals below: a sphere under a constant sky.
_SKY = """<scene version="3.0.0">{integrator}
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
        {film}
    </sensor>
    <shape type="sphere"/>
    <emitter type="constant"/>
</scene>"""
_HDRFILM = '<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>'


_SPECFILM = ('<film type="specfilm"><integer name="width" value="8"/><integer name="height" '
             'value="8"/><spectrum name="band" value="400:1, 700:1"/></film>')


@pytest.mark.parametrize("variant, integrator, film, options, message", [
    # Mitsuba 3.9.1's stokes sample() segfaults when called from Python: refused first.
    ("llvm_ad_spectral_polarized", '<integrator type="stokes"><integrator type="path"/>'
     '</integrator>', _HDRFILM, ["--spp", "4"], "stokes integrator"),
    ("llvm_ad_spectral", "", _SPECFILM, ["--spp", "4"], "hdrfilm"),
    ("llvm_ad_spectral", "", _SPECFILM, ["--adaptive"], "hdrfilm"),
])
def test_what_mcrt_cannot_render_is_a_one_line_error(capsys, tmp_path, variant, integrator,
                                                     film, options, message):
    scene = tmp_path / "s.xml"
    scene.write_text(_SKY.format(integrator=integrator, film=film))
    code, _, err = run_cli(capsys, "--variant", variant, "render", str(scene), *options,
                           "-o", str(tmp_path / "out"))
    lines = err.strip().splitlines()
    errors = [line for line in lines if not line.startswith("mcrt: note:")]
    assert code == 2 and len(errors) == 1 and message in errors[0], err
    assert not (tmp_path / "out.exr").exists()
