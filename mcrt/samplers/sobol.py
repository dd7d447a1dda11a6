"""Progressive, padded, Owen-scrambled Sobol' sampling."""

from __future__ import annotations

import mitsuba as mi

from ._sobol import padded_sobol_1d, padded_sobol_2d
from ._types import Mask
from .base import McrtSampler


class SobolSampler(McrtSampler):
    r"""
    .. _sampler-sobol:

    Owen-scrambled Sobol' sampler (:monosp:`sobol`)
    -----------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Samples per pixel; any positive count. (Default: 4)
     * - seed
       - |int|
       - Seed offset. (Default: 0)

    Every dimension pair (film position, lens, light, BSDF, ...) of every pixel
    is its own Owen-scrambled Sobol' (0,2)-sequence (dimensions 0 and 1 of
    Sobol', scrambled by hashing as in Burley 2020), and every 1D dimension its
    own scrambled (0,1)-sequence. The sample index is Owen-scrambled too, with a
    key per (seed, pixel, dimension), which decorrelates the pairs ("padding").
    See :mod:`mcrt.samplers._sobol`.

    The sampler is *progressive*: a pixel's samples continue one sequence
    across passes and adaptive batches (sample ``j`` is always the same point),
    so the first ``2^m`` samples of a pixel, and every aligned block of ``2^m``,
    form a (0,m,2)-net: each elementary interval of area ``2^-m`` holds exactly
    one point. Counts between powers of two are fine, with the stratification
    of the largest power of two below.

    .. tabs::

        .. code-tab:: python

            'type': 'sobol',
            'sample_count': 64
    """

    plugin_name = "sobol"
    summary = "progressive, padded, Owen-scrambled Sobol' (0,2)-sequences"
    claims = frozenset({"net"})
    progressive = True

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        return padded_sobol_1d(sample, key)

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        return padded_sobol_2d(sample, key)


PLUGINS = (SobolSampler,)
