"""Hard cases (``scenes/hard/``): every sampler, finite results, counted NaN/Inf,
agreement with references within their confidence intervals.

Each scene is rendered through the planned scene (:func:`plan_scene`, what
``mcrt render`` and ``mcrt reference`` render) at a tiny resolution and low spp
with every sampler of :data:`ALL_SAMPLERS`, into exact per-pixel statistics
(:func:`render_stats`). For every render:

* every mean and M2 is finite and every variance >= 0;
* every drawn sample is accounted for: ``count + nonfinite == spp`` per pixel;
* the estimate agrees with the reference within its confidence interval.

How "agrees" is tested (:func:`agreement_z`)
    The image is cut into tiles; for each tile and channel, the mean difference
    ``d`` between the render and the reference has the standard error
    ``sqrt(sum_i s_i^2 (1/n_i + 1/N_i)) / K`` over the tile's ``K`` pixels,
    where ``s_i^2`` is the *reference's* per-sample variance of pixel ``i``
    and ``n_i``, ``N_i`` the finite samples of the render and the reference
    (:func:`mcrt.analysis.metrics.bias` does the sum). Using the reference's
    variance for both terms, rather than the render's own, matters for
    heavy-tailed pixels: at 64 spp most caustic pixels have seen no firefly
    at all, and their own sample variance says "no noise here", which would
    turn a perfectly normal render into a 20-sigma "failure"; the reference
    has 64x more samples and sees many fireflies per tile. For the
    independent sampler this is the exact variance of ``d`` (up to the
    reference's estimation error); stratified and low-discrepancy samplers
    have less variance than that, so for them the test is conservative (it
    can only miss biases smaller than ~Z_MAX x the independent error).
    Channels are tested separately (grey scenes have perfectly correlated
    channels; summing them as independent would understate the variance).

Why |z| < Z_MAX = 5
    Each scene has at most ~50 tile-channels and 10 samplers, so ~2,000
    z-scores in the file. At 5 sigma a Gaussian false alarm has probability
    5.7e-7 each, 1e-3 for the whole file; the firefly tiles are skewed
    (Poisson-like counts of rare hits with expected counts in the tens to
    hundreds) whose upper 5-sigma tail is ~10x fatter, still ~1e-2 for the
    file. The seeds are fixed, so the outcome is deterministic; the margin
    says that changing a seed will almost never break the test, while a real
    bias (a lost pass, mis-weighted samples, zeroed NaNs, float32 drift) moves
    whole tiles by many sigma.

``uniform_grid`` is a deterministic quadrature in the film plane (sample at
cell centres) and aliases sub-pixel features; it is held to the same
finiteness and bookkeeping checks, and its bias against the reference is
measured and bounded in a separate test (documented in docs/hard-cases.md, "Hard
cases" table), not hidden by loosening the test for the other samplers.
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.analysis.metrics import bias
from mcrt.analysis.reference import get_reference
from mcrt.core.engine import MAX_LANES_PER_PASS
from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.core.stats import PixelStats
from mcrt.io import read_exr
from mcrt.render.plan import PlannedScene, plan_scene
from mcrt.samplers import ALL_SAMPLERS
from tests.conftest import run_cli

REPO = Path(__file__).resolve().parents[2]
HARD = REPO / "scenes" / "hard"

#: Largest |z| a tile of a render may show against its reference (see above).
Z_MAX = 5.0

#: Samplers whose render is a random estimator (the CI test applies).
RANDOM_SAMPLERS = tuple(s for s in ALL_SAMPLERS if s != "uniform_grid")


# --------------------------------------------------------------------------- helpers


@functools.cache
def _planned(name: str, params: tuple[tuple[str, str], ...]) -> PlannedScene:
    return plan_scene(HARD / name, dict(params))


def planned(name: str, **params) -> PlannedScene:
    """The planned scene of ``scenes/hard/<name>`` with ``-D``-style params."""
    return _planned(name, tuple(sorted((k, str(v)) for k, v in params.items())))


def render(name: str, sampler: str, spp: int, seed: int = 0, film: bool = False, **params):
    """``render_stats`` (or ``render_film``) of a hard scene, as the CLI renders it."""
    scene = planned(name, **params)
    smp = make_sampler(sampler, spp)
    passes, on_pass = scene.schedule(smp, smp.sample_count(), seed)
    fn = render_film if film else render_stats
    return fn(scene.scene, smp, seed=seed, passes=passes, on_pass=on_pass)


@functools.cache
def _reference(name: str, spp: int, seed: int, params: tuple[tuple[str, str], ...]):
    return get_reference(HARD / name, dict(params), spp=spp, sampler="independent", seed=seed,
                         cache=False)


def reference(name: str, spp: int, seed: int = 1000, **params):
    """An independent-sampler reference (other seeds than any test render)."""
    return _reference(name, spp, seed, tuple(sorted((k, str(v)) for k, v in params.items())))


def assert_sound(stats: PixelStats, spp: int) -> None:
    """Finite moments, non-negative variances, every drawn sample accounted for."""
    assert np.isfinite(stats.mean).all(), "non-finite mean"
    assert np.isfinite(stats.m2).all(), "non-finite M2"
    assert (stats.m2 >= 0).all() and (stats.variance >= 0).all(), "negative variance"
    assert (stats.count >= 0).all() and (stats.nonfinite >= 0).all()
    assert (stats.count + stats.nonfinite == spp).all(), "samples lost or invented"


def agreement_z(stats: PixelStats, ref: PixelStats, tile: tuple[int, int]) -> np.ndarray:
    """z-scores (tiles_y, tiles_x, 3) of the render's tile means against the
    reference's (module docstring): per pixel, the per-sample variance is the
    larger of the render's and the reference's estimates. Pixels without finite
    samples on either side are left out; a tile with no pixel left gets z = 0."""
    h, w = stats.count.shape
    ty, tx = tile
    n = stats.count[..., None].astype(np.float64)
    big_n = ref.count[..., None].astype(np.float64)
    usable = ((n > 0) & (big_n > 0))[..., 0]
    per_sample = np.maximum(stats.variance, ref.variance)
    var_img = per_sample / np.maximum(n, 1)
    var_ref = per_sample / np.maximum(big_n, 1)
    out = np.zeros((math.ceil(h / ty), math.ceil(w / tx), 3))
    for i, y in enumerate(range(0, h, ty)):
        for j, x in enumerate(range(0, w, tx)):
            sel = usable[y:y + ty, x:x + tx]
            if not sel.any():
                continue
            for c in range(3):
                est = bias(stats.mean[y:y + ty, x:x + tx, c][sel],
                           ref.mean[y:y + ty, x:x + tx, c][sel],
                           var_img[y:y + ty, x:x + tx, c][sel],
                           var_ref[y:y + ty, x:x + tx, c][sel])
                if est.standard_error > 0:
                    out[i, j, c] = est.value / est.standard_error
                elif est.value != 0:
                    out[i, j, c] = math.inf
    return out



def cli_render(tmp_path, capsys, monkeypatch, name: str, spp: int, params: dict):
    """``mcrt -q render scenes/hard/NAME --sampler jittered`` into ``tmp_path``:
    (stdout, EXR layers, EXR metadata); the command must succeed."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / Path(name).stem
    defines = [arg for key, value in params.items() for arg in ("-D", f"{key}={value}")]
    code, stdout, _ = run_cli(capsys, "-q", "render", str(HARD / name), "--sampler", "jittered",
                              "--spp", str(spp), *defines, "-o", str(out))
    assert code == 0
    layers, meta = read_exr(out.with_suffix(".exr"))
    return stdout, layers, meta


def covered(scene: mi.Scene, hit) -> np.ndarray:
    """(H, W) bool: pixels whose four corners (inset by 1% of a pixel) all see a
    surface point ``p`` with ``hit(p)`` True (``p`` an (N, 3) array, NaN where
    the ray escapes). The footprints are convex and so are the tested regions
    here, so such a pixel sees only that region: every one of its samples does."""
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())
    ys, xs = np.mgrid[0:height, 0:width]
    inside = np.ones((height, width), bool)
    for dx, dy in ((0.01, 0.01), (0.99, 0.01), (0.01, 0.99), (0.99, 0.99)):
        film = mi.Point2f(((xs + dx) / width).ravel(), ((ys + dy) / height).ravel())
        ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5))
        si = scene.ray_intersect(ray)
        p = np.array(si.p, dtype=np.float64).reshape(3, -1).T.copy()
        p[~np.array(si.is_valid(), dtype=bool)] = np.nan
        inside &= np.asarray(hit(p), dtype=bool).reshape(height, width)
    return inside


def on_panel(cx: float, half: float, cy: float = 0.45):
    """``hit`` predicate of a square panel of ``degenerate.xml`` (plane z = 0)."""
    def hit(p: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return ((np.abs(p[:, 2]) < 1e-4) & (np.abs(p[:, 0] - cx) <= half)
                    & (np.abs(p[:, 1] - cy) <= half))
    return hit


# --------------------------------------------------------------------------- meshes


def test_meshes_are_exactly_what_make_meshes_writes(tmp_path):
    """The committed PLY files are the generator's output, byte for byte."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_meshes", HARD / "make_meshes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    written = module.write_meshes(tmp_path)
    assert {p.name for p in written} == {p.name for p in (HARD / "meshes").glob("*.ply")}
    for path in written:
        assert path.read_bytes() == (HARD / "meshes" / path.name).read_bytes(), path.name


# --------------------------------------------------------------------------- every sampler


#: scene, -D params, spp, reference spp (independent sampler, seed 1000), tile.
CASES = {
    "fireflies": ("fireflies.xml", {"width": 32, "height": 24}, 64, 4096, (8, 8)),
    "dynamic_range": ("dynamic_range.xml", {"width": 48, "height": 24}, 64, 4096, (8, 8)),
    "grazing": ("grazing.xml", {"width": 48, "height": 24}, 64, 4096, (8, 8)),
    "degenerate": ("degenerate.xml", {"width": 32, "height": 16}, 16, 1024, (8, 8)),
}


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ALL_SAMPLERS)
@pytest.mark.parametrize("case", CASES)
def test_hard_scene_with_every_sampler(case, sampler):
    """Statistics and film of one hard scene with one sampler (same seed, so the
    same samples): finite everywhere, variances >= 0, samples accounted for,
    NaN/Inf counted identically by both accumulators, the float32 film equal to
    the float64 per-pixel means (box filter), and, for random samplers, every
    tile and the whole image within Z_MAX of the reference."""
    name, params, spp, ref_spp, tile = CASES[case]
    result = render(name, sampler, spp, seed=7, **params)
    stats = result.stats
    assert_sound(stats, result.spp)
    film = render(name, sampler, spp, seed=7, film=True, **params)
    assert np.isfinite(film.image).all()
    np.testing.assert_array_equal(film.nonfinite, stats.nonfinite)
    # 1e-6 relative + a float32 ulp of the dimmest values: both accumulate the same
    # samples in float64 (the film rounds its sums and its quotient to float32).
    np.testing.assert_allclose(film.rgb, stats.mean, rtol=1e-6, atol=1e-9)
    if case == "degenerate":
        assert stats.nonfinite.sum() > 0
    else:
        assert stats.nonfinite.sum() == 0
    if sampler == "uniform_grid":
        return  # deterministic quadrature: see test_uniform_grid_bias_is_bounded
    ref = reference(name, ref_spp, **params).stats
    z = agreement_z(stats, ref, tile)
    assert np.abs(z).max() < Z_MAX, (case, sampler, np.round(z, 1))
    whole = agreement_z(stats, ref, stats.count.shape)
    assert np.abs(whole).max() < Z_MAX, (case, sampler, whole.ravel())


#: Bound on uniform_grid's relative bias of the image mean (any channel) against
#: the reference at the CASES settings. Measured (seed 7): fireflies -25.5% (its
#: 8 x 8 cell centres miss the light, which covers 2% of one pixel and carries a
#: quarter of the image's energy), dynamic_range -0.04%, grazing +0.6..0.9%
#: (moire on the checkerboard; image z up to 5.8), degenerate +3.9% (16 fixed
#: directions for the sky light of the floor; image z 11).
UNIFORM_GRID_BIAS = {"fireflies": 0.35, "dynamic_range": 0.01, "grazing": 0.02,
                     "degenerate": 0.06}


@pytest.mark.parametrize("case", CASES)
def test_uniform_grid_bias_is_bounded(case):
    """``uniform_grid`` samples every dimension at cell centres: a deterministic
    quadrature whose error is a bias, not noise. It is measured here against
    the same reference and bounded loosely (docs/hard-cases.md lists the measured
    values); where it exceeds the CI it is reported as a bias, not hidden."""
    name, params, spp, ref_spp, tile = CASES[case]
    stats = render(name, "uniform_grid", spp, seed=7, **params).stats
    ref = reference(name, ref_spp, **params).stats
    usable = (stats.count > 0) & (ref.count > 0)
    rel = stats.mean[usable].mean(0) / ref.mean[usable].mean(0) - 1
    assert np.abs(rel).max() < UNIFORM_GRID_BIAS[case], (case, rel)


# --------------------------------------------------------------------------- the CI test can fail


def test_the_agreement_test_catches_zeroed_nans_and_small_biases():
    """The agreement test has power: the degenerate scene's render with its
    NaN/Inf samples *zeroed* instead of left out (what a renderer that folds
    them away would report) fails it, and so does a 3% brighter render of the
    grazing scene (its smallest detectable bias is ~1%; the noisier scenes'
    are in docs/hard-cases.md)."""
    name, params, spp, ref_spp, tile = CASES["degenerate"]
    stats = render(name, "jittered", spp, seed=7, **params).stats
    ref = reference(name, ref_spp, **params).stats
    zeros = PixelStats(count=stats.nonfinite.copy(), mean=np.zeros_like(stats.mean),
                       m2=np.zeros_like(stats.m2), nonfinite=np.zeros_like(stats.nonfinite))
    zeroed = stats.merge(zeros)
    zeroed = PixelStats(zeroed.count, zeroed.mean, zeroed.m2, np.zeros_like(stats.nonfinite))
    assert np.abs(agreement_z(zeroed, ref, tile)).max() > Z_MAX
    name, params, spp, ref_spp, tile = CASES["grazing"]
    stats = render(name, "jittered", spp, seed=7, **params).stats
    ref = reference(name, ref_spp, **params).stats
    brighter = PixelStats(stats.count, stats.mean * 1.03, stats.m2 * 1.03 ** 2, stats.nonfinite)
    assert np.abs(agreement_z(brighter, ref, tile)).max() > Z_MAX


# --------------------------------------------------------------------------- dynamic range

#: The facade's exact radiance in dynamic_range.xml at the default sun:
#: albedo / pi * E * cos(theta), cos(theta) = 0.8 / |(0.25, -0.55, -0.8)|.
FACADE = 0.5 / math.pi * 1e5 * 0.8 / math.sqrt(0.25 ** 2 + 0.55 ** 2 + 0.8 ** 2)
DR_PARAMS = CASES["dynamic_range"][1]


def _facade(p: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return p[:, 2] < -29.0


def _front_wall(p: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.abs(p[:, 2] + 2.0) < 1e-3


@pytest.mark.parametrize("sampler", ["jittered", "independent"])
def test_dynamic_range_sunlit_facade_is_exact_next_to_the_dim_interior(sampler):
    """Pixels that see only the facade (all four corners through the window)
    hold k samples of exactly 2 L (the sun picked, weight 2) and n - k of ~0
    (the lamp: a ~1e-4 trace through the window), so ``mean n / 2L`` is an
    integer k to 1e-4 (every bright sample equals 2 L = 25402 to ~3e-6) and
    ``M2 = (2L)^2 k (n - k) / n`` to 1e-5. Over all facade pixels the mean is L
    within Z_MAX standard errors (per-sample sd L, exact for a fair coin).
    The front wall around the window, 6 orders of magnitude dimmer, stays
    positive and finite in the same render."""
    scene = planned("dynamic_range.xml", **DR_PARAMS).scene
    facade = covered(scene, _facade)
    wall = covered(scene, _front_wall)
    assert facade.sum() >= 100 and wall.sum() >= 100
    result = render("dynamic_range.xml", sampler, 64, seed=3, **DR_PARAMS)
    stats, n = result.stats, result.spp
    mean = stats.mean[facade][:, 0]
    k = mean * n / (2 * FACADE)
    assert np.abs(k - np.round(k)).max() < 1e-4
    kk = np.round(k)
    expected_m2 = (2 * FACADE) ** 2 * kk * (n - kk) / n
    np.testing.assert_allclose(stats.m2[facade][:, 0], expected_m2, rtol=1e-5, atol=1e-3)
    z = (mean.mean() - FACADE) / (FACADE / math.sqrt(mean.size * n))
    assert abs(z) < Z_MAX
    dim = stats.mean[wall]
    assert np.isfinite(dim).all() and (dim > 1e-3).all() and (dim < 5e-2).all()
    assert stats.mean[facade].min() / dim.max() > 1e5  # the dynamic range really is there


def test_dynamic_range_float32_exr_keeps_both_ends(tmp_path, capsys, monkeypatch):
    """``mcrt render`` writes a float32 EXR whose pixels equal the film bit for
    bit and the float64 per-pixel means to 1e-6 relative, on the 1.3e4 facade
    and on the 1e-2 wall alike (a float16 film, Mitsuba's default, keeps 11
    bits: 2.4e-4 relative at best, and overflows above 65504)."""
    _, layers, meta = cli_render(tmp_path, capsys, monkeypatch, "dynamic_range.xml", 64,
                                 DR_PARAMS)
    rgb = layers["rgb"]
    assert rgb.dtype == np.float32 and rgb.shape == (24, 48, 3)
    assert meta["nonfinite_samples"] == 0 and "nonfinite" not in layers
    film = render("dynamic_range.xml", "jittered", 64, seed=0, film=True, **DR_PARAMS)
    np.testing.assert_array_equal(rgb, film.rgb)
    stats = render("dynamic_range.xml", "jittered", 64, seed=0, **DR_PARAMS).stats
    np.testing.assert_allclose(rgb, stats.mean, rtol=1e-6, atol=0)
    assert rgb.max() > 1e4 and rgb.min() < 2e-2


@pytest.mark.slow
def test_dynamic_range_many_passes_do_not_drift():
    """The same 64 samples per pixel (jittered is counter-based: pass k draws
    samples k*g .. k*g + g - 1 of each pixel) in 1 pass and in 64 passes of
    one: the float64 statistics agree to 1e-12 (means) and 1e-9 (M2), the
    float32 films to 1e-6 relative, on 1e4 and 1e-2 pixels alike."""
    scene = planned("dynamic_range.xml", **DR_PARAMS).scene
    one = render_stats(scene, make_sampler("jittered", 64), seed=5, passes=1).stats
    many = render_stats(scene, make_sampler("jittered", 64), seed=5, passes=64).stats
    np.testing.assert_array_equal(one.count, many.count)
    np.testing.assert_allclose(many.mean, one.mean, rtol=1e-12, atol=0)
    np.testing.assert_allclose(many.m2, one.m2, rtol=1e-9, atol=1e-12)
    film_one = render_film(scene, make_sampler("jittered", 64), seed=5, passes=1)
    film_many = render_film(scene, make_sampler("jittered", 64), seed=5, passes=64)
    assert film_many.passes == 64
    np.testing.assert_allclose(film_many.rgb, film_one.rgb, rtol=1e-6, atol=0)


@pytest.mark.slow
def test_tens_of_millions_of_samples_per_pixel_do_not_drift():
    """One pixel of ``sky.xml`` (every sample exactly float32(0.3)) at 2^24 spp.
    Mitsuba's own film accumulates in float32 and drifts (measured: +2.1% at
    2^22 spp, -8.7% at 2^24); mcrt's film (per-pass float64 block sums) and
    statistics (float64 moments, int64 counts) give float32(0.3) exactly and a
    variance of exactly 0."""
    spp = 1 << 24
    exact = float(np.float32(0.3))
    scene = planned("sky.xml", width=1, height=1).scene
    from mcrt.render.scene import load_scene

    plain = load_scene(HARD / "sky.xml", {"width": "1", "height": "1", "spp": str(spp)})
    theirs = float(np.array(mi.render(plain, seed=1))[0, 0, 0])
    assert abs(theirs / exact - 1) > 1e-3  # the failure mcrt avoids
    film = render_film(scene, make_sampler("independent", spp), seed=1)
    assert film.passes == spp // MAX_LANES_PER_PASS and film.rgb[0, 0, 0] == np.float32(0.3)
    stats = render_stats(scene, make_sampler("independent", spp), seed=1).stats
    assert stats.count[0, 0] == spp and stats.samples == spp
    assert stats.mean[0, 0, 0] == exact and stats.m2[0, 0, 0] == 0.0


# --------------------------------------------------------------------------- extreme shapes and counts


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ALL_SAMPLERS)
@pytest.mark.parametrize("shape,spp", [((4096, 1), 16), ((1, 4096), 16), ((1, 1), 256)])
def test_extreme_image_shapes_give_the_furnace_value(shape, spp, sampler):
    """``furnace.xml`` (exact value 0.5 everywhere) at 4096 x 1, 1 x 4096 and
    1 x 1 with every sampler: sound statistics, a finite film equal to them,
    and the image mean within Z_MAX standard errors of 0.5 (each sample lies in
    [0, 2]: a bounded estimator, 256 to 65536 samples, the CLT holds; the
    render's own variance is used, conservative for stratified samplers).
    uniform_grid's deterministic bias is bounded instead (measured +7.5% at
    16 spp, +2.9% at 256 spp)."""
    width, height = shape
    result = render("furnace.xml", sampler, spp, seed=3, width=width, height=height)
    stats = result.stats
    assert stats.count.shape == (height, width)
    assert_sound(stats, result.spp)
    assert stats.samples == width * height * result.spp
    film = render("furnace.xml", sampler, spp, seed=3, film=True, width=width, height=height)
    assert film.image.shape[:2] == (height, width) and np.isfinite(film.image).all()
    np.testing.assert_allclose(film.rgb, stats.mean, rtol=1e-6)
    est = bias(stats.mean[..., 0], np.full((height, width), 0.5), stats.variance_of_mean[..., 0])
    if sampler == "uniform_grid":
        assert abs(est.value) < 0.1 * 0.5, est
    else:
        assert abs(est.value / est.standard_error) < Z_MAX, est


@pytest.mark.slow
@pytest.mark.serial  # one render that keeps both cores busy for half a minute: CI runs it alone
def test_more_than_2_32_samples_in_one_render():
    """4096 x 1 pixels of ``sky.xml`` at 1,049,600 spp (2^20 + 2^10): 4,299,161,600
    samples, 2^32 + 4,194,304, in 4100 passes of 4096 x 256 lanes merged with
    Chan's formula. What it proves: the pass renderer goes past Mitsuba's
    2^32-sample limit of one wavefront; the total and per-pixel counts are exact
    (int64, no 32-bit wrap-around); every mean stays exactly float32(0.3) and
    every variance exactly 0 (no drift, never negative) after 1025 merges; the
    float64 moments are finite. Every sample of this scene is the same value, so
    the exact answer is known bit for bit (noisy estimators are checked against
    exact values in the furnace tests above, at affordable totals).

    Slow on purpose (~45-60 s on 2 cores at ~70-100 M samples/s): the point is
    the total, and it is the cheapest scene mcrt can render."""
    spp = (1 << 20) + (1 << 10)
    result = render("sky.xml", "independent", spp, seed=11, width=4096, height=1)
    stats = result.stats
    assert result.passes == spp // (MAX_LANES_PER_PASS // 4096) and result.spp == spp
    total = 4096 * spp
    assert total > 2 ** 32 and result.samples == total and stats.samples == total
    assert stats.count.dtype == np.int64 and (stats.count == spp).all()
    assert (stats.nonfinite == 0).all()
    assert (stats.mean == float(np.float32(0.3))).all()
    assert (stats.m2 == 0).all() and (stats.variance == 0).all()


# --------------------------------------------------------------------------- degenerate data

DEG_PARAMS = CASES["degenerate"][1]
PANEL_A, PANEL_B, PANEL_C, PANEL_D = (on_panel(-1.2, 0.3), on_panel(-0.4, 0.3),
                                      on_panel(0.4, 0.3), on_panel(1.2, 0.15))


def test_nan_and_inf_samples_are_counted_excluded_and_never_zeroed():
    """Panel D (+Inf radiance) makes every sample that sees it +Inf: pixels it
    covers have no finite sample (count 0, nonfinite = spp). Panel C (a NaN
    vertex colour) has a NaN BSDF value; ~30% of its samples come out NaN and
    are counted, the rest are exact zeros made by Mitsuba's own masks before
    mcrt sees them (pinned here: C's finite samples are all 0, so a non-zero
    count is the only sign of trouble, and it is there in every C pixel).
    Floor pixels that see C or D after a bounce have a few non-finite samples,
    left out of estimates that stay finite. The film counts the same samples.
    Mitsuba's own film on the same scene has NaN/Inf pixels."""
    scene = planned("degenerate.xml", **DEG_PARAMS).scene
    c_full, d_full = covered(scene, PANEL_C), covered(scene, PANEL_D)
    assert c_full.sum() >= 4 and d_full.sum() >= 1
    result = render("degenerate.xml", "jittered", 16, seed=2, **DEG_PARAMS)
    stats, spp = result.stats, result.spp
    assert_sound(stats, spp)
    assert (stats.count[d_full] == 0).all() and (stats.nonfinite[d_full] == spp).all()
    assert (stats.nonfinite[c_full] > 0).all() and (stats.count[c_full] > 0).all()
    assert (stats.mean[c_full] == 0).all() and (stats.m2[c_full] == 0).all()
    nan_fraction = stats.nonfinite[c_full].sum() / (spp * c_full.sum())
    assert 0.1 < nan_fraction < 0.6
    scattered = (stats.nonfinite > 0) & (stats.count > 0) & ~c_full & ~d_full
    assert scattered.sum() >= 3
    assert np.isfinite(stats.mean[scattered]).all() and (stats.mean[scattered] > 0).all()
    film = render("degenerate.xml", "jittered", 16, seed=2, film=True, **DEG_PARAMS)
    np.testing.assert_array_equal(film.nonfinite, stats.nonfinite)
    assert film.nonfinite_samples == int(stats.nonfinite.sum())
    mitsuba = np.array(mi.render(scene, spp=16, seed=2))
    assert not np.isfinite(mitsuba).all()


def test_cli_reports_nonfinite_samples_in_summary_and_exr(tmp_path, capsys, monkeypatch):
    """``mcrt render`` on the degenerate scene prints the count of NaN/Inf
    samples and the pixels affected, and writes the same total to the EXR's
    ``nonfinite_samples`` attribute and the per-pixel counts as its
    ``nonfinite`` layer; the image itself is finite."""
    stdout, layers, meta = cli_render(tmp_path, capsys, monkeypatch, "degenerate.xml", 16,
                                      DEG_PARAMS)
    film = render("degenerate.xml", "jittered", 16, seed=0, film=True, **DEG_PARAMS)
    count, pixels = film.nonfinite_samples, int((film.nonfinite > 0).sum())
    assert count > 0
    match = re.search(r"non-finite samples: (\d+) .*?(\d+) pixels", stdout)
    assert match, stdout
    assert (int(match.group(1)), int(match.group(2))) == (count, pixels)
    assert int(meta["nonfinite_samples"]) == count
    np.testing.assert_array_equal(layers["nonfinite"], film.nonfinite.astype(np.float32))
    assert np.isfinite(layers["rgb"]).all()
    np.testing.assert_array_equal(layers["rgb"], film.rgb)


def test_zero_area_triangles_are_harmless_with_face_normals():
    """With face normals (``face_normals_a=true``), panel A's four zero-area
    triangles change nothing: bit for bit the image of the plain quad. Embree
    never reports a hit on them."""
    a = render("degenerate.xml", "independent", 16, seed=4, face_normals_a="true",
               **DEG_PARAMS).stats
    b = render("degenerate.xml", "independent", 16, seed=4, face_normals_a="true",
               quad_a="quad.ply", **DEG_PARAMS).stats
    assert covered(planned("degenerate.xml", **DEG_PARAMS).scene, PANEL_A).sum() >= 4
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.nonfinite, b.nonfinite)


def test_zero_area_triangles_silently_corrupt_recomputed_vertex_normals():
    """A KNOWN LIMITATION, pinned so that it stays documented. Without normals
    in the file Mitsuba computes angle-weighted vertex normals; a collinear
    "needle" triangle has an angle of pi at its middle vertex and, once
    ``to_world`` has rounded its vertices off the line, a unit normal of
    arbitrary sign. The quad's corner that is a needle's middle vertex gets
    (0, 0, -1): part of panel A turns black or dark. All samples are finite,
    nothing can be counted. If this fails, Mitsuba changed: update docs/hard-cases.md."""
    scene = planned("degenerate.xml", **DEG_PARAMS).scene
    normals = np.array(mi.traverse(scene)["panel_a.vertex_normals"]).reshape(-1, 3)
    np.testing.assert_allclose(normals[2], [0, 0, -1], atol=1e-6)  # the quad's corner (1, 1)
    np.testing.assert_allclose(normals[[0, 1, 3]], [[0, 0, 1]] * 3, atol=1e-6)
    a_full = covered(scene, PANEL_A)
    broken = render("degenerate.xml", "independent", 16, seed=4, **DEG_PARAMS).stats
    plain = render("degenerate.xml", "independent", 16, seed=4, quad_a="quad.ply",
                   **DEG_PARAMS).stats
    assert (broken.nonfinite[a_full] == 0).all()
    assert (plain.mean[a_full] > 0.3).all()
    black = a_full & (broken.mean[..., 0] == 0)
    assert black.sum() >= 2 and (broken.nonfinite[black] == 0).all()


def test_zero_length_normals_are_a_silent_black_panel():
    """A KNOWN LIMITATION, pinned so that it stays documented: Mitsuba 3.9.1
    normalises zero vertex normals to NaN at load; the NaN shading frame fails
    every ``cos > 0`` test of the BSDF, the emitter and the integrator, so
    panel B comes out exactly 0 in every sample. No sample is NaN, so nothing
    can be counted: a silently wrong, finite value (the same panel with proper
    normals, ``quad_b=quad.ply``, is ~0.4). If this test fails, Mitsuba changed
    its behaviour: update the "Hard cases" table of docs/hard-cases.md."""
    scene = planned("degenerate.xml", **DEG_PARAMS).scene
    b_full = covered(scene, PANEL_B)
    assert b_full.sum() >= 4
    assert np.isnan(np.array(mi.traverse(scene)["panel_b.vertex_normals"])).all()
    black = render("degenerate.xml", "independent", 16, seed=4, **DEG_PARAMS).stats
    assert (black.mean[b_full] == 0).all() and (black.nonfinite[b_full] == 0).all()
    fine = render("degenerate.xml", "independent", 16, seed=4, quad_b="quad.ply",
                  **DEG_PARAMS).stats
    assert (fine.mean[b_full] > 0.2).all()
