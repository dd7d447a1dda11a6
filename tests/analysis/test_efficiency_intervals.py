"""Efficiency, its ratio to a baseline and the bias flags, on synthetic data
whose truth is known: the 95% intervals cover it about 95% of the time, the
paired ratio survives a drifting machine load, and Holm's correction keeps the
false-alarm rate of a study's bias flags at 5%."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from mcrt.analysis.convergence import (
    LogEstimate,
    efficiency_estimate,
    efficiency_ratio,
    excess_mse,
    paired_time_ratio,
    recorded_excess_mse,
    typical_time,
)
from mcrt.analysis.significance import holm, two_sided_p

FLOOR = 1e-4
TRIALS = 3000
# Monte-Carlo margin of an observed coverage at 0.95 over TRIALS trials: binomial
# sd sqrt(0.95 x 0.05 / 3000) = 0.004; 4 sd = 0.016. The delta method and the
# median's standard error are asymptotic, so the tests allow that margin plus
# 0.015 of approximation on the low side (0.919) and are stricter than needed on
# the high side; a forgotten variance term or a normal quantile at 3 degrees of
# freedom lands near 0.85-0.88, well outside.
LOW, HIGH = 0.919, 0.985


def _seeds(rng: np.random.Generator, mse: float, k: int = 4) -> list[float]:
    """Per-seed MSEs around ``mse`` (sd 14%, like a 64x64 image's) plus the floor."""
    return list(FLOOR + mse * rng.gamma(50, 1 / 50, k))


def test_efficiency_interval_covers_the_truth():
    rng = np.random.default_rng(11)
    truth, covered, normal_covered = 1 / (1e-3 * 0.05), 0, 0
    for _ in range(TRIALS):
        mse = excess_mse(_seeds(rng, 1e-3), FLOOR)
        time = typical_time(list(0.05 * np.exp(rng.normal(0, 0.05, 5))))
        eff = efficiency_estimate(mse, time)
        low, high = eff.interval()
        covered += low <= truth <= high
        # the same standard error with the normal quantile (df ignored)
        n_low, n_high = LogEstimate(eff.value, eff.se_log, math.inf).interval()
        normal_covered += n_low <= truth <= n_high
    assert LOW <= covered / TRIALS <= HIGH, covered / TRIALS
    assert normal_covered / TRIALS < covered / TRIALS - 0.02  # t matters at these df


@pytest.mark.slow
def test_paired_ratio_holds_under_a_drifting_load():
    """Sampler A is 1.5x faster than B and has half its MSE: efficiency ratio 3.
    Each round runs both under a common load factor drawn in [1, 3] (another
    process taking the cores): pairing cancels it, the interval stays narrow
    and covers 3; unpaired medians would mix rounds of different load."""
    rng = np.random.default_rng(12)
    covered, widths, unpaired_widths = 0, [], []
    for _ in range(TRIALS):
        load = rng.uniform(1, 3, 5)
        ta = list(0.05 * load * np.exp(rng.normal(0, 0.02, 5)))
        tb = list(0.075 * load * np.exp(rng.normal(0, 0.02, 5)))
        ratio = paired_time_ratio(ta, tb)
        eff = efficiency_ratio(excess_mse(_seeds(rng, 1e-3, 8), FLOOR),
                               excess_mse(_seeds(rng, 2e-3, 8), FLOOR), ratio)
        low, high = eff.interval()
        covered += low <= 3.0 <= high
        t_low, t_high = ratio.interval()
        widths.append(t_high / t_low)
        a, b = typical_time(ta), typical_time(tb)
        unpaired = LogEstimate(a.value / b.value, math.hypot(a.se_log, b.se_log), 8)
        u_low, u_high = unpaired.interval()
        unpaired_widths.append(u_high / u_low)
    assert LOW <= covered / TRIALS <= HIGH, covered / TRIALS
    assert np.median(widths) < 1.1 < 2.0 < np.median(unpaired_widths)


def test_resolved_inputs_only():
    assert math.isnan(excess_mse([1e-4, 0.9e-4], FLOOR).value)  # below the floor
    assert math.isnan(efficiency_estimate(excess_mse([1.0], 0.0), typical_time([1.0])).se_log)
    assert math.isnan(paired_time_ratio([1.0], [1.0]).value)  # one round: no spread
    low, high = LogEstimate(2.0, 0.0, 3.0).interval()
    assert low == high == 2.0


def test_holm_flags_keep_the_family_wise_rate_and_find_a_real_bias():
    """40 cells, all unbiased: z ~ N(0, 1). Over 4000 studies Holm at 0.05 flags
    at least one cell in at most 5% of them (binomial sd 0.0034: bound 0.05 +
    4 sd); a biased cell at 6 sigma is flagged nearly always."""
    rng = np.random.default_rng(13)
    studies, false, found = 4000, 0, 0
    for _ in range(studies):
        z = rng.normal(0, 1, 40)
        false += any(holm([two_sided_p(v) for v in z]))
        z[0] += 6.0
        found += holm([two_sided_p(v) for v in z])[0]
    assert false / studies <= 0.05 + 4 * 0.0034
    assert false / studies > 0.02  # not vacuous: the rate is near, not far below, 5%
    assert found / studies > 0.95


@pytest.mark.parametrize("k", [3, 4, 8])
def test_excess_mse_standard_error_is_the_seeds_spread(k):
    values = [2e-3, 3e-3, 2.5e-3, 2.2e-3, 2.9e-3, 2.4e-3, 2.6e-3, 2.1e-3][:k]
    est = excess_mse(values, FLOOR)
    mean = float(np.mean(values)) - FLOOR
    assert est.value == pytest.approx(mean)
    assert est.se_log == pytest.approx(np.std(values, ddof=1) / math.sqrt(k) / mean)
    assert est.df == k - 1


def test_the_error_plots_bar_covers_the_excess_mse():
    """The study plots' vertical bar, from a cell's recorded mse_excess, mse_sd and
    K = 4 seeds (``recorded_excess_mse``, the efficiency's MSE term): over 2000
    synthetic cells it covers the true excess MSE 0.9485 of the time, inside the
    binomial(2000, 0.95) count's central 99.9% range. The +-1 standard error bar it
    replaced covered 0.61: below even a normal bar's 68.3% (its 99.9% range starts
    at 0.648), as Student's t on 3 degrees of freedom makes it."""
    rng = np.random.default_rng(14)
    r, new, old = 2000, 0, 0
    for _ in range(r):
        seeds = np.array(_seeds(rng, 1e-3))
        excess, sd = float(seeds.mean()) - FLOOR, float(seeds.std(ddof=1))
        low, high = recorded_excess_mse(excess, sd, len(seeds)).interval()
        assert (low, high) == excess_mse(list(seeds), FLOOR).interval()
        new += low <= 1e-3 <= high
        old += abs(excess - 1e-3) <= sd / math.sqrt(len(seeds))
    band = stats.binom.ppf([0.0005, 0.9995], r, 0.95) / r
    assert band[0] <= new / r <= band[1], new / r
    assert old / r < stats.binom.ppf(0.0005, r, 0.6827) / r, old / r
    assert math.isnan(recorded_excess_mse(1e-3, 1e-4, 1).interval()[0])  # one seed: none


def test_a_cost_of_zero_is_called_resolved_at_the_stated_rate():
    """The study's cost columns show a value only when its 95% interval lies above 0
    (else a bound). A sampler whose per-sample cost is 0, timed at 3 sizes x 2 rounds
    (6 renders, 4 degrees of freedom) with normal noise: Student's t shows a value
    in 3.0% of 4000 fits, within the binomial(4000, 0.025) count's central 99.9%
    range (one-sided 2.5%); the normal 1.96 it replaced did in 6.3%."""
    from mcrt.analysis.study.conclude import cost_df, cost_text
    from mcrt.core.timing import fit_cost

    rng = np.random.default_rng(17)
    r, new, old = 4000, 0, 0
    units = [64 * 64 * spp for spp in (4, 16, 64) for _ in range(2)]
    for _ in range(r):
        fit = fit_cost(units, list(0.02 + rng.normal(0, 1e-3, len(units))))
        df = cost_df([{"times": [0.02] * 2} for _ in range(3)])  # the cells' 6 renders
        shown = cost_text(fit.per_unit, fit.per_unit_se, 1e9, df=df)
        new += shown[0] not in "<-"
        old += cost_text(fit.per_unit, fit.per_unit_se, 1e9)[0] not in "<-"
    band = stats.binom.ppf([0.0005, 0.9995], r, 0.025) / r
    assert band[0] <= new / r <= band[1], new / r
    assert old / r > band[1], old / r
