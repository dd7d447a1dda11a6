"""The filter's neighbourhood gather (mcrt.core.reach): every sample in reach,
each with its weight, and the same bits whatever block of targets a lane takes."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.packed import Packed
from mcrt.core.reach import BLOCK, FilterReach, dense

FILTERS = {"gaussian": {"type": "gaussian"}, "tent": {"type": "tent"},
           "lanczos": {"type": "lanczos"},
           "wide gaussian": {"type": "gaussian", "stddev": 1.3}}

#: Targets 13 x 9 from film pixel (2, 1); sources: a 17 x 12 grid from film pixel
#: (0, -1) (a border all round, uneven), 3 samples per pixel and pass.
SIZE, ORIGIN, GRID, GRID_ORIGIN, GROUP = (13, 9), (2, 1), (17, 12), (0, -1), 3


def _samples(seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Per lane (pixel-major): values (3, n) and film positions (2, n); every
    7th sample non-finite (x NaN, values zeroed, as the film stores it)."""
    rng = np.random.default_rng(seed)
    n = GRID[0] * GRID[1] * GROUP
    pixel = np.arange(n) // GROUP
    x = pixel % GRID[0] + GRID_ORIGIN[0] + rng.random(n)
    y = pixel // GRID[0] + GRID_ORIGIN[1] + rng.random(n)
    values = rng.random((3, n)) * 10.0
    bad = np.arange(n) % 7 == 3
    x[bad], values[:, bad] = np.nan, 0.0
    return values.astype(np.float32), np.stack([x, y]).astype(np.float32)


def _gathered(rfilter, block: tuple[int, int], unrolled: int | None = None) -> np.ndarray:
    values, position = _samples()
    packed = Packed.of([mi.Float(v) for v in values] + [mi.Float(p) for p in position])
    dr.eval(packed.arrays)
    loop = {} if unrolled is None else {"unrolled": unrolled}  # (None: the default)
    reach = FilterReach(rfilter, SIZE, ORIGIN, GRID, GRID_ORIGIN, block=block, **loop)

    def terms(weight, stored):
        return [mi.Float64(weight), *(mi.Float64(v * weight) for v in stored)]

    sums = dense(reach.sums(packed, GROUP, 4, terms), SIZE[0] * SIZE[1])
    return np.stack([np.array(s, dtype=np.float64) for s in sums])


@pytest.mark.parametrize("name", FILTERS)
def test_every_sample_in_reach_is_summed_with_its_weight(name):
    """Against brute force over every (target, sample) pair, weights from the
    filter's own eval: a neighbour left out, a wrong centre or a NaN sample
    counted would show far above float32 rounding."""
    rfilter = mi.load_dict(FILTERS[name])
    values, (x, y) = _samples()
    got = _gathered(rfilter, BLOCK)
    w, h = SIZE
    tx, ty = np.meshgrid(np.arange(w) + ORIGIN[0] + 0.5, np.arange(h) + ORIGIN[1] + 0.5)

    def weights(d: np.ndarray) -> np.ndarray:
        return np.array(rfilter.eval(mi.Float(d.astype(np.float32).ravel())),
                        dtype=np.float64).reshape(d.shape)

    good = ~np.isnan(x)
    wx = weights(tx.ravel()[:, None] - x[good][None, :])
    wy = weights(ty.ravel()[:, None] - y[good][None, :])
    weight = wx * wy
    want = np.stack([weight.sum(1), *(weight @ v[good].astype(np.float64) for v in values)])
    assert np.count_nonzero(weight) > 10 * w * h  # neighbours reach each target
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-9)


@pytest.mark.parametrize("name", ["gaussian", "lanczos"])  # lanczos: negative lobes
def test_the_sums_do_not_depend_on_the_block_a_lane_gathers_for(name):
    """Each target adds its terms in its own order whatever the block shape,
    including blocks that overhang the 13 x 9 targets: the same bits."""
    rfilter = mi.load_dict(FILTERS[name])
    one = _gathered(rfilter, (1, 1))
    for block in [BLOCK, (3, 1), (2, 3)]:
        np.testing.assert_array_equal(_gathered(rfilter, block), one, err_msg=str(block))


@pytest.mark.parametrize("name", ["tent", "lanczos", "wide gaussian"])
def test_a_looped_gather_adds_the_unrolled_bits(name):
    """Past UNROLLED_SOURCES the sources are visited by a symbolic loop: the same
    order and arithmetic, so the same bits as the unrolled gather, whatever the
    block (lanczos: negative lobes; the wide gaussian reaches 5 pixels)."""
    rfilter = mi.load_dict(FILTERS[name])
    one = _gathered(rfilter, (1, 1), unrolled=10**9)
    for block in [BLOCK, (3, 1)]:
        np.testing.assert_array_equal(_gathered(rfilter, block, unrolled=0), one,
                                      err_msg=str(block))


def test_a_wide_filters_kernel_does_not_grow_with_its_reach():
    """A tent of radius 8 (a reach of 8 pixels: 18 x 18 sources a lane) made a
    kernel of about 15000 operations, 11 s of LLVM compilation per pass shape (a
    radius of 20: minutes, where mi.render takes a fraction of a second); its
    sources are now looped over, a kernel of a few hundred whatever the radius."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # (clears it)
        _gathered(mi.load_dict({"type": "tent", "radius": 8.0}), BLOCK)
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    counts = [k["operation_count"] for k in history if "operation_count" in k]
    assert counts and max(counts) < 1000, counts
