"""Counter-based hashing: every random number is a pure function of its keys.

The samplers keep no per-lane random state. A value is ``hash(seed, pixel,
dimension, sample)``, so revisiting a (pixel, sample) gives the same bits,
cloning a sampler costs nothing, and dimensions are decorrelated by construction
(pbrt-v4 decorrelates its samplers the same way).

``mix32`` is the "lowbias32" integer finaliser found by Chris Wellons' hash
prospector: a bijection on 32-bit integers with very low avalanche bias.
"""

from __future__ import annotations

import mitsuba as mi

from ._types import Mask

#: 2^32 / golden ratio, used to spread small consecutive keys over 32 bits.
GOLDEN_U32 = 0x9E3779B9

#: Start of every hash chain.
HASH_INIT = 0x6A09E667

#: Multiplier turning the top 24 bits of a uint32 into a float in [0, 1).
INV_2_24 = 1.0 / (1 << 24)


def mix32(x: mi.UInt32) -> mi.UInt32:
    """Bijective 32-bit avalanche mix (lowbias32)."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def hash_extend(h: mi.UInt32, *keys: mi.UInt32 | int) -> mi.UInt32:
    """Continue a hash chain: ``hash_extend(hash_keys(a, b), c) == hash_keys(a, b, c)``.

    Lets callers hash a prefix of keys once (e.g. seed and pixel) and extend it
    per dimension.
    """
    for k in keys:
        spread = (k * GOLDEN_U32 + 0x7F4A7C15) & 0xFFFFFFFF if isinstance(k, int) \
            else k * GOLDEN_U32 + 0x7F4A7C15
        h = mix32(h ^ spread)
    return h


def hash_keys(*keys: mi.UInt32 | int) -> mi.UInt32:
    """Hash an ordered tuple of 32-bit keys into one well-mixed 32-bit value.

    The order matters (``hash_keys(a, b) != hash_keys(b, a)``), so callers can
    use positions as "which key is which" without extra tagging.
    """
    return hash_extend(mi.UInt32(HASH_INIT), *keys)


def unit_float(h: mi.UInt32) -> mi.Float:
    """Map a uniformly distributed uint32 to a float32 in [0, 1) (24-bit grid)."""
    return mi.Float(h >> 8) * INV_2_24



def mix32_int(x: int) -> int:
    """:func:`mix32` on a Python int (for keys known at trace time, e.g. seeds).

    Computing seed keys in Python keeps them out of the kernel: a new seed is a
    new *value* of an opaque variable, never a new kernel.
    """
    x &= 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    return x ^ (x >> 16)


def hash_keys_int(*keys: int) -> int:
    """:func:`hash_keys` on Python ints; equal to it for the same keys."""
    h = HASH_INIT
    for k in keys:
        h = mix32_int(h ^ ((k * GOLDEN_U32 + 0x7F4A7C15) & 0xFFFFFFFF))
    return h


def permute(index: mi.UInt32, n: int, key: mi.UInt32, active: Mask = True) -> mi.UInt32:
    """Element ``index`` of a pseudo-random permutation of ``[0, n)`` chosen by ``key``.

    For a power of two ``n = 2^k`` this is mcrt's own keyed bijection on ``k``-bit
    integers: rounds of "multiply by an odd number mod 2^k" (moves low bits up)
    and "xor with itself shifted right" (moves high bits down), two of the
    multipliers and three xor/add offsets taken from ``key``. Every step is a
    bijection, so every ``key`` gives a permutation. It has no loop and half the
    multiplies of Kensler's hashed permutation ("Correlated Multi-Jittered
    Sampling", Pixar 2013; ``mi.permute_kensler``), which costs ~5% of a Cornell
    box render when every draw of every dimension uses it, and it is closer to
    uniformly random: over 2e5 keys, the chi-square per degree of freedom of the
    pairs (perm(0), perm(1)) is 1.13 at n = 64 and 38 at n = 16 (Kensler's: 5.2
    and 272; 1 is ideal), and of the relation between two dimensions'
    permutations 1.0 and 2.4 (Kensler's 1.0 and 14); see
    ``tests/samplers/test_samplers.py``.
    Other ``n`` use ``mi.permute_kensler`` (it cycle-walks to stay below ``n``).
    """
    if n & (n - 1) or n == 1:
        # The stub spells the variant's types as drjit.auto.ad.* (see ._types).
        return mi.permute_kensler(index, n, key, active)  # type: ignore[arg-type,return-value]
    k = n.bit_length() - 1
    w = n - 1
    half, third = max(1, (k + 1) // 2), max(1, k // 3)
    t = (index ^ key) & w
    t = (t * ((key >> 16) | 1)) & w
    t ^= t >> half
    t ^= (key >> 8) & w
    t = (t * 0x2C1B3C6D) & w
    t ^= t >> half
    t = (t * ((key >> 24) * 2 + 1)) & w
    t ^= t >> half
    t = (t * 0x297A2D39) & w
    t ^= t >> third
    return (t + (key >> 4)) & w
