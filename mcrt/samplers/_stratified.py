"""Stratified 1D and 2D draws with a jitter amount: one implementation for all.

``uniform_grid`` (jitter 0), ``jittered`` (any jitter) and the 1D dimensions of
``poisson_disk`` call these functions; only the jitter amount differs.

A sample index ``j`` is split into its epoch ``j // n`` and its rank ``j % n``.
Within an epoch, ranks are mapped to strata by a pseudo-random permutation
seeded per (seed, pixel, dimension, epoch) - Mitsuba's "padding", which
decorrelates dimension pairs - so every epoch fills each stratum exactly once.
"""

from __future__ import annotations

import mitsuba as mi

from ._hash import GOLDEN_U32, hash_extend, mix32, permute, unit_float
from ._strata import (
    GOLDEN_FRAC_U32,
    R2_X_U32,
    R2_Y_U32,
    epoch_offset,
    jittered_offset,
    place_in_stratum,
)
from ._types import Mask


def split_sample(sample: mi.UInt32, n: int) -> tuple[mi.UInt32, mi.UInt32]:
    """``(epoch, rank)`` of a sample index for patterns of ``n`` points."""
    if n & (n - 1) == 0:
        shift = n.bit_length() - 1
        return sample >> shift, sample & (n - 1)
    epoch = sample // n
    return epoch, sample - epoch * n


def epoch_key(dim_key: mi.UInt32, epoch: mi.UInt32) -> mi.UInt32:
    """Key of one epoch of one (seed, pixel, dimension).

    ``dim_key`` is already a well-mixed hash, and every consumer of the epoch key
    hashes it again (Kensler's permutation, ``hash_extend`` for jitter, table and
    shift choices), so the epoch is folded in without a mix of its own: one
    multiply and one xor instead of a full mix on every draw. Epoch 0 (every
    sample of a single-pass render) keeps ``dim_key`` unchanged."""
    return dim_key ^ (epoch * GOLDEN_U32)


def permuted_stratum(dim_key: mi.UInt32, sample: mi.UInt32, n: int, active: Mask = True
                     ) -> tuple[mi.UInt32, mi.UInt32, mi.UInt32, mi.UInt32]:
    """``(epoch, rank, key, stratum)`` of a sample among ``n`` strata per epoch:
    its epoch and rank in it, the epoch's key and the stratum the rank takes
    (a permutation of the ``n`` strata per epoch and dimension)."""
    epoch, rank = split_sample(sample, n)
    key = epoch_key(dim_key, epoch)
    return epoch, rank, key, permute(rank, n, key, active)


def stratified_1d(dim_key: mi.UInt32, sample: mi.UInt32, n: int, jitter: float,
                  active: Mask = True) -> mi.Float:
    """One point per stratum of ``n`` equal 1D strata per epoch."""
    epoch, rank, key, cell = permuted_stratum(dim_key, sample, n, active)
    u = unit_float(hash_extend(key, rank))
    t = jittered_offset(u, jitter, epoch_offset(epoch, GOLDEN_FRAC_U32))
    return place_in_stratum(cell, n, t)


def stratified_2d(dim_key: mi.UInt32, sample: mi.UInt32, k: int, jitter: float,
                  active: Mask = True) -> mi.Point2f:
    """One point per cell of a ``k x k`` grid per epoch (``n = k^2`` points)."""
    epoch, rank, key, cell = permuted_stratum(dim_key, sample, k * k, active)
    row, col = split_sample(cell, k)
    h = hash_extend(key, rank)
    tx = jittered_offset(unit_float(h), jitter, epoch_offset(epoch, R2_X_U32))
    ty = jittered_offset(unit_float(mix32(h)), jitter, epoch_offset(epoch, R2_Y_U32))
    return mi.Point2f(place_in_stratum(col, k, tx), place_in_stratum(row, k, ty))
