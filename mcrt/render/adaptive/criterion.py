"""The adaptive error test: luminance error, image level, error ratio, dilation.

A pixel stays active while ``z * se_Y > threshold * max(Y, dark_floor * Ybar)``
(see :mod:`mcrt.render.adaptive`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import drjit as dr
import numpy as np

from ...core.colour import LUMINANCE_WEIGHTS
from ...core.stats import PixelStats
from .settings import AdaptiveSettings

#: Luminance weights of linear sRGB R, G, B (:data:`mcrt.core.colour.LUMINANCE_WEIGHTS`).
LUMINANCE = np.array(LUMINANCE_WEIGHTS)

#: Quantile above which pixel luminances are clipped before averaging ``Ybar``.
IMAGE_MEAN_QUANTILE = 0.99


def luminance_error(stats: PixelStats) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel mean luminance and the bound ``sum_c w_c se_c`` on its standard
    error, ``se_c = sqrt(var_c / n)`` the channels' i.i.d. standard errors.

    Elementwise (the same bits for a pixel whichever other pixels are given, so
    the engine may update only the pixels a pass changed)."""
    return _luminance(stats.mean), _luminance(stats.standard_error)


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return (rgb[..., 0] * LUMINANCE[0] + rgb[..., 1] * LUMINANCE[1]) + rgb[..., 2] * LUMINANCE[2]


def luminance_error_device(moments: Sequence[Any]) -> list[Any]:
    """:func:`luminance_error` on the device, from the moments ``(n, mean x 3,
    M2 x 3, ...)`` as Dr.Jit Float64 arrays: the same float64 operations in the
    same order, so on the LLVM backend, which does not fuse a multiply and an
    add, the same bits (tests/render/test_adaptive_sums.py). The adaptive
    reduction kernel computes it for the pixels it updates, and a restored
    checkpoint for every pixel, so the two agree on any backend."""
    n, means, m2s = moments[0], moments[1:4], moments[4:7]
    errors = []
    for m2 in m2s:  # PixelStats.variance, .variance_of_mean, .standard_error
        variance = dr.select(n > 1, m2 / dr.maximum(n - 1, 1), 0.0)
        # NaN (unknown) below two finite samples, as PixelStats.standard_error
        errors.append(dr.select(n > 1, dr.sqrt(variance / dr.maximum(n, 1)), dr.nan))
    weights = [float(w) for w in LUMINANCE]
    return [(x[0] * weights[0] + x[1] * weights[1]) + x[2] * weights[2] for x in (means, errors)]


def image_mean_luminance(mean_y: np.ndarray, count: np.ndarray) -> float:
    """``Ybar``: mean luminance of the pixels with finite samples, each clipped at
    the image's 99th percentile (a winsorised mean).

    Clipping keeps a small, very bright light from setting the level: in
    ``scenes/edges.xml`` at 48 x 36 the plain mean is 25 times the median because
    of the light's few pixels, which would turn the dark floor into a floor for
    almost every pixel.
    """
    y = np.abs(mean_y[count > 0])
    if y.size == 0:
        return 0.0
    return float(np.mean(np.minimum(y, np.quantile(y, IMAGE_MEAN_QUANTILE))))


def error_ratio(mean_y: np.ndarray, se_y: np.ndarray, count: np.ndarray,
                settings: AdaptiveSettings) -> np.ndarray:
    """``z * se_Y / (threshold * max(Y, dark_floor * Ybar))`` per pixel.

    A pixel fails the test (stays active) when the ratio exceeds 1; pixels with
    fewer than two finite samples (or a ``nan`` standard error) get ``inf``.
    ``Ybar`` is :func:`image_mean_luminance`.
    """
    known = (count >= 2) & np.isfinite(se_y)
    level = settings.dark_floor * image_mean_luminance(mean_y, count)
    tolerance = settings.threshold * np.maximum(np.abs(mean_y), level)
    spread = settings.z * np.where(known, se_y, 0.0)
    ratio = np.divide(spread, tolerance, out=np.full(spread.shape, np.inf),
                      where=tolerance > 0)
    ratio = np.where(spread <= 0, 0.0, ratio)  # no spread: passes, whatever the tolerance
    return np.where(known, ratio, np.inf)


def dilate(image: np.ndarray, radius: int) -> np.ndarray:
    """Dilation of a 2D array by a ``(2r+1) x (2r+1)`` square (separable max
    filter; for a boolean mask, the binary dilation). Borders are clipped."""
    out = image.copy()
    for axis in (1, 0):
        src = out.copy()
        for d in range(1, radius + 1):
            if d >= src.shape[axis]:
                break
            lead = [slice(None)] * 2
            lag = [slice(None)] * 2
            lead[axis], lag[axis] = slice(d, None), slice(None, -d)
            out[tuple(lead)] = np.maximum(out[tuple(lead)], src[tuple(lag)])
            out[tuple(lag)] = np.maximum(out[tuple(lag)], src[tuple(lead)])
    return out


__all__ = ["IMAGE_MEAN_QUANTILE", "LUMINANCE", "dilate", "error_ratio", "image_mean_luminance",
           "luminance_error", "luminance_error_device"]
