"""Poisson-disk (blue-noise) sampling from precomputed, decorrelated tables."""

from __future__ import annotations

import mitsuba as mi

from ._stratified import stratified_1d
from ._types import Mask
from .base import McrtSampler
from .pointset import device_table, draw_from_tables

# .poisson_tables (numpy) is imported on first use: `import mcrt` registers this
# plugin, and most programs never construct it.

def _device_tables(n: int) -> tuple[mi.Float, mi.Float, int]:
    """Tables for ``n`` points as flat Dr.Jit arrays (x, y) and the table count."""
    from .poisson_tables import load_tables

    return device_table(("poisson_disk", n), lambda: load_tables(n))


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
    summary = "blue-noise Poisson-disk sets from decorrelated tables"
    claims = frozenset({"min_distance"})

    def _effective_count(self, spp: int) -> int:
        from .poisson_tables import MAX_POINTS

        if spp > MAX_POINTS:
            raise self._too_many(MAX_POINTS, spp, "its largest precomputed point set")
        return spp

    def _sample_count_changed(self, spp: int) -> None:
        _device_tables(spp)  # generate / load now, not in the middle of a render

    def frozen_inputs(self) -> tuple:
        return _device_tables(self.sample_count())[:2]

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        return stratified_1d(key, sample, self.sample_count(), 1.0, active)

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        n = self.sample_count()
        return draw_from_tables(key, sample, n, _device_tables(n), "symmetry_shift", active)


PLUGINS = (PoissonDiskSampler,)
