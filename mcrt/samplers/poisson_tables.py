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
``rho = d_min / d_hex ~ 0.78`` [RSA]_, but leaves a low-frequency floor in the
spectrum (~0.075 near ``k = 0`` at every ``n``: a random packing's density
fluctuates on every scale), so Poisson-disk sets gained only a constant factor
over random points (error slope -1.2 on an edge against jittering's -1.5). The
sets are therefore relaxed after dart throwing (a few particle-mesh and
Gaussian-blue-noise steps with a hard core, :mod:`mcrt.samplers._poisson_relax`):
the averaged power spectrum is ~0.004-0.005 for ``f = |k| d < 0.5`` (``mcrt
pattern``'s low-frequency power), peaks at ~2.0-2.6 around ``|k| ~ 1.0-1.06
sqrt(n)`` and then oscillates around 1, and ``rho`` stays >= 0.765.
The descent stops early, before the sets drift towards a lattice (whose spectrum
has sharp peaks). Every set is verified with the exact
:func:`toroidal_min_distances` and regenerated if it falls short; tables read
from disk are validated too.
Sets of one point have no minimum distance (the requirement is void).

Algorithm
=========

First, maximal Poisson-disk sampling by dart throwing at the fixed radius
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
5. The complete sets are relaxed (see above; the relaxation's hard core is
   ``0.765 d_hex``) and rounded to float32; the exact check follows.

The work is linear in the number of points: every round and split handles flat
blocks of (25 neighbour offsets x active squares), and the number of rounds is
fixed (per 16,384 points on a 2-core machine: dart throwing ~0.08 s, the
relaxation ~0.15 s). :func:`generate` checks the spacing of the float32-rounded sets
in float64 and returns these float32-representable values, and the float32
tables store them without rounding. Points are listed in acceptance order, so a
prefix of a set is itself well spread. Compared with
``scipy.stats.qmc.PoissonDisk`` (Bridson's algorithm [Bri07]_, one Python loop
iteration per candidate, not toroidal, not maximal) the dart throwing is one to
two orders of magnitude faster, see ``BENCHMARKS.md``.

Determinism and caching
=======================

``generate(n, n_sets, seed)`` draws everything from
``np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, n])))``
and uses only correctly rounded arithmetic, fixed-order sums and numpy's own
FFT, so the same arguments give the same bits on every run and machine for a
given numpy (numpy keeps ``Generator`` streams and its FFT stable in practice
but does not promise it across versions, which is harmless: a cached table
stays valid; workers of one cluster should run one numpy). :func:`load_tables`
uses ``seed = TABLE_SEED`` and caches the float32 tables in memory and in
``<cache>/poisson/v{VERSION}-n{n}-t{T}.npz`` (a :class:`mcrt.core.state_file.Checkpoint`:
the table's key and a checksum of its content), where ``<cache>`` is
``$MCRT_CACHE_DIR`` if set and non-empty, else ``$XDG_CACHE_HOME/mcrt`` or
``~/.cache/mcrt``. Bump :data:`VERSION` whenever the output changes, so stale
files are never reused. Files are written atomically (temporary file in the same
directory, then ``os.replace``); unreadable, damaged or wrong files (checked:
key, checksum, shape, dtype, range and spacing) are set aside as ``*.damaged``
with a note, regenerated and replaced, and an unwritable
cache directory only means the tables are not stored (one note, the one failure
policy of saved state, :class:`mcrt.core.state_file.Saving`).

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

from ._poisson_darts import generate_batch
from ._poisson_relax import close_pairs, relax

log = logging.getLogger("mcrt.poisson")

__all__ = [
    "MAX_POINTS", "RHO_GUARANTEE", "RHO_TARGET", "TABLE_SEED", "VERSION",
    "cache_dir", "cache_path", "clear_memory_cache", "d_hex", "generate", "load_tables",
    "n_tables", "toroidal_min_distance", "toroidal_min_distances",
]

#: Largest supported set size. First-time generation of its 8 tables takes about
#: 1.7 s on a 2-core machine (see BENCHMARKS.md); the cost is linear in n.
MAX_POINTS = 16384

#: Version of the generator's output; part of the cache file name.
VERSION = 3

#: Spacing the sampler promises (``d_min >= RHO_GUARANTEE * d_hex``).
RHO_GUARANTEE = 0.75

#: Spacing every generated set and every table is verified against (the radius).
RHO_TARGET = 0.76

#: Seed of the tables behind :func:`load_tables` (mixed with ``n``).
TABLE_SEED = 0x5EED_B1E

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

def toroidal_min_distances(points: np.ndarray) -> np.ndarray:
    """Exact toroidal minimum distance of every set in ``points`` (``(B, n, 2)``).

    Returns a float64 array of shape ``(B,)``; ``inf`` for sets of fewer than two
    points. Coordinates are taken mod 1. No ``n`` points on the torus are all
    farther apart than ``d_hex(n)`` (the hexagonal packing bound), so the closest
    pair is among the pairs closer than ``1.01 d_hex(n)``, which
    :func:`~mcrt.samplers._poisson_relax.close_pairs` finds in a grid of cells:
    linear time for well-spread points, never worse than a few times brute force.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 2:
        raise ValueError(f"expected an array of shape (B, n, 2), got {pts.shape}")
    n_sets, n = pts.shape[:2]
    if n < 2 or n_sets == 0:
        return np.full(n_sets, np.inf)
    if not np.all(np.isfinite(pts)):
        raise ValueError("points must be finite")
    i, _, d = close_pairs(pts - np.floor(pts), 1.01 * d_hex(n))
    best = np.full(n_sets, np.inf)
    np.minimum.at(best, i // n, (d * d).sum(axis=1))
    return np.sqrt(best)


def toroidal_min_distance(points: np.ndarray) -> float:
    """Exact minimum distance between two of ``points`` (``(n, 2)``) on the unit torus.

    ``inf`` for fewer than two points (the spacing requirement is then void).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"expected an array of shape (n, 2), got {pts.shape}")
    return float(toroidal_min_distances(pts[None])[0])


# --------------------------------------------------------------------------- generator

def _float32_torus(points: np.ndarray) -> np.ndarray:
    """``points`` rounded to float32 values in [0, 1) (a coordinate rounding up to 1
    becomes 0: the same place on the torus), as float64."""
    p = points.astype(np.float32)
    p[p >= 1.0] = 0.0
    return p.astype(np.float64)


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
        pts, ok = generate_batch(n, len(todo) + extra, RHO_TARGET * d_hex(n), rng)
        pts[ok] = _float32_torus(relax(pts[ok]))
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
    from ..cache import cache_dir as shared_cache_dir  # lazy: only when tables are cached

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
    from ..core.state_file import Checkpoint  # lazy: only when tables are cached

    found = Checkpoint.load(path, _key(n), valid=lambda c: _valid(c.arrays.get("tables"), n),
                            invalid="not a valid Poisson-disk table")
    return None if found is None else found.arrays["tables"]


def _write(path: Path, tables: np.ndarray, n: int | None = None) -> bool:
    """Store ``tables`` atomically (:class:`mcrt.core.state_file.Checkpoint`); a
    failure (read-only or full disk, ...) is noted under the one failure policy
    (:class:`mcrt.core.state_file.Saving`) and gives False. Nothing is left behind
    on any error, ``KeyboardInterrupt`` included (which propagates)."""
    from ..core.state_file import Checkpoint, Saving

    n = tables.shape[1] if n is None else n
    saving = Saving(f"the poisson_disk tables for {n} samples per pixel",
                    "they are kept in memory, for this process only")
    return saving(lambda: Checkpoint({"n": n}, {"tables": tables}).save(path, _key(n)))


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
