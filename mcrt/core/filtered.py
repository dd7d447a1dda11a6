"""Per-pixel statistics of a film developed with its own reconstruction filter.

A film with a filter ``f`` (gaussian, tent, mitchell, ...) develops pixel ``p``
from every sample ``s`` within the filter's reach, as the ratio

    R_p = sum_s w_ps L_s / sum_s w_ps,   w_ps = f(p_x + 1/2 - x_s) f(p_y + 1/2 - y_s),

so neighbouring pixels share samples and are correlated. :class:`FilteredStats`
keeps, per pixel and in float64, the sums that give ``R_p`` and the variance of
that ratio estimator by the delta method (linearisation, exact as n grows):

    Var(R_p) ~= sum_s w_ps^2 (L_s - R_p)^2 / (sum_s w_ps)^2
             = (S_w2L2 - 2 R S_w2L + R^2 S_w2) / S_w^2.

Samples are independent across pixels and passes (they are for the
``independent`` sampler the reference uses), so this is the variance of each
pixel's estimate with every weight accounted for; the correlation between
neighbours changes no single pixel's variance. All sums add across passes, so
passes merge by addition. The expanded form cancels only below float64's
relative precision (1e-16 of mean^2): negative rounding residue is clamped to 0.

:class:`FilteredMomentsAccumulator` is the pass engine's sink that makes these
sums (a gather per target pixel, no atomics: bit-identical across runs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from .packed import Packed
from .reach import FilterReach, dense
from .trace import CameraSamples, film_grid_size

#: Per-pixel sums kept by :class:`FilteredStats`, with their channel counts.
SUMS = (("w", 1), ("w2", 1), ("wl", 3), ("w2l", 3), ("w2l2", 3))


@dataclass
class FilteredStats:
    """Filter-weighted float64 sums over a film's developed pixels (its crop).

    ``count`` (H, W) int64: finite samples drawn in each pixel; ``nonfinite``
    (H, W) int64: NaN/Inf samples drawn there (left out of every sum);
    ``sums`` maps the names of :data:`SUMS` to (H, W, C) float64 arrays.
    """

    count: np.ndarray
    nonfinite: np.ndarray
    sums: dict[str, np.ndarray]

    def merge(self, other: FilteredStats) -> FilteredStats:
        """Add another pass's sums of the same film."""
        if self.count.shape != other.count.shape:
            raise ValueError(f"cannot merge {other.count.shape} into {self.count.shape}")
        return FilteredStats(self.count + other.count, self.nonfinite + other.nonfinite,
                             {k: self.sums[k] + other.sums[k] for k in self.sums})

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name (for checkpoints)."""
        return {"count": self.count, "nonfinite": self.nonfinite,
                **{f"sum_{k}": v for k, v in self.sums.items()}}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> FilteredStats:
        return cls(arrays["count"], arrays["nonfinite"],
                   {k: arrays[f"sum_{k}"] for k, _ in SUMS})

    @property
    def samples(self) -> int:
        """Total finite samples drawn in the developed pixels (exact Python int)."""
        return int(self.count.sum())

    @property
    def mean(self) -> np.ndarray:
        """The filtered pixel values ``R_p`` (H, W, 3); 0 where no weight reached."""
        w = self.sums["w"]
        return np.where(w != 0, self.sums["wl"] / np.where(w != 0, w, 1.0), 0.0)

    @property
    def variance_of_mean(self) -> np.ndarray:
        """Delta-method variance of ``R_p`` (H, W, 3), clamped at 0."""
        w, r = self.sums["w"], self.mean
        spread = self.sums["w2l2"] - 2.0 * r * self.sums["w2l"] + r * r * self.sums["w2"]
        return np.where(w != 0, np.maximum(spread, 0.0) / np.where(w != 0, w * w, 1.0), 0.0)

    @property
    def standard_error(self) -> np.ndarray:
        """``sqrt(variance_of_mean)``; NaN (unknown) where no finite sample
        reached the pixel (every one NaN/Inf, left out)."""
        unknown = (self.sums["w2"][..., 0] == 0)[..., None]  # no finite sample's weight
        return np.where(unknown, np.nan, np.sqrt(self.variance_of_mean))

    @property
    def effective_count(self) -> np.ndarray:
        """Kish's effective sample count ``(sum w)^2 / sum w^2`` (H, W)."""
        w, w2 = self.sums["w"][..., 0], self.sums["w2"][..., 0]
        return np.where(w2 > 0, w * w / np.where(w2 > 0, w2, 1.0), 0.0)

    @property
    def variance(self) -> np.ndarray:
        """Weighted per-sample variance ``sum w^2 (L - R)^2 / sum w^2`` (H, W, 3):
        ``variance_of_mean`` times :attr:`effective_count`."""
        return self.variance_of_mean * self.effective_count[..., None]


class FilteredMomentsAccumulator:
    """The pass engine's sink for :class:`FilteredStats` of ``film``: per
    developed pixel, each pass's samples within the filter's reach are gathered
    in a fixed order (offsets, then samples) and their weighted sums added."""

    def __init__(self, film: mi.Film) -> None:
        rfilter = film.rfilter()
        self.film, self.rfilter = film, rfilter
        crop, offset = film.crop_size(), film.crop_offset()
        self.size = (int(crop[0]), int(crop[1]))
        self.offset = (int(offset[0]), int(offset[1]))
        grid = film_grid_size(film)
        self.grid = (int(grid[0]), int(grid[1]))
        self.inset = int(rfilter.border_size()) if film.sample_border() else 0
        self.reach = FilterReach(rfilter, self.size, self.offset, self.grid,
                                 (self.offset[0] - self.inset, self.offset[1] - self.inset))
        w, h = self.size
        self.sums = {k: np.zeros((h, w, c)) for k, c in SUMS}
        self.count = np.zeros((h, w), np.int64)
        self.nonfinite = np.zeros((h, w), np.int64)
        self._pending: tuple | None = None

    def add(self, samples: CameraSamples, values: list[Any], group: int) -> None:
        # Stored interleaved (packet loads); a non-finite sample zeroed, its x NaN.
        rgb = [mi.Float(v) for v in values[:3]]
        finite = dr.isfinite(rgb[0]) & dr.isfinite(rgb[1]) & dr.isfinite(rgb[2])
        position = mi.Point2f(samples.position)
        packed = Packed.of([*(dr.select(finite, v, 0.0) for v in rgb),
                            dr.select(finite, position.x, dr.nan), position.y])
        dr.eval(packed.arrays, finite)
        w, h = self.size
        sums = dense(self.reach.sums(packed, group, sum(c for _, c in SUMS), _moment_terms),
                     w * h)
        good = dr.block_sum(dr.select(finite, mi.UInt32(1), mi.UInt32(0)), group)
        dr.eval(sums, good)
        gw, gh = self.grid
        good_grid = np.array(good, np.int64).reshape(gh, gw)
        i = self.inset
        good_crop = good_grid[i:i + h, i:i + w]
        self._pending = (sums, good_crop, group - good_crop)

    def commit(self) -> None:
        if self._pending is None:
            return
        sums, good, bad = self._pending
        w, h = self.size
        column = 0
        for name, channels in SUMS:
            planes = [np.array(sums[column + c], np.float64).reshape(h, w)
                      for c in range(channels)]
            self.sums[name] = self.sums[name] + np.stack(planes, -1)
            column += channels
        self.count = self.count + good
        self.nonfinite = self.nonfinite + bad
        self._pending = None

    def stats(self) -> FilteredStats:
        return FilteredStats(self.count.copy(), self.nonfinite.copy(),
                             {k: v.copy() for k, v in self.sums.items()})

    def state(self) -> dict[str, np.ndarray]:
        return self.stats().arrays()

    def restore(self, state: dict[str, np.ndarray]) -> None:
        restored = FilteredStats.from_arrays(state)
        if restored.count.shape != self.count.shape:
            raise McrtError("the saved statistics do not match this film")
        self.count, self.nonfinite, self.sums = (restored.count, restored.nonfinite,
                                                 restored.sums)


def _moment_terms(weight: Any, rgb: list[Any]) -> list[mi.Float64]:
    """One sample's terms of :data:`SUMS`: w, w^2, w L, w^2 L, w^2 L^2."""
    w = mi.Float64(weight)
    w2 = w * w
    values = [mi.Float64(v) for v in rgb]
    return [w, w2, *(w * v for v in values), *(w2 * v for v in values),
            *(w2 * v * v for v in values)]
