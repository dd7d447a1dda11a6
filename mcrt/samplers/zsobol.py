"""Screen-space blue-noise Sobol' sampling: Morton-ordered, digit-permuted (ZSobol)."""

from __future__ import annotations

import logging

import drjit as dr
import mitsuba as mi

from ..errors import SamplerError
from ._hash import hash_extend, mix32, mix32_int
from ._sobol import scrambled_sobol_1d, scrambled_sobol_2d, shuffle_index
from ._types import Mask
from .base import McrtSampler

log = logging.getLogger(__name__)

#: The 6 invertible 2x2 matrices over GF(2), 4 bits each (columns as 2-bit
#: vectors): every ordered pair of distinct non-zero columns. With the 4
#: translations they form AGL(2, 2), which is all 24 permutations of a base-4 digit.
_GL22 = [(a, b) for a in (1, 2, 3) for b in (1, 2, 3) if a != b]
_GL22_PACKED = sum((a | b << 2) << (4 * i) for i, (a, b) in enumerate(_GL22))


def permute_digit(digit: mi.UInt32, h: mi.UInt32) -> mi.UInt32:
    """Permutation number ``floor(24 * (h >> 8) / 2^24)`` of S4 applied to a
    base-4 ``digit``, as the affine map ``A digit + c`` over GF(2)^2."""
    v = ((h >> 8) * 24) >> 24  # uniform in [0, 24)
    matrix = (mi.UInt32(_GL22_PACKED) >> ((v >> 2) << 2)) & 15
    col0 = dr.select((digit & 1) != 0, matrix & 3, 0)
    col1 = dr.select((digit & 2) != 0, matrix >> 2, 0)
    return col0 ^ col1 ^ (v & 3)


def permute_digits(index: mi.UInt32, bits: int, key: mi.UInt32) -> mi.UInt32:
    """Owen-scramble the ``bits``-bit ``index`` in base 4 from its top digit:
    each digit is permuted by a random permutation chosen by the digits above
    it (and ``key``). A lowest base-2 digit (odd ``bits``) is flipped at random.

    An aligned block of indices (a pixel's samples, a 2x2 quad of pixels, ...)
    therefore maps onto an aligned block of the same size."""
    out = mi.UInt32(0)
    odd = bits & 1
    for shift in range(bits - 2, odd - 1, -2):
        digit = (index >> shift) & 3
        higher = index >> (shift + 2) if shift + 2 < 32 else mi.UInt32(0)
        out = out | (permute_digit(digit, _level_hash(higher, key, shift)) << shift)
    if odd:
        out = out | ((index & 1) ^ (_level_hash(index >> 1, key, 0) >> 31))
    return out


def _level_hash(higher: mi.UInt32, key: mi.UInt32, shift: int) -> mi.UInt32:
    """Hash of (digits above a level, key, level); its top bits are used."""
    return mix32(higher ^ (key + mix32_int(shift + 0x5A17)))


def spread_bits(v: mi.UInt32) -> mi.UInt32:
    """The 16 low bits of ``v`` moved to the even bit positions."""
    v = (v | (v << 8)) & 0x00FF00FF
    v = (v | (v << 4)) & 0x0F0F0F0F
    v = (v | (v << 2)) & 0x33333333
    return (v | (v << 1)) & 0x55555555


def tile_bits(width: int, log2_spp: int) -> int:
    """log2 of the side of the square Morton tiles: the film width rounded up to
    a power of two, smaller when the index (2 bits per level plus the sample
    bits) would not fit in 32 bits."""
    return min((width - 1).bit_length(), (32 - log2_spp) // 2)


def zsobol_index(pixel: mi.UInt32, sample: mi.UInt32, width: int, log2_spp: int,
                 seed_key: mi.UInt32) -> tuple[mi.UInt32, mi.UInt32]:
    """Digit-permuted index and key of sample ``sample`` of linear pixel ``pixel``.

    The index is ``Morton(x, y) << log2_spp | rank`` inside a square tile,
    digit-permuted. Tiles (rows of tiles below a film wider than it is tall)
    and epochs (``sample // spp``: later passes) get keys of their own. The
    same for every dimension: :func:`zsobol_dimension` makes them differ."""
    t = tile_bits(width, log2_spp)
    side = 1 << t
    y = pixel // width
    x = pixel - y * width
    tile = (y >> t) * ((width + side - 1) >> t) + (x >> t)
    morton = spread_bits(x & (side - 1)) | (spread_bits(y & (side - 1)) << 1)
    epoch = sample >> log2_spp
    index = (morton << log2_spp) | (sample & ((1 << log2_spp) - 1))
    key = hash_extend(seed_key, tile, epoch)
    return permute_digits(index, 2 * t + log2_spp, key), key


def zsobol_dimension(index: mi.UInt32, key: mi.UInt32,
                     dim: mi.UInt32) -> tuple[mi.UInt32, mi.UInt32]:
    """Sobol' index and scrambling key of one dimension: the digit-permuted
    index Owen-scrambled in base 2 by a key of (seed, tile, epoch, dimension).

    The scramble is nested from the top bit and the same for all pixels of a
    tile, so aligned blocks (pixels, quads of pixels) stay aligned blocks,
    while each dimension gets its own assignment of samples to points (padding:
    as in ``sobol``). Composed with the shared uniform base-4 permutations it is
    again a uniform permutation of every digit, in every dimension."""
    dim_key = hash_extend(key, dim)
    return shuffle_index(index, dim_key), dim_key


class ZSobolSampler(McrtSampler):
    r"""
    .. _sampler-zsobol:

    Blue-noise Sobol' sampler (:monosp:`zsobol`)
    --------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Samples per pixel, rounded up to a power of two (with a logged note).
         (Default: 4)
     * - width
       - |int|
       - Width of the film's pixel grid (its crop width, plus twice the filter
         border when the film samples the border). mcrt fills it in whenever it
         renders; a plain Mitsuba scene must give it.
     * - seed
       - |int|
       - Seed offset. (Default: 0)

    Ahmed and Wonka, "Screen-Space Blue-Noise Diffusion of Monte Carlo Sampling
    Error via Hierarchical Ordering of Pixels" (SIGGRAPH Asia 2020), as in
    pbrt-v4's ``ZSobolSampler``: sample ``j`` of pixel ``(x, y)`` takes index
    ``Morton(x, y) * spp + j`` of one Owen-scrambled Sobol' (0,2)-sequence per
    dimension pair, after a random permutation of every base-4 digit of that
    index chosen by the digits above it. A pixel's samples are a (0,m,2)-net,
    and so are those of every aligned 2x2, 4x4, ... block of pixels, so
    neighbouring pixels' errors cancel: the error is blue noise over the screen.

    Passes beyond the sample count start a fresh, independently scrambled
    pattern per ``spp`` samples (for progressive nets across passes, use
    :monosp:`sobol`).

    .. tabs::

        .. code-tab:: python

            'type': 'zsobol',
            'sample_count': 16,
            'width': 640
    """

    plugin_name = "zsobol"
    summary = "Morton-ordered, digit-permuted Sobol': blue-noise error over the screen"
    claims = frozenset({"net"})

    def _configure(self, props: mi.Properties) -> None:
        self.width = 0
        if "width" in props:
            self.set_film_width(props["width"])

    @staticmethod
    def example_params(spp: int) -> dict:
        return {"width": 8}

    def _parameters(self) -> dict:
        return {"width": self.width} if self.width else {}

    def _effective_count(self, spp: int) -> int:
        count = 1 << (spp - 1).bit_length()
        if count > 1 << 16:
            raise self._too_many(1 << 16, spp, "its Morton index keeps 16 bits per pixel "
                                                     "for the sample")
        if count != spp:
            log.warning("%s: sample count %d is not a power of two, rounding up to %d",
                        self.plugin_name, spp, count)
        return count

    def _sample_count_changed(self, spp: int) -> None:
        self.log2_spp = spp.bit_length() - 1

    def set_film_width(self, width: object) -> None:
        """Set the width of the pixel grid the sampler renders (``width``)."""
        if isinstance(width, bool) or not isinstance(width, int) or width <= 0:
            raise SamplerError(f"{self.plugin_name}: 'width' must be a positive integer (the "
                               f"film width in pixels), got {width!r}")
        self.width = width

    def _set_lanes(self, pixel: mi.UInt32, first_sample: mi.UInt32, stride: int) -> None:
        """As the base class, but keeps the raw pixel index (the Morton order
        needs it) where the base keeps the (seed, pixel) hash."""
        if not self.width:
            raise SamplerError(
                f"{self.plugin_name}: the film width is unknown; set the integer property "
                f"'width' to the film width in pixels, e.g. <integer name=\"width\" "
                f"value=\"640\"/> (mcrt fills it in when it renders)")
        self._lanes = (mi.UInt32(pixel), mi.UInt32(first_sample))
        self._lane_stride = stride
        self._restart(0)

    def _restart(self, pass_count: int | mi.UInt32) -> None:
        """Also the lanes' digit-permuted index and key of this pass: lazy, and
        the same for every dimension, so a render computes them once per path
        (they are loop-invariant sampler state) instead of once per dimension."""
        super()._restart(pass_count)
        if self._lanes is not None:
            pixel, first_sample = self._lanes
            self._zsobol = zsobol_index(pixel, first_sample + self._pass * self._lane_stride,
                                        self.width, self.log2_spp, self._key)

    def clone(self) -> McrtSampler:
        other = super().clone()
        if self._lanes is not None:
            other._zsobol = self._zsobol  # type: ignore[attr-defined]
        return other

    def _next_dimension(self) -> tuple[mi.UInt32, mi.UInt32]:
        """Scrambling key and Sobol' index of this dimension per lane."""
        self._drawable_lanes()
        dim = self._dim
        self._dim = dim + 1
        index, key = zsobol_dimension(*self._zsobol, dim)
        return key, index

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        return scrambled_sobol_1d(sample, key)

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        return scrambled_sobol_2d(sample, key)


PLUGINS = (ZSobolSampler,)
