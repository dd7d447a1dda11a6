"""The dart-throwing engine behind :mod:`mcrt.samplers.poisson_tables`.

Maximal Poisson-disk sampling at a fixed radius on the unit torus, with the cell
and sub-cell bookkeeping of Ebeida et al. and Wei's grid-parallel darts, run
with numpy on many sets at once (the algorithm and its references are in
:mod:`mcrt.samplers.poisson_tables`, which checks and caches what this makes).
"""

from __future__ import annotations

import math

import numpy as np

BLOCK = 1 << 15              # elements per (darts x neighbours) block
_ROUNDS = (3, 1, 2, 2, 2, 2)  # dart rounds at sub-cell level 0, 1, ...
_FIRST_FRACTION = 0.35       # share of the cells in the first round

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
        for arr, v in zip(arrays, (x, y) + more, strict=True):
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
        for arr, v in zip(arrays, values, strict=True):
            arr[q] = v

    @staticmethod
    def _blocks(m: int, width: int):
        """Column ranges of blocks of about ``BLOCK`` elements."""
        step = max(1, BLOCK // max(width, 1))
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


def generate_batch(n: int, n_sets: int, radius: float,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One attempt at ``n_sets`` sets of ``n`` points at least ``radius`` apart
    on the torus: the points and which sets are complete."""
    batch = _Batch(n, n_sets, radius, rng)
    batch.run()
    return batch.points(), batch.done
