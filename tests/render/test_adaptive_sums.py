"""The adaptive render's sums (mcrt.render.adaptive.sums) against numpy, and the
aligned uploads (mcrt.core.upload) that keep its kernels from being compiled
once per alignment of numpy's buffers."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.upload import ALIGNMENT, aligned_copy, to_device
from mcrt.render.adaptive.sums import CELLS_PER_KERNEL, PixelSums

PIXELS = 37


def _wavefront(rng, ids, m, channels, cells):
    """Random samples of ``m`` lanes per pixel: float32 values with some NaN and
    Inf lanes, and their sub-pixel cells."""
    lanes = ids.size * m
    values = rng.normal(1.0, 3.0, (channels, lanes)).astype(np.float32)
    if channels == 4:
        values[3] = rng.integers(0, 2, lanes)  # alpha: 0 or 1, always finite
    bad = rng.random(lanes) < 0.05
    values[rng.integers(0, 3, lanes)[bad], np.flatnonzero(bad)] = rng.choice(
        [np.nan, np.inf, -np.inf], bad.sum())
    cell = rng.integers(0, cells, lanes).astype(np.uint32)
    return values, cell


def _reduce(acc, ids, m, values, cell):
    dvalues = [mi.Float(v) for v in values]
    finite = dr.isfinite(dvalues[0]) & dr.isfinite(dvalues[1]) & dr.isfinite(dvalues[2])
    return acc.reduce(ids, m, dvalues, finite, mi.UInt32(cell))


def _render(rng, acc, passes=3, log=None):
    """Passes of two wavefronts each (disjoint random pixels, different batch
    sizes), committed at the pass's end; ``log`` collects every sample."""
    cells = acc.s * acc.s
    for _ in range(passes):
        chosen = rng.permutation(PIXELS)[:rng.integers(PIXELS // 2, PIXELS)]
        half = chosen.size // 2
        staged = []
        for ids, m in ((np.sort(chosen[:half]), 3), (np.sort(chosen[half:]), 5)):
            values, cell = _wavefront(rng, ids, m, acc.channels, cells)
            staged.append(_reduce(acc, ids, m, values, cell))
            if log is not None:
                log.append((np.repeat(ids, m), values, cell))
        for pending in staged:
            acc.commit(pending)


@pytest.mark.parametrize("s, channels", [(4, 3), (9, 4)])
def test_sums_equal_numpy_over_passes_and_wavefronts(s, channels):
    """Moments and sub-pixel sums of samples split over passes and wavefronts
    equal numpy's over all samples at once. ``s`` = 9 has 81 sub-pixels, more
    than one kernel reduces (``CELLS_PER_KERNEL``); channel 4 is alpha.
    Welford's update and numpy's two-pass formula differ by rounding only
    (relative 1e-12 here, for 10-20 samples of spread 3 per pixel)."""
    assert s * s > CELLS_PER_KERNEL or s == 4
    rng = np.random.default_rng(7)
    acc = PixelSums(PIXELS, s, channels)
    log: list = []
    _render(rng, acc, log=log)
    pixel = np.concatenate([x[0] for x in log])
    values = np.concatenate([x[1] for x in log], axis=1).astype(np.float64)
    cell = np.concatenate([x[2] for x in log]).astype(np.int64)
    finite = np.isfinite(values[:3]).all(axis=0)
    stats = acc.pixel_stats()
    assert np.array_equal(acc.traced, np.bincount(pixel, minlength=PIXELS))
    assert np.array_equal(stats.count, np.bincount(pixel[finite], minlength=PIXELS))
    assert np.array_equal(stats.nonfinite, np.bincount(pixel[~finite], minlength=PIXELS))
    assert stats.nonfinite.sum() > 0
    for p in range(PIXELS):
        own = values[:3, (pixel == p) & finite]
        if own.shape[1] == 0:
            assert (stats.mean[p] == 0).all() and (stats.m2[p] == 0).all()
            continue
        mean = own.mean(axis=1)
        np.testing.assert_allclose(stats.mean[p], mean, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(stats.m2[p], ((own - mean[:, None]) ** 2).sum(axis=1),
                                   rtol=1e-12)
    sums, counts = acc.sub_pixels()
    key = pixel[finite] * s * s + cell[finite]
    expected_counts = np.bincount(key, minlength=PIXELS * s * s).reshape(PIXELS, s * s)
    assert np.array_equal(counts, expected_counts)
    for c in range(channels):
        expected = np.bincount(key, weights=values[c, finite], minlength=PIXELS * s * s)
        np.testing.assert_allclose(sums[..., c].ravel(), expected, rtol=1e-12, atol=1e-12)


def test_variance_of_a_large_offset_survives_many_passes():
    """A bright pixel with a tiny spread (12345.678 +- 0.01 in float32) over 64
    passes of 16: Welford's update keeps M2 to 1e-9 of numpy's two-pass result,
    where sum-of-squares in float64 would lose ~8 of its 16 digits."""
    rng = np.random.default_rng(2)
    acc = PixelSums(1, 1, 3)
    ids = np.zeros(1, np.int64)
    kept = []
    for _ in range(64):
        values = (12345.678 + rng.normal(0.0, 0.01, (3, 16))).astype(np.float32)
        kept.append(values)
        acc.commit(_reduce(acc, ids, 16, values, np.zeros(16, np.uint32)))
    own = np.concatenate(kept, axis=1).astype(np.float64)
    m2 = ((own - own.mean(axis=1, keepdims=True)) ** 2).sum(axis=1)
    np.testing.assert_allclose(acc.pixel_stats().m2[0], m2, rtol=1e-9)


def test_a_reduced_wavefront_changes_nothing_until_committed():
    rng = np.random.default_rng(3)
    acc = PixelSums(PIXELS, 4, 3)
    _render(rng, acc, passes=1)
    before = acc.arrays()
    ids = np.arange(0, PIXELS, 2)
    _reduce(acc, ids, 4, *_wavefront(rng, ids, 4, 3, 16))  # not committed
    after = acc.arrays()
    assert all(np.array_equal(before[k], after[k]) for k in before)


@pytest.mark.parametrize("s, channels", [(4, 3), (9, 4)])
def test_a_first_wavefront_of_every_pixel_gives_the_bits_of_split_ones(s, channels):
    """A first pass of every pixel in one wavefront (its sums become the grid,
    interleaved without additions) and the same samples in two wavefronts
    (added to the zero grid) give the same bits, and so do the passes after."""
    rng = np.random.default_rng(3)
    ids, m, half = np.arange(PIXELS), 4, PIXELS // 2
    values, cell = _wavefront(rng, ids, m, channels, s * s)
    whole, split = PixelSums(PIXELS, s, channels), PixelSums(PIXELS, s, channels)
    whole.commit(_reduce(whole, ids, m, values, cell))
    staged = [_reduce(split, ids[:half], m, values[:, :half * m], cell[:half * m]),
              _reduce(split, ids[half:], m, values[:, half * m:], cell[half * m:])]
    for pending in staged:
        split.commit(pending)
    for acc in (whole, split):
        _render(np.random.default_rng(4), acc, passes=2)
    a, b = whole.arrays(), split.arrays()
    assert all(a[k].tobytes() == b[k].tobytes() for k in a)


def test_checkpoint_arrays_resume_to_the_same_bits():
    """arrays() restored into a fresh PixelSums and continued gives the bits of
    the uninterrupted sums."""
    whole, part = PixelSums(PIXELS, 4, 4), PixelSums(PIXELS, 4, 4)
    _render(np.random.default_rng(5), whole, passes=4)
    rng = np.random.default_rng(5)
    _render(rng, part, passes=2)
    resumed = PixelSums(PIXELS, 4, 4)
    resumed.restore(part.arrays())
    # What the error test reads is recomputed by restore() with the bits the
    # commits left (the luminance error on the device, as the kernel computes it).
    assert all(_host(part)[k].tobytes() == _host(resumed)[k].tobytes() for k in _host(part))
    _render(rng, resumed, passes=2)
    a, b = {**whole.arrays(), **_host(whole)}, {**resumed.arrays(), **_host(resumed)}
    assert all(a[k].tobytes() == b[k].tobytes() for k in a)


def _host(acc: PixelSums) -> dict[str, np.ndarray]:
    return {"count": acc.count, "bad": acc.bad, "mean_y": acc.mean_y, "se_y": acc.se_y}


def test_the_luminance_error_on_the_device_has_numpys_bits():
    """luminance_error_device (in the reduction kernel and restore) against the
    numpy definition the docs state, bit for bit, on moments of every kind:
    no, one, two and many samples, zero and huge spreads, dark and bright means.
    Computed with fused multiply-adds instead, 19% of them differ."""
    from mcrt.core.stats import PixelStats
    from mcrt.render.adaptive.criterion import luminance_error, luminance_error_device

    rng = np.random.default_rng(13)
    size = 200_000
    count = rng.choice([0, 1, 2, 3, 16, 1000, 1 << 20], size) + rng.integers(0, 50, size)
    count[:1000] = rng.choice([0, 1, 2], 1000)
    mean = rng.lognormal(0.0, 4.0, (size, 3)) * rng.choice([0.0, 1.0], (size, 3), p=[0.05, 0.95])
    m2 = rng.lognormal(0.0, 6.0, (size, 3)) * rng.choice([0.0, 1.0], (size, 3), p=[0.1, 0.9])
    stats = PixelStats(count=count, mean=mean, m2=m2, nonfinite=np.zeros(size, np.int64))
    columns = [mi.Float64(count.astype(np.float64)), *(mi.Float64(mean[:, c]) for c in range(3)),
               *(mi.Float64(m2[:, c]) for c in range(3))]
    expected = luminance_error(stats)
    got = [np.asarray(x, dtype=np.float64) for x in luminance_error_device(columns)]
    for e, g in zip(expected, got, strict=True):
        assert e.tobytes() == g.tobytes()


@pytest.mark.parametrize("rfilter", ["box", "gaussian", "lanczos", "tent"])
@pytest.mark.parametrize(("s", "channels"), [(4, 3), (3, 4), (2, 3)])
def test_the_reconstruction_on_the_device_has_numpys_bits(rfilter, s, channels):
    """reconstruct_grid (the adaptive render's image) against the numpy
    reconstruct of the same sums, bit for bit: empty sub-pixels, wide dynamic
    range, a pixel of negative zeros, a filter reaching past the film's edges
    (lanczos: negative weights). Adding the cells or taps in reverse order fails
    every case."""
    from mcrt.render.adaptive.reconstruct import reconstruct, reconstruct_grid, subpixel_filter

    rng = np.random.default_rng(17)
    h, w = 7, 9
    count = rng.choice([0, 1, 2, 5, 300], (h, w, s, s), p=[0.3, 0.2, 0.2, 0.2, 0.1])
    sums = rng.lognormal(0.0, 5.0, (h, w, s, s, channels)) * rng.choice([-1.0, 1.0], (
        h, w, s, s, channels), p=[0.1, 0.9]) * count[..., None]
    sums[0, 0] = -0.0
    count[0, 0] = 1
    grid = np.concatenate([sums, count[..., None].astype(np.float64)], -1)
    taps = subpixel_filter(mi.load_dict({"type": rfilter}), s)
    expected, _ = reconstruct(sums, count, taps)
    got = reconstruct_grid(mi.Float64(grid.ravel()), (h, w), s, channels, taps)
    assert got.shape == expected.shape == (h, w, channels)
    assert got.tobytes() == expected.tobytes()


def test_sums_are_the_same_bits_for_any_thread_count():
    images = []
    for threads in (1, 3):
        dr.set_thread_count(threads)
        try:
            acc = PixelSums(PIXELS, 4, 3)
            _render(np.random.default_rng(11), acc)
            images.append(acc.arrays())
        finally:
            dr.set_thread_count(2)
    assert all(images[0][k].tobytes() == images[1][k].tobytes() for k in images[0])


def test_restore_refuses_other_shapes():
    from mcrt.errors import McrtError

    saved = PixelSums(PIXELS, 4, 3).arrays()
    with pytest.raises(McrtError, match="does not match"):
        PixelSums(PIXELS, 2, 3).restore(saved)


# -- aligned uploads --------------------------------------------------------------

def _at_offset(values: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``values`` starting ``offset`` bytes past a 128-byte boundary."""
    raw = np.empty(values.nbytes + 2 * ALIGNMENT, np.uint8)
    start = (-raw.ctypes.data) % ALIGNMENT + offset
    out = raw[start:start + values.nbytes].view(values.dtype)
    out[...] = values
    assert out.ctypes.data % ALIGNMENT == offset
    return out


def _kernel_hash(x) -> str:
    dr.kernel_history()  # clears it
    dr.eval(x * 2.0 + 1.0)
    jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    assert len(jit) == 1
    return jit[0]["hash"]


def test_uploads_from_any_alignment_run_one_kernel():
    """The premise (Dr.Jit 1.5, LLVM): the same kernel over an input mapped from
    an aligned and from a misaligned numpy buffer is compiled twice. Through
    to_device it is one kernel."""
    if dr.backend_v(mi.Float64) != dr.JitBackend.LLVM:
        pytest.skip("the alignment specialisation is the LLVM backend's")
    values = np.linspace(0.0, 1.0, 4099)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        plain = {_kernel_hash(mi.Float64(_at_offset(values, o))) for o in (0, 8)}
        ours = {_kernel_hash(to_device(mi.Float64, _at_offset(values, o))) for o in (0, 8, 48)}
        result = to_device(mi.Float64, _at_offset(values, 8))
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(plain) == 2, "Dr.Jit no longer specialises on alignment: mcrt.core.upload " \
                            "could go"
    assert len(ours) == 1
    assert np.array_equal(np.asarray(result), values)


def test_aligned_copy_is_aligned_and_equal():
    for dtype in (np.float32, np.float64, np.uint32, np.bool_):
        values = (np.arange(1001) % 7).astype(dtype)
        copy = aligned_copy(values[1:])
        assert copy.ctypes.data % ALIGNMENT == 0 and copy.flags.c_contiguous
        assert np.array_equal(copy, values[1:]) and copy.dtype == dtype
    assert np.array_equal(np.asarray(to_device(mi.UInt32, np.arange(6).reshape(2, 3))),
                          np.arange(6))
