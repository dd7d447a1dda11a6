"""Numerically stable per-pixel moments: Welford updates and Chan's merge, in float64.

The naive ``E[x^2] - E[x]^2`` cancels catastrophically for bright pixels (mean
1000, sigma 1 and 16384 float32 samples gives -2.0 instead of 0.99). We keep
``(n, mean, M2)`` per pixel and channel, where ``M2 = sum (x - mean)^2``, and
combine partial results with Chan et al.'s pairwise formula::

    n    = n_a + n_b
    d    = mean_b - mean_a
    mean = mean_a + d * n_b / n
    M2   = M2_a + M2_b + d^2 * n_a * n_b / n

which is exact for a constant image (``d = 0``), never produces a negative
``M2`` (every term is non-negative), and lets passes, seeds and machines be
merged in any order. Counts are int64, so totals beyond 2^32 samples are exact.

References: B. P. Welford, Technometrics 4(3), 1962; T. F. Chan, G. H. Golub,
R. J. LeVeque, "Updating formulae and a pairwise algorithm for computing sample
variances", COMPSTAT 1982.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


def chan_merge(n_a, mean_a, m2_a, n_b, mean_b, m2_b):
    """Merge two sets of moments ``(n, mean, M2)`` (arrays broadcast per pixel).

    ``n`` may be zero on either side (the other side is returned unchanged).
    Returns ``(n, mean, M2)`` as float64 arrays (``n`` as int64).
    """
    n_a = np.asarray(n_a, dtype=np.int64)
    n_b = np.asarray(n_b, dtype=np.int64)
    n = n_a + n_b
    mean_a = np.asarray(mean_a, dtype=np.float64)
    mean_b = np.asarray(mean_b, dtype=np.float64)
    na = n_a.astype(np.float64)
    nb = n_b.astype(np.float64)
    nf = n.astype(np.float64)
    if mean_a.ndim > na.ndim:  # per-channel moments with per-pixel counts
        na, nb, nf = na[..., None], nb[..., None], nf[..., None]
    safe = np.where(nf > 0, nf, 1.0)
    delta = mean_b - mean_a
    mean = np.where(nf > 0, mean_a + delta * (nb / safe), 0.0)
    m2 = (np.asarray(m2_a, dtype=np.float64) + np.asarray(m2_b, dtype=np.float64)
          + delta * delta * (na * nb / safe))
    return n, mean, m2


def welford_update(n, mean, m2, x):
    """Add one observation ``x`` to moments ``(n, mean, M2)``; returns the new triple."""
    n = np.asarray(n, dtype=np.int64) + 1
    x = np.asarray(x, dtype=np.float64)
    nf = n.astype(np.float64)
    if x.ndim > nf.ndim:
        nf = nf[..., None]
    delta = x - mean
    mean = mean + delta / nf
    m2 = m2 + delta * (x - mean)
    return n, mean, m2


@dataclass
class PixelStats:
    """Per-pixel moments of a render's samples.

    ``count`` (H, W) int64 finite samples per pixel; ``mean`` and ``m2`` (H, W, C)
    float64; ``nonfinite`` (H, W) int64 samples that were NaN/Inf and were left
    out of the moments (never silently averaged in).
    """

    count: np.ndarray
    mean: np.ndarray
    m2: np.ndarray
    nonfinite: np.ndarray

    @classmethod
    def zeros(cls, height: int, width: int, channels: int = 3) -> PixelStats:
        return cls(count=np.zeros((height, width), np.int64),
                   mean=np.zeros((height, width, channels), np.float64),
                   m2=np.zeros((height, width, channels), np.float64),
                   nonfinite=np.zeros((height, width), np.int64))

    @classmethod
    def from_images(cls, images: Iterable[np.ndarray]) -> PixelStats:
        """Moments over K independent renders (each one observation per pixel),
        streamed with Welford's update so K can be large."""
        stats = None
        for image in images:
            image = np.asarray(image, dtype=np.float64)
            if image.ndim == 2:
                image = image[..., None]
            if stats is None:
                stats = cls.zeros(*image.shape)
            finite = np.isfinite(image).all(axis=-1)
            n, mean, m2 = welford_update(stats.count, stats.mean, stats.m2,
                                         np.where(finite[..., None], image, stats.mean))
            stats.count = np.where(finite, n, stats.count)
            keep = finite[..., None]
            stats.mean = np.where(keep, mean, stats.mean)
            stats.m2 = np.where(keep, m2, stats.m2)
            stats.nonfinite += ~finite
        if stats is None:
            raise ValueError("from_images() needs at least one image")
        return stats

    def merge(self, other: PixelStats) -> PixelStats:
        """Chan-merge another set of moments of the same image."""
        if self.mean.shape != other.mean.shape:
            raise ValueError(f"cannot merge {other.mean.shape} into {self.mean.shape}")
        n, mean, m2 = chan_merge(self.count, self.mean, self.m2,
                                 other.count, other.mean, other.m2)
        return PixelStats(n, mean, m2, self.nonfinite + other.nonfinite)

    @property
    def samples(self) -> int:
        """Total finite samples (a Python int, exact beyond 2^32)."""
        return int(self.count.sum())

    @property
    def variance(self) -> np.ndarray:
        """Unbiased per-pixel sample variance ``M2 / (n - 1)`` (0 where n < 2)."""
        n = self.count[..., None].astype(np.float64)
        return np.where(n > 1, self.m2 / np.maximum(n - 1, 1), 0.0)

    @property
    def variance_of_mean(self) -> np.ndarray:
        """Variance of the pixel estimate, ``variance / n``."""
        n = self.count[..., None].astype(np.float64)
        return np.where(n > 0, self.variance / np.maximum(n, 1), 0.0)

    @property
    def standard_error(self) -> np.ndarray:
        """Standard error of the pixel estimate, ``sqrt(variance / n)``; NaN (unknown)
        where fewer than two samples were finite (NaN/Inf ones are left out): one
        sample has no spread to estimate it from, and 0 would claim it exact."""
        unknown = (self.count < 2)[..., None]
        return np.where(unknown, np.nan, np.sqrt(self.variance_of_mean))
