"""Precomputed toroidal Poisson-disk (blue-noise) point sets for ``poisson_disk``.

Public interface
================

* :data:`MAX_POINTS` and :func:`load_tables` are what the sampler plugin uses:
  ``load_tables(n)`` returns ``T = n_tables(n)`` point sets of ``n`` points as a
  read-only ``(T, n, 2)`` float32 array with values in ``[0, 1)``, generated on
  first use and cached in memory and on disk.
* :func:`generate` is the generator itself (float64 output, no caching);
  :func:`d_hex`, :func:`toroidal_min_distance` and :func:`toroidal_min_distances`
  state and check the spacing guarantee.

Guarantee
=========

Every set of ``n >= 2`` points has a *toroidal* minimum distance (distance on
the unit torus, i.e. the unit square with opposite edges identified) of at least
``RHO_TARGET * d_hex(n)`` with :data:`RHO_TARGET` = 0.76, where
``d_hex(n) = sqrt(2 / (sqrt(3) n))`` is the spacing of a hexagonal packing of
``n`` points on the unit square (no ``n`` points on the torus have a larger
minimum distance).
The sampler promises :data:`RHO_GUARANTEE` = 0.75; the margin absorbs its
float32 symmetries and shifts (~1e-7). Saturated (maximal) dart throwing reaches
``rho = d_min / d_hex ~ 0.78`` [RSA]_, so 0.76 is "as good as maximal dart
throwing" while the sets stay dart-throwing-like: no relaxation towards a
lattice, whose spectrum has strong peaks. The averaged power spectrum is
~0.06 near ``k = 0``, below 0.1 up to ``|k| = 0.5 sqrt(n)``, peaks at ~1.7
around ``|k| ~ 1.15 sqrt(n)`` and then oscillates around 1 (measured at
``n = 256``). Every set is verified with the exact :func:`toroidal_min_distances`
and regenerated if it falls short; tables read from disk are validated too.
Sets of one point have no minimum distance (the requirement is void).

Algorithm
=========

Maximal Poisson-disk sampling by dart throwing at the fixed radius
``r = RHO_TARGET * d_hex(n)``, stopped at ``n`` points, with the cell and
sub-cell bookkeeping of Ebeida et al. [EMP11]_ and the grid-parallel darts of
Wei [Wei08]_, run with numpy on many sets at once:

1. The torus is cut into ``G x G`` cells of side ``1/G <= r / sqrt(2)``, so a
   cell holds at most one point and only the 5 x 5 block of cells around it can
   hold a point closer than ``r``. Each set's grid is padded with periodic copies
   of the border cells (storing the coordinates of the *image* point), so a
   neighbour is a constant index offset and differences need no wrapping; the
   grids of all sets of a batch live in one flat array.
2. The *active squares* start as all cells. A round throws one uniform dart into
   every active square (all active squares have the same area, so darts are
   uniform over the remaining region), drops darts closer than ``r`` to an
   accepted point, keeps the highest-priority dart of each cell, then every dart
   with no higher-priority dart closer than ``r`` (one step of Luby's parallel
   maximal independent set; priorities are a random permutation, increasing from
   round to round). The accepted darts are a subset of those that sequential dart
   throwing in priority order would accept; the others are simply rethrown later.
   Squares of occupied cells and of complete sets are dropped. (The very first
   round, on the empty grid, uses a random 35% of the cells: with a dart in every
   cell most would lose against a neighbour.)
3. After a few rounds every active square is split into four and the children
   lying inside the disk of one point (all four corners closer than ``r``) are
   dropped [EMP11]_; darts then go only where there may still be room. After
   five levels (squares of ``1/32`` of a cell side) the set is nearly maximal:
   only tiny slivers of uncovered area are left.
4. A set is complete when it holds ``n`` points; if the last round overshoots,
   it keeps the ``n`` darts earliest in priority order (a subset of a valid set is
   valid). Stopping at ``n`` happens when the set is ~96% of the way to
   saturation (the saturated count at this radius is ~1.04 ``n``), so the few
   remaining gaps are scattered at random. Sets that saturate with fewer than
   ``n`` points (10-23% of the sets for ``n < 40``, ~1% at ``n = 256``, none seen
   beyond) are regenerated; small ``n`` throws a few extra sets up front instead.

The work is linear in the number of points: every round and split handles flat
blocks of (25 neighbour offsets x active squares), and the number of rounds is
fixed. Distances are computed in float32 against ``r + 1e-6`` (far more than
float32 rounding), so the float32 coordinates of every set satisfy the bound in
exact arithmetic; :func:`generate` checks it in float64 and returns these
float32-representable values, and the float32 tables store them without
rounding. Points are listed in acceptance order, so a prefix of a set is itself
well spread. Compared with ``scipy.stats.qmc.PoissonDisk`` (Bridson's algorithm
[Bri07]_, one Python loop iteration per candidate, not toroidal, not maximal)
this is one to two orders of magnitude faster, see ``BENCHMARKS.md``.

Determinism and caching
=======================

``generate(n, n_sets, seed)`` draws everything from
``np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, n])))``
and uses only element-wise IEEE arithmetic, so the same arguments give the same
bits on every run and machine (for a given numpy random stream; numpy keeps
``Generator`` streams stable in practice but does not promise it across
versions, which is harmless: a cached table stays valid). :func:`load_tables`
uses ``seed = TABLE_SEED`` and caches the float32 tables in memory and in
``<cache>/poisson/v{VERSION}-n{n}-t{T}.npz`` (a :class:`mcrt.core.job.Checkpoint`:
the table's key and a checksum of its content), where ``<cache>`` is
``$MCRT_CACHE_DIR`` if set and non-empty, else ``$XDG_CACHE_HOME/mcrt`` or
``~/.cache/mcrt``. Bump :data:`VERSION` whenever the output changes, so stale
files are never reused. Files are written atomically (temporary file in the same
directory, then ``os.replace``); unreadable, damaged or wrong files (checked:
key, checksum, shape, dtype, range and spacing) are set aside as ``*.damaged``
with a note, regenerated and replaced, and an unwritable
cache directory only means the tables are not stored.

References
==========

.. [EMP11] M. S. Ebeida, A. A. Davidson, A. Patney, P. M. Knupp, S. A. Mitchell,
   J. D. Owens. "Efficient maximal Poisson-disk sampling". ACM TOG 30(4), 2011.
.. [Wei08] L.-Y. Wei. "Parallel Poisson disk sampling". ACM TOG 27(3), 2008.
.. [RSA] J. Feder. "Random sequential adsorption". J. Theor. Biol. 87, 1980:
   saturated dart throwing (random sequential adsorption) covers ~54.7% of the
   plane with disks of radius ``d_min / 2``, i.e. ``d_min ~ 0.777 d_hex``.
.. [Bri07] R. Bridson. "Fast Poisson disk sampling in arbitrary dimensions".
   SIGGRAPH 2007 sketches.
"""

from __future__ import annotations

import logging
import math
import threading
from pathlib import Path

import numpy as np

log = logging.getLogger("mcrt.poisson")

__all__ = [
    "MAX_POINTS", "RHO_GUARANTEE", "RHO_TARGET", "TABLE_SEED", "VERSION",
    "cache_dir", "cache_path", "clear_memory_cache", "d_hex", "generate", "load_tables",
    "n_tables", "toroidal_min_distance", "toroidal_min_distances",
]

#: Largest supported set size. First-time generation of its 8 tables takes about
#: one second on a 2-core machine (see BENCHMARKS.md); the cost is linear in n.
MAX_POINTS = 16384

#: Version of the generator's output; part of the cache file name.
VERSION = 2

#: Spacing the sampler promises (``d_min >= RHO_GUARANTEE * d_hex``).
RHO_GUARANTEE = 0.75

#: Spacing every generated set and every table is verified against (the radius).
RHO_TARGET = 0.76

#: Seed of the tables behind :func:`load_tables` (mixed with ``n``).
TABLE_SEED = 0x5EED_B1E

_ROUNDS = (3, 1, 2, 2, 2, 2)  # dart rounds at sub-cell level 0, 1, ...
_FIRST_FRACTION = 0.35       # share of the cells in the first round
_BLOCK = 1 << 15             # elements per (darts x neighbours) block
_MAX_ATTEMPTS = 64           # regeneration passes before giving up (never reached)


def d_hex(n: int) -> float:
    """Spacing of ``n`` points in a hexagonal packing of the unit square."""
    if n < 1:
        raise ValueError(f"d_hex needs n >= 1, got {n}")
    return math.sqrt(2.0 / (math.sqrt(3.0) * n))


def n_tables(n: int) -> int:
    """Number of tables ``T`` kept for sets of ``n`` points (a power of two, 8 to 64)."""
    _check_n(n)
    t = 64
    while t > 8 and t * n > 65536:
        t //= 2
    return t


def _check_n(n: int) -> None:
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool):
        raise TypeError(f"n must be an int, got {type(n).__name__}")
    if not 1 <= n <= MAX_POINTS:
        raise ValueError(f"n must be in [1, {MAX_POINTS}], got {n}")


# --------------------------------------------------------------------------- distances

def _wrap_delta(d: np.ndarray) -> np.ndarray:
    """Minimal-image difference on the unit torus (in [-0.5, 0.5])."""
    return d - np.rint(d)


def toroidal_min_distances(points: np.ndarray) -> np.ndarray:
    """Exact toroidal minimum distance of every set in ``points`` (``(B, n, 2)``).

    Returns a float64 array of shape ``(B,)``; ``inf`` for sets of fewer than two
    points. Coordinates are taken mod 1. Points are binned into a grid of cells of
    side ``>= d_hex(n)``; no ``n`` points on the torus are all farther apart than
    ``d_hex(n)`` (the hexagonal packing bound), so the closest pair lies in the same
    or in neighbouring cells and only those pairs are compared: linear time for
    well-spread points, never worse than a few times brute force.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 2:
        raise ValueError(f"expected an array of shape (B, n, 2), got {pts.shape}")
    n_sets, n = pts.shape[:2]
    if n < 2 or n_sets == 0:
        return np.full(n_sets, np.inf)
    if not np.all(np.isfinite(pts)):
        raise ValueError("points must be finite")
    pts = pts - np.floor(pts)
    g = int(1.0 / d_hex(n))
    if g < 3 or n <= 48:  # few points: all pairs (the grid needs distinct neighbours)
        out = np.empty(n_sets)
        step = max(1, _BLOCK // (n * n))
        diag = np.arange(n)
        for i in range(0, n_sets, step):
            p = pts[i:i + step]
            d = _wrap_delta(p[:, :, None, :] - p[:, None, :, :])
            d2 = (d * d).sum(axis=-1)
            d2[:, diag, diag] = np.inf
            out[i:i + step] = np.sqrt(d2.min(axis=(1, 2)))
        return out
    p = pts.reshape(-1, 2)
    cell = np.minimum((p * g).astype(np.int64), g - 1)
    set_base = np.repeat(np.arange(n_sets) * (g * g), n)
    flat = set_base + cell[:, 1] * g + cell[:, 0]
    counts = np.bincount(flat, minlength=n_sets * g * g)
    m = int(counts.max())
    order = np.argsort(flat, kind="stable")
    slot = np.arange(len(flat)) - (np.cumsum(counts) - counts)[flat[order]]
    slots = np.full((n_sets * g * g, m), -1, dtype=np.int64)  # points of each cell
    slots[flat[order], slot] = order
    # Half of the 3x3 neighbourhood plus the cell itself sees every pair once.
    half = ((0, 0), (0, 1), (1, -1), (1, 0), (1, 1))
    nb = np.stack([set_base + ((cell[:, 1] + dy) % g) * g + (cell[:, 0] + dx) % g
                   for dy, dx in half], axis=1)
    best = np.full(len(p), np.inf)
    step = max(1, _BLOCK // (len(half) * m))
    for i in range(0, len(p), step):
        j = min(i + step, len(p))
        cand = slots[nb[i:j]].reshape(j - i, -1)  # (points, 5 m) candidate partners
        me = np.arange(i, j)[:, None]
        valid = cand >= 0
        valid[:, :m] &= cand[:, :m] > me  # own cell: each pair once, not itself
        d = _wrap_delta(p[cand] - p[me])
        d2 = (d * d).sum(axis=-1)
        d2[~valid] = np.inf
        best[i:j] = d2.min(axis=1)
    return np.sqrt(best.reshape(n_sets, n).min(axis=1))


def toroidal_min_distance(points: np.ndarray) -> float:
    """Exact minimum distance between two of ``points`` (``(n, 2)``) on the unit torus.

    ``inf`` for fewer than two points (the spacing requirement is then void).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"expected an array of shape (n, 2), got {pts.shape}")
    return float(toroidal_min_distances(pts[None])[0])


# --------------------------------------------------------------------------- generator

_F = np.float32  # the generator works in float32 (half the memory traffic)
_EMPTY = 1e4     # coordinate of "no point": farther than any radius from [-1, 2]


class _Batch:
    """Grids of ``n_sets`` sets being filled by parallel dart throwing of radius ``r``.

    Each set has ``G x G`` cells padded by ``K`` cells of periodic copies on every
    side, so a cell's neighbour is a constant offset in the flat arrays. A copy
    stores the coordinates of the point's periodic *image* at that place, so
    differences need no wrapping. Neighbourhood tests work on blocks of shape
    (neighbour offsets, darts) and reduce over the first axis.
    """

    def __init__(self, n: int, n_sets: int, r: float, rng: np.random.Generator):
        self.n, self.n_sets, self.rng = n, n_sets, rng
        # Cell side s = 1/G <= r / sqrt(2): two points in one cell are too close.
        g = max(1, math.ceil(math.sqrt(2.0) / r))
        self.g, self.s = g, 1.0 / g
        # Conflict radius, widened by far more than the float32 rounding of
        # coordinates and differences (< 3e-7) so that every accepted pair is
        # >= r apart in exact arithmetic; generate() verifies it in float64.
        self.r = r + 1e-6
        self.r2 = _F(self.r * self.r)
        k = math.ceil(self.r * g + 1e-9)  # cells up to K away may hold a point closer than r
        gp = g + 2 * k
        self.k, self.gp, self.gp2 = k, gp, gp * gp
        size = n_sets * self.gp2
        self.px = np.full(size, _EMPTY, dtype=_F)
        self.py = np.full(size, _EMPTY, dtype=_F)
        self.key = np.full(size, np.inf)  # acceptance order: round + (1 - priority)
        # Scratch grids: darts of a round and their priorities. Priorities grow from
        # round to round, so entries left over from earlier rounds never count as
        # a higher-priority dart and the grids need no clearing.
        self.dx = np.full(size, _EMPTY, dtype=_F)
        self.dy = np.full(size, _EMPTY, dtype=_F)
        self.dprio = np.full(size, -1, dtype=np.int64)
        self.next_prio = 0
        self.count = np.zeros(n_sets, dtype=np.int64)
        self.done = np.zeros(n_sets, dtype=bool)
        self.round = 0
        # Primary cells (inside the padding) of every set, as padded flat indices.
        iy, ix = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
        local = ((iy + k) * gp + (ix + k)).ravel()
        self.cells = (np.arange(n_sets)[:, None] * self.gp2 + local[None, :]).ravel()
        self.cell_x = np.tile(ix.ravel().astype(_F) / _F(g), n_sets)
        self.cell_y = np.tile(iy.ravel().astype(_F) / _F(g), n_sets)
        # Periodic copies in the padding: padded cell (Y, X) shows the primary cell
        # ((Y - K) mod G, (X - K) mod G) shifted by ((Y - K) // G, (X - K) // G).
        yy, xx = np.divmod(np.arange(self.gp2), gp)
        sy, sx = (yy - k) // g, (xx - k) // g
        src = ((yy - k) % g + k) * gp + (xx - k) % g + k
        is_copy = (sy != 0) | (sx != 0)
        order = np.argsort(src[is_copy], kind="stable")
        self.copy_dst = np.flatnonzero(is_copy)[order]
        self.copy_sx = sx[is_copy][order].astype(_F)
        self.copy_sy = sy[is_copy][order].astype(_F)
        self.n_copies = np.bincount(src[is_copy], minlength=self.gp2)
        self.first_copy = np.cumsum(self.n_copies) - self.n_copies
        # Offsets of the cells that may hold a point closer than r.
        offsets, gaps = [], []
        for dy in range(-k, k + 1):
            gy = max(abs(dy) - 1, 0) * self.s
            for dx in range(-k, k + 1):
                gx = max(abs(dx) - 1, 0) * self.s
                if gx * gx + gy * gy < self.r * self.r * (1 + 1e-9):
                    offsets.append(dy * gp + dx)
                    gaps.append((gx, gy))
        self.offs = np.array(offsets, dtype=np.int64)[:, None]
        self.gaps = np.array(gaps)  # per offset: distance between the cells along x, y

    def _scatter(self, arrays: tuple[np.ndarray, ...], p: np.ndarray, x: np.ndarray,
                 y: np.ndarray, *more: np.ndarray) -> None:
        """Write points (x, y, more...) of primary cells ``p`` and all their images."""
        for arr, v in zip(arrays, (x, y) + more):
            arr[p] = v
        local = p % self.gp2
        cnt = self.n_copies[local]
        total = int(cnt.sum())
        if total == 0:
            return
        rep = np.repeat(np.arange(len(p)), cnt)
        j = np.arange(total) + np.repeat(self.first_copy[local] - (np.cumsum(cnt) - cnt), cnt)
        q = (p - local)[rep] + self.copy_dst[j]
        values = (x[rep] + self.copy_sx[j], y[rep] + self.copy_sy[j]) + tuple(v[rep] for v in more)
        for arr, v in zip(arrays, values):
            arr[q] = v

    @staticmethod
    def _blocks(m: int, width: int):
        """Column ranges of blocks of about ``_BLOCK`` elements."""
        step = max(1, _BLOCK // max(width, 1))
        return ((i, min(i + step, m)) for i in range(0, m, step))

    def run(self) -> None:
        """Throw darts until every set has ``n`` points or is (nearly) maximal."""
        sq = self.cells
        x0, y0 = self.cell_x, self.cell_y
        h = self.s
        # First round on an empty grid: darts in a random subset of the cells. With
        # darts in every cell most would be rejected by a neighbour of higher priority.
        pick = np.flatnonzero(self.rng.random(len(sq), dtype=_F) < _F(_FIRST_FRACTION))
        self._round(sq[pick], x0[pick], y0[pick], h)
        keep = self.px[sq] == _EMPTY
        sq, x0, y0 = sq[keep], x0[keep], y0[keep]
        for level, rounds in enumerate(_ROUNDS):
            if level > 0:
                if len(sq) == 0:
                    break
                sq, x0, y0, h = self._split(sq, x0, y0, h)
            for _ in range(rounds):
                if len(sq) == 0:
                    break
                self._round(sq, x0, y0, h)
                keep = (self.px[sq] == _EMPTY) & ~self.done[sq // self.gp2]
                sq, x0, y0 = sq[keep], x0[keep], y0[keep]

    def _split(self, sq, x0, y0, h):
        """Split squares into four; drop children inside the disk of one point."""
        h *= 0.5
        r2 = self.r2
        # Only a point whose cell is close enough can hold a whole child in its disk.
        offs = self.offs[((self.gaps + h) ** 2).sum(axis=1) < self.r * self.r]
        c1, c2, e = _F(0.5 * h), _F(1.5 * h), _F(0.5 * h)  # child centres, half side
        cov = np.empty((4, len(sq)), dtype=bool)
        for i, j in self._blocks(len(sq), len(offs)):
            idx = offs + sq[i:j]
            ex = self.px.take(idx)
            ex -= x0[i:j]
            ey = self.py.take(idx)
            ey -= y0[i:j]
            fx1 = np.abs(ex - c1)
            fx1 += e
            fx1 *= fx1
            fx2 = np.abs(ex - c2)
            fx2 += e
            fx2 *= fx2
            fy1 = np.abs(ey - c1)
            fy1 += e
            fy1 = r2 - fy1 * fy1
            fy2 = np.abs(ey - c2)
            fy2 += e
            fy2 = r2 - fy2 * fy2
            # Child (cx, cy) is covered if (far corner distance)^2 < r^2 for some point.
            np.logical_or.reduce(fx1 < fy1, axis=0, out=cov[0, i:j])
            np.logical_or.reduce(fx2 < fy1, axis=0, out=cov[1, i:j])
            np.logical_or.reduce(fx1 < fy2, axis=0, out=cov[2, i:j])
            np.logical_or.reduce(fx2 < fy2, axis=0, out=cov[3, i:j])
        idx = np.flatnonzero(~cov.T.ravel())
        parent, child = idx // 4, idx % 4
        hf = _F(h)
        return (sq[parent], x0[parent] + hf * (child & 1), y0[parent] + hf * (child >> 1), h)

    def _near(self, gx, gy, c, x, y, prio=None) -> np.ndarray:
        """Per dart: is a point of the grids ``gx, gy`` (with a higher priority
        in ``dprio`` if ``prio`` is given) closer than ``r``?"""
        out = np.empty(len(c), dtype=bool)
        for i, j in self._blocks(len(c), len(self.offs)):
            idx = self.offs + c[i:j]
            ex = gx.take(idx)
            ex -= x[i:j]
            ex *= ex
            ey = gy.take(idx)
            ey -= y[i:j]
            ey *= ey
            ex += ey
            hit = ex < self.r2
            if prio is not None:
                hit &= self.dprio.take(idx) > prio[i:j]
            np.logical_or.reduce(hit, axis=0, out=out[i:j])
        return out

    def _round(self, sq, x0, y0, h) -> None:
        """One dart per active square; accept a conflict-free subset."""
        m = len(sq)
        u = self.rng.random((2, m), dtype=_F)
        hf = _F(h)
        x = x0 + hf * u[0]
        y = y0 + hf * u[1]
        # Distinct priorities, a random order, all above those of earlier rounds.
        prio = self.rng.permutation(m) + self.next_prio
        base = self.next_prio
        self.next_prio += m
        # 1. Drop darts closer than r to an existing point.
        if not self.count.any():  # nothing accepted yet
            idx = np.arange(m)
        else:
            idx = np.flatnonzero(~self._near(self.px, self.py, sq, x, y))
        if len(idx) == 0:
            return
        c, x, y, prio = sq[idx], x[idx], y[idx], prio[idx]
        # 2. One dart per cell (the highest priority): they would collide.
        #    (At level 0 there is one square per cell.)
        if h < self.s:
            np.maximum.at(self.dprio, c, prio)
            win = self.dprio[c] == prio
            c, x, y, prio = c[win], x[win], y[win], prio[win]
        # 3. Keep darts with no higher-priority dart closer than r (Luby).
        self._scatter((self.dx, self.dy, self.dprio), c, x, y, prio)
        ok = ~self._near(self.dx, self.dy, c, x, y, prio)
        c, x, y, prio = c[ok], x[ok], y[ok], prio[ok]
        # 4. Accept, keeping at most n points per set (earliest in priority order).
        b = c // self.gp2
        added = np.bincount(b, minlength=self.n_sets)
        room = self.n - self.count
        if np.any(added > room):
            order = np.lexsort((-prio, b))
            sb = b[order]
            rank = np.arange(len(sb)) - np.searchsorted(sb, sb, side="left")
            order = order[rank < room[sb]]
            c, x, y, prio, b = c[order], x[order], y[order], prio[order], b[order]
            added = np.bincount(b, minlength=self.n_sets)
        self.key[c] = self.round + (1.0 - (prio - base) / m)
        self._scatter((self.px, self.py), c, x, y)
        self.count += added
        self.done |= self.count >= self.n
        self.round += 1

    def points(self) -> np.ndarray:
        """``(n_sets, n, 2)`` float64 points of complete sets, in acceptance order,
        wrapped into [0, 1) (other sets: garbage)."""
        keys = self.key[self.cells].reshape(self.n_sets, -1)
        order = np.argsort(keys, axis=1, kind="stable")[:, :self.n]
        p = np.take_along_axis(self.cells.reshape(self.n_sets, -1), order, axis=1)
        pts = np.stack((self.px[p], self.py[p]), axis=-1).astype(np.float64)
        pts[pts >= 1.0] -= 1.0  # a dart rounded up onto x = 1 is the point x = 0
        return pts


def _generate_batch(n: int, n_sets: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One attempt at ``n_sets`` sets: the points and which sets are complete."""
    batch = _Batch(n, n_sets, RHO_TARGET * d_hex(n), rng)
    batch.run()
    return batch.points(), batch.done


def generate(n: int, n_sets: int, seed: int = 0) -> np.ndarray:
    """``n_sets`` toroidal Poisson-disk sets of ``n`` points, ``(n_sets, n, 2)`` float64.

    Every set's toroidal minimum distance is verified to be at least
    ``RHO_TARGET * d_hex(n)``; coordinates are float32 numbers in [0, 1), points
    in acceptance order. Deterministic in ``(n, n_sets, seed)`` (``seed >= 0``).
    """
    _check_n(n)
    if n_sets < 0:
        raise ValueError(f"n_sets must be >= 0, got {n_sets}")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), int(n)])))
    if n == 1:
        return rng.random((n_sets, 1, 2), dtype=np.float32).astype(np.float64)
    out = np.empty((n_sets, n, 2))
    todo = np.arange(n_sets)
    threshold = RHO_TARGET * d_hex(n)
    for _ in range(_MAX_ATTEMPTS):
        if len(todo) == 0:
            return out
        # Small sets fail (saturate below n points) up to ~20% of the time: throw
        # a few extra sets at once instead of paying for another pass.
        extra = math.ceil(0.2 * len(todo)) + 2 if n < 128 else \
            math.ceil(0.05 * len(todo)) + 1 if n < 512 else 0
        pts, ok = _generate_batch(n, len(todo) + extra, rng)
        ok[ok] = toroidal_min_distances(pts[ok]) >= threshold
        good = np.flatnonzero(ok)[:len(todo)]
        out[todo[:len(good)]] = pts[good]
        todo = todo[len(good):]
    raise RuntimeError(f"could not generate {len(todo)} Poisson-disk sets of {n} points")


# --------------------------------------------------------------------------- tables + cache

_MEMORY: dict[int, np.ndarray] = {}
_LOCK = threading.Lock()


def cache_dir() -> Path:
    """Directory of the on-disk tables: ``<cache>/poisson`` (see the module docstring)."""
    from ..cache import cache_dir as shared_cache_dir  # lazy: this module also loads standalone

    return shared_cache_dir("poisson")


def cache_path(n: int) -> Path:
    """Cache file of the tables for ``n`` points (includes :data:`VERSION` and ``T``)."""
    return cache_dir() / f"v{VERSION}-n{n}-t{n_tables(n)}.npz"


def _key(n: int) -> str:
    """What a cached table belongs to (checked on load with the checksum)."""
    return f"poisson-v{VERSION}-n{n}-t{n_tables(n)}-seed{TABLE_SEED}"


def clear_memory_cache() -> None:
    """Forget the tables held in memory (the disk cache is left alone)."""
    with _LOCK:
        _MEMORY.clear()


def _valid(tables: object, n: int) -> bool:
    """Whether ``tables`` are acceptable tables for ``n`` points (shape, dtype, range, rho)."""
    if not isinstance(tables, np.ndarray) or tables.dtype != np.float32:
        return False
    if tables.shape != (n_tables(n), n, 2):
        return False
    if not (np.all(tables >= 0.0) and np.all(tables < 1.0)):  # also rejects NaN
        return False
    return bool(np.all(toroidal_min_distances(tables) >= RHO_TARGET * d_hex(n)))


def _read(path: Path, n: int) -> np.ndarray | None:
    """The cached tables at ``path`` if intact (key, checksum) and valid, else
    None; a damaged or invalid file is set aside with a note."""
    from ..core.job import Checkpoint, set_aside  # lazy: this module also loads standalone

    try:
        found = Checkpoint.load(path, _key(n))
    except Exception:  # e.g. the path is a directory
        return None
    if found is None:
        return None
    tables = found.arrays.get("tables")
    if not _valid(tables, n):
        set_aside(path, "not a valid Poisson-disk table")
        return None
    return tables


def _write(path: Path, tables: np.ndarray, n: int | None = None) -> bool:
    """Store ``tables`` atomically (:class:`mcrt.core.job.Checkpoint`); False (and
    nothing left behind) on any error, ``KeyboardInterrupt`` included."""
    from ..core.job import Checkpoint

    n = tables.shape[1] if n is None else n
    try:
        Checkpoint({"n": n}, {"tables": tables}).save(path, _key(n))
        return True
    except Exception:  # best effort: read-only or full disk, odd file systems, ...
        return False


def load_tables(n: int, *, disk_cache: bool = True) -> np.ndarray:
    """The ``T = n_tables(n)`` point sets of ``n`` points, ``(T, n, 2)`` float32 in [0, 1).

    Generated with :func:`generate` (``seed = TABLE_SEED``) on first use, then served
    from memory and from the disk cache (unless ``disk_cache`` is False). The
    returned array is shared and read-only.
    """
    _check_n(n)
    with _LOCK:
        tables = _MEMORY.get(n)
        if tables is not None:
            return tables
        path = cache_path(n) if disk_cache else None
        tables = _read(path, n) if path is not None else None
        if tables is None:
            log.info("building the poisson_disk tables for %d samples per pixel (once: they are "
                     "cached%s)", n, f" in {path}" if path is not None else " in memory")
            points = generate(n, n_tables(n), TABLE_SEED)  # verified, float32 values
            tables = points.astype(np.float32)
            if not np.array_equal(tables, points) and not _valid(tables, n):
                raise RuntimeError(f"Poisson-disk tables for n={n} failed validation")
            if path is not None:
                _write(path, tables, n)
        tables.setflags(write=False)
        _MEMORY[n] = tables
        return tables
