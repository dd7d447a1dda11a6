"""``mcrt check``: the properties a sampler claims (:data:`registry.CLAIMS`), tested exactly.

Each claim made is checked on real pixels' points (:meth:`.check.Subject.points`)
in dimensions 0 and 2 (:data:`CLAIM_DIMENSIONS`):

* **stratified** (N = 16, 64: one point per k x k cell);
* **latin** (one per column and row);
* **net** (N = 16, 64, 256: one point per elementary interval 2^-i x 2^-(m-i), all i);
* **min_distance** (N = 64, 256: toroidal rho >= 0.75);
* **progressive** (the first 16 of 64 samples are the 16 samples; dimensions 0,
  1 (1D) and 3);
* **quadrature** (N = 16, 64, film dimension only: every pixel's points are the
  k x k cell centres, one each; :mod:`.check_stats` then leaves the film's bias
  out of the unbiasedness test).

A sampler that serves only some counts is checked at those of its counts the
claim names, else at the one nearest the first (:meth:`.check.Subject.counts`);
progressive at its two smallest. A point within :data:`EDGE_TOL` of a border
counts for either cell (float32 rounding of ``(cell + u) / k``): a set passes if
its points can be matched one to a cell (:func:`one_per_cell`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from . import patterns
from .check import Budget, Check, CheckResult, Subject, Unsupported

EDGE_TOL = 2.0 ** -20  # 16 float32 ulps of 1; cell borders here are >= 2^-8 apart
CLAIM_DIMENSIONS = (0, 2)


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


def _square(n: int) -> list[tuple[int, int]]:
    """The k x k grid of a square count, else none."""
    k = math.isqrt(n)
    return [(k, k)] if k * k == n else []


def _claim_sets(subject: Subject, budget: Budget, seed: int, counts: tuple[int, ...],
                fits: Callable[[int], bool], dimensions: tuple[int, ...] = CLAIM_DIMENSIONS
                ) -> list[tuple[int, int, np.ndarray]]:
    """``(N, dimension, points)`` at the counts to test of ``counts`` that ``fits``
    (Unsupported if none), in ``dimensions``."""
    usable = subject.counts(counts, fits)
    if not usable:
        raise Unsupported(f"{subject.name} makes no count the claim needs from {counts}")
    return [(n, d, subject.points(budget.claim_pixels, n, dimension=d, seed=seed))
            for n in usable for d in dimensions]


def _where(sets: list[tuple[int, int, np.ndarray]]) -> str:
    return (f"N = {sorted({s[0] for s in sets})}, dims {tuple(sorted({s[1] for s in sets}))}, "
            f"{len(sets[0][2])} px")


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
    detail = "; ".join(bad[:6]) + " not one point per cell" if bad else "one point per cell"
    return CheckResult(name, not bad, f"{off}/{total} sets off", f"{_where(sets)}: {detail}",
                       values={"sets_off": off, "sets": total})


def check_stratified(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    return _grid_claim("stratified", subject, budget, seed, (16, 64), _square)


def check_latin(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    return _grid_claim("latin", subject, budget, seed, (16, 64), lambda n: [(n, 1), (1, n)])


def check_net(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    def shapes(n: int) -> list[tuple[int, int]]:  # 2^i x 2^(m-i) cells, i = 0..m
        m = n.bit_length() - 1
        return [(1 << i, 1 << (m - i)) for i in range(m + 1)] if n == 1 << m else []
    return _grid_claim("net", subject, budget, seed, (16, 64, 256), shapes)


def check_min_distance(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    bad, worst = [], math.inf
    sets = _claim_sets(subject, budget, seed, (64, 256), lambda n: n > 1)
    for n, dim, pts in sets:
        rho = np.atleast_1d(patterns.min_distance_ratio(pts))
        worst = min(worst, float(rho.min()))
        if rho.min() < 0.75 - 2.0 ** -22 / patterns.d_hex(n):  # float32 coordinates
            bad.append(f"N={n} dim {dim}: {np.count_nonzero(rho < 0.75)}/{len(rho)} sets")
    detail = "; ".join(bad) + " below 0.75" if bad else "d_min / d_hex >= 0.75 in every set"
    return CheckResult("min_distance", not bad, f"min rho {worst:.3f}",
                       f"{_where(sets)}: {detail}", values={"rho_min": worst})


def check_progressive(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    small, large = (16, 64) if subject.served is None else (subject.served + (0, 0))[:2]
    if not 0 < small < large:
        raise Unsupported(f"{subject.name} serves one count, N = {small}: nothing to continue")
    bad = []
    for dim, ndim in ((0, 2), (1, 1), (3, 2)):
        first = subject.points(budget.claim_pixels, small, dim, ndim, seed)
        more = subject.points(budget.claim_pixels, large, dim, ndim, seed)
        if more.shape[1] != large or first.shape[1] != small:
            raise Unsupported(f"{subject.name} does not make {small} and {large} samples")
        if not np.array_equal(more[:, :small], first):
            bad.append(f"dim {dim} ({ndim}D): {np.mean(more[:, :small] != first):.0%} differ")
    return CheckResult("progressive", not bad, f"{3 - len(bad)}/3 dims equal", "; ".join(bad)
                       or f"the first {small} of {large} samples are the {small} samples "
                          f"(dims 0, 1 (1D), 3)")


def check_quadrature(subject: Subject, budget: Budget, seed: int = 0) -> CheckResult:
    """Film points at the k x k cell centres, one each, in every pixel."""
    sets = _claim_sets(subject, budget, seed, (16, 64), lambda n: bool(_square(n)),
                       dimensions=(0,))
    bad, off, total = [], 0, 0
    for n, _, pts in sets:
        k = math.isqrt(n)
        centred = np.abs(pts * k - np.floor(pts * k) - 0.5) <= EDGE_TOL * k
        wrong = int(np.count_nonzero(~(np.all(centred, axis=(1, 2)) & one_per_cell(pts, k, k))))
        off, total = off + wrong, total + len(pts)
        if wrong:
            bad.append(f"N={n}: {wrong}/{len(pts)} sets")
    detail = ("; ".join(bad) + " not the cell centres" if bad
              else "film points are the k x k cell centres in every pixel")
    return CheckResult("quadrature", not bad, f"{off}/{total} sets off",
                       f"{_where(sets)}: {detail}", values={"sets_off": off, "sets": total})


CLAIM_CHECKS: dict[str, Check] = {
    "stratified": check_stratified, "latin": check_latin, "net": check_net,
    "min_distance": check_min_distance, "progressive": check_progressive,
    "quadrature": check_quadrature}
