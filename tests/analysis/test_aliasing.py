"""The aliasing measure: calibrated on synthetic errors, then the checkerboard.

Synthetic cases fix what the two statistics mean (white noise ~1, moire >> 1,
blue noise < 1); the checkerboard test is the issue's demonstration: at low
spp on the shipped plane, the uniform grid's error is structured (moire) while
jittered and Poisson-disk sampling leave noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from mcrt.analysis.aliasing import (
    MIN_SIZE,
    Z_THRESHOLD,
    aliasing_score,
    error_spectrum,
    low_band_ratio,
    peak_to_median,
    white_noise_ratio_sd,
)
from mcrt.analysis.metrics import error_map
from tests.conftest import CHECKERBOARD


def _hann(n):
    return 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)


def _brute_force(e, cutoff=0.25, cells=16):
    """The definitions written out on the full complex spectrum (the module
    uses the half spectrum of a real FFT; the two must agree exactly): the
    low-band ratio, and the peak-to-median of the ring-median-whitened spectrum's
    cell means."""
    h, w = e.shape
    power = np.abs(np.fft.fft2(np.outer(_hann(h), _hann(w)) * e)) ** 2
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    keep = ~((np.abs(fy * h) < 1.5) & (np.abs(fx * w) < 1.5))
    low = keep & (np.hypot(fx, fy) < cutoff)
    ratio = (power[low].sum() / power[keep].sum()) / (low.sum() / keep.sum())
    ring = np.floor(np.hypot(fx, fy) * 32).astype(int)  # rings 1/32 cycle/pixel wide
    stored = keep & (np.arange(w) <= w // 2)[None, :]  # the f_x >= 0 half rfft2 keeps
    ring_median = np.array([np.median(power[stored & (ring == r)]) if (stored & (ring == r)).any()
                            else np.inf for r in range(ring.max() + 1)])
    whitened = power / ring_median[ring]
    cell = (np.clip(np.floor((fy + 0.5) * cells), 0, cells - 1) * cells
            + np.clip(np.floor((fx + 0.5) * cells), 0, cells - 1)).astype(int)
    sums = np.bincount(cell[keep], whitened[keep], cells * cells)
    counts = np.bincount(cell[keep], None, cells * cells)
    means = sums[counts > 0] / counts[counts > 0]
    return ratio, means.max() / np.median(means)


@pytest.mark.parametrize("shape", [(240, 320), (33, 47), (64, 65), (32, 32)])
def test_half_spectrum_bookkeeping_matches_the_definition(shape):
    rng = np.random.default_rng(sum(shape))
    e = rng.standard_normal(shape) + np.sin(0.7 * np.arange(shape[1]))[None, :]
    ratio, peak = _brute_force(e)
    assert low_band_ratio(e) == pytest.approx(ratio, rel=1e-10)
    assert peak_to_median(e) == pytest.approx(peak, rel=1e-10)
    assert error_spectrum(e).shape == shape


def test_white_noise_ratio_is_one_within_the_derived_sd():
    """Homoscedastic white noise: the ratio's expectation is 1 and its sd is
    :func:`white_noise_ratio_sd` (0.086 at 64x64, 0.020 at 320x240), which 300
    noise images must reproduce: the sd of 300 draws is itself known to ~4%
    (1 / sqrt(2 * 299)), so 15% is a 3.7-sd margin, and the mean of 300 draws
    is within 4 standard errors of 1."""
    rng = np.random.default_rng(1)
    ratios = np.array([low_band_ratio(rng.standard_normal((64, 64))) for _ in range(300)])
    sd = white_noise_ratio_sd((64, 64))
    assert 0.07 < sd < 0.1
    assert abs(ratios.mean() - 1.0) < 4 * sd / np.sqrt(ratios.size)
    assert ratios.std(ddof=1) == pytest.approx(sd, rel=0.15)
    big = white_noise_ratio_sd((240, 320))
    assert 0.015 < big < 0.025  # ~ 1 / sqrt(bins in the band): 2x the side, ~1/4.3 the sd
    for seed in range(3):
        e = np.random.default_rng(seed).standard_normal((240, 320))
        assert abs(low_band_ratio(e) - 1.0) < 5 * big


def test_independent_noise_with_varying_variance_is_noise():
    """Errors independent between pixels but concentrated in a band (as on the
    checkerboard's horizon) still have a flat expected spectrum: the ratio stays
    near 1 and the sign-flip null, not the white-noise formula, gives its spread."""
    rng = np.random.default_rng(2)
    sigma = np.zeros((240, 320))
    sigma[80:120] = 1.0
    sigma[120:] = 0.05
    score = aliasing_score(rng.standard_normal(sigma.shape) * sigma)
    assert score.verdict == "noise"
    assert abs(score.ratio_z) < Z_THRESHOLD and score.peak_z < Z_THRESHOLD
    assert score.ratio_null_mean == pytest.approx(1.0, abs=3 * score.ratio_null_sd)
    assert score.ratio_null_sd > 1.5 * white_noise_ratio_sd(sigma.shape)  # fewer noisy pixels


def test_a_global_bias_is_not_a_pattern():
    """A constant offset lands in the 3x3 bins around DC (periodic Hann window),
    which are excluded: adding one changes neither statistic."""
    e = np.random.default_rng(3).standard_normal((96, 128))
    assert low_band_ratio(e + 5.0) == pytest.approx(low_band_ratio(e), rel=1e-9)
    assert peak_to_median(e + 5.0) == pytest.approx(peak_to_median(e), rel=1e-9)


def test_synthetic_moire_scores_aliased():
    """A sinusoidal moire (wavelength 20 px, tilted) under noise of the same
    power: half the energy sits in one low-frequency pair of bins, so the ratio
    is ~(0.5 + 0.5 * 0.2) / 0.2 = 3 and the peak cell is ~100 x the median."""
    rng = np.random.default_rng(4)
    y, x = np.mgrid[0:240, 0:320]
    moire = np.sqrt(2) * np.sin(2 * np.pi * (0.045 * x + 0.02 * y))
    score = aliasing_score(moire + rng.standard_normal(x.shape))
    assert score.ratio > 2.5 and score.peak > 20
    assert score.ratio_z > 10 and score.peak_z > 10
    assert score.verdict == "aliased"
    # A coherent pattern above the low band: the ratio misses it, the peak does not.
    high = np.sqrt(2) * np.sin(2 * np.pi * 0.35 * x)
    score = aliasing_score(high + rng.standard_normal(x.shape))
    assert score.ratio < 1.0 and score.peak_z > 10 and score.verdict == "aliased"


def test_blue_noise_scores_below_one():
    """High-pass noise (white minus its 3x3 box blur) has almost no energy at
    low frequencies: ratio << 1 and the verdict is 'blue'. Its spectrum rises
    with |f| but is isotropic, so the ring-whitened peak stays noise-like."""
    rng = np.random.default_rng(5)
    e = rng.standard_normal((240, 320))
    blur = sum(np.roll(np.roll(e, dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9
    score = aliasing_score(e - blur)
    assert score.ratio < 0.5
    assert score.ratio_z < -Z_THRESHOLD and score.verdict == "blue"
    assert score.peak_z < Z_THRESHOLD


def test_input_checks():
    with pytest.raises(ValueError, match="at least"):
        low_band_ratio(np.zeros((MIN_SIZE - 1, 64)))
    with pytest.raises(ValueError, match="non-finite"):
        aliasing_score(np.full((64, 64), np.nan))
    with pytest.raises(ValueError, match="cutoff"):
        aliasing_score(np.zeros((64, 64)), cutoff=0.7)
    rgb = np.random.default_rng(0).standard_normal((64, 64, 3))
    assert aliasing_score(rgb).ratio > 0  # RGB is reduced to luminance
    zero = aliasing_score(np.zeros((64, 64)))  # no error at all: neutral values
    assert zero.ratio == 1.0 and zero.verdict == "noise"


@pytest.fixture(scope="module")
def checkerboard():
    """The shipped checkerboard at its default 320x240 and an independent
    reference of 256 spp (~1 s; not cached, so the test is hermetic)."""
    from mcrt.analysis.reference import get_reference
    from mcrt.render.scene import load_scene

    reference = get_reference(CHECKERBOARD, spp=256, seed=7, cache=False)
    return load_scene(CHECKERBOARD), reference.mean


@pytest.mark.slow
@pytest.mark.parametrize("spp", [4, 16])
def test_checkerboard_uniform_grid_aliases_jittered_and_poisson_disk_are_noise(checkerboard,
                                                                                spp):
    """The issue's demonstration. Measured (render seed 0, this reference):
    uniform_grid ratio 1.89 / 1.53 with z 25 / 11 and peak z 24 / 12 at 4 / 16
    spp. Margins: the verdict threshold z = 5 (see the aliasing module: false
    alarms ~1e-6 for the ratio, ~1e-3 for the peak; 224 stochastic renders of
    the full study never passed 3.9), which the uniform grid clears 2-5x over.
    For the noisy samplers the ratio must also be within 0.2 of 1: measured
    over render seeds 0-23 (jittered, Poisson-disk, independent at 4 and 16
    spp) its spread is sd 0.013-0.040, range 0.893-1.067 (seed 0, the one
    used here, gives jittered's minimum 0.893, z -3.6, at 16 spp), so 0.2 is 5
    of the largest sd, while an aliased render is off by 0.5-0.9. The grid's z
    must also exceed each noisy sampler's by Z_THRESHOLD: the noisy z-scores
    over those seeds lie in [-3.6, 2.8] (Poisson-disk's 2.8 at 16 spp is seed
    0's), the grid's are 24.9 / 11.0, a separation of at least 8.2."""
    from mcrt.core.render import render_film
    from mcrt.core.sampling import make_sampler

    scene, reference = checkerboard
    scores = {}
    for name in ("uniform_grid", "jittered", "poisson_disk"):
        image = render_film(scene, make_sampler(name, spp), seed=0).rgb
        scores[name] = aliasing_score(error_map(image, reference))
    grid = scores["uniform_grid"]
    assert grid.verdict == "aliased"
    assert grid.ratio > 1.3 and grid.ratio_z > 2 * Z_THRESHOLD and grid.peak_z > Z_THRESHOLD
    for name in ("jittered", "poisson_disk"):
        s = scores[name]
        assert s.verdict == "noise", (name, s)
        assert abs(s.ratio - 1.0) < 0.2 and abs(s.ratio_z) < Z_THRESHOLD, (name, s)
        assert s.peak_z < Z_THRESHOLD, (name, s)
        assert grid.ratio_z > s.ratio_z + Z_THRESHOLD


def test_scores_do_not_depend_on_the_blas_thread_count():
    """The band sums are numpy reductions, not BLAS products (whose rounding
    follows the thread count): a 320x240 score is the same to the last bit with
    1 and 2 OpenBLAS threads, as on a cluster worker and in the client."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from mcrt.analysis.aliasing import aliasing_score\n"
            "rng = np.random.default_rng(3)\n"
            "e = rng.normal(size=(240, 320)) + np.sin(np.arange(320) / 3.0)[None, :]\n"
            "print(repr(aliasing_score(e, null_draws=32, seed=1).as_dict()))\n")
    outs = []
    for threads in ("1", "2"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                              text=True, check=True)
        outs.append(done.stdout)
    assert outs[0] == outs[1] and "ratio" in outs[0]


@pytest.mark.parametrize("correlation", [None, np.array([1.0, 0.25])])
def test_null_draws_are_the_sequential_stream_in_order(correlation):
    """The null batches run on two threads; the draws must still be the ones a
    single thread takes from the seed's stream, batch after batch, in order:
    written out here sequentially (8 sign images per batch, 2 * bit - 1), the
    null means and sds agree to the last bit, and on every call."""
    from mcrt.analysis import aliasing

    rng = np.random.default_rng(11)
    e = rng.normal(size=(40, 48)) * np.linspace(0.2, 1.0, 48)[None, :]
    draws, seed = 28, 9  # 3 full batches and one of 4
    layout = aliasing._layout(e.shape, aliasing.DEFAULT_CUTOFF, aliasing.DEFAULT_CELLS)
    draw = aliasing._null_draws(e, layout.window * e, layout.window, correlation)
    stream = np.random.default_rng(seed)
    ratios, peaks = [], []
    for k in (8, 8, 8, 4):
        signs = stream.integers(0, 2, size=(k, *e.shape)) * 2.0 - 1.0
        r, p = aliasing._statistics(aliasing._half_power(draw(signs)), layout)
        ratios.append(r)
        peaks.append(p)
    ratio, peak = np.concatenate(ratios), np.concatenate(peaks)
    for _ in range(3):
        s = aliasing_score(e, null_draws=draws, seed=seed, correlation=correlation)
        assert (s.ratio_null_mean, s.ratio_null_sd) == (ratio.mean(), ratio.std(ddof=1))
        assert (s.peak_null_mean, s.peak_null_sd) == (peak.mean(), peak.std(ddof=1))
