"""Filtered films' correlated pixel noise: the
variance factor of a mean over pixels, the bias interval and the aliasing null
model, each against a brute-force filtered film on a tiny image.

The brute force (:func:`develop`) draws ``n`` uniform samples in every pixel of
an ``H x W`` film, each with independent noise, and develops every pixel as
Mitsuba's film does: ``sum_s w_ps L_s / sum_s w_ps`` with the filter's weights
``w(x) w(y)`` (evaluated by Mitsuba's own filter plugin) of every sample within
its reach, no samples outside the film.
"""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest

from mcrt.analysis.aliasing import aliasing_score
from mcrt.analysis.filter_noise import filter_correlation, noise_spectrum, variance_factor
from mcrt.analysis.metrics import bias

FILTERS = ("tent", "gaussian", "mitchell")


def develop(rng: np.random.Generator, name: str, shape: tuple[int, int], n: int,
            signal=None, sd=None, reps: int = 1) -> np.ndarray:
    """``reps`` developed films (reps, H, W) of ``signal(x, y) + sd(x, y) * N(0, 1)``."""
    rfilter = mi.load_dict({"type": name})
    radius = float(rfilter.radius())
    reach = math.ceil(radius + 0.5) - 1
    h, w = shape
    x = np.arange(w)[None, None, :, None] + rng.random((reps, h, w, n))
    y = np.arange(h)[None, :, None, None] + rng.random((reps, h, w, n))
    value = (0.0 if signal is None else signal(x, y)) \
        + (1.0 if sd is None else sd(x, y)) * rng.standard_normal(x.shape)

    def weight(d: np.ndarray) -> np.ndarray:
        return np.array(rfilter.eval(mi.Float(d.ravel())), dtype=np.float64).reshape(d.shape)

    num, den = np.zeros((reps, h, w)), np.zeros((reps, h, w))
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):  # samples of pixel (py + dy, px + dx) into (py, px)
            ty, sy = slice(max(-dy, 0), h - max(dy, 0)), slice(max(dy, 0), h + min(dy, 0))
            tx, sx = slice(max(-dx, 0), w - max(dx, 0)), slice(max(dx, 0), w + min(dx, 0))
            cy = (np.arange(h)[ty] + 0.5)[None, :, None, None]
            cx = (np.arange(w)[tx] + 0.5)[None, None, :, None]
            wt = weight(x[:, sy, sx] - cx) * weight(y[:, sy, sx] - cy)
            num[:, ty, tx] += (wt * value[:, sy, sx]).sum(axis=-1)
            den[:, ty, tx] += wt.sum(axis=-1)
    return num / den


def test_correlation_of_known_filters():
    assert filter_correlation(None).tolist() == [1.0] == filter_correlation("box").tolist()
    np.testing.assert_allclose(filter_correlation("tent"), [0.25, 1, 0.25], atol=1e-4)
    # gaussian, stddev s = 0.5: (int w)^2 / int w^2 = 2 s sqrt(pi) per axis -> F = pi
    assert variance_factor(filter_correlation("gaussian")) == pytest.approx(math.pi, rel=0.01)
    spectrum = noise_spectrum(filter_correlation("gaussian"), (16, 16))
    assert spectrum[0, 0] == pytest.approx(variance_factor(filter_correlation("gaussian")))
    assert spectrum.min() > 0


@pytest.mark.parametrize("name", FILTERS)
def test_variance_factor_matches_a_brute_force_film(name):
    """Var(mean of the interior pixels) over 300 films = F x sum Var(pixel) / P^2."""
    films = develop(np.random.default_rng(3), name, (20, 20), 4, reps=300)[:, 3:-3, 3:-3]
    pixels = films[0].size
    measured = films.mean(axis=(1, 2)).var(ddof=1)
    predicted = variance_factor(filter_correlation(name)) * films.var(axis=0, ddof=1).sum() \
        / pixels ** 2
    assert measured == pytest.approx(predicted, rel=0.2)
    assert measured > 1.3 * films.var(axis=0, ddof=1).sum() / pixels ** 2  # not independent


def test_bias_interval_covers_zero_as_often_as_it_says_on_a_filtered_grey_film():
    """Three-seed cells of an unbiased gaussian-filtered grey film: with the filter's
    variance factor and correlated channels, the z-scores of the bias have sd ~1;
    as independent pixel-channels they had sd ~sqrt(3 F) = 3 (the -4.8e-4 of a
    4-spp gaussian compare was ~1.5 true SE, not a bias: the film's ratio estimator
    is unbiased to first order and its second-order term was below 1e-5 there)."""
    rng = np.random.default_rng(5)
    films = develop(rng, "gaussian", (24, 24), 4, sd=lambda x, y: 1 + (x > 12), reps=120)
    grey = np.repeat(films[..., None], 3, axis=-1)
    factor = variance_factor(filter_correlation("gaussian"))
    new, old = [], []
    for cell in grey.reshape(40, 3, 24, 24, 3):
        mean, var = cell.mean(axis=0), cell.var(axis=0, ddof=1) / 3
        b = bias(mean, np.zeros_like(mean), image_variance=var, variance_factor=factor,
                 correlated_channels=True)
        new.append(b.value / b.standard_error)
        b = bias(mean, np.zeros_like(mean), image_variance=var)
        old.append(b.value / b.standard_error)
    assert 0.6 < np.std(new) < 1.5
    assert np.std(old) > 2.0


def test_bias_options_on_a_grey_image():
    image = np.full((4, 4, 3), 0.5)
    var = np.full((4, 4, 3), 0.04)
    plain = bias(image, np.zeros_like(image), image_variance=var).standard_error
    grey = bias(image, np.zeros_like(image), image_variance=var,
                correlated_channels=True).standard_error
    assert grey == pytest.approx(plain * math.sqrt(3))
    scaled = bias(image, np.zeros_like(image), image_variance=var, variance_factor=4.0,
                  correlated_channels=True).standard_error
    assert scaled == pytest.approx(2 * grey)


@pytest.mark.parametrize("name", FILTERS)
def test_filtered_noise_is_not_called_aliased(name):
    """Heteroscedastic noise developed with a wide filter: the white null sees
    excess low-band energy (its spectrum is low-pass; gaussian: "aliased"); the
    filter-aware null does not, while a moire pattern under the same noise stays
    aliased."""
    rng = np.random.default_rng(11)
    shape = (48, 64)
    sd = lambda x, y: 0.5 + (y > 24)  # noqa: E731
    noise = develop(rng, name, shape, 4, sd=sd)[0]
    correlation = filter_correlation(name)
    aware = aliasing_score(noise, correlation=correlation, null_draws=32)
    assert aware.verdict == "noise", aware
    white = aliasing_score(noise, null_draws=32)  # the white null's excess: 5.4-8.9 z
    assert white.ratio_z > aware.ratio_z + 4
    assert white.verdict == "aliased" or name != "gaussian"
    moire = lambda x, y: 0.4 * np.cos(2 * np.pi * (0.06 * x + 0.02 * y))  # noqa: E731
    pattern = develop(rng, name, shape, 4, signal=moire, sd=sd)[0]
    assert aliasing_score(pattern, correlation=correlation, null_draws=32).verdict == "aliased"


def test_box_correlation_is_the_white_null():
    error = np.random.default_rng(2).standard_normal((40, 40))
    a = aliasing_score(error, null_draws=16)
    b = aliasing_score(error, null_draws=16, correlation=filter_correlation("box"))
    assert a == b
