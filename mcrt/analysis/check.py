"""``mcrt check``: the variance-comparison suite as plain functions, for any sampler.

Each ``check_*`` function tests one property of a registered sampler (mcrt's,
Mitsuba's or a user's) and returns a :class:`CheckResult`; :func:`run_checks`
runs those that apply, in order: the contract (here), the claims the sampler
makes (:mod:`.check_claims`) and the statistics (:mod:`.check_stats`). Seeds
are fixed: a result is a function of (sampler, seed, budget) and never flakes.

Contract, through Mitsuba's interface as a render drives it (wavefront of
``pixels * N`` lanes, the calls :data:`CALLS`): **determinism** (two fresh
instances, same seed: same bits), **range** (finite, in [0, 1), on
``unbiased_lanes`` lanes: 2^20, quick 2^16, nine coordinates each, so a sampler
that leaves [0, 1) once in 2^20 values is found with probability 1 - e^-9, quick
once in 2^16; with 4096 lanes it passed), **clone** (made mid-stream after
``advance()``: the same values), **fork** (reseeded: what a fresh instance
draws), **seeding** (another seed changes every call: at most half of the lanes
keep a value; a permuted grid keeps ~1/N, a seed-blind call all), **pixels**
(pixels do not share values: :func:`check_pixels`).

Sample counts. A sampler may serve only some counts: its ``sample_counts()``
(``pointset``: the set sizes of its file) lists them; without the method, or
when it gives None, any count serves (after the sampler's own rounding). Where
a check wants N samples per pixel (the contract and unbiasedness 16, the
discrepancy and spectrum 256, 64 quick), it takes the smallest served count
>= N, else the largest (:meth:`Subject.count`); ``--spp`` (``spp=``) chooses
that count instead, and must be one the sampler serves. The claims take the
served counts they can test, the MSE rate those in the budget's range; a check
left with too few is skipped, with the reason, not failed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import mitsuba as mi
import numpy as np

from ..core.sampling import (
    check_sampler_name,
    make_sampler,
    quiet_sampler_warnings,
    raise_if_interrupted,
)
from ..errors import SamplerError
from ..samplers import registry
from ..samplers.points import lane_array, point_sets

CALLS: tuple[str, ...] = ("2d", "1d", "1d", "2d", "2d", "1d")
MAX_KEPT_SHARE = 0.5
#: Most likely chance repeat of one value, per value of another pixel (:func:`check_pixels`).
CHANCE_1D = 2.0 ** -20
#: Share of a call's values found in other pixels, beyond chance, that fails the pixels row.
MAX_SHARED_SHARE = 0.5


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
    """Work per check; pixels are the independent trials. Counts are those a
    check wants (see the module doc for samplers that serve only some)."""

    contract_pixels: int = 16    # at contract_spp; range: unbiased_lanes
    contract_spp: int = 16
    claim_pixels: int = 64       # point sets per count and dimension
    unbiased_spp: int = 16
    unbiased_pixels: int = 16384
    unbiased_lanes: int = 1 << 20  # at most pixels x N: fewer pixels at large N
    rate_counts: tuple[int, ...] = (16, 64, 256, 1024, 4096, 16384)
    rate_trials: int = 1024
    rate_budget: int = 1 << 22   # points per count: trials = min(rate_trials, budget / N)
    pattern_spp: int = 256
    pattern_pixels: int = 128
    pattern_pairs: int = 128 * 256 ** 2  # at most pixels x N^2: fewer pixels at large N


FULL = Budget()
QUICK = Budget(contract_pixels=8, claim_pixels=16, unbiased_pixels=1024,
               unbiased_lanes=1 << 16, rate_counts=(16, 64, 256, 1024), rate_trials=256,
               rate_budget=1 << 18, pattern_spp=64, pattern_pixels=32,
               pattern_pairs=32 * 64 ** 2)


def budget_for(quick: bool = False, spp: int | None = None) -> Budget:
    """The budget of a run: quick or full; ``spp`` (``--spp``) the count of the
    contract, unbiasedness, discrepancy and spectrum checks."""
    budget = QUICK if quick else FULL
    if spp is None:
        return budget
    return replace(budget, contract_spp=spp, unbiased_spp=spp, pattern_spp=spp)


class Unsupported(SamplerError):
    """The sampler cannot be made at a count a check needs (the check is skipped)."""


class Subject:
    """The sampler under check; the registry's example parameters for each count
    fill in what it needs outside a render (zsobol's width, pointset's file)."""

    def __init__(self, name: str, params: dict[str, Any] | None = None) -> None:
        self.name = check_sampler_name(name)
        self.info = registry.info(self.name)
        self.user = dict(params or {})
        #: The counts the sampler serves, ascending; None: any (module doc).
        self.served = self._served()

    def _served(self) -> tuple[int, ...] | None:
        if set(self.info.example_params(16)) - set(self.user):
            return None  # example parameters are made for each count (pointset's file)
        try:  # without a sample_count, which the sampler may not serve
            with quiet_sampler_warnings():
                probe = mi.load_dict({"type": self.name, **self.user})
        except Exception as error:
            raise_if_interrupted(error)
            return None  # make() reports it at the count a check asks for
        served = getattr(probe, "sample_counts", None)
        counts = served() if callable(served) else None
        return None if counts is None else tuple(sorted(int(c) for c in counts))

    def count(self, want: int) -> int:
        """The count to ask for in place of ``want``: ``want`` if any count
        serves, else the smallest served count >= ``want``, else the largest."""
        if self.served is None:
            return want
        return next((c for c in self.served if c >= want), self.served[-1])

    def counts(self, wanted: tuple[int, ...],
               fits: Callable[[int], bool] = lambda n: True) -> list[int]:
        """Counts to test a property at, ascending: the ``wanted`` ones that
        ``fits`` (as the sampler rounds them); for a sampler that serves only
        some counts, its counts in ``wanted`` that fit, else the one of those
        that fit nearest :meth:`count` would pick."""
        if self.served is None:
            return sorted({n for n in (self.make(c).sample_count() for c in wanted) if fits(n)})
        usable = [c for c in self.served if fits(c)]
        if not usable:
            return []
        return [c for c in usable if c in wanted] or [
            next((c for c in usable if c >= wanted[0]), usable[-1])]

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
        """Points of pixels 0..P-1 as rendered, float64 ``(P, N, ndim)``; points
        outside [0, 1) raise :class:`~.integrate.PointsOutside` (see :func:`run_checks`)."""
        from .integrate import check_points

        with quiet_sampler_warnings():
            points = point_sets(self.make(spp), pixels, spp, dimension=dimension, ndim=ndim,
                                seed=seed).astype(np.float64)
        check_points(self.name, points, "coordinates")
        return points


def draw(sampler: mi.Sampler, lanes: int, calls: tuple[str, ...] = CALLS) -> list[np.ndarray]:
    """Values of ``calls`` ("1d"/"2d") on ``lanes`` lanes (those it was seeded
    with) as float64 ``(lanes, 1 or 2)`` arrays; a call that does not return one
    value per lane is the sampler's error, said so. (Not ``wavefront_size()``: a
    plain ``mi.Sampler`` subclass whose ``seed`` does not call the base's, as
    renders allow, reports 0.)"""
    return [lane_array(sampler.next_2d() if call == "2d" else sampler.next_1d(), lanes, call,
                       f"call {i + 1} (next_{call}) ", np.float64)
            for i, call in enumerate(calls)]


def lanes(sampler: mi.Sampler, pixels: int) -> int:
    """Lanes of a sampler :meth:`Subject.seeded` seeded for ``pixels`` pixels."""
    return pixels * sampler.sample_count()


# --------------------------------------------------------------------------- contract

def _same(name: str, a: list[np.ndarray], b: list[np.ndarray], what: str) -> CheckResult:
    diff = [f"call {i + 1} ({CALLS[i]}): {np.mean(x != y):.0%} of values differ"
            if x.shape == y.shape else f"call {i + 1}: {len(x)} vs {len(y)} lanes"
            for i, (x, y) in enumerate(zip(a, b, strict=True))
            if not np.array_equal(x, y, equal_nan=True)]
    same = f"the same bits in {len(a)} calls ({', '.join(CALLS)}) of {len(a[0])} lanes"
    return CheckResult(name, not diff, f"{len(a) - len(diff)}/{len(a)} calls equal",
                       f"{what}: {'; '.join(diff) or same}")


def check_determinism(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = subject.count(budget.contract_spp), budget.contract_pixels
    a, b = (subject.seeded(n, pixels, seed) for _ in range(2))
    return _same("determinism", draw(a, lanes(a, pixels)), draw(b, lanes(b, pixels)),
                 f"two fresh instances, seed {seed}")


def outside(values: np.ndarray) -> str:
    """How many ``values`` are not finite or lie outside [0, 1), with one of
    them; "" when none does."""
    out = ~(np.isfinite(values) & (values >= 0.0) & (values < 1.0))
    count = np.count_nonzero(out)
    return (f"{count} value{'s' if count > 1 else ''} outside [0, 1), e.g. "
            f"{float(values[out][0])}" if count else "")


def check_range(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n = subject.count(budget.contract_spp)
    pixels = max(16 * budget.contract_pixels, budget.unbiased_lanes // n)
    sampler = subject.seeded(n, pixels, seed)
    values = draw(sampler, lanes(sampler, pixels))
    bad = [f"call {i + 1} ({CALLS[i]}): {outside(v)}" for i, v in enumerate(values)
           if outside(v)]
    low, high = (float(f([f(v) for v in values])) for f in (np.nanmin, np.nanmax))
    detail = "; ".join(bad) or f"{sum(v.size for v in values)} values: finite, in [0, 1)"
    top = f"1 - {1 - high:.2g}" if high < 1 else f"{high:.3g}"  # (a value >= 1 fails)
    return CheckResult("range", not bad, f"[{low:.2g}, {top}]", detail,
                       values={"min": low, "max": high})


def check_clone(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    sampler = subject.seeded(subject.count(budget.contract_spp), budget.contract_pixels, seed)
    width = lanes(sampler, budget.contract_pixels)
    draw(sampler, width, CALLS[:3])
    sampler.advance()
    draw(sampler, width, CALLS[:1])
    twin = sampler.clone()
    return _same("clone", draw(sampler, width), draw(twin, width),
                 "a clone after 3 calls, advance(), 1 call")


def check_fork(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = subject.count(budget.contract_spp), budget.contract_pixels
    sampler = subject.seeded(n, pixels, seed)
    draw(sampler, lanes(sampler, pixels), CALLS[:2])  # mid-stream
    fresh = sampler.fork()
    other = (seed + 1) % (1 << 32)
    fresh.set_samples_per_wavefront(fresh.sample_count())
    fresh.seed(other, pixels * fresh.sample_count())  # type: ignore[arg-type]
    again = subject.seeded(n, pixels, other)
    return _same("fork", draw(fresh, lanes(fresh, pixels)), draw(again, lanes(again, pixels)),
                 f"a fork reseeded with {other} vs a fresh instance")


def check_seeding(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    n, pixels = subject.count(budget.contract_spp), budget.contract_pixels
    other = (seed + 1) % (1 << 32)
    a, b = (draw(s, lanes(s, pixels)) for s in (subject.seeded(n, pixels, x)
                                                 for x in (seed, other)))
    kept = [float(np.mean(np.all(x == y, axis=1))) for x, y in zip(a, b, strict=True)]
    stuck = [f"call {i + 1} ({CALLS[i]}) keeps {k:.0%} of its values"
             for i, k in enumerate(kept) if k > MAX_KEPT_SHARE]
    detail = "; ".join(stuck) or f"every call changes (<= {max(kept):.1%} of lanes keep a value)"
    return CheckResult("seeding", not stuck, f"max {max(kept):.0%} kept",
                       f"seeds {seed} and {other}: {detail}", values={"kept": kept})


def table_sets(sampler: mi.Sampler) -> int | None:
    """Sets T that pixels share unshifted (``pointset`` with randomize none or
    symmetry: pixels that draw one set get its points); None for any other
    sampler (a random shift makes each set's estimate unbiased on its own, and
    the pixels' estimates uncorrelated)."""
    table = getattr(sampler, "_table", None)
    if table is None or getattr(sampler, "randomize", None) not in ("none", "symmetry"):
        return None
    return int(table()[2])


def shared_values(values: np.ndarray, n: int) -> tuple[float, bool, tuple[int, int, int]]:
    """Of ``values`` ``(lanes, d)`` on pixel-major lanes, ``n`` per pixel: the
    share of lanes whose value also occurs in another pixel, whether every
    pixel holds every value, and an example ``(pixel, other pixel, values in
    common)`` (``(0, 0, 0)`` when none is shared)."""
    pixels = len(values) // n
    pixel = np.arange(len(values)) // n
    _, ids = np.unique(values, axis=0, return_inverse=True)
    ids = ids.reshape(-1)
    owners = np.unique(ids * pixels + pixel)  # (value, pixel) pairs
    holders = np.bincount(owners // pixels, minlength=int(ids.max()) + 1)[ids]
    shared = holders > 1
    if not shared.any():
        return 0.0, False, (0, 0, 0)
    first = int(np.argmax(shared))
    p = int(pixel[first])
    q = int(next(o % pixels for o in owners[owners // pixels == ids[first]] if o % pixels != p))
    common = np.intersect1d(ids[p * n:(p + 1) * n], ids[q * n:(q + 1) * n]).size
    return float(np.mean(shared)), bool(np.all(holders == pixels)), (p, q, int(common))


def _calls(indices: list[int]) -> str:
    return ", ".join(f"{i + 1} ({CALLS[i]})" for i in indices)


def check_pixels(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    """Pixels decorrelated: per call, the share of values (1D values, 2D points)
    that also occur in another pixel at that call, on the contract's P x N lanes.

    A sampler that leaves the pixel out of its keys gives every pixel the same
    values (100%), one keyed on half the pixel index pairs of pixels (100%).
    By chance, a value of another pixel equals a given one with probability
    at most ``CHANCE_1D = 2^-20`` per 1D value of that pixel (mcrt: positions
    inside one of n strata on 2^(22 - ceil log2 n) steps, end steps 1.5 times
    as likely, so <= 3 n 2^-22 for its one stratum-mate; values on 2^-24;
    Mitsuba's on 2^-23 or finer) and ``2^-40`` per 2D point: the expected
    share is at most ``chance = (P - 1) N 2^-20`` (1D; 2D is ~0): 2.3e-4 at
    16 px x 16 (quick 8 px: 1.1e-4; jittered's jitter 0.01 squeezes the steps
    100-fold: 0.8% seen). A call fails above ``chance + MAX_SHARED_SHARE``
    (1/2). Independent values coincide lane by lane (Poisson, mean
    P N chance / 2 = 0.03 pairs, where P N / 4 = 64 fail); a
    lattice shifted per pixel (``uniform_grid`` off the film, Mitsuba's
    ``ldsampler``: 2 of 16 pixels coincide at N = 4096) a whole pixel at a
    time, with probability <= N 2^-20 per pair of pixels: failing takes more
    than P/2 pixels, at least P/4 + 1 coinciding pairs, Poisson of mean
    C(P, 2) N 2^-20: >= 5 of 1.8e-3 (full, ~2e-16), >= 3 of 4.3e-4 (quick,
    ~1e-11). A 1D call at N >= ~35000 (P = 16) cannot fail: chance could reach 1/2.

    Shared by design, reported and not tested: the film call of a sampler
    claiming **quadrature** (``uniform_grid``: the same cell centres in every
    pixel; the claim checks them), and the calls an unshifted table serves
    (``pointset``, randomize none or symmetry: its 2D calls, and 1D calls with
    dims1d projection): pixels that draw one of its T sets share its points,
    as :data:`~mcrt.samplers.pointset.RANDOMIZATIONS` says: a share of
    ``1 - (1 - 1/K)^(P - 1)`` expected, K = T sets (x 8 symmetries), T the
    user's (16 sets, none: 62%; 88% seen in a call), so no margin passes every
    sound table; the error they share is what unbiasedness tests, with
    ``se^2 = sd^2 (1/P + 1/T)`` (``none`` on sets that are not random fails there)."""
    n, pixels = subject.count(budget.contract_spp), budget.contract_pixels
    sampler = subject.seeded(n, pixels, seed)
    n = sampler.sample_count()
    calls = draw(sampler, lanes(sampler, pixels))
    exempt: dict[int, str] = {}
    sets = table_sets(sampler)
    if sets is not None:
        projected = getattr(sampler, "dims1d", None) == "projection"
        randomize = getattr(sampler, "randomize", "none")
        kinds = sets * (8 if randomize == "symmetry" else 1)  # sets x symmetries
        expected = 1 - (1 - 1 / kinds) ** (pixels - 1)
        exempt.update({i: f"{sets} unshifted table sets (randomize={randomize}): pixels that "
                          f"draw one set share its points (~{expected:.1%} expected)"
                       for i, c in enumerate(CALLS) if c == "2d" or projected})
    if "quadrature" in subject.info.claims:
        exempt[0] = "quadrature: the film grid is the same in every pixel (see the claim)"
    found = [shared_values(v, n) for v in calls]
    shares = [share for share, _, _ in found]
    chance = [(pixels - 1) * n * CHANCE_1D ** (2 if c == "2d" else 1) for c in CALLS]
    tested = [i for i in range(len(CALLS)) if i not in exempt]
    bad = [i for i in tested if shares[i] > chance[i] + MAX_SHARED_SHARE]
    where = f"{pixels} px x {n} spp"
    if bad:
        same = [i for i in bad if found[i][1]]
        p, q, common = found[bad[0]][2]
        every = "every call" if len(same) == len(CALLS) else f"call{'s' * (len(same) > 1)} " \
            f"{_calls(same)}"
        cause = (f"every pixel gets the same values in {every}: the values do not depend on "
                 f"the pixel" if same else
                 f"e.g. pixels {p} and {q} have {common} of {n} values in common in call "
                 f"{bad[0] + 1}: pixels share keys")
        detail = (f"{where}: pixels share samples: "
                  + ", ".join(f"call {i + 1} ({CALLS[i]}) {shares[i]:.0%}" for i in bad)
                  + f" of values also occur in another pixel (chance alone <= "
                    f"{max(chance[i] for i in bad):.2%}); {cause}; hash the whole pixel into "
                    f"each value's key, as mcrt and pbrt-v4 hash (seed, pixel, dimension)")
    else:
        top = max((shares[i] for i in tested), default=0.0)
        detail = (f"{where}: at most {top:.2%} of a call's values occur in another pixel "
                  f"(chance alone <= {max(chance[i] for i in tested):.2%}; more than "
                  f"{MAX_SHARED_SHARE:.0%} above chance fails)" if tested
                  else f"{where}: no call tested")
        blind = [i for i in tested if chance[i] + MAX_SHARED_SHARE >= 1]
        if blind:
            detail += f"; calls {_calls(blind)} cannot fail at N = {n}: chance alone is too high"
    for reason in dict.fromkeys(exempt.values()):
        idx = [i for i in exempt if exempt[i] == reason]
        detail += (f"; call{'s' * (len(idx) > 1)} {_calls(idx)} "
                   f"{'/'.join(f'{shares[i]:.0%}' for i in idx)} shared, not tested: {reason}")
    figure = (f"max {max(shares[i] for i in tested):.0%} shared" if tested
              else "none tested")
    return CheckResult("pixels", not bad, figure, detail,
                       values={"shared": shares, "chance": chance,
                               "tested": [i not in exempt for i in range(len(CALLS))]})


Check = Callable[[Subject, Budget, int], CheckResult]
CONTRACT: tuple[Check, ...] = (check_determinism, check_range, check_clone, check_fork,
                               check_seeding, check_pixels)


def checks_for(subject: Subject) -> list[tuple[str, Check]]:
    """The checks that apply to ``subject`` by row name, in report order."""
    from .check_claims import CLAIM_CHECKS  # they build on this module
    from .check_stats import STATISTICS

    claims = [CLAIM_CHECKS[c] for c in registry.CLAIMS if c in subject.info.claims]
    return [(f.__name__[6:], f) for f in (*CONTRACT, *claims, *STATISTICS)]


def run_checks(name: str, params: dict[str, Any] | None = None, quick: bool = False,
               seed: int = 0, progress: Callable[[str], None] | None = None,
               spp: int | None = None) -> list[CheckResult]:
    """Every check that applies to sampler ``name`` (plugin ``params``), in order;
    ``spp``: the count of the contract, unbiasedness and pattern checks (module
    doc). User errors (unknown name, parameters refused, a count the sampler
    does not serve) raise SamplerError. A check the sampler cannot run at its
    counts is skipped; an exception inside one (the sampler crashed) fails it.
    ``progress(row)`` follows each check.

    A check whose points include values outside [0, 1) (NaN, or a 1.0 that a
    float32 rounding made) fails as "not tested", saying so in one line: the
    range row has found the defect, and measuring on the valid points alone is
    not sound: dropping points changes the count N the MSE rate, discrepancy and
    spectrum are normalised by and the claims count cells with, and it drops them
    selectively (a 1.0 is a point rounded at the square's edge), so what is left is
    not the sampler's point set and a pass would vouch for a sampler that was not
    measured."""
    from .integrate import PointsOutside

    subject, budget = Subject(name, params), budget_for(quick, spp)
    if spp is not None and subject.served is not None and spp not in subject.served:
        raise SamplerError(f"{subject.name} serves {', '.join(map(str, subject.served))} "
                           f"samples per pixel, not {spp}: choose --spp from those")
    try:
        subject.make(subject.count(budget.contract_spp))
    except Unsupported as error:
        raise SamplerError(str(error)) from None
    results = []
    for row, fn in checks_for(subject):
        try:
            result = fn(subject, budget, seed)
        except Unsupported as error:
            result = CheckResult(row, True, "n/a", f"skipped: {error}", skipped=True)
        except PointsOutside as error:
            result = CheckResult(row, False, "not tested", f"cannot be measured: {error.where} "
                                 f"(see range)")
        except Exception as error:  # the sampler failed while drawing
            raise_if_interrupted(error)
            result = CheckResult(row, False, "error", f"{type(error).__name__}: {error}")
        results.append(result)
        if progress is not None:
            progress(row)
    return results
