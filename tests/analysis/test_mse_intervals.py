"""`mcrt integrate`'s intervals on data whose truth is known: the MSE's 95% interval
per N and the slope's, against the rules they replaced (``exp(+-2 se_log)`` drawn as
error bars, ``slope +- stderr``).

Coverage bands: with R replications of a rule whose true coverage is c, the count
of covering replications is binomial(R, c); ``_band(c)`` is its central 99.9%
range (scipy's binomial quantiles), so a correct rule leaves it once in 1000
seeds and the fixed seeds below make every run the same. A rule that may be
conservative by design is held to [the band's low end at 0.95, its high end at
the stated bound], so an interval that is honest only by being huge still fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special, stats

from mcrt.analysis import integrate as ib
from mcrt.analysis.mse_interval import (
    chi2_quantile,
    log_mse_variance,
    mse_dof,
    mse_interval,
    trigamma,
)

R = 2000


def _band(c: float, r: int = R) -> tuple[float, float]:
    return stats.binom.ppf(0.0005, r, c) / r, stats.binom.ppf(0.9995, r, c) / r


def test_chi2_quantile_and_trigamma_match_scipy():
    for df in (0.5, 1.0, 2.0, 3.7, 15.0, 16.0, 100.0, 1024.0, 65536.0, 1e6):
        for p in (1e-9, 0.005, 0.025, 0.5, 0.975, 0.995, 1 - 1e-9):
            assert chi2_quantile(p, df) == pytest.approx(stats.chi2.ppf(p, df), rel=1e-10)
    # trigamma: closed forms (psi'(1) = pi^2 / 6, psi'(1/2) = pi^2 / 2), the recurrence
    # psi'(x + 1) = psi'(x) - 1 / x^2, and psi'(x) ~ 1 / x + 1 / (2 x^2) for large x.
    assert trigamma(1.0) == pytest.approx(math.pi ** 2 / 6, rel=1e-12)
    assert trigamma(0.5) == pytest.approx(math.pi ** 2 / 2, rel=1e-12)
    for x in (0.05, 7.5, 512.0):
        assert trigamma(x + 1) == pytest.approx(trigamma(x) - 1 / x ** 2, rel=1e-12)
    assert trigamma(1e7) == pytest.approx(1e-7 + 0.5e-14, rel=1e-12)
    with pytest.raises(ValueError):
        chi2_quantile(1.0, 3.0)


def test_degenerate_and_capped_intervals():
    assert mse_interval(0.25, 0.0, 16) == (0.25, 0.25)  # identical errors: exact
    assert mse_interval(0.0, 0.3, 16) == (0.0, 0.0)
    assert all(math.isnan(v) for v in mse_interval(0.25, math.nan, 16))
    assert mse_dof(0.01, 16) == 16.0 and mse_dof(0.5, 16) == pytest.approx(8.0)
    # P = 16 Gaussian errors: exactly the chi-square pivot on 16 degrees of freedom
    low, high = mse_interval(1.0, 0.1, 16)
    assert low == pytest.approx(16 / stats.chi2.ppf(0.975, 16))
    assert high == pytest.approx(16 / stats.chi2.ppf(0.025, 16))
    assert log_mse_variance(0.1, 16) == pytest.approx(float(special.polygamma(1, 8.0)))
    assert log_mse_variance(0.0, 16) == 0.0


def _mse_coverage(errors: np.ndarray, truth: float) -> tuple[int, int]:
    """Covering replications of the new interval and of ``exp(+-2 se_log)``; rows of
    ``errors`` are replications."""
    new = old = 0
    for e in errors:
        s = ib.mse_summary(e)
        low, high = s.interval()
        new += low <= truth <= high
        old += s.mse * math.exp(-2 * s.se_log) <= truth <= s.mse * math.exp(2 * s.se_log)
    return new, old


def _gaussian_case(trials: int) -> tuple[int, int]:
    rng = np.random.default_rng(20 + trials)
    return _mse_coverage(rng.normal(0.0, 0.3, (R, trials)), 0.09)


def _multijitter_case() -> tuple[int, int]:
    conv = ib.run_convergence("multijitter", ["disk"], counts=(16,), max_trials=32768,
                              budget=1 << 20, seed=4, timed=False)["disk"]
    errors = conv.points[0].estimates - conv.points[0].exact
    rng = np.random.default_rng(5)
    return _mse_coverage(rng.choice(errors, (R, 16)), float(np.mean(errors ** 2)))


@pytest.mark.parametrize("trials", [8, 16])
def test_mse_interval_covers_gaussian_errors(trials):
    """Zero-mean Gaussian errors (what an average of N samples gives): the new rule
    is the exact chi-square pivot whenever the sample kurtosis is below 3 and wider
    otherwise, so its coverage is 95% to ~96% (0.956 / 0.960 here at 8 / 16 trials):
    band from 0.95 to 0.97. ``exp(+-2 se_log)`` covered 0.871 / 0.907."""
    new, old = _gaussian_case(trials)
    assert _band(0.95)[0] <= new / R <= _band(0.97)[1], new / R
    assert old / R < _band(0.95)[0], old / R


def test_mse_interval_covers_a_samplers_own_errors():
    """The errors of 32768 pixels of ``multijitter`` on the disk at N = 16 (kurtosis
    ~5: a few strata the edge cuts decide the error) are the population; replications
    draw 16 of them with replacement, so the truth is the population's mean squared
    error exactly. The chi-square interval gets nu < 16 from the larger se_log and
    covers 0.946 (band 0.95 to 0.97); ``exp(+-2 se_log)`` 0.847."""
    new, old = _multijitter_case()
    assert _band(0.95)[0] <= new / R <= _band(0.97)[1], new / R
    assert old / R < _band(0.95)[0], old / R


def _slope_coverage(trials: list[int], wiggle: float, seed: int) -> tuple[int, int]:
    """An exact power law MSE = N^-1.5 at N = 16 .. 65536, Gaussian errors, ``trials``
    per N; ``wiggle``: a random offset of each N's ln MSE per replication (a curve
    that scatters about its power law, as the edges' strata counts make it).
    Covering replications of the new 95% interval and of the old ``slope +- 1.96
    stderr_scaled`` (the known-variance standard error from se_log alone)."""
    rng = np.random.default_rng(seed)
    n = [4 ** e for e in range(2, 9)]
    new = old = 0
    for _ in range(R):
        offset = rng.normal(0.0, wiggle, len(n))
        summaries = [ib.mse_summary(rng.normal(0.0, k ** -0.75 * math.exp(o / 2), p))
                     for k, o, p in zip(n, offset, trials, strict=True)]
        mse, se = [s.mse for s in summaries], [s.se_log for s in summaries]
        low, high = ib.fit_slope(n, mse, se, trials).interval()
        new += low <= -1.5 <= high
        before = ib.fit_slope(n, mse, se)
        old += abs(before.slope + 1.5) <= 1.96 * before.stderr_scaled
    return new, old


def test_slope_interval_covers_at_8_trials():
    """8 trials per N: se_log from 8 trials is low (the sample kurtosis is biased
    low), so the old standard error was too small and slope +- 1.96 of it covered
    0.912 (0.935 at 16 trials); the new standard error takes at least Gaussian
    errors' psi'(4) per point and the t quantile once chi2/dof > 1, and covers 0.993
    (0.986 at 16; band 0.95 to 0.99: the sqrt(chi2/dof) widening applies only
    upwards and chi2/dof exceeds 1 by chance in about half the fits, so the interval
    is conservative for an exact power law)."""
    new, old = _slope_coverage([8] * 7, 0.0, 30)
    assert _band(0.95)[0] <= new / R <= _band(0.99)[1], new / R
    assert old / R < _band(0.95)[0], old / R


def test_slope_interval_covers_a_curve_that_scatters():
    """The default trials (1024 down to 64 at large N) and ln MSE scattering by 0.1
    about the power law (chi2/dof ~6): the residuals set the error, on 5 degrees of
    freedom, and the normal quantile covered 0.870; Student's t covers 0.942 (0.94
    to 0.95 over other seeds: with unequal weights the residuals carry somewhat
    fewer than 5 degrees of freedom), so the band is from 0.93 to 0.97."""
    new, old = _slope_coverage([ib.trials_for(4 ** e) for e in range(2, 9)], 0.1, 31)
    assert _band(0.93)[0] <= new / R <= _band(0.97)[1], new / R
    assert old / R < _band(0.93)[0], old / R


def test_deterministic_points_have_exact_intervals():
    conv = ib.run_convergence("uniform_grid", ["gaussian"], counts=(16, 64), max_trials=16,
                              timed=False)["gaussian"]
    for p in conv.points:
        assert p.summary.se_log == 0.0 and p.summary.interval() == (p.summary.mse,) * 2
    low, high = conv.fit().interval()  # two points, unweighted: no residual, no interval
    assert math.isnan(low) and math.isnan(high)


if __name__ == "__main__":  # python -m tests.analysis.test_mse_intervals: the coverage table
    cases = {"MSE, Gaussian errors, 8 trials": lambda: _gaussian_case(8),
             "MSE, Gaussian errors, 16 trials": lambda: _gaussian_case(16),
             "MSE, multijitter on the disk, N = 16, 16 trials": _multijitter_case,
             "MSE, Laplace errors (kurtosis 6), 16 trials": lambda: _mse_coverage(
                 np.random.default_rng(40).laplace(0.0, 0.3, (R, 16)), 2 * 0.09),
             "slope, power law, 8 trials per N": lambda: _slope_coverage([8] * 7, 0.0, 30),
             "slope, power law, 16 trials per N": lambda: _slope_coverage([16] * 7, 0.0, 30),
             "slope, ln MSE scattering by 0.1, default trials": lambda: _slope_coverage(
                 [ib.trials_for(4 ** e) for e in range(2, 9)], 0.1, 31)}
    print(f"coverage of 95% intervals over {R} replications: new rule, old rule")
    for name, case in cases.items():
        new, old = case()
        print(f"  {name:50s} {new / R:.3f}  {old / R:.3f}")
