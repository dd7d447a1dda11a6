"""Intervals for a mean squared error over independent trials, and for a slope of ln MSE.

An MSE from ``P`` independent trials, ``MSE_hat = mean(e^2)``, is a mean of
positive, right-skewed values: at small ``P`` a symmetric interval on it (or on
its log, ``exp(+-2 se_log)``) misses the truth far more often than it says (for
Gaussian errors and 16 trials, ``exp(+-2 se_log)`` covers 89%, not 95%; the
trial-estimated ``se_log`` is low when the sample happens to be tight). The
rules here:

``mse_dof(se_log, trials)``
    The degrees of freedom ``nu`` of a scaled chi-square ``MSE chi2_nu / nu``
    with the MSE's relative variance: ``nu = 2 / se_log^2`` (Satterthwaite 1946:
    the chi-square whose first two moments match), capped at ``P``, the value of
    zero-mean Gaussian errors (``P MSE_hat / MSE ~ chi2_P`` exactly). The cap
    says the MSE is never taken as better known than Gaussian errors would make
    it: a sample kurtosis from a few trials is biased low, and the uncapped
    ``nu`` covered 90% at ``P = 16``. Errors lighter-tailed than Gaussian
    (uniform), or biased ones (``e = b + noise``), have a smaller relative
    variance, and the cap makes their interval conservative; heavier-tailed
    errors (kurtosis above 3) get ``nu < P`` from their larger ``se_log``
    (Laplace errors still cover only ~0.88 at ``P = 16``, 0.91 at 64, 0.94 at
    1024: no interval from 16 draws can know a heavy tail it has not seen).
    ``se_log == 0`` (identical squared errors in every trial, a deterministic
    estimator): ``inf``, the MSE is exact.
``mse_interval(mse, se_log, trials, confidence=0.95)``
    ``(MSE_hat nu / chi2_{nu, (1+c)/2}, MSE_hat nu / chi2_{nu, (1-c)/2})``, the
    chi-square pivot with ``nu`` from :func:`mse_dof`: exact for zero-mean
    Gaussian errors, and skewed as the MSE's own distribution is (more room
    above than below). Coverage at 95% on the samplers' own errors
    (``mcrt integrate``'s integrands, independent / jittered / poisson_disk /
    sobol / multijitter at N = 16 to 256, 16 trials drawn from 65536): 0.94 to
    0.98, where ``exp(+-2 se_log)`` gave 0.84 to 0.95.
``log_mse_variance(se_log, trials)``
    ``Var[ln MSE_hat]`` under that model, ``psi'(nu / 2)`` (the trigamma
    function; ``~ 2 / nu + 2 / nu^2``), never below the Gaussian errors' value
    at ``P`` trials. :func:`mcrt.analysis.integrate.fit_slope` uses it for the
    standard error of a slope of ``ln MSE`` (the estimated ``se_log`` alone made
    that standard error ~20% too small at 16 trials).
``chi2_quantile(p, df)``, ``trigamma(x)``
    From scipy.special: ``2 gammaincinv(df / 2, p)`` (``gammainccinv`` on
    ``1 - p`` above the median, each tail to full relative precision) and
    ``polygamma(1, x)``.

References:
  F. E. Satterthwaite (1946), An approximate distribution of estimates of
    variance components, Biometrics Bulletin 2, 110-114.
"""

from __future__ import annotations

import functools
import math


@functools.lru_cache(maxsize=4096)
def chi2_quantile(p: float, df: float) -> float:
    """The ``p`` quantile of chi-square on ``df > 0`` degrees of freedom."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1), got {p!r}")
    if not df > 0.0:
        raise ValueError(f"degrees of freedom must be positive, got {df!r}")
    if math.isinf(df):
        return math.inf
    from scipy import special  # (0.15 s to import: only when an interval is asked for)

    if p < 0.5:  # on the smaller tail (1 - p is exact only for p >= 1/2)
        return 2.0 * float(special.gammaincinv(0.5 * df, p))
    return 2.0 * float(special.gammainccinv(0.5 * df, 1.0 - p))


def trigamma(x: float) -> float:
    """``psi'(x)`` for ``x > 0``."""
    if not x > 0.0:
        raise ValueError(f"trigamma needs x > 0, got {x!r}")
    from scipy import special

    return float(special.polygamma(1, x))


def mse_dof(se_log: float, trials: int) -> float:
    """``min(2 / se_log^2, trials)``; ``inf`` for ``se_log == 0``, NaN for NaN (module doc)."""
    if math.isnan(se_log):
        return math.nan
    if se_log < 0:
        raise ValueError(f"standard error must be non-negative, got {se_log!r}")
    if trials < 1:
        raise ValueError(f"trials must be at least 1, got {trials!r}")
    if se_log == 0.0:
        return math.inf
    return min(2.0 / (se_log * se_log), float(trials))


def mse_interval(mse: float, se_log: float, trials: int, confidence: float = 0.95
                 ) -> tuple[float, float]:
    """The chi-square interval of an MSE over ``trials`` independent trials (module doc):
    ``(mse, mse)`` when ``se_log == 0`` or ``mse == 0``, NaN when either is NaN."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    nu = mse_dof(se_log, trials)
    if math.isnan(nu) or math.isnan(mse):
        return math.nan, math.nan
    if math.isinf(nu) or mse == 0.0:
        return mse, mse
    tail = 0.5 * (1.0 - confidence)
    return (mse * nu / chi2_quantile(1.0 - tail, nu), mse * nu / chi2_quantile(tail, nu))


def log_mse_variance(se_log: float, trials: int) -> float:
    """``Var[ln MSE_hat] = psi'(nu / 2)``, ``nu`` from :func:`mse_dof` (0 when exact)."""
    nu = mse_dof(se_log, trials)
    if math.isnan(nu):
        return math.nan
    return 0.0 if math.isinf(nu) else trigamma(0.5 * nu)


__all__ = ["chi2_quantile", "log_mse_variance", "mse_dof", "mse_interval", "trigamma"]
