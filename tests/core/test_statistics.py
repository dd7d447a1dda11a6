"""Welford/Chan moments: stable, exact for constants, mergeable; render_stats."""

from __future__ import annotations

import numpy as np
import pytest

from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.core.stats import PixelStats, chan_merge, welford_update
from tests.conftest import small_cornell


def test_bright_pixel_variance_where_the_naive_formula_fails():
    """mean 1000, sigma 1, 16384 float32 samples: E[x^2]-E[x]^2 in float32 is
    wildly wrong (often negative); merged Welford/Chan moments match float64."""
    rng = np.random.default_rng(0)
    x = (1000 + rng.standard_normal(16384)).astype(np.float32)
    # A renderer's running float32 sums (sequential, as np.cumsum adds them):
    n32 = np.float32(x.size)
    naive = np.cumsum(x * x)[-1] / n32 - (np.cumsum(x)[-1] / n32) ** 2
    exact = np.var(x.astype(np.float64), ddof=1)
    assert abs(naive - exact) > 0.5  # the failure we guard against
    n, mean, m2 = 0, 0.0, 0.0
    for chunk in np.split(x, 64):  # 64 passes of 256 samples, merged with Chan
        c = chunk.astype(np.float64)
        n, mean, m2 = chan_merge(n, mean, m2, c.size, c.mean(), ((c - c.mean()) ** 2).sum())
    assert int(n) == 16384
    assert m2 / (n - 1) == pytest.approx(exact, rel=1e-12)


def test_welford_matches_two_pass_and_merge_is_order_free():
    rng = np.random.default_rng(1)
    x = rng.lognormal(3, 2, size=(1000, 4, 3))
    n, mean, m2 = np.zeros(4, np.int64), np.zeros((4, 3)), np.zeros((4, 3))
    for row in x:
        n, mean, m2 = welford_update(n, mean, m2, row)
    np.testing.assert_allclose(mean, x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(m2 / (n[:, None] - 1), x.var(0, ddof=1), rtol=1e-10)
    parts = [(len(p), p.mean(0), ((p - p.mean(0)) ** 2).sum(0)) for p in np.split(x, [10, 300, 301])]
    forward = parts[0]
    for p in parts[1:]:
        forward = chan_merge(*forward, *p)
    backward = parts[-1]
    for p in reversed(parts[:-1]):
        backward = chan_merge(*p, *backward)
    np.testing.assert_allclose(forward[1], backward[1], rtol=1e-13)
    np.testing.assert_allclose(forward[2], backward[2], rtol=1e-10)


def test_constant_image_is_exact_and_variance_never_negative():
    value = np.full((3, 5, 3), 1234.5678)
    stats = PixelStats.from_images([value] * 7)
    assert (stats.mean == value).all() and (stats.m2 == 0).all() and (stats.count == 7).all()
    merged = stats.merge(stats)
    assert (merged.m2 == 0).all() and (merged.count == 14).all()
    rng = np.random.default_rng(2)
    noisy = PixelStats.from_images(1e6 + rng.standard_normal((50, 3, 5, 3)) * 1e-3)
    assert (noisy.variance >= 0).all()


def test_nonfinite_observations_are_counted_not_averaged():
    images = [np.ones((2, 2, 3)), np.full((2, 2, 3), np.nan), 3 * np.ones((2, 2, 3))]
    images[2][0, 0, 1] = np.inf
    stats = PixelStats.from_images(images)
    assert stats.nonfinite.tolist() == [[2, 1], [1, 1]]
    assert stats.count.tolist() == [[1, 2], [2, 2]]
    assert np.isfinite(stats.mean).all() and stats.mean[1, 1, 0] == 2.0
    # One finite sample has no spread to estimate an error from: unknown, not 0.
    se = stats.standard_error
    assert np.isnan(se[0, 0]).all() and np.isfinite(se[stats.count >= 2]).all()


def test_empty_side_of_a_merge_is_neutral():
    n, mean, m2 = chan_merge(0, 0.0, 0.0, 5, 2.5, 1.0)
    assert (int(n), float(mean), float(m2)) == (5, 2.5, 1.0)
    n, mean, m2 = chan_merge(0, 0.0, 0.0, 0, 0.0, 0.0)
    assert (int(n), float(mean), float(m2)) == (0, 0.0, 0.0)


def test_render_stats_agrees_with_the_film_and_across_passes():
    """With a box filter the per-pixel mean is the film's pixel; 4 passes give
    the same moments as 1 (same samples, Chan-merged) and exact counts."""
    scene = small_cornell(16, spp=16, box_filter=True)
    film = render_film(scene, make_sampler("jittered", 16), seed=4)
    one = render_stats(scene, make_sampler("jittered", 16), seed=4)
    four = render_stats(scene, make_sampler("jittered", 16), seed=4, passes=4)
    assert (one.stats.count == 16).all() and (four.stats.count == 16).all()
    assert four.passes == 4 and one.samples == 16 * 16 * 16
    np.testing.assert_allclose(one.stats.mean, four.stats.mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(one.stats.variance, four.stats.variance, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(one.stats.mean, film.rgb, rtol=1e-5, atol=1e-6)
