"""Multi-level reconstruction: samples binned into ``s x s`` uniform sub-pixels,
each the mean of its samples, then filtered into pixels with the film's
reconstruction filter evaluated at the sub-pixel centres (empty sub-pixels left
out, the weights renormalised; see :mod:`mcrt.render.adaptive`)."""

from __future__ import annotations

import math
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...errors import McrtError


def subpixel_filter(rfilter: mi.ReconstructionFilter | None, s: int) -> tuple[int, np.ndarray]:
    """1D weights of the reconstruction filter at sub-pixel centres.

    Returns ``(t0, weights)``: tap ``i`` is the sub-pixel ``t0 + i`` counted from
    the pixel's first sub-pixel (negative: the neighbour to the left/top). A
    ``None`` filter is the box (the pixel's own ``s`` sub-pixels, weight 1).
    """
    if rfilter is None or rfilter.is_box_filter():
        return 0, np.ones(s)
    radius = float(rfilter.radius())
    lo = math.floor(-(radius - 0.5) * s - 0.5)
    hi = math.ceil((radius + 0.5) * s - 0.5)
    taps = np.arange(lo, hi + 1)
    offsets = (taps + 0.5) / s - 0.5
    at = mi.Float(offsets.astype(np.float32))
    weights = np.array(rfilter.eval(at), dtype=np.float64)  # type: ignore[arg-type]
    weights[np.abs(offsets) >= radius] = 0.0
    nonzero = np.flatnonzero(weights)
    if nonzero.size == 0:
        raise McrtError("adaptive: the reconstruction filter has no weight at sub-pixel "
                        "centres; use more sub-pixels")
    first, last = nonzero[0], nonzero[-1]
    return int(taps[first]), weights[first:last + 1]


def _filter_axis(a: np.ndarray, s: int, t0: int, w: np.ndarray, axis: int) -> np.ndarray:
    """Filter ``s`` sub-pixels per pixel along ``axis`` into one value per pixel."""
    n = a.shape[axis] // s
    before = max(0, -t0)
    after = max(0, t0 + len(w) - s)
    pad = [(0, 0)] * a.ndim
    pad[axis] = (before, after)
    padded = np.pad(a, pad)
    out = None
    for i, weight in enumerate(w):  # tap by tap (the order reconstruct_grid adds them)
        start = before + t0 + i
        index = [slice(None)] * a.ndim
        index[axis] = slice(start, start + n * s, s)
        term = weight * padded[tuple(index)]
        out = term if out is None else out + term
    assert out is not None  # (a filter has taps)
    return out


def reconstruct(sub_sum: np.ndarray, sub_count: np.ndarray,
                taps: tuple[int, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Multi-level reconstruction from sub-pixel sums.

    ``sub_sum`` (H, W, s, s, C) sums of sample values per sub-pixel (row ``sy``,
    column ``sx``), ``sub_count`` (H, W, s, s) finite samples per sub-pixel;
    ``taps`` from :func:`subpixel_filter` (default: box). Returns the (H, W, C)
    image and the (H, W) total filter weight of non-empty sub-pixels (0: no
    sample reached the pixel's filter support; such pixels are 0).
    """
    h, w, s, s2, c = sub_sum.shape
    if s != s2 or sub_count.shape != (h, w, s, s):
        raise ValueError("reconstruct(): expected sub_sum (H, W, s, s, C) and sub_count "
                         "(H, W, s, s)")
    t0, weights = taps if taps is not None else (0, np.ones(s))
    # Level 1: uniform sub-pixels, each the mean of its own samples.
    filled = (sub_count > 0).astype(np.float64)
    mean = np.divide(sub_sum, sub_count[..., None], out=np.zeros(sub_sum.shape),
                     where=sub_count[..., None] > 0)
    if _is_box(t0, weights, s):
        # Box filter: the mean of the pixel's own non-empty sub-pixels, summed
        # cell by cell in row-major order (the order reconstruct_grid adds them).
        den = filled.sum(axis=(2, 3))
        num = mean[:, :, 0, 0].copy()
        for cell in range(1, s * s):
            num += mean[:, :, cell // s, cell % s]  # empty sub-pixels hold 0
        image = np.divide(num, den[..., None], out=np.zeros(num.shape),
                          where=den[..., None] > 0)
        return image, den * weights[0] ** 2
    # Lay the sub-pixels out as an (H*s, W*s) image, then level 2: filter into pixels.
    grid = mean.transpose(0, 2, 1, 3, 4).reshape(h * s, w * s, c)
    mask = filled.transpose(0, 2, 1, 3).reshape(h * s, w * s)
    num = _filter_axis(_filter_axis(grid * mask[..., None], s, t0, weights, 1),
                       s, t0, weights, 0)
    den = _filter_axis(_filter_axis(mask, s, t0, weights, 1), s, t0, weights, 0)
    image = np.divide(num, den[..., None], out=np.zeros(num.shape),
                      where=den[..., None] > 0)
    return image, den


def _is_box(t0: int, weights: np.ndarray, s: int) -> bool:
    return t0 == 0 and len(weights) == s and bool(np.all(weights == weights[0]))


def reconstruct_grid(grid: Any, shape: tuple[int, int], s: int, channels: int,
                     taps: tuple[int, np.ndarray]) -> np.ndarray:
    """:func:`reconstruct` on the device, from the adaptive render's sub-pixel
    sums (:attr:`~.sums.PixelSums.grid`: pixel-major rows of ``s * s`` cells of
    ``channels`` sums and a count, cells row-major): the (H, W, C) image as numpy.

    The same float64 operations in the same order as :func:`reconstruct`, so on
    the LLVM backend (which fuses no multiply-add) the same bits
    (tests/render/test_adaptive_sums.py): one kernel for a box filter, one per
    axis for a wider one, instead of numpy's temporaries of the whole sub-pixel
    image and a copy of the sums to the host.
    """
    h, w = shape
    t0, weights = taps
    width = channels + 1
    one, zero = mi.Float64(1.0), mi.Float64(0.0)  # (float literals would select float32)
    row = s * s * width
    if _is_box(t0, weights, s):
        base = dr.arange(mi.UInt32, h * w) * row
        sums: list[Any] = [None] * width  # (the first term starts each sum: no 0 + x)
        for cell in range(s * s):
            at = base + cell * width
            count = dr.gather(mi.Float64, grid, at + channels)
            nonempty = count > 0
            sums = _added(sums, [dr.select(nonempty, dr.gather(mi.Float64, grid, at + j) / count,
                                           zero) for j in range(channels)]
                          + [dr.select(nonempty, one, zero)])  # (exact: any order)
        return _divided(sums[:channels], sums[channels], shape, zero)
    # Level 2, separable: along x, one thread per (sub-pixel row, pixel column) ...
    thread = dr.arange(mi.UInt32, h * s * w)
    sub_row, x = thread // w, thread % w
    rows: list[Any] = [None] * width
    for i, weight in enumerate(weights):
        col = mi.Int32(x * s) + (t0 + i)
        inside = (col >= 0) & (col < w * s)
        colu = mi.UInt32(dr.maximum(col, 0))
        at = ((sub_row // s) * w + colu // s) * row + ((sub_row % s) * s + colu % s) * width
        count = dr.gather(mi.Float64, grid, at + channels, inside)
        filled = inside & (count > 0)
        terms = [dr.select(filled, dr.gather(mi.Float64, grid, at + j, inside) / count, zero)
                 for j in range(channels)] + [dr.select(filled, one, zero)]
        rows = _added(rows, [float(weight) * t for t in terms])
    dr.eval(rows)
    # ... then along y, one thread per pixel.
    pixel = dr.arange(mi.UInt32, h * w)
    y, x = pixel // w, pixel % w
    out: list[Any] = [None] * width
    for i, weight in enumerate(weights):
        r = mi.Int32(y * s) + (t0 + i)
        inside = (r >= 0) & (r < h * s)
        at = mi.UInt32(dr.maximum(r, 0)) * w + x
        out = _added(out, [float(weight) * dr.gather(mi.Float64, v, at, inside) for v in rows])
    return _divided(out[:channels], out[channels], shape, zero)


def _added(sums: list[Any], terms: list[Any]) -> list[Any]:
    """``sums + terms`` elementwise, a ``None`` sum started by its term."""
    return [t if x is None else x + t for x, t in zip(sums, terms, strict=True)]


def _divided(num: list[Any], den: Any, shape: tuple[int, int], zero: Any) -> np.ndarray:
    """``num / den`` where ``den > 0`` (else 0), as an (H, W, C) numpy array."""
    image = [dr.select(den > 0, x / den, zero) for x in num]
    dr.eval(image)
    return np.stack([np.asarray(x, dtype=np.float64) for x in image], -1).reshape(*shape, -1)


def bin_samples(pixel: np.ndarray, position: np.ndarray, values: np.ndarray,
                shape: tuple[int, int], s: int) -> tuple[np.ndarray, np.ndarray]:
    """Bin samples into ``s x s`` sub-pixels: sums (H, W, s, s, C) and counts.

    ``pixel`` (N, 2) integer (x, y), ``position`` (N, 2) continuous film
    positions (inside the pixel), ``values`` (N, C). Non-finite samples are
    left out.
    """
    pixel = np.asarray(pixel, dtype=np.int64)
    position = np.asarray(position, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    h, w = shape
    sub = np.clip(np.floor((position - pixel) * s), 0, s - 1).astype(np.int64)
    keep = np.isfinite(values).all(axis=1)
    key = (((pixel[:, 1] * w + pixel[:, 0]) * s + sub[:, 1]) * s + sub[:, 0])[keep]
    size = h * w * s * s
    counts = np.bincount(key, minlength=size).reshape(h, w, s, s)
    sums = np.stack([np.bincount(key, weights=values[keep, i], minlength=size)
                     for i in range(values.shape[1])], axis=-1).reshape(h, w, s, s, -1)
    return sums, counts


def reconstruct_samples(pixel: np.ndarray, position: np.ndarray, values: np.ndarray,
                        shape: tuple[int, int], s: int = 4,
                        rfilter: mi.ReconstructionFilter | None = None) -> np.ndarray:
    """Multi-level reconstruction of arbitrary samples (see :func:`bin_samples`)."""
    sums, counts = bin_samples(pixel, position, values, shape, s)
    return reconstruct(sums, counts, subpixel_filter(rfilter, s))[0]


__all__ = ["bin_samples", "reconstruct", "reconstruct_grid", "reconstruct_samples",
           "subpixel_filter"]
