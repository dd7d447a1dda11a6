"""Edge-spread measurements on a slanted-edge image: blur and ringing of a filter.

A straight edge between two flat levels, slightly rotated from the pixel grid
(``scenes/filters/slanted_edge.xml``), is sampled by the pixel centres at every
sub-pixel offset from the edge. :func:`edge_distance` fits the edge (each row's
crossing of the mid level, linearly interpolated; a least-squares line through
them) and gives every pixel centre its signed distance to it;
:func:`edge_profile` bins the pixel values by that distance into the
*edge-spread function* (ESF); :func:`edge_metrics` reads off

* ``width``: the 10-90% rise distance of the normalised ESF in pixels (blur;
  1D box-filtered step: 0.8),
* ``overshoot`` / ``undershoot``: how far the ESF goes beyond the two levels, in
  % of the step (the ringing of a filter's negative lobes; 0 for non-negative
  filters),

and, given several renders of the same image (seeds), the mean variance of the
pixel estimate within 2 pixels of the edge (``noise``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def edge_distance(image: np.ndarray, low: float, high: float) -> np.ndarray:
    """Signed distance (pixels, positive on the ``high`` side to the right) of
    every pixel centre of a 2D ``image`` to its near-vertical edge."""
    h, w = image.shape
    mid = 0.5 * (low + high)
    rows, cols = [], []
    for r in range(h):
        line = image[r]
        i = int(np.argmax((line[:-1] < mid) & (line[1:] >= mid)))
        if line[i] < mid <= line[i + 1]:
            cols.append(i + 0.5 + (mid - line[i]) / (line[i + 1] - line[i]))
            rows.append(r + 0.5)
    if len(rows) < 2:
        raise ValueError("no rising edge found in the image")
    slope, offset = np.polyfit(rows, cols, 1)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    return (xx - (slope * yy + offset)) / np.hypot(1.0, slope)


def edge_profile(image: np.ndarray, distance: np.ndarray, step: float = 1 / 16,
                 reach: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """(distance in pixels, mean value) of the ESF: pixels within ``reach`` of
    the edge binned every ``step`` pixels."""
    keep = np.abs(distance) < reach
    bins = np.round(distance[keep] / step).astype(int)
    index = bins - bins.min()
    sums = np.bincount(index, image[keep])
    counts = np.bincount(index)
    ok = counts > 0
    return (np.arange(counts.size)[ok] + bins.min()) * step, sums[ok] / counts[ok]


def rise_width(x: np.ndarray, esf: np.ndarray, lo: float = 0.1, hi: float = 0.9) -> float:
    """Distance between the first crossings of ``lo`` and ``hi`` by a normalised ESF."""
    rising = np.maximum.accumulate(esf)  # first crossings: a monotone envelope
    return float(np.interp(hi, rising, x) - np.interp(lo, rising, x))


@dataclass(frozen=True)
class EdgeMetrics:
    width: float       # 10-90% rise distance [pixels]
    overshoot: float   # max above the high level [% of the step]
    undershoot: float  # max below the low level [% of the step]
    noise: float       # mean variance of the pixel estimate within 2 px of the edge
    x: np.ndarray      # ESF abscissae [pixels]
    esf: np.ndarray    # ESF, normalised: low level 0, high level 1


def edge_metrics(images: list[np.ndarray], low: float, high: float) -> EdgeMetrics:
    """Blur, ringing and noise of renders (seeds) of one slanted-edge image."""
    mean = np.mean(images, axis=0)
    distance = edge_distance(mean, low, high)
    x, esf = edge_profile(mean, distance)
    norm = (esf - low) / (high - low)
    noise = float(np.var(images, axis=0, ddof=1)[np.abs(distance) < 2].mean()) \
        if len(images) > 1 else float("nan")
    return EdgeMetrics(width=rise_width(x, norm),
                       overshoot=float(max(norm.max() - 1.0, 0.0) * 100),
                       undershoot=float(max(-norm.min(), 0.0) * 100),
                       noise=noise, x=x, esf=norm)


__all__ = ["EdgeMetrics", "edge_distance", "edge_metrics", "edge_profile", "rise_width"]
