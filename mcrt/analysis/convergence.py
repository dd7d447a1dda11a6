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


__all__ = ["LogLogFit", "efficiency", "fit_loglog"]
