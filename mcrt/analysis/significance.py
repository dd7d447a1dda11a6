"""Small-sample statistics for intervals and tests: Student's t, Welch, Holm, medians.

Pure Python and numpy (no scipy at run time); every function takes and returns
plain floats (or lists of them) and treats NaN as "unknown": NaN in gives NaN
out unless stated otherwise. Definitions and references:

``t_cdf(t, df)``
    ``P(T <= t)`` for Student's t with ``df > 0`` degrees of freedom (any real
    ``df``; ``math.inf`` is the standard normal). For ``s = |t|`` and
    ``x = df / (df + s^2)`` the lower tail is ``P(T <= -s) = I_x(df/2, 1/2) / 2``
    and the central part ``P(0 < T <= s) = I_{1-x}(1/2, df/2) / 2``
    (Abramowitz & Stegun 1964, 26.7.1 with 26.5.27), where ``I`` is the
    regularised incomplete beta function. ``I_x(a, b)`` is evaluated by its
    continued fraction (Numerical Recipes, Press et al. 2007, section 6.4, the
    one behind ``betacf``) on whichever of ``I_x(a, b)`` and
    ``I_{1-x}(b, a) = 1 - I_x(a, b)`` converges fast
    (``x < (a + 1) / (a + b + 2)``); the other follows by subtraction, so both
    the tail and the central part keep full *relative* precision (a tail of
    1e-300 is not lost to ``1 - x`` rounding). ``x`` and ``1 - x`` are formed
    separately and their logs from ``log1p``. The fraction is evaluated bottom
    up (NR section 5.2) at depths 16, 32, ... until two depths agree, with its
    odd partial denominators ``1 + d_{2m+1}`` formed without cancellation from
    ``1 - x``: at large ``df`` (``x`` within ``1/df`` of 1) the textbook
    modified-Lentz loop loses ``log10(df)`` digits (1e-4 relative error at
    ``df = 1e12``). From ``df >= 1e30`` the normal is used (equal in double
    precision). The prefactor
    ``x^a (1-x)^b / B(a, b)`` is taken in logs with ``math.lgamma``; when one
    argument of ``B`` is large (``df / 2 >= 10``) ``log B`` uses the Stirling
    series for ``lgamma(b) - lgamma(a + b)`` (A&S 6.1.40) instead of the
    difference of two huge ``lgamma`` values (which alone would cost ~1e-9
    relative accuracy at ``df = 1e6``).
``t_quantile(p, df)``
    The inverse of ``t_cdf`` for ``0 < p < 1`` and ``df >= 0.5`` (``math.inf``:
    ``statistics.NormalDist().inv_cdf``, Wichura's AS 241, 1988). By symmetry
    it solves ``P(T <= -s) = min(p, 1 - p)`` for ``s > 0``: on the log of the
    tail probability when ``p < 1/4`` and on the log of the central part
    ``1/2 - p`` otherwise (both well conditioned), by Newton's method in
    ``log s`` safeguarded by a bracket (bisection in ``log s`` whenever a step
    leaves it). It starts from the normal quantile, which is never farther out
    than the t quantile. Relative error below 1e-12 for any ``df`` (against
    scipy: at most 4e-13 over ``df`` from 0.5 to 1e13, 4e-15 on the usual
    ``p``); a quantile beyond the largest float (``df`` near 0.5 and ``p`` below
    about 1e-154) is ``-inf`` / ``inf``. Results are cached (the same few
    quantiles are asked for again and again).
``two_sided_p(z, df=inf)``
    ``P(|T| >= |z|) = 2 P(T <= -|z|)``: the two-sided p-value of a z statistic
    (``df`` infinite: ``erfc(|z| / sqrt 2)``) or of a t statistic.
``welch_df(variances, dfs)``
    The Welch-Satterthwaite effective degrees of freedom of a sum of
    independent variance estimates ``v_i``, each on ``df_i`` degrees of freedom,
    ``(sum v_i)^2 / sum(v_i^2 / df_i)`` (Satterthwaite 1946; Welch 1947): the
    ``df`` of the chi-square whose first two moments match the sum's. Terms
    with ``v_i == 0`` carry no information and are skipped (their ``df`` may be
    anything, NaN included); ``df_i = inf`` (a known variance) adds nothing to
    the denominator; no positive ``v_i`` or only known ones give ``inf``.
``holm(pvalues, alpha=0.05)``
    Holm's (1979) step-down procedure: with the ``m`` non-NaN p-values in
    ascending order ``p_(1) <= ... <= p_(m)``, reject ``H_(k)`` for
    ``k = 1, 2, ...`` while ``p_(k) <= alpha / (m - k + 1)`` and stop at the
    first that is not. It controls the family-wise error rate at ``alpha``
    under any dependence, and is uniformly more powerful than Bonferroni. NaN
    p-values (tests that could not be done) are never rejected and do not
    count in ``m``. Returns ``True`` for rejected, in the input's order.
``log_interval(center, se_log, df, confidence=0.95)``
    The Student-t interval on the log scale, back-transformed:
    ``(center exp(-q se_log), center exp(q se_log))`` with
    ``q = t_quantile((1 + confidence) / 2, df)`` -- for a positive estimate
    whose log has standard error ``se_log`` on ``df`` degrees of freedom (a
    geometric mean, a ratio, a median time). Exact coverage when
    ``log center`` is normal with ``se_log`` its usual estimate; the interval
    is multiplicative, so it never reaches zero or negative values.
``median_and_se_log(values)``
    The median of the finite positive values, the standard error of its log
    ``sqrt(pi / 2) sd(log x) / sqrt(n)`` (``sd`` with ``ddof = 1``) and ``n``.
    The log of the median is the median of the logs (for odd ``n``; the mean of
    the middle two for even ``n`` is their geometric mean, close), and the
    sample median of ``n`` normal values has asymptotic variance
    ``pi sigma^2 / (2 n)`` (``1 / (4 n f(median)^2)``; e.g. van der Vaart 1998,
    ch. 21): the median's efficiency ``2 / pi`` relative to the mean. Applied
    to the logs, so right-skewed data (timings) are handled on the log scale;
    ``sd`` is not robust, so an outlier inflates the standard error -- the
    conservative direction. With ``n < 2`` the standard error is NaN.
``robust_sd(values)``
    ``1.4826 * median(|x - median x|)``, the normal-consistent median absolute
    deviation (Hampel 1974; Rousseeuw & Croux 1993: ``1.4826 ~ 1 / Phi^-1(3/4)``)
    of the finite values; NaN for fewer than two.

References:
  M. Abramowitz & I. A. Stegun (1964), Handbook of Mathematical Functions, NBS.
  F. R. Hampel (1974), The influence curve and its role in robust estimation,
    JASA 69, 383-393.
  S. Holm (1979), A simple sequentially rejective multiple test procedure,
    Scand. J. Statist. 6, 65-70.
  W. H. Press, S. A. Teukolsky, W. T. Vetterling & B. P. Flannery (2007),
    Numerical Recipes, 3rd ed., sections 5.2 and 6.4.
  P. J. Rousseeuw & C. Croux (1993), Alternatives to the median absolute
    deviation, JASA 88, 1273-1283.
  F. E. Satterthwaite (1946), An approximate distribution of estimates of
    variance components, Biometrics Bulletin 2, 110-114.
  A. W. van der Vaart (1998), Asymptotic Statistics, Cambridge.
  B. L. Welch (1947), The generalization of "Student's" problem when several
    different population variances are involved, Biometrika 34, 28-35.
  M. J. Wichura (1988), Algorithm AS 241: the percentage points of the normal
    distribution, Applied Statistics 37, 477-484.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike

#: Normal-consistency factor of the median absolute deviation (``1 / Phi^-1(3/4)``).
MAD_SCALE = 1.4826

#: Two continued-fraction depths agreeing to this (relative) end the evaluation.
_CF_EPS = 1e-15
#: Guard against division by zero in the continued fraction.
_CF_TINY = 1e-300
#: Continued-fraction depth before giving up (the t distribution needs <= 128).
_CF_MAX_TERMS = 100_000
#: Below this ``max(a, b)`` log B(a, b) is a plain sum of ``lgamma``s.
_STIRLING_FROM = 10.0
#: Newton stops once a step in ``log s`` is below this (quadratic convergence:
#: the error after that step is far smaller).
_NEWTON_STEP_TOL = 1e-11
_MAX_ITERATIONS = 400
_LOG_MAX_FLOAT = math.log(np.finfo(np.float64).max)
#: From here on Student's t is the normal in double precision: the relative
#: difference of the two, about ``(z^4 + ...) / (4 df)``, is below 1e-25 for every
#: ``|z| < 40`` (beyond, both tails underflow).
_NORMAL_FROM = 1e30


# ---------------------------------------------------------------------------
# The regularised incomplete beta function
# ---------------------------------------------------------------------------

def _stirling_correction(x: float) -> float:
    """``lgamma(x) - ((x - 1/2) log x - x + log(2 pi) / 2)`` for ``x >= 10`` (A&S 6.1.40,
    seven terms: the first omitted one is below 4e-17 there)."""
    r = 1.0 / x
    r2 = r * r
    return r * (1.0 / 12 + r2 * (-1.0 / 360 + r2 * (1.0 / 1260 + r2 * (
        -1.0 / 1680 + r2 * (1.0 / 1188 + r2 * (-691.0 / 360360 + r2 / 156))))))


def _log_beta(a: float, b: float) -> float:
    """``log B(a, b) = lgamma(a) + lgamma(b) - lgamma(a + b)`` for ``a, b > 0``."""
    small, large = (a, b) if a <= b else (b, a)
    if large < _STIRLING_FROM:
        return math.lgamma(small) + math.lgamma(large) - math.lgamma(small + large)
    # lgamma(large) - lgamma(small + large) from Stirling's series without forming
    # the two (possibly huge, nearly equal) values themselves.
    ratio = (-small * math.log(large) - (small + large - 0.5) * math.log1p(small / large)
             + small + _stirling_correction(large) - _stirling_correction(small + large))
    return math.lgamma(small) + ratio


def _beta_continued_fraction(a: float, b: float, x: float, y: float) -> float:
    """The continued fraction of ``I_x(a, b) a B(a, b) / (x^a y^b)`` (``y = 1 - x``),
    ``1 / (1 + d_1 / (1 + d_2 / (1 + ...)))`` with ``d_{2m+1} = -(a + m)(a + b + m) x /
    ((a + 2m)(a + 2m + 1))`` and ``d_{2m} = m (b - m) x / ((a + 2m - 1)(a + 2m))``
    (Numerical Recipes 6.4); it converges fast for ``x < (a+1)/(a+b+2)``.

    Evaluated from the bottom up (``F_k = 1 + d_k / F_{k+1}``), at depths 16, 32, ...
    until two agree, rather than by the modified Lentz method: for large ``a`` and
    ``x`` near 1 (the t distribution at large ``df``) ``1 + d_{2m+1} ~ (2m + 1 - b) / a
    + y`` is a difference of nearly equal numbers that would lose ``log10(a)`` digits.
    Here it is formed from ``y`` when ``x > 1/2``, and each odd level as
    ``F_{2m+1} = ((1 + d_{2m+1}) + (F_{2m+2} - 1)) / F_{2m+2}`` with ``F_{2m+2} - 1 =
    d_{2m+2} / F_{2m+3}`` small and exact, so nothing cancels."""
    near_one = x > 0.5

    def one_plus_odd(m: int) -> float:
        """``1 + d_{2m+1}``."""
        ratio = (a + m) / (a + 2 * m) * ((a + b + m) / (a + 2 * m + 1))
        if near_one:
            # (a+2m)(a+2m+1) - (a+m)(a+b+m) = a (2m + 1 - b) + m (3m + 2 - b), exactly.
            gap = ((2 * m + 1 - b) + m * (3 * m + 2 - b) / a) / (a + 2 * m) * (a / (a + 2 * m + 1))
            return gap + ratio * y
        return 1.0 - ratio * x

    def evaluate(depth: int) -> float:
        g = 0.0  # F_{2m+2} - 1, truncated to 0 below the depth
        for m in range(depth, 0, -1):
            f_odd = (one_plus_odd(m) + g) / (1.0 + g)
            if abs(f_odd) < _CF_TINY:
                f_odd = _CF_TINY
            g = m * (b - m) / (a + 2 * m - 1) / f_odd * (x / (a + 2 * m))  # F_{2m} - 1
        f_1 = (one_plus_odd(0) + g) / (1.0 + g)
        return 1.0 / f_1 if abs(f_1) >= _CF_TINY else 1.0 / _CF_TINY

    depth = 16
    previous = evaluate(depth)
    while depth < _CF_MAX_TERMS:
        depth *= 2
        current = evaluate(depth)
        if abs(current - previous) <= _CF_EPS * abs(current):
            return current
        previous = current
    raise ArithmeticError(f"incomplete beta continued fraction did not converge "
                          f"(a={a}, b={b}, x={x})")


def _beta_inc_pair(a: float, b: float, x: float, y: float, log_x: float, log_y: float,
                   log_beta: float) -> tuple[float, float]:
    """``(I_x(a, b), I_y(b, a))`` with ``y = 1 - x`` (given separately, with both logs
    and ``log B(a, b)``, so that neither loses precision). The one whose continued
    fraction converges fast is evaluated directly, the other as its complement."""
    if log_x == -math.inf:  # x may underflow to 0 with log x still finite: that is fine
        return 0.0, 1.0
    if log_y == -math.inf:
        return 1.0, 0.0
    direct = x < (a + 1.0) / (a + b + 2.0) if x <= y else y > (b + 1.0) / (a + b + 2.0)
    log_front = a * log_x + b * log_y - log_beta
    if direct:
        ix = math.exp(log_front) * _beta_continued_fraction(a, b, x, y) / a
        return ix, 1.0 - ix
    iy = math.exp(log_front) * _beta_continued_fraction(b, a, y, x) / b
    return 1.0 - iy, iy


# ---------------------------------------------------------------------------
# Student's t
# ---------------------------------------------------------------------------

def _t_split(s: float, df: float, log_beta: float) -> tuple[float, float, float]:
    """For ``s >= 0``: ``(P(T <= -s), P(0 < T <= s), log pdf(s))``, the first two
    each to full relative precision. ``log_beta`` is ``log B(df/2, 1/2)``."""
    if s == 0.0:
        return 0.5, 0.0, -0.5 * math.log(df) - log_beta
    if math.isinf(s):
        return 0.0, 0.5, -math.inf
    # r^2 = s^2 / df; x = 1 / (1 + r^2), y = 1 - x = r^2 / (1 + r^2).
    log_r = math.log(s) - 0.5 * math.log(df)
    if log_r > 0.0:
        q = math.exp(-2.0 * log_r)  # 1 / r^2, may underflow harmlessly
        x, y = q / (1.0 + q), 1.0 / (1.0 + q)
        log_y = -math.log1p(q)
        log_x = -2.0 * log_r + log_y
    else:
        r2 = math.exp(2.0 * log_r) if log_r < -300.0 else (s / math.sqrt(df)) ** 2
        x, y = 1.0 / (1.0 + r2), r2 / (1.0 + r2)
        log_x = -math.log1p(r2)
        log_y = 2.0 * log_r + log_x
    ix, iy = _beta_inc_pair(0.5 * df, 0.5, x, y, log_x, log_y, log_beta)
    log_pdf = -0.5 * math.log(df) - log_beta + 0.5 * (df + 1.0) * log_x
    return 0.5 * ix, 0.5 * iy, log_pdf


def _check_df(df: float) -> None:
    if not df > 0.0:  # also NaN
        raise ValueError(f"degrees of freedom must be positive, got {df!r}")


def t_cdf(t: float, df: float) -> float:
    """``P(T <= t)`` for Student's t with ``df > 0`` degrees of freedom
    (``math.inf``: the standard normal); NaN ``t`` or ``df`` gives NaN."""
    if math.isnan(t) or math.isnan(df):
        return math.nan
    _check_df(df)
    if df >= _NORMAL_FROM:
        return 0.5 * math.erfc(-t / math.sqrt(2.0))
    tail, centre, _ = _t_split(abs(t), df, _log_beta(0.5 * df, 0.5))
    return tail if t < 0.0 else 0.5 + centre


def two_sided_p(z: float, df: float = math.inf) -> float:
    """``P(|T| >= |z|)``: the two-sided p-value of a t statistic on ``df`` degrees of
    freedom, or of a z statistic (``df = inf``, the default); NaN in, NaN out."""
    if math.isnan(z) or math.isnan(df):
        return math.nan
    _check_df(df)
    if df >= _NORMAL_FROM:
        return math.erfc(abs(z) / math.sqrt(2.0))
    tail, _, _ = _t_split(abs(z), df, _log_beta(0.5 * df, 0.5))
    return min(1.0, 2.0 * tail)


def t_quantile(p: float, df: float) -> float:
    """The ``p`` quantile of Student's t with ``df >= 0.5`` degrees of freedom (any
    real ``df``; ``math.inf``: the standard normal). ``0 < p < 1``, else ValueError."""
    if not 0.0 < p < 1.0:  # also NaN
        raise ValueError(f"probability must be in (0, 1), got {p!r}")
    if not df >= 0.5:  # also NaN
        raise ValueError(f"degrees of freedom must be >= 0.5, got {df!r}")
    return _t_quantile(float(p), float(df))


@functools.lru_cache(maxsize=4096)
def _t_quantile(p: float, df: float) -> float:
    if df >= _NORMAL_FROM:
        return NormalDist().inv_cdf(p)
    if p == 0.5:
        return 0.0
    if p > 0.5:
        return _t_upper(1.0 - p, df)  # 1 - p is exact for p >= 1/2
    return -_t_upper(p, df)


def _t_upper(p: float, df: float) -> float:
    """``s > 0`` with ``P(T <= -s) = p`` for ``0 < p < 1/2``."""
    log_beta = _log_beta(0.5 * df, 0.5)
    # Solve G(u) = 0 for u = log s, G increasing: the log of the central part against
    # log(1/2 - p) near the centre, of the tail against log p (sign flipped) beyond.
    centre_mode = p > 0.25
    log_target = math.log(0.5 - p) if centre_mode else math.log(p)

    def objective(u: float) -> tuple[float, float]:
        s = math.exp(u)
        tail, centre, log_pdf = _t_split(s, df, log_beta)
        value = centre if centre_mode else tail
        if value <= 0.0:
            return (-math.inf if centre_mode else math.inf), math.nan
        log_value = math.log(value)
        g = log_value - log_target if centre_mode else log_target - log_value
        return g, math.exp(u + log_pdf - log_value)  # d log(value) / d log s, > 0

    # The normal quantile is never beyond the t quantile: start there.
    u = math.log(-NormalDist().inv_cdf(p))
    lo, hi = -math.inf, math.inf  # bracket on u: G(lo) < 0 < G(hi)
    expand = 1.0
    for _ in range(_MAX_ITERATIONS):
        g, slope = objective(u)
        if g == 0.0:
            return math.exp(u)
        if g < 0.0:
            lo = u
        else:
            hi = u
        step = -g / slope if slope > 0.0 and math.isfinite(slope) else math.nan
        new = u + step
        if not lo < new < hi:  # Newton failed or left the bracket
            if math.isinf(hi):  # no upper end yet: step out, further each time
                new, expand = lo + expand, 2.0 * expand
            elif math.isinf(lo):
                new, expand = hi - expand, 2.0 * expand
            else:
                new = 0.5 * (lo + hi)
        elif abs(step) < _NEWTON_STEP_TOL:
            return math.exp(new)
        if new > _LOG_MAX_FLOAT:
            if lo >= _LOG_MAX_FLOAT:
                return math.inf  # G < 0 at the largest float: the quantile is beyond
            new = _LOG_MAX_FLOAT
        if new == u or hi - lo < 1e-15:
            return math.exp(new)
        u = new
    raise ArithmeticError(f"t quantile did not converge (p={p}, df={df})")


# ---------------------------------------------------------------------------
# Degrees of freedom, multiple tests, intervals
# ---------------------------------------------------------------------------

def welch_df(variances: Sequence[float] | ArrayLike, dfs: Sequence[float] | ArrayLike
             ) -> float:
    """Welch-Satterthwaite degrees of freedom ``(sum v)^2 / sum(v^2 / df)`` of a sum of
    independent variance estimates ``v`` on ``df`` degrees of freedom each (``v == 0``
    skipped, ``df = inf`` allowed; none left: ``inf``). NaN in a used term gives NaN;
    negative variances, non-positive ``df`` or unequal lengths raise ValueError."""
    v = np.asarray(variances, dtype=np.float64)
    d = np.asarray(dfs, dtype=np.float64)
    if v.ndim != 1 or v.shape != d.shape:
        raise ValueError(f"variances and dfs must be 1-D of one length, got shapes "
                         f"{v.shape} and {d.shape}")
    if np.any(v < 0):
        raise ValueError("variances must be non-negative")
    used = v != 0  # NaN variances stay (NaN != 0)
    v, d = v[used], d[used]
    if v.size == 0:
        return math.inf
    if np.any(np.isnan(v)) or np.any(np.isnan(d)):
        return math.nan
    if np.any(d <= 0):
        raise ValueError("degrees of freedom must be positive")
    if np.any(np.isinf(v)):
        return math.nan
    w = v / v.max()  # scale out: no overflow or underflow in the squares
    denominator = float(np.sum(w * w / d))
    return float(np.sum(w)) ** 2 / denominator if denominator > 0 else math.inf


def holm(pvalues: Sequence[float] | ArrayLike, alpha: float = 0.05) -> list[bool]:
    """Holm-Bonferroni step-down rejections (``True`` = rejected) at family-wise level
    ``alpha``, in the input's order; NaN p-values are never rejected and not counted."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    p = np.asarray(pvalues, dtype=np.float64)
    if p.ndim != 1:
        raise ValueError(f"p-values must be 1-D, got shape {p.shape}")
    valid = np.flatnonzero(~np.isnan(p))
    if np.any((p[valid] < 0) | (p[valid] > 1)):
        raise ValueError("p-values must be in [0, 1]")
    rejected = [False] * p.size
    m = valid.size
    for k, index in enumerate(valid[np.argsort(p[valid], kind="stable")]):
        if not p[index] <= alpha / (m - k):
            break
        rejected[int(index)] = True
    return rejected


def log_interval(center: float, se_log: float, df: float, confidence: float = 0.95
                 ) -> tuple[float, float]:
    """``(center exp(-q se_log), center exp(q se_log))``, ``q`` Student's t quantile at
    ``(1 + confidence) / 2`` on ``df`` degrees of freedom. NaN when ``center`` is not
    finite and positive or ``se_log`` or ``df`` is NaN; ``(center, center)`` when
    ``se_log == 0``."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if not (math.isfinite(center) and center > 0) or math.isnan(se_log):
        return math.nan, math.nan
    if se_log < 0:
        raise ValueError(f"standard error must be non-negative, got {se_log!r}")
    if se_log == 0:
        return center, center
    if math.isnan(df):
        return math.nan, math.nan
    half = t_quantile(0.5 * (1.0 + confidence), df) * se_log
    return center * math.exp(-half), center * math.exp(half)


def _finite(values: ArrayLike) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64).ravel()
    return x[np.isfinite(x)]


def median_and_se_log(values: Sequence[float] | ArrayLike) -> tuple[float, float, int]:
    """The median of the finite positive ``values``, the standard error of its log
    ``sqrt(pi/2) sd(log x, ddof=1) / sqrt(n)`` (NaN for ``n < 2``) and their number
    ``n`` (other values are ignored; none: NaN median)."""
    x = _finite(values)
    x = x[x > 0]
    n = int(x.size)
    if n == 0:
        return math.nan, math.nan, 0
    median = float(np.median(x))
    if n < 2:
        return median, math.nan, n
    sd = float(np.std(np.log(x), ddof=1))
    return median, math.sqrt(0.5 * math.pi) * sd / math.sqrt(n), n


def robust_sd(values: Sequence[float] | ArrayLike) -> float:
    """``1.4826 * median |x - median x|`` of the finite ``values`` (NaN for fewer than 2)."""
    x = _finite(values)
    if x.size < 2:
        return math.nan
    return MAD_SCALE * float(np.median(np.abs(x - np.median(x))))


__all__ = ["MAD_SCALE", "holm", "log_interval", "median_and_se_log", "robust_sd", "t_cdf",
           "t_quantile", "two_sided_p", "welch_df"]
