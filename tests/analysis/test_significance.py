"""mcrt.analysis.significance: Student's t, Welch, Holm, log intervals, medians.

scipy (a test-only dependency) is the reference for the t distribution; closed
forms (Cauchy at df = 1, df = 2) check the far tails where scipy itself fails.
"""

from __future__ import annotations

import itertools
import math
from statistics import NormalDist

import numpy as np
import pytest
from scipy import stats

from mcrt.analysis.significance import (
    holm,
    log_interval,
    median_and_se_log,
    robust_sd,
    t_cdf,
    t_quantile,
    two_sided_p,
    welch_df,
)

SPEC_DFS = (0.5, 1, 1.5, 2, 3, 4, 7, 30, 1e3, 1e6)
SPEC_PS = (1e-6, 0.001, 0.025, 0.3, 0.5, 0.7, 0.975, 0.999, 1 - 1e-6)


def rel_err(got: float, want: float) -> float:
    return abs(got - want) / abs(want) if want else abs(got)


# --- Student's t ---------------------------------------------------------------------

@pytest.mark.parametrize("df", SPEC_DFS)
def test_t_quantile_matches_scipy(df):
    for p in SPEC_PS:
        assert rel_err(t_quantile(p, df), stats.t.ppf(p, df)) <= 1e-9, (p, df)
    assert t_quantile(0.5, df) == 0.0


@pytest.mark.parametrize("df", (0.75, 2.5, 12.3, 1e9, 1e12, 1e20, 1e40))
def test_t_quantile_non_integer_and_huge_df(df):
    for p in (1e-9, 0.01, 0.2, 0.3, 0.45, 0.8, 0.99):
        assert rel_err(t_quantile(p, df), stats.t.ppf(p, df)) <= 1e-9, (p, df)


def test_t_quantile_closed_forms_in_the_far_tails():
    # df = 1 is the Cauchy distribution: F^-1(p) = tan(pi (p - 1/2)) = -1 / tan(pi p);
    # df = 2: F^-1(p) = (2p - 1) / sqrt(2 p (1 - p)). scipy's ppf is unreliable this far out.
    for p in (1e-12, 1e-100, 1e-300):
        assert rel_err(t_quantile(p, 1), -1.0 / math.tan(math.pi * p)) <= 1e-12
        assert rel_err(t_quantile(p, 2), (2 * p - 1) / math.sqrt(2 * p * (1 - p))) <= 1e-12
        assert rel_err(t_cdf(t_quantile(p, 3.5), 3.5), p) <= 1e-12
    # Beyond the largest float (df = 1/2 has tails ~ s^-1/2): infinite, not an error.
    assert t_quantile(1e-300, 0.5) == -math.inf
    assert t_quantile(1 - 1e-16, 0.5) > 1e30


def test_t_quantile_normal_limit_and_int_df():
    for p in (1e-6, 0.025, 0.3, 0.975):
        assert t_quantile(p, math.inf) == NormalDist().inv_cdf(p)
    assert t_quantile(0.975, 3) == pytest.approx(3.182446305284263, rel=1e-12)


@pytest.mark.parametrize("p", (0.0, 1.0, -0.1, 1.5, math.nan))
def test_t_quantile_rejects_bad_p(p):
    with pytest.raises(ValueError):
        t_quantile(p, 3)


@pytest.mark.parametrize("df", (math.nan, 0.4, 0.0, -2.0))
def test_t_quantile_rejects_bad_df(df):
    with pytest.raises(ValueError):
        t_quantile(0.9, df)


def test_t_cdf_matches_scipy():
    ts = (-1e6, -50.0, -12.0, -4.0, -2.0, -1.7, -1.0, -0.3, -1e-3, 0.0, 1e-3, 0.4, 1.8, 6.0,
          40.0)
    for df in (*SPEC_DFS, 0.7, 2.5, 1e12):
        for t in ts:
            want = stats.t.cdf(t, df)
            if want > 1e-300:  # compare where scipy does not underflow
                assert rel_err(t_cdf(t, df), want) <= 1e-12, (t, df)
    # Where the continued fraction converges slowest: near x = (a + 1) / (a + b + 2),
    # i.e. t^2 ~ 3 for large df (up to ~128 terms).
    for df in (100, 1e3, 1e6):
        for t in np.linspace(-2.6, -1.6, 41):
            assert rel_err(t_cdf(t, df), stats.t.cdf(t, df)) <= 1e-12, (t, df)
    assert t_cdf(0.0, 7) == 0.5
    assert t_cdf(-math.inf, 3) == 0.0 and t_cdf(math.inf, 3) == 1.0


def test_t_cdf_closed_forms():
    # Lower tails P(T <= -s) in cancellation-free closed form: Cauchy atan(1/s) / pi,
    # df = 2: 1 / (r (r + s)) with r = sqrt(2 + s^2). Includes |t| where scipy rounds to 0.5.
    for s in (1e-10, 0.01, 0.7, 3.0, 1e5, 1e150, 1e300):
        r = math.sqrt(2 + s * s) if s < 1e150 else s
        assert rel_err(t_cdf(-s, 1), math.atan(1 / s) / math.pi) <= 1e-13, s
        assert rel_err(t_cdf(-s, 2), 1 / (r * (r + s))) <= 1e-13, s
        assert rel_err(t_cdf(s, 1), 1 - math.atan(1 / s) / math.pi) <= 1e-15, s


def test_t_cdf_nan_and_bad_df():
    assert math.isnan(t_cdf(math.nan, 3)) and math.isnan(t_cdf(1.0, math.nan))
    with pytest.raises(ValueError):
        t_cdf(1.0, 0.0)


def test_two_sided_p():
    for z in (0.0, 0.5, 1.96, 3.0, 8.0, 30.0):
        for sign in (1, -1):
            assert rel_err(two_sided_p(sign * z), 2 * stats.norm.sf(z)) <= 1e-12, z
            for df in (1, 2.5, 4, 30, 1e5):
                assert rel_err(two_sided_p(sign * z, df), 2 * stats.t.sf(z, df)) <= 1e-12, (z, df)
    assert two_sided_p(0.0, 5) == 1.0
    assert math.isnan(two_sided_p(math.nan)) and math.isnan(two_sided_p(1.0, math.nan))
    assert two_sided_p(math.inf, 3) == 0.0
    # t needs a larger statistic than z for the same p-value.
    assert two_sided_p(2.0, 5) > two_sided_p(2.0) > 0.045


# --- Welch-Satterthwaite ---------------------------------------------------------------

def test_welch_df_hand_example():
    # s1^2 = 4, n1 = 10 and s2^2 = 9, n2 = 15: v = (0.4, 0.6), df = (9, 14);
    # (0.4 + 0.6)^2 / (0.16/9 + 0.36/14) = 1 / (5.48 / 126) = 126 / 5.48 = 22.9927...
    assert welch_df([0.4, 0.6], [9, 14]) == pytest.approx(126 / 5.48, rel=1e-14)
    assert welch_df([2.0, 2.0], [5, 5]) == pytest.approx(10.0, rel=1e-14)  # equal: the sum
    assert welch_df(np.array([1e200, 2e200]), [3, 5]) == pytest.approx(welch_df([1, 2], [3, 5]))


def test_welch_df_matches_scipy_welch_test():
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.5])
    b = np.array([2.0, 4.0, 7.0, 8.0, 9.0, 12.0, 3.0])
    ref = stats.ttest_ind(a, b, equal_var=False)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    df = welch_df([va, vb], [a.size - 1, b.size - 1])
    assert df == pytest.approx(ref.df, rel=1e-12)
    t = (a.mean() - b.mean()) / math.sqrt(va + vb)
    assert two_sided_p(t, df) == pytest.approx(ref.pvalue, rel=1e-10)


def test_welch_df_special_terms():
    assert welch_df([0.0, 0.5], [math.nan, 7]) == pytest.approx(7.0, rel=1e-14)  # v = 0 skipped
    assert welch_df([1.0, 1.0], [math.inf, 4]) == pytest.approx(16.0, rel=1e-14)  # 4 / (1/4)
    assert welch_df([1.0], [math.inf]) == math.inf
    assert welch_df([0.0, 0.0], [3, 4]) == math.inf
    assert welch_df([], []) == math.inf
    assert math.isnan(welch_df([math.nan, 1.0], [3, 4]))
    assert math.isnan(welch_df([1.0, 1.0], [math.nan, 4]))
    for bad in (([-1.0, 1.0], [3, 4]), ([1.0, 1.0], [3]), ([1.0], [0.0])):
        with pytest.raises(ValueError):
            welch_df(*bad)


# --- Holm --------------------------------------------------------------------------------

def holm_by_closed_testing(pvalues: list[float], alpha: float) -> list[bool]:
    """Brute force: Holm's procedure is the closure of Bonferroni tests (Holm 1979), so
    H_i is rejected iff every subset S of hypotheses containing i has
    min_{j in S} p_j <= alpha / |S|."""
    valid = [i for i, p in enumerate(pvalues) if not math.isnan(p)]
    out = []
    for i, p in enumerate(pvalues):
        if math.isnan(p):
            out.append(False)
            continue
        others = [j for j in valid if j != i]
        out.append(all(min(pvalues[j] for j in (i, *rest)) <= alpha / (1 + len(rest))
                       for k in range(len(others) + 1)
                       for rest in itertools.combinations(others, k)))
    return out


def test_holm_hand_examples():
    # Sorted 0.005 <= 0.05/4, 0.01 <= 0.05/3, then 0.03 > 0.05/2: stop.
    assert holm([0.01, 0.04, 0.03, 0.005], 0.05) == [True, False, False, True]
    # Step-down: 0.04 <= 0.05 alone, but the smallest (0.03 > 0.025) already fails.
    assert holm([0.03, 0.04]) == [False, False]
    assert holm([0.001, 0.03, 0.012]) == [True, True, True]
    # The bound is inclusive (0.0125 == 0.05 / 4 exactly in binary).
    assert holm([0.0125, 0.5, 0.5, 0.5]) == [True, False, False, False]
    # NaN is never rejected and does not count in m (m = 4 here, as in the first case).
    assert holm([0.01, math.nan, 0.04, 0.03, 0.005]) == [True, False, False, False, True]
    assert holm([0.01, math.nan], 0.05) == [True, False]
    assert holm([]) == []
    assert holm([0.02, 0.02]) == [True, True]
    assert holm([0.02, 0.02], 0.01) == [False, False]


def test_holm_matches_closed_testing():
    rng = np.random.default_rng(1979)
    for _ in range(300):
        m = int(rng.integers(1, 8))
        p = np.where(rng.random(m) < 0.5, rng.random(m) * 0.06, rng.random(m))
        p = np.round(p, int(rng.integers(2, 5)))  # ties
        p[rng.random(m) < 0.15] = np.nan
        alpha = float(rng.choice([0.01, 0.05, 0.1, 0.2]))
        pl = [float(v) for v in p]
        assert holm(pl, alpha) == holm_by_closed_testing(pl, alpha), (pl, alpha)


def test_holm_rejects_bad_input():
    for bad in (([0.5, 1.2], 0.05), ([-0.1], 0.05), ([0.5], 0.0), ([0.5], math.nan)):
        with pytest.raises(ValueError):
            holm(*bad)


# --- intervals on the log scale ---------------------------------------------------------

def test_log_interval_values_and_edges():
    q = stats.t.ppf(0.975, 3)
    low, high = log_interval(2.0, 0.1, 3)
    assert low == pytest.approx(2.0 * math.exp(-0.1 * q), rel=1e-12)
    assert high == pytest.approx(2.0 * math.exp(0.1 * q), rel=1e-12)
    low, high = log_interval(2.0, 0.1, 3, confidence=0.5)
    assert high == pytest.approx(2.0 * math.exp(0.1 * stats.t.ppf(0.75, 3)), rel=1e-12)
    assert log_interval(5.0, 0.0, 3) == (5.0, 5.0)
    assert log_interval(5.0, 0.0, math.nan) == (5.0, 5.0)  # no spread: df is moot
    assert all(math.isnan(v) for v in log_interval(5.0, 0.1, math.nan))
    for center, se in ((0.0, 0.1), (-1.0, 0.1), (math.inf, 0.1), (math.nan, 0.1), (1.0, math.nan)):
        assert all(math.isnan(v) for v in log_interval(center, se, 3)), (center, se)
    with pytest.raises(ValueError):
        log_interval(1.0, 0.1, 3, confidence=1.0)


def test_log_interval_coverage_needs_student_t():
    """95% t intervals for the geometric mean of n = 4 lognormal values cover it in 95%
    of 4000 trials; with the normal quantile instead they cover only ~85.5%."""
    trials, n, mu, sigma = 4000, 4, 0.3, 0.8
    logs = np.random.default_rng(12345).normal(mu, sigma, size=(trials, n))
    centers = np.exp(logs.mean(axis=1))
    ses = logs.std(axis=1, ddof=1) / math.sqrt(n)
    truth = math.exp(mu)

    def coverage(df: float) -> float:
        hits = 0
        for c, se in zip(centers, ses, strict=True):
            low, high = log_interval(float(c), float(se), df)
            hits += low <= truth <= high
        return hits / trials

    # The binomial sd of a coverage fraction is sqrt(c (1 - c) / trials); allow 4 sd:
    # 4 sqrt(0.95 * 0.05 / 4000) = 0.0138, so the test does not flake (P ~ 6e-5) yet an
    # interval that is 0.9638+ (too wide, e.g. (0, inf)) or below 0.9362 fails.
    t_cov = coverage(n - 1)
    assert abs(t_cov - 0.95) <= 4 * math.sqrt(0.95 * 0.05 / trials)
    # With z = 1.96 the true coverage is P(|T_3| <= 1.96) = 0.8551: clearly too low
    # (again within 4 binomial sd), so the t quantile is what makes the interval right.
    z_cov = coverage(math.inf)
    expected = 2 * stats.t.cdf(NormalDist().inv_cdf(0.975), n - 1) - 1
    assert abs(z_cov - expected) <= 4 * math.sqrt(expected * (1 - expected) / trials)
    assert z_cov < 0.95 - 4 * math.sqrt(0.95 * 0.05 / trials)


# --- medians ---------------------------------------------------------------------------

def test_median_and_se_log_hand_example():
    values = [16.0, 1.0, 4.0, 2.0, 8.0, -1.0, 0.0, math.nan, math.inf]
    median, se, n = median_and_se_log(values)
    # Used: 1, 2, 4, 8, 16 (logs ln2 * (0..4), sd = ln2 * sqrt(2.5)).
    assert (median, n) == (4.0, 5)
    assert se == pytest.approx(math.sqrt(math.pi / 2) * math.log(2) * math.sqrt(2.5) / math.sqrt(5),
                               rel=1e-14)
    median, se, n = median_and_se_log([3.0, -2.0])
    assert (median, n) == (3.0, 1) and math.isnan(se)
    median, se, n = median_and_se_log([])
    assert n == 0 and math.isnan(median) and math.isnan(se)
    assert median_and_se_log(np.array([2.0, 2.0, 2.0]))[:2] == (2.0, 0.0)


def test_median_se_log_is_calibrated():
    """The reported se matches the actual scatter of log(median) over repeated samples
    (without the sqrt(pi/2) efficiency factor it would be 20% too small)."""
    rng = np.random.default_rng(7)
    samples = np.exp(rng.normal(0.0, 0.5, size=(2000, 201)))
    results = [median_and_se_log(s) for s in samples]
    actual = np.std([math.log(m) for m, _, _ in results], ddof=1)
    reported = np.mean([se for _, se, _ in results])
    # The sd of 2000 draws is known to ~1.6% (1 / sqrt(2 * 2000)); 8% is 5 of those.
    assert reported / actual == pytest.approx(1.0, abs=0.08)


def test_robust_sd():
    assert robust_sd([1.0, 2.0, 3.0, 4.0, 100.0]) == pytest.approx(1.4826, rel=1e-14)
    x = np.random.default_rng(3).normal(10.0, 2.0, size=20001)
    assert robust_sd(x) == pytest.approx(stats.median_abs_deviation(x, scale="normal"), rel=1e-5)
    assert robust_sd(x) == pytest.approx(2.0, rel=0.03)
    assert robust_sd(np.append(x, [1e9, math.nan, -math.inf])) == pytest.approx(2.0, rel=0.03)
    assert math.isnan(robust_sd([1.0])) and math.isnan(robust_sd([1.0, math.nan]))
    assert robust_sd([5.0, 5.0]) == 0.0
