"""Owen-scrambled Sobol' points in two dimensions, as pure Dr.Jit functions.

Only the first two Sobol' dimensions are used (mcrt pads: every dimension pair
is its own 2D sequence), and together they form a (0,2)-sequence in base 2:
every aligned block of ``2^m`` consecutive indices is a (0,m,2)-net.

* Dimension 0 is the van der Corput sequence: the bits of the index, reversed.
* Dimension 1 has the generator matrix of Sobol's second dimension (primitive
  polynomial ``x + 1``, initial direction number ``m_1 = 1``; Joe & Kuo,
  "Constructing Sobol sequences with better two-dimensional projections", SIAM
  J. Sci. Comput. 30, 2008, file ``new-joe-kuo-6.21201``, line ``2 1 0 1``).
  Its recurrence ``m_k = 2 m_{k-1} xor m_{k-1}`` gives the Pascal matrix mod 2:
  index bit ``c`` sets output digit ``r`` iff ``binom(c, r)`` is odd, i.e. iff
  the bits of ``r`` are a subset of those of ``c`` (Lucas' theorem). The sum
  over supersets is computed with five xor-shift steps (:func:`sobol_dim1_bits`)
  instead of a loop over 32 direction numbers; ``tests/samplers/test_sobol.py`` checks
  it against the recurrence.

Both generator matrices are upper triangular, so the first ``a`` digits of a
point depend only on the lowest ``a`` bits of its index: any ``2^m`` indices
whose lowest ``m`` bits are all different give a (0,m,2)-net.

Randomisation (Burley, "Practical Hash-based Owen Scrambling", JCGT 9(4), 2020):

* The *output* digits are Owen-scrambled (nested uniform scrambling: the flip
  of digit ``k`` is a random function of digits ``1..k-1``) by a Laine-Karras
  style hash applied to the bit-reversed value; nets stay nets.
* The *index* is Owen-scrambled the same way, read from its most significant
  bit, so the first ``2^m`` indices map onto one aligned block of ``2^m``
  Sobol' indices in a random order: every power-of-two prefix of a shuffled
  sequence is still a (0,m,2)-net, and the shuffle (seeded per pixel and per
  dimension pair) decorrelates the pairs ("padding").

The Laine-Karras hash is Nathan Vegdahl's improved version ("Building a Better
LK Hash", psychopath.io, 2021; constants 0x3d20adea, 0x05526c56, 0x53a22864
from there). Each of its steps changes a bit only as a function of the bits
below it and is a bijection, which is all nested scrambling needs.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ._hash import mix32, unit_float

#: Seeds of the two output scramblers are derived from one key with these offsets.
_SCRAMBLE_X = 0x68E31DA4
_SCRAMBLE_Y = 0xB5297A4D


def laine_karras(x: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """A keyed bijection whose flip of bit ``k`` depends only on bits ``< k``."""
    # No in-place operators: Dr.Jit's would modify the caller's array.
    x = x ^ (x * 0x3D20ADEA)
    x = x + seed
    x = x * ((seed >> 16) | 1)
    x = x ^ (x * 0x05526C56)
    return x ^ (x * 0x53A22864)


def shuffle_index(index: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """Owen-scramble a sample index, reading it from its most significant bit:
    maps ``[0, 2^m)`` onto one aligned block of ``2^m`` indices, for every ``m``."""
    return dr.brev(laine_karras(dr.brev(index), seed))


def sobol_dim1_bits(index: mi.UInt32) -> mi.UInt32:
    """Sobol' dimension 1 with its digits in bit order: bit ``r`` of the result
    (digit ``r + 1`` of the point, weight ``2^-(r+1)``) is the xor of the index
    bits ``c`` whose binary digits contain those of ``r``."""
    z = index
    for step, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F),
                       (8, 0x00FF00FF), (16, 0x0000FFFF)):
        z = z ^ ((z >> step) & mask)
    return z


def scrambled_sobol_2d(index: mi.UInt32, key: mi.UInt32) -> mi.Point2f:
    """Point ``index`` of the Sobol' (0,2)-sequence, Owen-scrambled by ``key``.

    ``dr.brev(index)`` is the van der Corput point; scrambling a value means
    hashing its bit-reversed digits, so the two reversals cancel."""
    x = dr.brev(laine_karras(index, mix32(key ^ _SCRAMBLE_X)))
    y = dr.brev(laine_karras(sobol_dim1_bits(index), mix32(key ^ _SCRAMBLE_Y)))
    return mi.Point2f(unit_float(x), unit_float(y))


def scrambled_sobol_1d(index: mi.UInt32, key: mi.UInt32) -> mi.Float:
    """The first coordinate of :func:`scrambled_sobol_2d`: a scrambled (0,1)-sequence."""
    return unit_float(dr.brev(laine_karras(index, mix32(key ^ _SCRAMBLE_X))))


def padded_sobol_2d(sample: mi.UInt32, key: mi.UInt32) -> mi.Point2f:
    """Sample ``sample`` of the 2D sequence of one (seed, pixel, dimension pair)."""
    return scrambled_sobol_2d(shuffle_index(sample, key), key)


def padded_sobol_1d(sample: mi.UInt32, key: mi.UInt32) -> mi.Float:
    """Sample ``sample`` of the 1D sequence of one (seed, pixel, dimension)."""
    return scrambled_sobol_1d(shuffle_index(sample, key), key)
