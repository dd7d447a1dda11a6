"""Image error metrics as plain functions of numpy arrays.

Every metric takes linear radiance (``(H, W, C)`` or ``(H, W)``, any float
dtype) and computes in float64. Scalar metrics average over pixels *and*
channels. Definitions (``x`` the image, ``r`` the reference, ``i`` running over
pixels and channels, ``M`` their number):

``mse``
    ``mean_i (x_i - r_i)^2``.
``rel_mse``
    ``mean_i (x_i - r_i)^2 / (r_i^2 + eps)`` with ``eps = 0.01`` by default: a
    reference value of 0.1 weighs like a black pixel, so dark pixels cannot
    dominate and black ones cannot divide by zero.
``reference_noise_floor``
    ``mean_i se_i^2``, the reference's own squared standard error. When the
    render and the reference are independent, ``E[mse] = MSE_true + floor``,
    so ``mse - floor`` estimates the error against the *exact* image
    (:func:`mse_excess`).
``bias``
    ``b = mean_i (x_i - r_i)`` with a normal confidence interval
    ``b +- z * sqrt(sum_i (v_i + se_i^2)) / M``, where ``v_i`` is the variance of
    the image's pixel estimate (e.g. per-sample variance / n, or the variance
    between independent renders / K) and ``se_i^2`` the reference's squared
    standard error; pixels are independent estimates, so their variances add.
``variance_map`` / ``standard_error_map``
    per-pixel variance of an estimate and its square root, averaged over
    channels (one number per pixel, for display and for "mean per-pixel
    variance").
``delta_e_2000``
    CIEDE2000 colour difference between the images *as displayed*: linear
    sRGB divided by ``white`` (default 1.0), clipped to [0, 1] like mcrt's PNGs
    (:mod:`mcrt.io.png`), converted to CIE XYZ with the sRGB primaries and D65
    white (no chromatic adaptation), then to CIELAB relative to D65 with
    ``Y_white = 1`` (so linear (1, 1, 1) is L* = 100); ``mean`` over pixels.
    About 1 is a just-noticeable difference; it measures what a viewer of the
    PNG sees, unlike the radiometric MSE.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from statistics import NormalDist

import numpy as np

from ..core.colour import LUMINANCE_WEIGHTS

#: Default epsilon of :func:`rel_mse`: keeps dark pixels from dominating.
REL_MSE_EPSILON = 1e-2

#: An MSE below this multiple of its reference's noise floor (:func:`reference_noise_floor`;
#: an estimated exact value's squared standard error in ``mcrt integrate``) cannot be
#: measured reliably against that reference: it is flagged unresolved and left out of fits.
RESOLVED_FACTOR = 2.0


def _pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if image.shape != reference.shape:
        raise ValueError(f"image shape {image.shape} differs from reference {reference.shape}")
    return image, reference


def mse(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean squared error ``mean((image - reference)^2)``."""
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2))


def rel_mse(image: np.ndarray, reference: np.ndarray, epsilon: float = REL_MSE_EPSILON) -> float:
    """Relative MSE ``mean((image - reference)^2 / (reference^2 + epsilon))``.

    ``epsilon`` (default 0.01, i.e. a reference value of 0.1) keeps black pixels
    from dividing by zero and dominating the average.
    """
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + epsilon)))


def reference_noise_floor(reference_standard_error: np.ndarray) -> float:
    """``mean(se^2)``: what the reference's own noise adds to the expected MSE
    of any independent render measured against it (over the pixels whose error
    is known: NaN, a pixel with fewer than two finite samples, is left out)."""
    se = np.asarray(reference_standard_error, dtype=np.float64)
    known = se[np.isfinite(se)]
    return float(np.mean(known ** 2)) if known.size else 0.0


def mse_excess(image: np.ndarray, reference: np.ndarray,
               reference_standard_error: np.ndarray) -> float:
    """``mse - reference_noise_floor``: an unbiased estimate of the MSE against
    the exact image when render and reference are independent (may come out
    negative when the render is better than the reference can resolve)."""
    return mse(image, reference) - reference_noise_floor(reference_standard_error)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Luminance ``Y`` of linear RGB ``(..., 3)`` (float64; the weights
    :data:`~mcrt.core.colour.LUMINANCE_WEIGHTS`, the sRGB -> XYZ ``Y`` row); a 2D array
    or a single channel is returned as float64 unchanged."""
    a = np.asarray(rgb, dtype=np.float64)
    if a.ndim == 2:
        return a
    if a.shape[-1] == 1:
        return a[..., 0]
    if a.shape[-1] < 3:
        raise ValueError(f"luminance needs RGB channels, got shape {a.shape}")
    return a[..., :3] @ np.asarray(LUMINANCE_WEIGHTS)


def error_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Signed per-pixel luminance error ``Y(image) - Y(reference)`` (H, W)."""
    image, reference = _pair(image, reference)
    return luminance(image) - luminance(reference)


def variance_map(variance: np.ndarray) -> np.ndarray:
    """Per-pixel variance averaged over channels: ``(H, W, C) -> (H, W)``."""
    v = np.asarray(variance, dtype=np.float64)
    if (v < 0).any():
        raise ValueError("variances must be non-negative")
    return v if v.ndim == 2 else v.mean(axis=-1)


def standard_error_map(variance_of_mean: np.ndarray) -> np.ndarray:
    """Per-pixel standard error ``sqrt(channel-mean variance of the estimate)`` (H, W)."""
    return np.sqrt(variance_map(variance_of_mean))


@dataclass(frozen=True)
class BiasEstimate:
    """Mean signed error with a normal confidence interval (see :func:`bias`)."""

    value: float
    standard_error: float
    low: float
    high: float
    confidence: float

    @property
    def significant(self) -> bool:
        """True when the interval excludes zero."""
        return self.low > 0 or self.high < 0

    def as_dict(self) -> dict:
        return asdict(self)


def _normal_quantile(p: float) -> float:
    """Standard normal quantile (``statistics.NormalDist``: no scipy at run time)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {p}")
    return NormalDist().inv_cdf(p)


def bias(image: np.ndarray, reference: np.ndarray, image_variance: np.ndarray | None = None,
         reference_variance: np.ndarray | None = None,
         confidence: float = 0.95, variance_factor: float = 1.0,
         correlated_channels: bool = False) -> BiasEstimate:
    """Mean of ``image - reference`` over pixels and channels, with a CI.

    ``image_variance`` and ``reference_variance`` are the per-pixel variances
    *of the estimates* (per-sample variance / n, or ``standard_error**2``),
    broadcastable to the image. The interval is
    ``b +- z_{(1+confidence)/2} * sqrt(sum(image_variance + reference_variance)) / M``
    (``M`` pixel-channel values; independent pixels). Missing variances count as
    zero: a deterministic render (e.g. the uniform grid) has none. With neither
    given, the spread of the differences themselves is used,
    ``std(x - r) / sqrt(M)`` (valid for i.i.d. errors only); a single value has
    no spread to give, and its standard error and interval are NaN (unknown; not
    0, which claimed its error exact and every non-zero one significant).

    Correlated values (with variances given): ``variance_factor`` multiplies the
    summed variance (a film filter wider than a pixel correlates neighbours:
    :func:`mcrt.analysis.filter_noise.variance_factor`, 3.1 for a gaussian);
    ``correlated_channels`` takes the last axis as a pixel's channels and their
    errors as perfectly correlated (exact for grey scenes, an upper bound
    otherwise): a pixel's channel mean then has the variance
    ``(mean_c sqrt(v_c))^2``, where independent channels would give a third of
    ``mean_c v_c`` (the interval ``sqrt(3)`` too narrow on grey images).
    """
    image, reference = _pair(image, reference)
    diff = image - reference
    m = diff.size
    value = float(diff.mean())
    if image_variance is None and reference_variance is None:
        se = float(diff.std(ddof=1) / math.sqrt(m)) if m > 1 else math.nan
    else:
        total = np.zeros(diff.shape)
        for v in (image_variance, reference_variance):
            if v is not None:
                v = np.broadcast_to(np.asarray(v, dtype=np.float64), diff.shape)
                if (v < 0).any():
                    raise ValueError("variances must be non-negative")
                total = total + v
        if correlated_channels and diff.ndim > 1:
            per_pixel = np.sqrt(total).mean(axis=-1) ** 2  # variance of the channel mean
            se = float(math.sqrt(per_pixel.sum() * variance_factor) / per_pixel.size)
        else:
            se = float(math.sqrt(total.sum() * variance_factor) / m)
    z = _normal_quantile(0.5 * (1.0 + confidence))
    return BiasEstimate(value=value, standard_error=se, low=value - z * se,
                        high=value + z * se, confidence=confidence)


def srgb_to_lab(rgb_linear: np.ndarray, white: float = 1.0) -> np.ndarray:
    """CIELAB (D65, ``Y_white = 1``) of linear sRGB divided by ``white`` and
    clipped to [0, 1] (the display rule of mcrt's PNGs at exposure 0)."""
    import colour

    if white <= 0:
        raise ValueError(f"white must be positive, got {white}")
    rgb = np.clip(np.asarray(rgb_linear, dtype=np.float64)[..., :3] / white, 0.0, 1.0)
    space = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(rgb, space, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, space.whitepoint)


def delta_e_2000_map(image: np.ndarray, reference: np.ndarray, white: float = 1.0,
                     reference_lab: np.ndarray | None = None) -> np.ndarray:
    """Per-pixel CIEDE2000 between the displayed images (H, W); see module doc.
    ``reference_lab``: the reference's :func:`srgb_to_lab` at ``white``, when the
    caller scores many images against one reference (the same values, computed once)."""
    import colour

    image, reference = _pair(image, reference)
    if reference_lab is None:
        reference_lab = srgb_to_lab(reference, white)
    elif reference_lab.shape != reference.shape:
        raise ValueError(f"reference_lab shape {reference_lab.shape} differs from the "
                         f"reference's {reference.shape}")
    return np.asarray(colour.difference.delta_E_CIE2000(srgb_to_lab(image, white),
                                                        reference_lab),
                      dtype=np.float64)


def delta_e_2000(image: np.ndarray, reference: np.ndarray, white: float = 1.0,
                 reference_lab: np.ndarray | None = None) -> float:
    """Mean CIEDE2000 over pixels between the displayed images (``reference_lab``:
    as in :func:`delta_e_2000_map`)."""
    return float(np.mean(delta_e_2000_map(image, reference, white, reference_lab)))


__all__ = ["BiasEstimate", "LUMINANCE_WEIGHTS", "REL_MSE_EPSILON", "RESOLVED_FACTOR", "bias",
           "delta_e_2000", "delta_e_2000_map", "error_map", "luminance", "mse", "mse_excess",
           "reference_noise_floor", "rel_mse", "srgb_to_lab", "standard_error_map",
           "variance_map"]
