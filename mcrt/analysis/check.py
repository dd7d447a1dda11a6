"""``mcrt check``: the variance-comparison suite as plain functions, for any sampler.

Each ``check_*`` function tests one property of a registered sampler (mcrt's,
Mitsuba's or a user's) and returns a :class:`CheckResult`; :func:`run_checks`
runs those that apply. Seeds are fixed: a result is a function of (sampler,
seed, budget) and never flakes.

Contract, through Mitsuba's interface as a render drives it (wavefront of
``pixels * N`` lanes, the calls :data:`CALLS`): **determinism** (two fresh
instances, same seed: same bits), **range** (finite, in [0, 1)), **clone** (made
mid-stream after ``advance()``: the same values), **fork** (reseeded: what a
fresh instance draws), **seeding** (another seed changes every call: at most
half of the lanes keep a value; a permuted grid keeps ~1/N, a seed-blind call all).

Claims (registry.CLAIMS, those made), exactly, on real pixels' points in
dimensions 0 and 2: **stratified** (N = 16, 64: one point per k x k cell),
**latin** (one per column and row), **net** (N = 16, 64, 256: one point per
elementary interval 2^-i x 2^-(m-i), all i), **min_distance** (N = 64, 256:
toroidal rho >= 0.75), **progressive** (the first 16 of 64 samples are the 16
samples). A point within :data:`EDGE_TOL` of a border counts for either cell
(float32 rounding of ``(cell + u) / k``): a set passes if its points can be
matched one to a cell (:func:`one_per_cell`).

Statistics, on :mod:`.integrate`'s integrands (values I known):

* **unbiasedness**: P pixels of N = 16 samples (calls ``2d, 1d, 2d, 2d``) are P
  trials of each integrand on the film call, on call 4, and of the product
  f(call 1) f(call 4) (value I^2 only if the dimensions are independent, as a
  path integrand needs: Mitsuba's ``ldsampler`` gives every dimension of a pixel
  the same points reordered, and fails). t of the mean on P - 1 degrees of
  freedom, Holm's step-down at family-wise ``ALPHA = 1e-3``. Power: a bias b is
  found with probability >= 0.999 once ``|b| >= (t_{1-ALPHA/2m} + t_{0.999}) se``
  (~7 se, m = 9); the detail prints the largest over the tests, relative to the
  value: 2.5% at P = 16384 (10% quick) for independent points, 2% (8%) for
  jittered; points in [0, 0.9) bias the disk by +23% (t > 10). Pixels sharing T
  unshifted table sets (pointset, randomize none/symmetry) share the table's
  error: ``se^2 = sd^2 (1/P + 1/T)``.
* **mse_rate**: MSE against N (run_convergence, fresh seeds per N), slope by
  fit_slope (se scaled by sqrt(chi2/dof)): pass if ``slope <= -1 + 0.1 + 3 se``
  on every integrand (independent points' rate), and ``<= -1.3 + 3 se`` on the
  disk for a stratified / net / min_distance claim (the variance suite's bound
  on the N^-1.5 of edges [Mitchell 1996]).
* **discrepancy** (mean L2-star D^2 over independent points' ``(1/4 - 1/9) / N``
  [Warnock 1972]) and **spectrum** (mean power at 0 < f < 0.5, white noise 1):
  se from the pixels; pass if ``<= 1 + 0.1 + 4 se`` (informative).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mitsuba as mi
import numpy as np

from ..core.sampling import check_sampler_name, make_sampler, quiet_sampler_warnings
from ..errors import SamplerError
from ..samplers import registry
from ..samplers.points import point_sets
from . import patterns
from .integrate import INTEGRANDS, Convergence, run_convergence
from .significance import holm, t_quantile, two_sided_p

CALLS: tuple[str, ...] = ("2d", "1d", "1d", "2d", "2d", "1d")
UNBIASED_CALLS: tuple[str, ...] = ("2d", "1d", "2d", "2d")
MAX_KEPT_SHARE = 0.5
EDGE_TOL = 2.0 ** -20  # 16 float32 ulps of 1; cell borders here are >= 2^-8 apart
CLAIM_DIMENSIONS = (0, 2)
ALPHA, POWER = 1e-3, 0.999
RATE_MARGIN, RATE_SIGMAS, STRATIFIED_DISK_SLOPE = 0.1, 3.0, -1.3
PATTERN_MARGIN, PATTERN_SIGMAS = 0.1, 4.0


@dataclass(frozen=True)
class CheckResult:
    """One property. ``skipped``: the sampler refuses the counts the check needs
    (not a failure); ``values``: numbers for JSON; ``data``: what the report draws."""

    name: str
    passed: bool
    figure: str
    detail: str
    skipped: bool = False
    values: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    data: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def status(self) -> str:
        return "skip" if self.skipped else "pass" if self.passed else "FAIL"


@dataclass(frozen=True)
class Budget:
    """Work per check; pixels are the independent trials."""

    contract_pixels: int = 16    # at contract_spp; range: 16x the pixels
    contract_spp: int = 16
    claim_pixels: int = 64       # point sets per count and dimension
    unbiased_pixels: int = 16384  # at N = 16
    rate_counts: tuple[int, ...] = (16, 64, 256, 1024, 4096, 16384)
    rate_trials: int = 1024
    rate_budget: int = 1 << 22   # points per count: trials = min(rate_trials, budget / N)
    pattern_spp: int = 256
    pattern_pixels: int = 128


FULL = Budget()
QUICK = Budget(contract_pixels=8, claim_pixels=16, unbiased_pixels=1024,
               rate_counts=(16, 64, 256, 1024), rate_trials=256, rate_budget=1 << 18,
               pattern_spp=64, pattern_pixels=32)


class Unsupported(SamplerError):
    """The sampler cannot be made at a count a check needs (the check is skipped)."""


class Subject:
    """The sampler under check; the registry's example parameters for each count
    fill in what it needs outside a render (zsobol's width, pointset's file)."""

    def __init__(self, name: str, params: dict[str, Any] | None = None) -> None:
        self.name = check_sampler_name(name)
        self.info = registry.info(self.name)
        self.user = dict(params or {})

    def params(self, spp: int) -> dict[str, Any]:
        return {**self.info.example_params(spp), **self.user}

    def make(self, spp: int) -> mi.Sampler:
        try:
            with quiet_sampler_warnings():
                return make_sampler(self.name, spp, **self.params(spp))
        except SamplerError as error:
            raise Unsupported(str(error)) from None

    def seeded(self, spp: int, pixels: int, seed: int) -> mi.Sampler:
        sampler = self.make(spp)
        sampler.set_samples_per_wavefront(sampler.sample_count())
        sampler.seed(seed, pixels * sampler.sample_count())  # type: ignore[arg-type]
        return sampler

    def points(self, pixels: int, spp: int, dimension: int = 0, ndim: int = 2,
               seed: int = 0) -> np.ndarray:
        """Points of pixels 0..P-1 as rendered, float64 ``(P, N, ndim)``."""
        with quiet_sampler_warnings():
            return point_sets(self.make(spp), pixels, spp, dimension=dimension, ndim=ndim,
                              seed=seed).astype(np.float64)


def draw(sampler: mi.Sampler, calls: tuple[str, ...] = CALLS) -> list[np.ndarray]:
    """Values of ``calls`` ("1d"/"2d") as float64 ``(lanes, 1 or 2)`` arrays."""
    return [np.array(sampler.next_2d(), dtype=np.float64).T if call == "2d"
            else np.array(sampler.next_1d(), dtype=np.float64).reshape(-1, 1) for call in calls]


def _same(name: str, a: list[np.ndarray], b: list[np.ndarray], what: str) -> CheckResult:
    diff = [f"call {i + 1} ({CALLS[i]}): {np.mean(x != y):.0%} of values differ"
            if x.shape == y.shape else f"call {i + 1}: {len(x)} vs {len(y)} lanes"
            for i, (x, y) in enumerate(zip(a, b)) if not np.array_equal(x, y, equal_nan=True)]
    same = f"the same bits in {len(a)} calls ({', '.join(CALLS)}) of {len(a[0])} lanes"
    return CheckResult(name, not diff, f"{len(a) - len(diff)}/{len(a)} calls equal",
                       f"{what}: {'; '.join(diff) or same}")


def check_determinism(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = budget.contract_spp, budget.contract_pixels
    return _same("determinism", draw(subject.seeded(n, pixels, seed)),
                 draw(subject.seeded(n, pixels, seed)), f"two fresh instances, seed {seed}")


def check_range(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    values = draw(subject.seeded(budget.contract_spp, 16 * budget.contract_pixels, seed))
    bad = [f"call {i + 1} ({CALLS[i]}): {np.count_nonzero(out)} values outside [0, 1), e.g. "
           f"{v[out][0]!r}" for i, v in enumerate(values)
           if (out := ~(np.isfinite(v) & (v >= 0.0) & (v < 1.0))).any()]
    low, high = (float(f([f(v) for v in values])) for f in (np.nanmin, np.nanmax))
    detail = "; ".join(bad) or f"{sum(v.size for v in values)} values: finite, in [0, 1)"
    return CheckResult("range", not bad, f"[{low:.2g}, 1 - {1 - high:.2g}]", detail,
                       values={"min": low, "max": high})


def check_clone(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    sampler = subject.seeded(budget.contract_spp, budget.contract_pixels, seed)
    draw(sampler, CALLS[:3])
    sampler.advance()
    draw(sampler, CALLS[:1])
    twin = sampler.clone()
    return _same("clone", draw(sampler), draw(twin), "a clone after 3 calls, advance(), 1 call")


def check_fork(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = budget.contract_spp, budget.contract_pixels
    sampler = subject.seeded(n, pixels, seed)
    draw(sampler, CALLS[:2])  # mid-stream
    fresh = sampler.fork()
    other = (seed + 1) % (1 << 32)
    fresh.set_samples_per_wavefront(fresh.sample_count())
    fresh.seed(other, pixels * fresh.sample_count())  # type: ignore[arg-type]
    return _same("fork", draw(fresh), draw(subject.seeded(n, pixels, other)),
                 f"a fork reseeded with {other} vs a fresh instance")


def check_seeding(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = budget.contract_spp, budget.contract_pixels
    other = (seed + 1) % (1 << 32)
    a, b = (draw(subject.seeded(n, pixels, s)) for s in (seed, other))
    kept = [float(np.mean(np.all(x == y, axis=1))) for x, y in zip(a, b)]
    stuck = [f"call {i + 1} ({CALLS[i]}) keeps {k:.0%} of its values"
             for i, k in enumerate(kept) if k > MAX_KEPT_SHARE]
    detail = "; ".join(stuck) or f"every call changes (<= {max(kept):.1%} of lanes keep a value)"
    return CheckResult("seeding", not stuck, f"max {max(kept):.0%} kept",
                       f"seeds {seed} and {other}: {detail}", values={"kept": kept})


# --------------------------------------------------------------------------- claims

def one_per_cell(points: np.ndarray, nx: int, ny: int, tol: float = EDGE_TOL) -> np.ndarray:
    """Per set of ``points`` ``(B, N, 2)``: can its points be given one to each cell
    of an ``nx x ny`` grid, each to a cell it lies in or within ``tol`` of?"""
    b, n, _ = points.shape
    if n != nx * ny:
        return np.zeros(b, dtype=bool)
    ix = np.clip(np.floor(points[..., 0] * nx), 0, nx - 1).astype(np.int64)
    iy = np.clip(np.floor(points[..., 1] * ny), 0, ny - 1).astype(np.int64)
    flat = (np.arange(b)[:, None] * n + iy * nx + ix).ravel()
    ok = np.all(np.bincount(flat, minlength=b * n).reshape(b, n) == 1, axis=1)
    for row in np.flatnonzero(~ok):  # rare: points on a border
        ok[row] = _matched(points[row], nx, ny, tol)
    return ok


def _matched(points: np.ndarray, nx: int, ny: int, tol: float) -> bool:
    """A perfect matching of points to cells: points off every border keep their
    cell, those near one take a free cell they touch."""
    def near(v: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        return (np.clip(np.floor((v - tol) * k), 0, k - 1).astype(np.int64),
                np.clip(np.floor((v + tol) * k), 0, k - 1).astype(np.int64))
    (lx, hx), (ly, hy) = near(points[:, 0], nx), near(points[:, 1], ny)
    border = (lx != hx) | (ly != hy)
    fixed = (ly * nx + lx)[~border]
    if not border.any() or np.unique(fixed).size < fixed.size:
        return False
    taken = set(fixed.tolist())
    loose = [sorted({int(i + nx * j) for i in (lx[p], hx[p]) for j in (ly[p], hy[p])} - taken)
             for p in np.flatnonzero(border)]
    owner: dict[int, int] = {}

    def place(p: int, seen: set[int]) -> bool:  # Kuhn: depth <= border points
        for c in loose[p]:
            if c not in seen:
                seen.add(c)
                if c not in owner or place(owner[c], seen):
                    owner[c] = p
                    return True
        return False
    return all(place(p, set()) for p in range(len(loose)))


def _claim_sets(subject: Subject, budget: Budget, seed: int, counts: tuple[int, ...],
                fits: Callable[[int], bool]) -> list[tuple[int, int, np.ndarray]]:
    """``(N, dimension, points)`` for the sampler's count for each of ``counts``
    that ``fits``, in the claim dimensions (Unsupported if none fits)."""
    usable = sorted({n for n in (subject.make(c).sample_count() for c in counts) if fits(n)})
    if not usable:
        raise Unsupported(f"{subject.name} makes no count the claim needs from {counts}")
    return [(n, d, subject.points(budget.claim_pixels, n, dimension=d, seed=seed))
            for n in usable for d in CLAIM_DIMENSIONS]


def _grid_claim(name: str, subject: Subject, budget: Budget, seed: int, counts: tuple[int, ...],
                grids: Callable[[int], list[tuple[int, int]]]) -> CheckResult:
    sets = _claim_sets(subject, budget, seed, counts, lambda n: bool(grids(n)))
    bad, off, total = [], 0, 0
    for n, dim, pts in sets:
        for nx, ny in grids(n):
            wrong = int(np.count_nonzero(~one_per_cell(pts, nx, ny)))
            off, total = off + wrong, total + len(pts)
            if wrong:
                bad.append(f"N={n} dim {dim} {nx}x{ny}: {wrong}/{len(pts)} sets")
    where = f"N = {sorted({s[0] for s in sets})}, dims {CLAIM_DIMENSIONS}, {len(sets[0][2])} px"
    detail = "; ".join(bad[:6]) + " not one point per cell" if bad else "one point per cell"
    return CheckResult(name, not bad, f"{off}/{total} sets off", f"{where}: {detail}",
                       values={"sets_off": off, "sets": total})


def check_stratified(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    return _grid_claim("stratified", subject, budget, seed, (16, 64),
                       lambda n: [(k, k)] if (k := math.isqrt(n)) ** 2 == n else [])


def check_latin(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    return _grid_claim("latin", subject, budget, seed, (16, 64), lambda n: [(n, 1), (1, n)])


def check_net(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    def shapes(n: int) -> list[tuple[int, int]]:  # 2^i x 2^(m-i) cells, i = 0..m
        m = n.bit_length() - 1
        return [(1 << i, 1 << (m - i)) for i in range(m + 1)] if n == 1 << m else []
    return _grid_claim("net", subject, budget, seed, (16, 64, 256), shapes)


def check_min_distance(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    bad, worst = [], math.inf
    for n, dim, pts in _claim_sets(subject, budget, seed, (64, 256), lambda n: n > 1):
        rho = np.atleast_1d(patterns.min_distance_ratio(pts))
        worst = min(worst, float(rho.min()))
        if rho.min() < 0.75 - 2.0 ** -22 / patterns.d_hex(n):  # float32 coordinates
            bad.append(f"N={n} dim {dim}: {np.count_nonzero(rho < 0.75)}/{len(rho)} sets")
    detail = "; ".join(bad) + " below 0.75" if bad else "d_min / d_hex >= 0.75 in every set"
    return CheckResult("min_distance", not bad, f"min rho {worst:.3f}", f"N = 64, 256: {detail}",
                       values={"rho_min": worst})


def check_progressive(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    bad = []
    for dim, ndim in ((0, 2), (1, 1), (3, 2)):
        small = subject.points(budget.claim_pixels, 16, dim, ndim, seed)
        large = subject.points(budget.claim_pixels, 64, dim, ndim, seed)
        if large.shape[1] != 64 or small.shape[1] != 16:
            raise Unsupported(f"{subject.name} does not make 16 and 64 samples")
        if not np.array_equal(large[:, :16], small):
            bad.append(f"dim {dim} ({ndim}D): {np.mean(large[:, :16] != small):.0%} differ")
    return CheckResult("progressive", not bad, f"{3 - len(bad)}/3 dims equal", "; ".join(bad)
                       or "the first 16 of 64 samples are the 16 samples (dims 0, 1 (1D), 3)")


CLAIM_CHECKS = {"stratified": check_stratified, "latin": check_latin, "net": check_net,
                "min_distance": check_min_distance, "progressive": check_progressive}


# --------------------------------------------------------------------------- statistics

def _table_sets(sampler: mi.Sampler) -> int | None:
    """Sets T that pixels share unshifted (a random shift makes each set's
    estimate unbiased on its own, and the pixels' estimates uncorrelated)."""
    table = getattr(sampler, "_table", None)
    if table is None or getattr(sampler, "randomize", None) not in ("none", "symmetry"):
        return None
    return int(table()[2])


def _t_test(values: np.ndarray, exact: float, sets: int | None) -> tuple[float, float, float]:
    """Relative bias, its standard error and t of per-pixel estimates (module doc)."""
    bias = float(np.mean(values)) - exact
    se = float(np.std(values, ddof=1)) * math.sqrt(1 / values.size + (1 / sets if sets else 0))
    se *= float(np.ptp(values) > 1e-12 * max(1.0, abs(exact)))  # 0: deterministic
    t = bias / se if se > 0 else 0.0 if abs(bias) <= 1e-9 else math.copysign(math.inf, bias)
    return bias / exact, se / abs(exact), t


def check_unbiasedness(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    pixels, n = budget.unbiased_pixels, 16
    sampler = subject.seeded(n, pixels, seed)
    sets, n = _table_sets(sampler), sampler.sample_count()
    calls = draw(sampler, UNBIASED_CALLS)
    first, last = calls[0].reshape(pixels, n, 2), calls[-1].reshape(pixels, n, 2)
    tests = {}
    for g in INTEGRANDS.values():
        f0, f3 = (g.function(p[..., 0], p[..., 1]) for p in (first, last))
        for key, f, exact in ((g.name, f0, g.exact), (f"{g.name} call 4", f3, g.exact),
                              (f"{g.name} x {g.name}", f0 * f3, g.exact ** 2)):
            tests[key] = _t_test(f.mean(axis=1), exact, sets)
    p = [two_sided_p(t, pixels - 1) if math.isfinite(t) else 0.0 for _, _, t in tests.values()]
    rejected = holm(p, ALPHA)
    limit = t_quantile(1 - ALPHA / (2 * len(p)), pixels - 1)
    detectable = (limit + t_quantile(POWER, pixels - 1)) * max(s for _, s, _ in tests.values())
    flagged = [f"{k}: bias {b:+.2%} (t = {t:+.3g}{', no sampling error' if s == 0 else ''})"
               for (k, (b, s, t)), r in zip(tests.items(), rejected) if r]
    detail = ("biased: " + "; ".join(flagged) if flagged else
              "t " + ", ".join(f"{k} {t:+.1f}" for k, (_, _, t) in tests.items())
              + f"; |t| > {limit:.2f} fails, biases above {detectable:.1%} are found")
    worst = max(abs(t) for _, _, t in tests.values())
    return CheckResult("unbiasedness", not flagged, f"max |t| {worst:.3g}",
                       f"{pixels} px x {n} spp, Holm alpha {ALPHA:g}: {detail}",
                       values={k: {"relative_bias": b, "t": t, "p": q}
                               for (k, (b, _, t)), q in zip(tests.items(), p)})


def convergence(subject: Subject, budget: Budget, seed: int = 0) -> dict[str, Convergence]:
    """MSE of every integrand at each of the budget's counts (fresh seed per count)."""
    out = {name: Convergence(subject.name, name) for name in INTEGRANDS}
    for index, n in enumerate(budget.rate_counts):
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
        if fit.points < 2:
            raise Unsupported(f"{subject.name} makes fewer than two of N = {budget.rate_counts}")
        se = fit.stderr_scaled if math.isfinite(fit.stderr_scaled) else 0.0
        limit = -1.0 + RATE_MARGIN + RATE_SIGMAS * se
        if name == "disk" and strict:
            limit = min(limit, STRATIFIED_DISK_SLOPE + RATE_SIGMAS * se)
        parts.append(f"{name} {fit.slope:+.2f} +- {se:.2f} (<= {limit:+.2f})")
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
                       f"{what} {ratio:.3g} +- {se:.2g} x independent points' (<= {limit:.3g})",
                       values={"ratio": ratio, "stderr": se, "limit": limit}, data=data)


def check_discrepancy(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    pts = subject.points(budget.pattern_pixels, budget.pattern_spp, seed=seed)
    d2 = np.atleast_1d(patterns.l2_star_discrepancy(pts, squared=True))
    return _relative("discrepancy", d2, (1 / 4 - 1 / 9) / pts.shape[1],
                     f"L2-star D^2, N = {pts.shape[1]}, {len(pts)} px:", {"points": pts[:2]})


def check_spectrum(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    pts = subject.points(budget.pattern_pixels, budget.pattern_spp, seed=seed)
    n, kmax = pts.shape[1], patterns.default_kmax(pts.shape[1])
    spectra = [patterns.power_spectrum(p, kmax) for p in pts]
    low = np.array([patterns.low_frequency_power(patterns.radial_spectrum(s, n)) for s in spectra])
    radial = patterns.radial_spectrum(np.mean(spectra, axis=0), n, len(pts))
    return _relative("spectrum", low, 1.0, f"power at 0 < f < 0.5, N = {n}:", {"radial": radial})


Check = Callable[[Subject, Budget, int], CheckResult]
CONTRACT: tuple[Check, ...] = (check_determinism, check_range, check_clone, check_fork,
                               check_seeding)
STATISTICS: tuple[Check, ...] = (check_unbiasedness, check_mse_rate, check_discrepancy,
                                 check_spectrum)


def checks_for(subject: Subject) -> list[tuple[str, Check]]:
    """The checks that apply to ``subject`` by row name, in report order."""
    claims = [CLAIM_CHECKS[c] for c in registry.CLAIMS if c in subject.info.claims]
    return [(f.__name__[6:], f) for f in (*CONTRACT, *claims, *STATISTICS)]


def run_checks(name: str, params: dict[str, Any] | None = None, quick: bool = False,
               seed: int = 0, progress: Callable[[str], None] | None = None) -> list[CheckResult]:
    """Every check that applies to sampler ``name`` (plugin ``params``), in order.
    User errors (unknown name, parameters refused) raise SamplerError. A check the
    sampler cannot run at its counts is skipped; an exception inside one (the
    sampler crashed) fails it. ``progress(row)`` follows each check."""
    subject, budget = Subject(name, params), QUICK if quick else FULL
    try:
        subject.make(budget.contract_spp)
    except Unsupported as error:
        raise SamplerError(str(error)) from None
    results = []
    for row, fn in checks_for(subject):
        try:
            result = fn(subject, budget, seed)
        except Unsupported as error:
            result = CheckResult(row, True, "n/a", f"skipped: {error}", skipped=True)
        except Exception as error:  # the sampler failed while drawing
            result = CheckResult(row, False, "error", f"{type(error).__name__}: {error}")
        results.append(result)
        if progress is not None:
            progress(row)
    return results
