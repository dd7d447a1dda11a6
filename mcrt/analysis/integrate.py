"""Monte-Carlo integration bench: how fast does each sampler's error shrink?

The lecture's experiment, run through the samplers' real point sets: estimate
an integral over the unit square with ``N`` samples of one pixel, as the renderer
would, and repeat over many pixels. Pixels are decorrelated by the samplers'
per-pixel seeding, so each pixel is an independent *trial* of the estimator

    I_hat = (1/N) sum_j f(x_j),     x_j = the N film samples of the pixel

and the trials give its mean squared error ``MSE = mean_p (I_hat_p - I)^2``
(bias included). mcrt's integrands (``INTEGRANDS``, :mod:`.integrands`) have exact values
(a user's own may have an estimated one instead, whose error is subtracted: see there):

* ``pi``: the indicator of the quarter disc ``x^2 + y^2 <= 1`` times 4, whose
  integral is pi (the lecture's dart-throwing estimate of pi);
* ``disk``: the indicator of the disc of radius 0.4 around (0.5, 0.5), integral
  ``0.16 pi`` (a discontinuity crossing the pixel, like a geometric edge);
* ``gaussian``: ``exp(-|x - c|^2 / (2 s^2))`` with ``c = (0.5, 0.5)`` and
  ``s = 0.2``; integral ``(s sqrt(2 pi) erf(1 / (2 sqrt(2) s)))^2`` (smooth).

Known rates for the MSE (the variance, for unbiased samplers): independent
samples ``N^-1`` for any square-integrable ``f``; jittered (stratified)
sampling ``N^-1.5`` for an indicator with a smooth boundary and ``N^-2`` for a
smooth ``f`` in 2D (``N^-(1 + 2/d)``) [Mitchell96]_ [Owen13]_.

Uncertainty
===========

With ``P`` independent trials, ``MSE_hat = mean(e^2)``, so by the delta method
``Var[ln MSE_hat] ~ Var[e^2] / (P MSE^2) = (kurt - 1) / P`` with ``kurt`` the
kurtosis of the error ``E[e^4] / E[e^2]^2`` (3 for Gaussian errors, giving the
familiar ``sqrt(2 / P)``). :func:`mse_summary` estimates it from the sample
moments, so heavy-tailed or discrete errors (an indicator at small ``N``) are
not under-reported. The MSE's 95% interval (:meth:`MSESummary.interval`) is a
chi-square interval (:func:`mcrt.analysis.mse_interval.mse_interval`: exact for
Gaussian errors, skewed like the MSE; ``exp(+-2 se_log)`` covered 89% at 16
trials). The slope of ``ln MSE`` against ``ln N`` is fitted by weighted least
squares with these variances (:func:`fit_slope`); its standard error takes each
point's ``Var[ln MSE]`` as at least Gaussian errors' (``psi'(P / 2)``), and its
95% interval (:meth:`SlopeFit.interval`) the normal quantile, or Student's t on
``points - 2`` degrees of freedom once the scatter about the power law sets the
error. Work is bounded by capping the points per ``N``
(:data:`POINT_BUDGET`): large ``N`` get fewer trials, so their ``ln MSE`` has a
larger standard error (``sqrt(2 / P)``: 0.044 at 1024 trials, 0.18 at 64) and
less weight in the fit.

References
==========

.. [Mitchell96] D. P. Mitchell. "Consequences of stratified sampling in
   graphics". SIGGRAPH 1996 (edge-type integrands: N^-1.5 for stratified 2D).
.. [Owen13] A. B. Owen. *Monte Carlo theory, methods and examples*, ch. 10
   (stratification: variance O(N^(-1-2/d)) for smooth integrands).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.sampling import mitsuba_message, quiet_sampler_warnings
from ..errors import McrtError, SamplerError
from ..samplers.points import point_sets
from .integrands import INTEGRANDS as INTEGRANDS  # (re-exported: the bench's own)
from .integrands import Integrand, IntegrandError, integrand
from .metrics import RESOLVED_FACTOR
from .mse_interval import log_mse_variance, mse_interval
from .significance import t_quantile

#: Default trials (pixels) per sample count.
DEFAULT_TRIALS = 1024

#: Default cap on points (trials x N) per sample count: 2^22 points, 32 MB as float32 pairs.
POINT_BUDGET = 1 << 22

#: Default sample counts: 16 ... 65536 by powers of 4.
DEFAULT_COUNTS = tuple(4 ** e for e in range(2, 9))


# --------------------------------------------------------------------------- statistics

@dataclass(frozen=True)
class MSESummary:
    """Mean squared error over independent trials and its uncertainty."""

    mse: float
    se_log: float     # standard error of ln(mse) (delta method, sample kurtosis)
    bias: float       # mean error
    trials: int

    @property
    def rmse(self) -> float:
        return math.sqrt(self.mse)

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """The MSE's interval: chi-square on ``min(2 / se_log^2, trials)`` degrees of
        freedom (:func:`~mcrt.analysis.mse_interval.mse_interval`); ``(mse, mse)`` for a
        deterministic estimator."""
        return mse_interval(self.mse, self.se_log, self.trials, confidence)


def mse_summary(errors: np.ndarray) -> MSESummary:
    """MSE of ``errors`` (one per independent trial) and the standard error of its log.

    ``se_log = sqrt(Var[e^2] / P) / MSE`` (delta method), with ``Var[e^2]``
    estimated from the trials; ``sqrt(2 / P)`` for Gaussian errors. It is 0 for
    a deterministic estimator (identical errors), whose MSE is exact.
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    p = e.size
    if p < 2:
        raise ValueError("mse_summary needs at least two trials")
    sq = e * e
    mse = float(np.mean(sq))
    se = 0.0 if mse == 0.0 else float(np.std(sq, ddof=1) / math.sqrt(p) / mse)
    return MSESummary(mse=mse, se_log=se, bias=float(np.mean(e)), trials=p)


@dataclass(frozen=True)
class SlopeFit:
    """``ln MSE = intercept + slope ln N``, weighted least squares."""

    slope: float
    stderr: float
    intercept: float
    points: int
    #: Weighted residual sum of squares per degree of freedom: ~1 when a power law
    #: fits within the stated errors, >> 1 when the curve bends (pre-asymptotic
    #: range, error floors); nan for unweighted fits or two points.
    chi2_dof: float = math.nan
    #: Weighted by the points' standard errors (else: ordinary least squares, whose
    #: standard error comes from the residuals).
    weighted: bool = False

    @property
    def stderr_scaled(self) -> float:
        """``stderr`` times ``sqrt(chi2_dof)`` when the points scatter about the line
        more than their errors allow (``chi2_dof > 1``): the slope's uncertainty
        including the misfit of the power law (as ``scipy.optimize.curve_fit``
        does with ``absolute_sigma=False``)."""
        if self.chi2_dof == self.chi2_dof and self.chi2_dof > 1.0:
            return self.stderr * math.sqrt(self.chi2_dof)
        return self.stderr

    def mse_at(self, n: float) -> float:
        return math.exp(self.intercept + self.slope * math.log(n))

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """``slope +- q stderr_scaled``: ``q`` the normal quantile while the points
        scatter within their errors (``chi2_dof <= 1``, or two points), Student's t
        on ``points - 2`` degrees of freedom when the residuals set the error (a
        scaled or an unweighted fit). NaN when there is no standard error."""
        half = 0.5 * (1.0 + confidence)
        se = self.stderr_scaled
        if not (math.isfinite(self.slope) and math.isfinite(se)):
            return math.nan, math.nan
        if self.weighted and not self.chi2_dof > 1.0:
            q = t_quantile(half, math.inf)
        elif self.points > 2:
            q = t_quantile(half, self.points - 2)
        else:
            return math.nan, math.nan
        return self.slope - q * se, self.slope + q * se


#: Floor on the standard error of ln(MSE) in the fit (deterministic samplers
#: have se 0; the floor keeps their weights finite and equal).
SE_FLOOR = 1e-3


def fit_slope(n: Sequence[float], mse: Sequence[float], se_log: Sequence[float] | None = None,
              trials: Sequence[int] | None = None) -> SlopeFit:
    """Weighted least-squares slope of ``ln mse`` against ``ln n``.

    Weights ``1 / se_log^2`` (floored at :data:`SE_FLOOR`); unweighted if
    ``se_log`` is None. ``stderr`` is the slope's standard error from the points'
    variances, ``sqrt(sum w^2 (x - x_w)^2 v) / sum w (x - x_w)^2``, i.e. it assumes
    the ``ln MSE`` values are independent and that a power law holds; ``chi2_dof``
    checks the latter. ``v = se_log^2`` (then ``sqrt(1 / sum w (x - x_w)^2)``); with
    each point's ``trials``, ``v = psi'(nu / 2)``, ``nu = min(2 / se_log^2, trials)``
    (:func:`~mcrt.analysis.mse_interval.log_mse_variance`): at least Gaussian errors'
    variance, where the trial-estimated ``se_log`` alone is low at a few trials
    (the slope's ``+-1.96 stderr`` covered 88% at 16 trials per point, not 95%).
    Unweighted fits use the residual variance instead. Points with ``mse <= 0``
    are skipped.
    """
    counts = np.asarray(n, dtype=np.float64)
    errors = np.asarray(mse, dtype=np.float64)
    keep = (errors > 0) & (counts > 0)
    if np.count_nonzero(keep) < 2:
        return SlopeFit(math.nan, math.nan, math.nan, int(np.count_nonzero(keep)))
    x, y = np.log(counts[keep]), np.log(errors[keep])
    variance = None
    if se_log is None:
        w = np.ones_like(x)
    else:
        se = np.asarray(se_log, dtype=np.float64)[keep]
        w = 1.0 / np.maximum(se, SE_FLOOR) ** 2
        variance = 1.0 / w
        if trials is not None:
            p = np.asarray(trials)[keep]
            variance = np.array([log_mse_variance(float(s), int(t)) for s, t in zip(se, p,
                                                                                   strict=True)])
    xm = np.sum(w * x) / np.sum(w)
    ym = np.sum(w * y) / np.sum(w)
    sxx = np.sum(w * (x - xm) ** 2)
    slope = float(np.sum(w * (x - xm) * (y - ym)) / sxx)
    intercept = float(ym - slope * xm)
    dof = x.size - 2
    resid = y - (intercept + slope * x)
    chi2_dof = math.nan
    if se_log is None:
        stderr = float(math.sqrt(np.sum(resid ** 2) / dof / sxx)) if dof > 0 else math.nan
    else:
        stderr = float(math.sqrt(np.sum(w * w * (x - xm) ** 2 * variance)) / sxx)
        if dof > 0:
            chi2_dof = float(np.sum(w * resid ** 2) / dof)
    return SlopeFit(slope=slope, stderr=stderr, intercept=intercept, points=int(x.size),
                    chi2_dof=chi2_dof, weighted=se_log is not None)


# --------------------------------------------------------------------------- the bench

@dataclass
class ConvergencePoint:
    """Results of one sampler at one sample count for one integrand."""

    sampler: str
    integrand: str
    n_requested: int
    n: int                 # effective samples per trial (after the sampler's rounding)
    trials: int
    estimates: np.ndarray  # (trials,)
    summary: MSESummary
    seconds: float         # generating the points + evaluating all integrands, warm
    exact: float
    seed: int = 0          # the seed of this count's points
    #: The standard error of ``exact`` when it was estimated (0: known exactly).
    exact_error: float = 0.0
    #: The integrand evaluated (:func:`time_samplers` evaluates it again); None: the one
    #: ``integrand`` names.
    definition: Integrand | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        # Identical estimates up to summation-order rounding: no sampling error, the MSE
        # is exact (se_log 0, a zero-width interval), not known to chi-square's P dof.
        if self.deterministic and self.summary.se_log != 0.0:
            self.summary = replace(self.summary, se_log=0.0)

    @property
    def ns_per_sample(self) -> float:
        return self.seconds / (self.n * self.trials) * 1e9

    @property
    def deterministic(self) -> bool:
        """Every trial gave the same estimate (up to summation-order rounding, relative
        to the estimates' magnitude), as for ``uniform_grid``: the MSE is then a squared
        bias with no sampling error. (An absolute floor would call every trial of an
        integrand of size 1e-30 the same.)"""
        scale = max(abs(self.exact), float(np.max(np.abs(self.estimates))))
        return float(np.ptp(self.estimates)) <= 1e-12 * scale

    @property
    def floor(self) -> float:
        """``exact_error^2``: what an estimated exact value's own error adds to the
        expected MSE (see :mod:`.integrands`); 0 for a known one."""
        return self.exact_error ** 2

    @property
    def mse_excess(self) -> float:
        """``mse - floor``: the MSE against the true integral (as a study's
        :func:`~mcrt.analysis.metrics.mse_excess`; may be negative when unresolved)."""
        return self.summary.mse - self.floor

    @property
    def resolved(self) -> bool:
        """Whether the MSE exceeds ``RESOLVED_FACTOR`` x the floor, which an estimated
        exact value can resolve (always, for a known one)."""
        return self.floor == 0.0 or self.summary.mse > RESOLVED_FACTOR * self.floor

    @property
    def se_log_excess(self) -> float:
        """The standard error of ``ln mse_excess``: the MSE's, and the floor's own
        (the estimate's squared error ``d^2`` varies by ``sqrt(2) floor`` for normal ``d``),
        relative to the excess; the MSE's ``se_log`` when there is no floor."""
        if self.floor == 0.0:
            return self.summary.se_log
        spread = math.hypot(self.summary.se_log * self.summary.mse, math.sqrt(2.0) * self.floor)
        return spread / self.mse_excess if self.mse_excess > 0 else math.inf


@dataclass
class Convergence:
    """All sample counts of one sampler for one integrand, with the fitted slope."""

    sampler: str
    integrand: str
    points: list[ConvergencePoint] = field(default_factory=list)
    skipped: list[tuple[int, str]] = field(default_factory=list)  # (n, reason)

    @property
    def deterministic(self) -> bool:
        return bool(self.points) and all(p.deterministic for p in self.points)

    def fit(self, min_n: int = 1) -> SlopeFit:
        """Slope over the counts ``>= min_n``: weighted by the MSE's standard errors,
        or, for a deterministic sampler (no sampling error), an unweighted fit whose
        standard error describes the scatter about the line. Against an estimated exact
        value, of the resolved counts' MSE less the floor (:attr:`ConvergencePoint.resolved`)."""
        sel = [p for p in self.points if p.n >= min_n and p.resolved]
        if self.deterministic:
            return fit_slope([p.n for p in sel], [p.mse_excess for p in sel])
        return fit_slope([p.n for p in sel], [p.mse_excess for p in sel],
                         [p.se_log_excess for p in sel], [p.trials for p in sel])


def trials_for(n: int, max_trials: int = DEFAULT_TRIALS, budget: int = POINT_BUDGET) -> int:
    """Trials at ``n`` samples: ``max_trials``, fewer if ``trials x n`` exceeds ``budget``
    (at least 16, so the MSE still has a usable uncertainty)."""
    return max(16, min(max_trials, budget // max(n, 1)))


def effective_count(sampler: str, n: int, **params) -> int:
    """Samples per pixel ``sampler`` actually uses when asked for ``n``."""
    with quiet_sampler_warnings():
        return mi.load_dict({"type": sampler, "sample_count": int(n), **params}).sample_count()


class PointsOutside(SamplerError):
    """A sampler's points (``(P, N, d)``) that are not finite or not in [0, 1)."""

    def __init__(self, sampler: str, points: np.ndarray, what: str = "film coordinates"):
        bad = ~(np.isfinite(points) & (points >= 0.0) & (points < 1.0))
        #: The points in words: "3 of 8192 film coordinates at N = 64 are outside ...".
        self.where = (f"{np.count_nonzero(bad)} of {points.size} {what} at N = "
                      f"{points.shape[1]} are outside [0, 1), e.g. {float(points[bad][0])!r}")
        super().__init__(f"{sampler}: {self.where} (mcrt check {sampler} tests the sampler "
                         f"contract)")


def check_points(sampler: str, points: np.ndarray, what: str = "film coordinates") -> None:
    """Refuse points that are not finite or not in [0, 1) (a user's sampler
    breaking the contract) with :class:`PointsOutside`: the integrands would be
    evaluated off the unit square, or on NaN, and the MSE would be wrong or NaN
    without saying why."""
    if not (np.isfinite(points) & (points >= 0.0) & (points < 1.0)).all():
        raise PointsOutside(sampler, points, what)


def run_convergence(sampler: str, integrands: Iterable[str | Integrand],
                    counts: Sequence[int] = DEFAULT_COUNTS, max_trials: int = DEFAULT_TRIALS,
                    budget: int = POINT_BUDGET, seed: int = 0, timed: bool = True,
                    progress: Callable[[], None] | None = None,
                    **params) -> dict[str, Convergence]:
    """Run the bench for one sampler: every count, every integrand, the same points.

    ``integrands``: names (mcrt's, or registered with
    :func:`~mcrt.analysis.integrands.register_integrand`) or
    :class:`~mcrt.analysis.integrands.Integrand` objects (e.g. from
    :func:`~mcrt.analysis.integrands.make_integrand`); the results are keyed by name.

    For each requested count ``n`` the trials are pixels ``0 .. P-1`` with
    ``P = trials_for(n_eff, max_trials, budget)``; their film points
    (dimension 0) come from :func:`~mcrt.samplers.points.point_sets` with seed
    ``seed + i`` (mod 2^32) for the ``i``-th count, so different counts use
    unrelated points and their ``ln MSE`` are independent (as :func:`fit_slope`
    assumes). With ``timed``, the same call is made once before timing (kernel
    compilation, Poisson tables), then the timed call runs between
    ``dr.sync_thread()`` barriers and includes evaluating the integrands.
    Counts the sampler cannot produce (e.g. ``poisson_disk`` above its table
    size) are recorded in ``skipped``; points that are not finite or not in
    [0, 1) raise SamplerError (:func:`check_points`). ``progress()`` is called
    after each count.
    """
    chosen: dict[str, Integrand] = {}
    for spec in integrands:
        item = integrand(spec)
        if chosen.setdefault(item.name, item) is not item:
            raise McrtError(f"two integrands are named {item.name!r}")
    results = {name: Convergence(sampler, name) for name in chosen}
    for index, n_req in enumerate(counts):
        count_seed = (seed + index) % (1 << 32)  # fresh points per count: independent ln MSE
        try:
            n = effective_count(sampler, n_req, **params)
        except Exception as error:  # the sampler refuses this count
            reason = mitsuba_message(error)
            for res in results.values():
                res.skipped.append((int(n_req), reason))
            if progress is not None:
                progress()
            continue
        trials = trials_for(n, max_trials, budget)
        with quiet_sampler_warnings():
            if timed:
                point_sets(sampler, trials, n_req, seed=count_seed, **params)  # warm-up
                dr.sync_thread()
            start = time.perf_counter()
            points = point_sets(sampler, trials, n_req, seed=count_seed, **params)
            try:
                estimates = {name: item.estimates(points) for name, item in chosen.items()}
            except IntegrandError:
                check_points(sampler, points)  # points off the square: the sampler's fault
                raise
            dr.sync_thread()
            seconds = time.perf_counter() - start
        if points.shape[1] != n:
            raise RuntimeError(f"{sampler}: expected {n} samples per pixel, got {points.shape[1]}")
        check_points(sampler, points)
        for name, item in chosen.items():
            est = estimates[name]
            results[name].points.append(ConvergencePoint(
                sampler=sampler, integrand=name, n_requested=int(n_req), n=n, trials=trials,
                estimates=est, summary=mse_summary(est - item.exact), seconds=seconds,
                exact=item.exact, seed=count_seed, exact_error=item.exact_error,
                definition=item))
        if progress is not None:
            progress()
    return results


def time_samplers(convergences: Iterable[Convergence], rounds: int = 3, seed: int = 0,
                  **params) -> None:
    """Time every sampler's points again by the timing protocol
    (:func:`mcrt.core.timing.run_interleaved`): per sample count, one case per
    sampler (its points and the integrand, as :func:`run_convergence` made them),
    a warm-up each, then ``rounds`` rounds in a shuffled order; every point's
    ``seconds`` becomes the median of its rounds. Interleaving puts a change of
    machine load on every sampler alike instead of on the one running then."""
    from ..core.timing import run_interleaved, summarise

    points = [p for conv in convergences for p in conv.points]
    for n_req in sorted({p.n_requested for p in points}):
        group = [p for p in points if p.n_requested == n_req]

        def case(point: ConvergencePoint) -> Callable[[], None]:
            def call() -> None:
                with quiet_sampler_warnings():
                    values = point_sets(point.sampler, point.trials, point.n_requested,
                                        seed=point.seed, **params)
                    (point.definition or integrand(point.integrand)).estimates(values)
            return call

        samples = run_interleaved([case(p) for p in group], rounds, seed=seed + n_req,
                                  sync=dr.sync_thread)
        for point, timing in zip(group, samples, strict=True):
            point.seconds = summarise(timing).median
