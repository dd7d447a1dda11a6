"""Error metrics against hand-computed values, and their statistical promises."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcrt.analysis.convergence import efficiency, fit_loglog
from mcrt.analysis.metrics import (
    LUMINANCE_WEIGHTS,
    REL_MSE_EPSILON,
    bias,
    delta_e_2000,
    delta_e_2000_map,
    error_map,
    luminance,
    mse,
    mse_excess,
    reference_noise_floor,
    rel_mse,
    srgb_to_lab,
    standard_error_map,
    variance_map,
)

Z95 = 1.959963984540054  # standard normal 97.5% quantile


def test_mse_and_rel_mse_by_hand():
    image = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert mse(image, np.zeros((2, 2))) == 7.5  # (1 + 4 + 9 + 16) / 4
    # (1 - 0)^2 / (0 + 0.01) = 100 and (3 - 1)^2 / (1 + 0.01) = 3.9604, mean 51.9802
    assert REL_MSE_EPSILON == 0.01
    assert rel_mse(np.array([1.0, 3.0]), np.array([0.0, 1.0])) == pytest.approx(
        (100.0 + 4.0 / 1.01) / 2, rel=1e-12)
    assert rel_mse(np.array([1.0]), np.array([0.0]), epsilon=1.0) == 1.0
    with pytest.raises(ValueError):
        mse(np.zeros(3), np.zeros(4))


def test_float32_inputs_are_computed_in_float64():
    """Squaring and averaging in float32 would be off by ~1e-7 relative; the
    float64 computation matches the float64 value of the float32 inputs to 1e-9."""
    image = np.full(10**6, 1.0001, np.float32)
    reference = np.ones(10**6, np.float32)
    expected = float((np.float64(np.float32(1.0001)) - 1.0) ** 2)
    assert mse(image, reference) == pytest.approx(expected, rel=1e-9)


def test_reference_noise_floor_and_mse_excess():
    se = np.array([[0.1, 0.2], [0.0, 0.3]])
    assert reference_noise_floor(se) == pytest.approx((0.01 + 0.04 + 0.0 + 0.09) / 4)
    image = np.array([[1.0, 1.0], [1.0, 1.0]])
    ref = np.array([[1.5, 1.0], [1.0, 1.0]])
    assert mse_excess(image, ref, se) == pytest.approx(0.25 / 4 - 0.035)


def test_mse_excess_is_unbiased_for_the_mse_against_the_truth():
    """E[(x - r)^2] = Var x + Var r for independent x, r around the same truth:
    subtracting the reference's squared standard error leaves Var x. Over 4e5
    pixels the estimate's relative sd is ~0.4%, so 3% is a wide margin; without
    the subtraction it would be off by 25% (Var r = Var x / 4)."""
    rng = np.random.default_rng(5)
    truth = rng.random(400_000)
    image = truth + rng.normal(0.0, 0.2, truth.size)
    ref_se = np.full(truth.size, 0.1)
    reference = truth + rng.normal(0.0, 1.0, truth.size) * ref_se
    assert mse(image, reference) == pytest.approx(0.05, rel=0.03)
    assert mse_excess(image, reference, ref_se) == pytest.approx(0.04, rel=0.03)


def test_luminance_and_error_map():
    rgb = np.zeros((1, 2, 3))
    rgb[0, 0] = (1.0, 0.0, 0.0)
    rgb[0, 1] = (1.0, 1.0, 1.0)
    red = LUMINANCE_WEIGHTS[0]  # 0.212671, Mitsuba's Y row (Rec. 709: 0.2126)
    np.testing.assert_allclose(luminance(rgb), [[red, 1.0]])
    np.testing.assert_allclose(error_map(rgb, np.zeros_like(rgb)), [[red, 1.0]])
    assert luminance(np.ones((2, 2))).shape == (2, 2)


def test_variance_and_standard_error_maps():
    v = np.zeros((1, 2, 3))
    v[0, 0] = (1.0, 2.0, 3.0)
    v[0, 1] = (4.0, 4.0, 4.0)
    np.testing.assert_allclose(variance_map(v), [[2.0, 4.0]])
    np.testing.assert_allclose(standard_error_map(v), [[math.sqrt(2.0), 2.0]])
    with pytest.raises(ValueError):
        variance_map(-np.ones((2, 2)))


def test_bias_by_hand():
    image = np.array([2.0, 0.0, 3.0, 4.0])
    reference = np.array([1.0, 1.0, 1.0, 2.0])  # differences 1, -1, 2, 2: mean 1
    b = bias(image, reference, image_variance=0.03, reference_variance=np.full(4, 0.01))
    # se = sqrt(4 * (0.03 + 0.01)) / 4 = 0.1
    assert b.value == 1.0 and b.standard_error == pytest.approx(0.1)
    assert b.low == pytest.approx(1.0 - Z95 * 0.1) and b.high == pytest.approx(1.0 + Z95 * 0.1)
    assert b.significant
    # Without variances: the differences' own spread, std(ddof=1) / sqrt(4)
    b = bias(image, reference)
    assert b.standard_error == pytest.approx(np.std([1, -1, 2, 2], ddof=1) / 2)
    # A deterministic render against an exact reference: zero width.
    b = bias(image, reference, image_variance=0.0)
    assert b.low == b.high == 1.0
    assert bias(image, reference, confidence=0.5).high < bias(image, reference).high


def test_bias_interval_covers_at_the_stated_rate():
    """2000 unbiased noisy images (per-pixel variances differ) against a noisy
    reference: the 95% interval must contain 0 in 95% of them. The count of
    misses is binomial(2000, 0.05): sd 9.7, so 100 +- 40 is a 4-sd band; a
    formula that forgot the reference term (half the variance here) would
    miss ~17% of the time."""
    rng = np.random.default_rng(11)
    h, w = 8, 8
    var_image = rng.uniform(0.5, 2.0, (h, w, 3))
    var_ref = var_image.copy()
    misses = 0
    for _ in range(2000):
        image = rng.normal(0.0, np.sqrt(var_image))
        reference = rng.normal(0.0, np.sqrt(var_ref))
        b = bias(image, reference, image_variance=var_image, reference_variance=var_ref)
        misses += not (b.low <= 0.0 <= b.high)
    assert 60 <= misses <= 140, misses


def test_lab_conversion_conventions():
    """Linear sRGB white (1, 1, 1) is L* = 100 (Y_white = 1, D65), a mid grey
    0.18 is L* = 116 * 0.18^(1/3) - 16 = 49.50 (no sRGB decoding applied to
    linear input), and values above 1 clip to white as in the PNGs."""
    lab = srgb_to_lab(np.array([[[1.0, 1.0, 1.0], [0.18, 0.18, 0.18], [4.0, 4.0, 4.0]]]))
    assert lab[0, 0, 0] == pytest.approx(100.0, abs=1e-6)
    assert lab[0, 1, 0] == pytest.approx(116 * 0.18 ** (1 / 3) - 16, abs=1e-4)
    assert np.abs(lab[0, :, 1:]).max() < 0.05  # neutral greys: a*, b* ~ 0
    np.testing.assert_allclose(lab[0, 2], lab[0, 0])


def test_delta_e_2000_by_hand_for_greys():
    """For neutral colours CIEDE2000 reduces to dL / S_L with
    S_L = 1 + 0.015 (Lm - 50)^2 / sqrt(20 + (Lm - 50)^2)."""
    def lightness(y):
        return 116 * y ** (1 / 3) - 16

    l1, l2 = lightness(0.18), lightness(0.2)
    lm = (l1 + l2) / 2
    s_l = 1 + 0.015 * (lm - 50) ** 2 / math.sqrt(20 + (lm - 50) ** 2)
    expected = (l2 - l1) / s_l  # 2.3376
    a = np.full((2, 3, 3), 0.18)
    b = np.full((2, 3, 3), 0.2)
    assert delta_e_2000(a, b) == pytest.approx(expected, abs=2e-3)
    assert delta_e_2000(a, a) == 0.0
    assert delta_e_2000_map(a, b).shape == (2, 3)
    # Scaling both by `white` gives the same numbers as the unscaled images.
    assert delta_e_2000(4 * a, 4 * b, white=4.0) == pytest.approx(delta_e_2000(a, b))


def test_delta_e_2000_of_a_published_pair():
    """Sharma, Wu & Dalal (2005), test pair 1: (50, 2.6772, -79.7751) vs
    (50, 0, -82.7485) has dE00 = 2.0425; we reach it through our Lab path."""
    import colour

    lab1, lab2 = np.array([50.0, 2.6772, -79.7751]), np.array([50.0, 0.0, -82.7485])
    assert float(colour.difference.delta_E_CIE2000(lab1, lab2)) == pytest.approx(2.0425,
                                                                                  abs=1e-4)


def test_efficiency_and_loglog_fit_by_hand():
    assert efficiency(0.01, 2.0) == pytest.approx(50.0)
    assert math.isnan(efficiency(0.0, 1.0)) and math.isnan(efficiency(-1.0, 1.0))
    np.testing.assert_allclose(efficiency(np.array([1.0, 0.5]), np.array([1.0, 4.0])),
                               [1.0, 0.5])
    # y = 3 x^-1.5 exactly: slope -1.5, intercept log10 3, r2 1, residual se 0
    x = np.array([4.0, 16.0, 64.0, 256.0])
    fit = fit_loglog(x, 3 * x ** -1.5)
    assert fit.slope == pytest.approx(-1.5) and fit.intercept == pytest.approx(math.log10(3))
    assert fit.r2 == pytest.approx(1.0) and fit.slope_se == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(fit.predict(x), 3 * x ** -1.5)
    # Hand-computed OLS: u = 0, 1, 2; v = 0, -1, -1 -> slope -0.5, residuals
    # (1/6, -1/3, 1/6), s^2 = (1/6) / 1, se = sqrt(s^2 / 2) = 0.2887
    fit = fit_loglog([1, 10, 100], [1, 0.1, 0.1])
    assert fit.slope == pytest.approx(-0.5) and fit.slope_se == pytest.approx(math.sqrt(1 / 12))
    with pytest.raises(ValueError):
        fit_loglog([4, 4], [1, 2])


def test_delta_e_2000_against_a_precomputed_reference_lab():
    """A study scores every render against one reference: its CIELAB, computed
    once and passed in, gives the same bits as computing it each time; a Lab of
    another shape is refused."""
    from mcrt.analysis.metrics import srgb_to_lab

    rng = np.random.default_rng(4)
    image, reference = rng.random((6, 5, 3)) * 1.5, rng.random((6, 5, 3))
    lab = srgb_to_lab(reference, 2.0)
    assert np.array_equal(delta_e_2000_map(image, reference, 2.0, reference_lab=lab),
                          delta_e_2000_map(image, reference, 2.0))
    assert delta_e_2000(image, reference, 2.0, lab) == delta_e_2000(image, reference, 2.0)
    with pytest.raises(ValueError, match="reference_lab shape"):
        delta_e_2000(image, reference, reference_lab=lab[:3])


def test_the_bias_of_one_value_without_variances_is_unknown():
    """One pixel-channel and no variances: the spread of the differences is
    undefined (std with ddof 1 of one value). The standard error was 0, so any
    non-zero error of a 1 x 1 grey image was 'significant' at any confidence;
    now it is NaN and the interval unknown, never significant."""
    b = bias(np.ones((1, 1)), np.zeros((1, 1)))
    assert b.value == 1.0
    assert math.isnan(b.standard_error) and math.isnan(b.low) and math.isnan(b.high)
    assert not b.significant
    # With the estimate's variance given, one value has its interval.
    b = bias(np.ones((1, 1)), np.zeros((1, 1)), image_variance=0.04)
    assert b.standard_error == pytest.approx(0.2) and b.significant
