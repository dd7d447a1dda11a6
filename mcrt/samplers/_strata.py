"""Stratum arithmetic shared by every sampler: where a point goes inside its cell.

A stratified point is ``(cell + t) / n`` with ``t`` in (0, 1) its position inside
the cell. Done naively in float32, ``cell + t`` rounds up to ``cell + 1`` when
``t`` is close to 1 and the point leaves its stratum. We snap ``t`` to a grid of
``2^m`` steps, keep it away from both cell borders, and choose ``m`` so that
``cell + t`` is exact in float32 and the final division cannot cross a border:
every point lies strictly inside its stratum, which the tests check in float64.

The same function serves jitter 0 (cell centres: the uniform grid), jitter 1
(stratified sampling) and everything between (the lecture's jitter amount).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Largest number of strata along one axis that keeps >= 4 positions per stratum.
MAX_STRATA = 1 << 20

#: R2 low-discrepancy increments (Roberts 2018) in 32-bit fixed point. Later
#: "epochs" (sample indices beyond the sample count) shift the uniform grid by
#: these, so a regular grid never repeats a point when a pixel gets more passes.
R2_X_U32 = 3242174889  # round(0.7548776662466927 * 2^32)
R2_Y_U32 = 2447445414  # round(0.5698402909980532 * 2^32)
GOLDEN_FRAC_U32 = 2654435769  # round(0.6180339887498949 * 2^32), for 1D


def offset_bits(n: int) -> int:
    """Number of fractional bits ``m`` used for positions inside one of ``n`` strata."""
    if not 1 <= n <= MAX_STRATA:
        raise ValueError(f"number of strata must be in [1, {MAX_STRATA}], got {n}")
    return 22 - (n - 1).bit_length()


def place_in_stratum(cell: mi.UInt32, n: int, t: mi.Float) -> mi.Float:
    """Return ``(cell + t) / n`` strictly inside ``[cell/n, (cell+1)/n)``.

    ``t`` in [0, 1] is rounded to the nearest of ``2^m - 1`` interior grid
    positions (``m = offset_bits(n)``); ``t = 0.5`` stays exactly the centre.
    """
    m = offset_bits(n)
    steps = float(1 << m)
    q = dr.clip(dr.round(t * steps), 1.0, steps - 1.0)
    return (mi.Float(cell) + q * (1.0 / steps)) / float(n)


def epoch_offset(epoch: mi.UInt32, increment_u32: int) -> mi.Float:
    """Cell-relative grid offset for an epoch: 0.5 (the centre) for epoch 0,
    then a low-discrepancy walk ``frac(0.5 + epoch * alpha)``."""
    fixed = epoch * increment_u32 + 0x80000000
    return mi.Float(fixed >> 8) * (1.0 / (1 << 24))


def jittered_offset(u: mi.Float, jitter: float, base: mi.Float | float) -> mi.Float:
    """Position inside a cell: ``frac(base + jitter * (u - 0.5))``.

    ``jitter = 0`` gives ``base`` (the centre for epoch 0), ``jitter = 1`` a uniform
    position (``u`` itself, since shifting a uniform variable mod 1 keeps it
    uniform), values between a box of width ``jitter`` around ``base``.
    """
    if jitter == 1.0:
        return u
    if jitter == 0.0:
        return mi.Float(base)
    t = base + jitter * (u - 0.5)
    return t - dr.floor(t)
