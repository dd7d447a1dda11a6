"""Convergence rates and efficiency: how error falls with samples and with time.

``fit_loglog(x, y)`` fits ``log10 y = intercept + slope * log10 x`` by ordinary
least squares. For Monte-Carlo error ``MSE ~ C * spp^slope``: independent
sampling gives slope -1 (variance ``sigma^2 / N``), stratified sampling of a
pixel with edges about -1.5 (in 2D), smooth integrands and good
low-discrepancy points approach -2; a biased estimator (the uniform grid)
flattens towards 0 once its bias dominates. Against wall time the slope is
about the same when time is proportional to samples, shallower when fixed
per-render overhead dominates small sample counts.

``efficiency(mse, seconds) = 1 / (mse * seconds)``: the classic Monte-Carlo
efficiency (inverse of variance times cost). Doubling samples halves the MSE of
an unbiased estimator and doubles the time, so it is constant along one
sampler's curve when the slope is -1 and cost is linear; a sampler that is 2x
more efficient reaches the same error in half the time.

Every efficiency carries a 95% interval (:class:`LogEstimate`, the delta method
on the log scale): ``log eff = -log(excess MSE) - log(time)``, so its variance
is the sum of the two logs' variances, ``var(mean MSE) / excess^2`` over the K
seeds (K - 1 degrees of freedom) and the squared standard error of the log of
the median time (:func:`mcrt.analysis.significance.median_and_se_log`, n - 1
for n timed renders); the interval takes Student's t at the Welch-Satterthwaite
degrees of freedom of that sum. A ratio of two samplers' efficiencies at one
sample count (:func:`efficiency_ratio`) adds both MSE terms and takes the time
ratio *paired*: round by round of the interleaved timing protocol
(:mod:`mcrt.core.timing`), the median of ``log t_a - log t_b``, so that load
which slows one round slows both sides of the ratio alike.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class LogLogFit:
    """Least-squares line through ``(log10 x, log10 y)``.

    ``slope_se`` is the usual OLS standard error of the slope,
    ``s / sqrt(sum (u - mean u)^2)`` with ``s^2`` the residual variance on
    ``n - 2`` degrees of freedom (NaN with fewer than 3 points); ``r2`` the
    coefficient of determination in log space.
    """

    slope: float
    intercept: float
    slope_se: float
    r2: float
    n: int

    def predict(self, x: float | np.ndarray) -> np.ndarray:
        """Fitted ``y`` at ``x`` (back in linear units)."""
        return 10.0 ** (self.intercept + self.slope * np.log10(np.asarray(x, dtype=np.float64)))

    def as_dict(self) -> dict:
        return asdict(self)


def fit_loglog(x, y) -> LogLogFit:
    """Fit ``y ~ C x^slope`` on positive, finite pairs; see :class:`LogLogFit`.

    The line itself is :func:`mcrt.analysis.integrate.fit_slope` (unweighted:
    ordinary least squares with the residual standard error; the slope does not
    depend on the logarithm's base); this adds the base-10 intercept and ``r2``.
    Raises ``ValueError`` when fewer than two distinct positive ``x`` remain.
    """
    from .integrate import fit_slope

    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {x.size} and {y.size}")
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    x, y = x[ok], y[ok]
    if x.size < 2 or np.unique(x).size < 2:
        raise ValueError("a log-log fit needs at least two distinct positive x values")
    fit = fit_slope(x, y)
    intercept = fit.intercept / math.log(10.0)
    v = np.log10(y)
    residual = v - (intercept + fit.slope * np.log10(x))
    ss_tot = float(((v - v.mean()) ** 2).sum())
    r2 = 1.0 - float((residual ** 2).sum()) / ss_tot if ss_tot > 0 else 1.0
    return LogLogFit(slope=fit.slope, intercept=intercept, slope_se=fit.stderr, r2=r2,
                     n=int(x.size))


def efficiency(mse: float | np.ndarray, seconds: float | np.ndarray) -> float | np.ndarray:
    """Monte-Carlo efficiency ``1 / (mse * seconds)`` (NaN where either is <= 0)."""
    mse = np.asarray(mse, dtype=np.float64)
    seconds = np.asarray(seconds, dtype=np.float64)
    product = mse * seconds
    out = np.where(product > 0, 1.0 / np.where(product > 0, product, 1.0), np.nan)
    return float(out) if out.ndim == 0 else out


@dataclass(frozen=True)
class LogEstimate:
    """A positive estimate with the standard error of its natural log and the
    degrees of freedom of that standard error (NaN value: none)."""

    value: float
    se_log: float
    df: float

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """Student-t interval on the log scale, back-transformed."""
        from .significance import log_interval

        if not (math.isfinite(self.value) and self.value > 0) or math.isnan(self.df):
            return math.nan, math.nan
        return log_interval(self.value, self.se_log, self.df, confidence)


NONE = LogEstimate(math.nan, math.nan, math.nan)


def _combine(value: float, parts: list[LogEstimate]) -> LogEstimate:
    """``value`` whose log's variance is the sum of ``parts``' (independent)."""
    from .significance import welch_df

    variances = [p.se_log ** 2 for p in parts]
    if not math.isfinite(value) or value <= 0 or any(math.isnan(v) for v in variances):
        return LogEstimate(value if math.isfinite(value) and value > 0 else math.nan,
                           math.nan, math.nan)
    return LogEstimate(value, math.sqrt(sum(variances)),
                       welch_df(variances, [p.df for p in parts]))


def excess_mse(per_seed_mse: list[float], floor: float) -> LogEstimate:
    """Mean MSE over seeds less the reference's noise floor, and the standard
    error of its log (K - 1 degrees of freedom); NaN when not positive."""
    a = np.asarray(per_seed_mse, dtype=np.float64)
    k = a.size
    excess = float(a.mean()) - floor if k else math.nan
    if not (k > 1 and excess > 0):
        return LogEstimate(excess if excess > 0 else math.nan, math.nan, math.nan)
    return LogEstimate(excess, float(a.std(ddof=1)) / math.sqrt(k) / excess, k - 1.0)


def recorded_excess_mse(excess: float, sd: float, seeds: int) -> LogEstimate:
    """:func:`excess_mse` from a cell's recorded fields: its ``mse_excess``, the
    seeds' ``mse_sd`` (``ddof = 1``) and their number K (the study figures' bars)."""
    if not (seeds > 1 and math.isfinite(excess) and excess > 0 and math.isfinite(sd)):
        return LogEstimate(excess if math.isfinite(excess) and excess > 0 else math.nan,
                           math.nan, math.nan)
    return LogEstimate(excess, sd / math.sqrt(seeds) / excess, seeds - 1.0)


def typical_time(times: list[float]) -> LogEstimate:
    """The median of a case's timed runs with the standard error of its log."""
    from .significance import median_and_se_log

    median, se_log, n = median_and_se_log(times)
    return LogEstimate(median, se_log, n - 1.0 if n > 1 else math.nan)


def efficiency_estimate(mse: LogEstimate, time: LogEstimate) -> LogEstimate:
    """``1 / (excess MSE x time)`` with its log's standard error (see the module doc)."""
    return _combine(1.0 / (mse.value * time.value), [mse, time])


def paired_time_ratio(times_a: list[float], times_b: list[float]) -> LogEstimate:
    """``t_a / t_b`` from runs timed in the same rounds (``times_a[r]`` and
    ``times_b[r]`` interleaved together): exp of the median of the paired log
    differences, with the standard error of that median's log."""
    from .significance import median_and_se_log

    n = min(len(times_a), len(times_b))
    a = np.asarray(times_a[:n], dtype=np.float64)
    b = np.asarray(times_b[:n], dtype=np.float64)
    ok = (a > 0) & (b > 0) & np.isfinite(a) & np.isfinite(b)
    if np.count_nonzero(ok) < 2:
        return NONE
    ratios = a[ok] / b[ok]
    median, se_log, used = median_and_se_log(list(ratios))
    return LogEstimate(median, se_log, used - 1.0)


def efficiency_ratio(mse_a: LogEstimate, mse_b: LogEstimate, time_ratio: LogEstimate
                     ) -> LogEstimate:
    """``efficiency_a / efficiency_b = (mse_b / mse_a) / (t_a / t_b)``; its
    inverse is the time ``a`` needs for ``b``'s error, relative to ``b``'s."""
    return _combine(mse_b.value / mse_a.value / time_ratio.value, [mse_a, mse_b, time_ratio])


__all__ = ["NONE", "LogEstimate", "LogLogFit", "efficiency", "efficiency_estimate",
           "efficiency_ratio", "excess_mse", "fit_loglog", "paired_time_ratio",
           "recorded_excess_mse", "typical_time"]
