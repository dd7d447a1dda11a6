"""``mcrt check``: the statistics, on :mod:`.integrate`'s integrands (values I known).

* **unbiasedness**: P pixels of N = 16 samples (calls ``2d, 1d, 2d, 2d``) are P
  trials of each integrand on the film call, on call 4, and of the products
  f(call a) f(call b) of every pair of the 2D calls 1, 3, 4 (value I^2 only if
  the dimensions are independent, as a path integrand needs: Mitsuba's
  ``ldsampler`` gives every dimension of a pixel the same points reordered, and
  fails; a sampler whose dimension 2 repeats dimension 0, call 3 = call 1, gives
  E[f^2] = I for an indicator, +99% on the disk, and passed when only calls 1 x 4
  were tested; Mitsuba's ``stratified`` pairs the strata of consecutive dimensions
  (Kensler permutations with seeds d and d + 1): calls 3 x 4 -3.6% on the
  gaussian, t ~ -14, and the same -3.4% on any two consecutive 2D dimensions
  seen directly, seeds 3, 4), and of the 1D call's mean (1/2) and
  share below 1/3 (:data:`ONE_D_TERMS`: BSDF lobes and Russian roulette draw
  1D samples). t of the mean on P - 1 degrees of
  freedom, Holm's step-down at family-wise ``ALPHA = 1e-3``. Power: a bias b is
  found with probability >= 0.999 once ``|b| >= (t_{1-ALPHA/2m} + t_{0.999}) se``
  (~7 se, m = 17); the detail prints the largest over the tests, relative to the
  value: 2.6% at P = 16384 (10.5% quick) for independent points, 2% (8%) for
  jittered; points in [0, 0.9) bias the disk by +23% (t > 10). Pixels sharing T
  unshifted table sets (pointset, randomize none/symmetry) share the table's
  error: ``se^2 = sd^2 (1/P + 1/T)``, for a product of calls a and b
  ``sd^2 / P + I^2 (sd_a + sd_b)^2 / T`` (both calls see the one table's error),
  and t has ``min(P, T) - 1`` degrees of freedom (the SDs behind the table's
  error come from T sets: with T = 16 and P - 1 the false alarms were ~0.9%, not
  0.1%). At a larger N, P is capped so that
  ``P N <= unbiased_lanes`` (16384 x 64; quick 1024 x 64).

  A sampler that claims **quadrature** (``uniform_grid``: film positions at the
  cell centres, on purpose) has a film estimate with no sampling error and a
  bias by design. Its terms that involve the film call (f(call 1) and the
  product f(call 1) f(call 4)) are reported in the detail as information, not
  tested; every term that does not is tested: f(call 4), the 1D terms and
  f(call 3) f(call 4) (m = 8). The claim lets off the film alone:
  a sampler biased in the other dimensions still fails.
* **mse_rate**: MSE against N (run_convergence, fresh seeds per N), slope by
  fit_slope (se: each point's ln MSE variance at least Gaussian errors', the
  whole scaled by sqrt(chi2/dof) > 1): pass if ``slope <= -1 + 0.1 + 3 se``
  on every integrand (independent points' rate), and ``<= -1.3 + 3 se`` on the
  disk for a stratified / net / min_distance claim (the variance suite's bound
  on the N^-1.5 of edges [Mitchell 1996]). A sampler that serves only some
  counts is fitted over those in the budget's range; fewer than
  :data:`MIN_RATE_COUNTS` skip the check.
* **discrepancy** (mean L2-star D^2 over independent points' ``(1/4 - 1/9) / N``
  [Warnock 1972]) and **spectrum** (mean power at 0 < f < 0.5, white noise 1):
  se from the pixels; pass if ``<= 1 + 0.1 + 4 se`` (informative). Both cost
  ~N^2 per pixel: at a larger N, P is capped so that ``P N^2 <= pattern_pairs``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import patterns
from .check import (
    Budget,
    Check,
    CheckResult,
    Subject,
    Unsupported,
    draw,
    lanes,
    outside,
    table_sets,
)
from .integrate import INTEGRANDS, Convergence, Integrand, run_convergence
from .significance import holm, t_quantile, two_sided_p

UNBIASED_CALLS: tuple[str, ...] = ("2d", "1d", "2d", "2d")
ALPHA, POWER = 1e-3, 0.999
RATE_MARGIN, RATE_SIGMAS, STRATIFIED_DISK_SLOPE = 0.1, 3.0, -1.3
MIN_RATE_COUNTS = 3
PATTERN_MARGIN, PATTERN_SIGMAS = 0.1, 4.0
#: Fewest pixels a capped budget leaves (unbiasedness, patterns).
MIN_PIXELS = 8


def _t_test(values: np.ndarray, exact: float, sets: int | None,
            table_sd: float | None = None) -> tuple[float, float, float]:
    """Relative bias, its standard error and t of per-pixel estimates (module doc);
    ``table_sd`` is the SD that carries a shared table's error when it is not the
    pixels' own (a product of two calls, :func:`_terms`)."""
    bias = float(np.mean(values)) - exact
    sd = float(np.std(values, ddof=1))
    table = sd if table_sd is None else table_sd
    se = math.sqrt(sd * sd / values.size + (table * table / sets if sets else 0.0))
    se *= float(np.ptp(values) > 1e-12 * max(1.0, abs(exact)))  # 0: deterministic
    t = bias / se if se > 0 else 0.0 if abs(bias) <= 1e-9 else math.copysign(math.inf, bias)
    return bias / exact, se / abs(exact), t


#: Per term: the values at each point (P, N), the integral, and the SD of its table
#: error (None: the pixels' own SD).
Terms = dict[str, tuple[np.ndarray, float, float | None]]


def _terms(g: Integrand, film: np.ndarray, third: np.ndarray, last: np.ndarray,
           quadrature: bool) -> tuple[Terms, Terms]:
    """Values of integrand ``g`` at each point ``(P, N)`` of calls 1, 3 and 4, and
    their integral, by term: (tested, reported only). Products of every pair of the
    three 2D calls. A quadrature sampler's film terms are reported (module doc).

    Both calls of a product draw their sets from one shared table, whose mean
    ``I + e`` they both see: the product's table error is ``2 I e`` to first order,
    so its SD is at most ``|I| (sd_a + sd_b)`` with ``sd`` each call's per-pixel SD
    (the pixels' own SD of the product is smaller: t's SD was 1.2-1.3, not 1)."""
    f0, f2, f3 = (g.function(c[..., 0], c[..., 1]) for c in (film, third, last))
    sd = {id(f): float(np.std(f.mean(axis=1), ddof=1)) for f in (f0, f2, f3)}

    def product_of(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, float]:
        return a * b, g.exact ** 2, abs(g.exact) * (sd[id(a)] + sd[id(b)])

    own, product, first = g.name, f"{g.name} call 1 x 4", f"{g.name} call 1 x 3"
    terms: Terms = {own: (f0, g.exact, None), f"{g.name} call 4": (f3, g.exact, None),
                    first: product_of(f0, f2), product: product_of(f0, f3),
                    f"{g.name} call 3 x 4": product_of(f2, f3)}
    if not quadrature:
        return terms, {}
    return terms, {key: terms.pop(key) for key in (own, product, first)}


#: The 1D call's tests: (name, function of u, its integral over [0, 1)). The
#: mean alone passes a sampler that returns 1/2 every time; the share below 1/3
#: tests the distribution too.
ONE_D_TERMS: tuple[tuple[str, Any, float], ...] = (
    ("u call 2", lambda u: u, 0.5),
    ("u < 1/3 call 2", lambda u: (u < 1.0 / 3.0).astype(np.float64), 1.0 / 3.0))


def check_unbiasedness(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n = subject.count(budget.unbiased_spp)
    pixels = min(budget.unbiased_pixels, max(MIN_PIXELS, budget.unbiased_lanes // n))
    sampler = subject.seeded(n, pixels, seed)
    sets, n = table_sets(sampler), sampler.sample_count()
    calls = draw(sampler, lanes(sampler, pixels), UNBIASED_CALLS)
    bad = [f"call {i + 1} (next_{UNBIASED_CALLS[i]}): {outside(c)}"
           for i, c in enumerate(calls) if outside(c)]
    if bad:  # a NaN makes every mean NaN ("bias +nan%"): say what is wrong instead
        return CheckResult("unbiasedness", False, "not tested", f"{pixels} px x {n} spp: "
                           + "; ".join(bad) + ": not a sampler's values (see range)")
    first, second, third, last = (c.reshape(pixels, n, -1) for c in calls)
    u = second[..., 0]
    tests = {name: _t_test(f(u).mean(axis=1), exact, sets) for name, f, exact in ONE_D_TERMS}
    film: dict[str, tuple[float, float, float]] = {}
    for g in INTEGRANDS.values():
        tested, info = _terms(g, first, third, last, "quadrature" in subject.info.claims)
        tests.update({k: _t_test(f.mean(axis=1), v, sets, table)
                      for k, (f, v, table) in tested.items()})
        film.update({k: _t_test(f.mean(axis=1), v, sets, table)
                     for k, (f, v, table) in info.items()})
    # A shared table of T sets: the SDs behind its error come from T sets, not P pixels.
    dof = pixels - 1 if sets is None else min(pixels, sets) - 1
    p = [two_sided_p(t, dof) if math.isfinite(t) else 0.0 for _, _, t in tests.values()]
    rejected = holm(p, ALPHA)
    limit = t_quantile(1 - ALPHA / (2 * len(p)), dof)
    detectable = (limit + t_quantile(POWER, dof)) * max(s for _, s, _ in tests.values())
    flagged = [f"{k}: bias {b:+.2%} (t = {t:+.3g}{', no sampling error' if s == 0 else ''})"
               for (k, (b, s, t)), r in zip(tests.items(), rejected, strict=True) if r]
    products = [" x " in k for k, r in zip(tests, rejected, strict=True) if r]
    if products and all(products):  # each call alone is unbiased
        flagged.append("only products of two calls: the dimensions are not independent")
    detail = ("biased: " + "; ".join(flagged) if flagged else
              "t " + ", ".join(f"{k} {t:+.1f}" for k, (_, _, t) in tests.items())
              + f"; |t| > {limit:.2f} fails, biases above {detectable:.1%} are found")
    if film:
        detail += ("; film terms (quadrature, biased by design, not tested): "
                   + ", ".join(f"{k} {b:+.2%}" for k, (b, _, _) in film.items()))
    worst = max(abs(t) for _, _, t in tests.values())
    values: dict[str, Any] = {k: {"relative_bias": b, "t": t, "p": q, "tested": True}
                              for (k, (b, _, t)), q in zip(tests.items(), p, strict=True)}
    values.update({k: {"relative_bias": b, "t": t, "p": None, "tested": False}
                   for k, (b, _, t) in film.items()})
    return CheckResult("unbiasedness", not flagged, f"max |t| {worst:.3g}",
                       f"{pixels} px x {n} spp, Holm alpha {ALPHA:g}: {detail}", values=values)


def rate_counts(subject: Subject, budget: Budget) -> tuple[int, ...]:
    """The counts of the rate: the budget's, or the served ones in its range
    (Unsupported if fewer than :data:`MIN_RATE_COUNTS`)."""
    if subject.served is None:
        return budget.rate_counts
    low, high = budget.rate_counts[0], budget.rate_counts[-1]
    inside = tuple(c for c in subject.served if low <= c <= high)
    if len(inside) < MIN_RATE_COUNTS:
        raise Unsupported(f"{subject.name} serves N = {', '.join(map(str, subject.served))}: "
                          f"{len(inside)} in {low}..{high}, a rate needs {MIN_RATE_COUNTS}")
    return inside


def convergence(subject: Subject, budget: Budget, seed: int = 0) -> dict[str, Convergence]:
    """MSE of every integrand at each of the rate's counts (fresh seed per count)."""
    out = {name: Convergence(subject.name, name) for name in INTEGRANDS}
    for index, n in enumerate(rate_counts(subject, budget)):
        for name, conv in run_convergence(
                subject.name, INTEGRANDS, [n], max_trials=budget.rate_trials,
                budget=budget.rate_budget, seed=seed + index, timed=False,
                **subject.params(n)).items():
            out[name].points += conv.points
            out[name].skipped += conv.skipped
    return out


def check_mse_rate(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    conv = convergence(subject, budget, seed)
    strict = bool(subject.info.claims & {"stratified", "net", "min_distance"})
    parts, failed, values = [], [], {}
    for name, c in conv.items():
        fit = c.fit()
        if fit.points < MIN_RATE_COUNTS:
            raise Unsupported(f"{subject.name} makes {fit.points} of N = "
                              f"{', '.join(map(str, rate_counts(subject, budget)))}, a rate "
                              f"needs {MIN_RATE_COUNTS}")
        se = fit.stderr_scaled if math.isfinite(fit.stderr_scaled) else 0.0
        limit = -1.0 + RATE_MARGIN + RATE_SIGMAS * se
        if name == "disk" and strict:
            limit = min(limit, STRATIFIED_DISK_SLOPE + RATE_SIGMAS * se)
        parts.append(f"{name} {fit.slope:+.2f} (se {se:.2f}, <= {limit:+.2f})")
        values[name] = {"slope": fit.slope, "stderr": se, "limit": limit}
        if not fit.slope <= limit:
            failed.append(name)
    counts = sorted({p.n for c in conv.values() for p in c.points})
    slopes = " / ".join(f"{v['slope']:+.2f}" for v in values.values())
    return CheckResult("mse_rate", not failed, slopes, f"MSE ~ N^slope, N = {counts[0]}.."
                       f"{counts[-1]}: " + ", ".join(parts)
                       + (f"; too slow: {', '.join(failed)}" if failed else ""),
                       values=values, data={"convergence": conv})


def _relative(name: str, samples: np.ndarray, expected: float, what: str,
              data: dict[str, Any]) -> CheckResult:
    ratio = float(np.mean(samples)) / expected
    se = float(np.std(samples, ddof=1)) / math.sqrt(len(samples)) / expected
    limit = 1.0 + PATTERN_MARGIN + PATTERN_SIGMAS * se
    return CheckResult(name, ratio <= limit, f"{ratio:.3g} x iid",
                       f"{what} {ratio:.3g} x independent points' (se {se:.2g}, <= {limit:.3g})",
                       values={"ratio": ratio, "stderr": se, "limit": limit}, data=data)


def _pattern_points(subject: Subject, budget: Budget, seed: int) -> np.ndarray:
    """Film points of the pattern checks, ``(P, N, 2)`` at the budget's count."""
    n = subject.count(budget.pattern_spp)
    pixels = min(budget.pattern_pixels, max(MIN_PIXELS, budget.pattern_pairs // (n * n)))
    return subject.points(pixels, n, seed=seed)


def check_discrepancy(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    pts = _pattern_points(subject, budget, seed)
    d2 = np.atleast_1d(patterns.l2_star_discrepancy(pts, squared=True))
    return _relative("discrepancy", d2, (1 / 4 - 1 / 9) / pts.shape[1],
                     f"L2-star D^2, N = {pts.shape[1]}, {len(pts)} px:", {"points": pts[:2]})


def check_spectrum(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    pts = _pattern_points(subject, budget, seed)
    n, kmax = pts.shape[1], patterns.default_kmax(pts.shape[1])
    spectra = [patterns.power_spectrum(p, kmax) for p in pts]
    low = np.array([patterns.low_frequency_power(patterns.radial_spectrum(s, n)) for s in spectra])
    if np.isnan(low).all():  # the first ring's f = 1 / sqrt(N) is 0.5 or more
        raise Unsupported(f"N = {n} has no frequency 0 < f < 0.5 (the lowest is 1 / sqrt(N)): "
                          f"check at --spp 5 or more for a spectrum")
    radial = patterns.radial_spectrum(np.mean(spectra, axis=0), n, len(pts))
    return _relative("spectrum", low, 1.0, f"power at 0 < f < 0.5, N = {n}:", {"radial": radial})


STATISTICS: tuple[Check, ...] = (check_unbiasedness, check_mse_rate, check_discrepancy,
                                 check_spectrum)
