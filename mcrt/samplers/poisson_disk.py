"""Poisson-disk (blue-noise) sampling from precomputed, decorrelated tables."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ._hash import hash_extend, permute
from ._stratified import epoch_key, split_sample, stratified_1d
from ._types import Mask
from .base import McrtSampler

# .poisson_tables (numpy) is imported on first use: `import mcrt` registers this
# plugin, and most programs never construct it.

#: Device copies of the tables by (variant, point count).
_TABLES: dict[tuple[str | None, int], tuple[mi.Float, mi.Float, int]] = {}


def _device_tables(n: int) -> tuple[mi.Float, mi.Float, int]:
    """Tables for ``n`` points as flat Dr.Jit arrays (x, y) and the table count.

    Kept out of the sampler's ``__dict__`` on purpose: Dr.Jit turns every array
    stored there into loop state, and a table is not per-lane state.
    """
    key = (mi.variant(), n)
    if key not in _TABLES:
        from .poisson_tables import load_tables

        tables = load_tables(n)  # (T, n, 2) float32, generated and cached on first use
        _TABLES[key] = (mi.Float(tables[:, :, 0].ravel()), mi.Float(tables[:, :, 1].ravel()),
                        tables.shape[0])
    return _TABLES[key]


#: Largest float32 below 1.
ONE_MINUS_EPSILON = float.fromhex("0x1.fffffep-1")
INV_2_16 = 1.0 / (1 << 16)


def _wrap(v: mi.Float) -> mi.Float:
    """``v mod 1`` for ``v`` in [0, 2]: exact (Sterbenz) and always below 1."""
    return dr.minimum(dr.select(v >= 1.0, v - 1.0, v), ONE_MINUS_EPSILON)


class PoissonDiskSampler(McrtSampler):
    r"""
    .. _sampler-poisson_disk:

    Poisson-disk sampler (:monosp:`poisson_disk`)
    ---------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Samples per pixel: the size of each pixel's point set, any value from 1
         to :data:`~mcrt.samplers.poisson_tables.MAX_POINTS`. (Default: 4)
     * - seed
       - |int|
       - Seed offset. (Default: 0)

    Every 2D dimension pair of every pixel gets a Poisson-disk point set of
    ``N`` points whose toroidal minimum distance is at least
    ``0.75 * d_hex`` (``d_hex = sqrt(2 / (sqrt(3) N))``, the spacing of a
    hexagonal packing of ``N`` points), as good as maximal dart throwing, with no
    low-frequency spectral energy (blue noise).

    The sets come from a small number of precomputed tables
    (:mod:`mcrt.samplers.poisson_tables`, generated deterministically and cached
    on disk on first use). Each (seed, pixel, dimension, epoch) picks a table,
    one of the 8 symmetries of the square, a toroidal shift and a permutation
    of the sample order. All four preserve toroidal distances, so every set keeps
    the spacing guarantee while pixels and dimensions are decorrelated.

    1D dimensions use ``N`` jittered strata (as :monosp:`jittered`).

    .. tabs::

        .. code-tab:: python

            'type': 'poisson_disk',
            'sample_count': 64
    """

    plugin_name = "poisson_disk"

    def _effective_count(self, spp: int) -> int:
        from .poisson_tables import MAX_POINTS

        if spp > MAX_POINTS:
            raise self._too_many(MAX_POINTS, spp, "its largest precomputed point set")
        return spp

    def _sample_count_changed(self, spp: int) -> None:
        _device_tables(spp)  # generate / load now, not in the middle of a render

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        return stratified_1d(key, sample, self.sample_count(), 1.0, active)

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        n = self.sample_count()
        table_x, table_y, n_tables = _device_tables(n)
        epoch, rank = split_sample(sample, n)
        set_key = epoch_key(key, epoch)
        index = permute(rank, n, set_key, active)
        # The set key is a well-mixed hash already: its bits pick the table and
        # the symmetry directly; one more mix gives the shift.
        table = ((set_key >> 8) & 0xFFFF) % n_tables
        point = table * n + index
        x = dr.gather(mi.Float, table_x, point, active)
        y = dr.gather(mi.Float, table_y, point, active)
        symmetry = set_key >> 29  # 3 bits: swap axes, mirror x, mirror y
        x, y = dr.select((symmetry & 1) != 0, y, x), dr.select((symmetry & 1) != 0, x, y)
        x = dr.select((symmetry & 2) != 0, 1.0 - x, x)
        y = dr.select((symmetry & 4) != 0, 1.0 - y, y)
        shift = hash_extend(set_key, 0x9D15C)  # 16 bits per axis: a shift on a 2^-16 grid
        x = _wrap(x + mi.Float(shift >> 16) * INV_2_16)
        y = _wrap(y + mi.Float(shift & 0xFFFF) * INV_2_16)
        return mi.Point2f(x, y)
