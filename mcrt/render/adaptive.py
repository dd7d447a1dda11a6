"""Adaptive, variance-driven sampling with multi-level reconstruction.

The lecture's recipe, made precise:

1. **Passes.** Pass 0 gives every pixel ``min_spp`` samples. After each pass
   every pixel's error is tested (below). A pixel that fails, and every
   neighbour within ``dilation`` pixels of it (against false negatives: a
   feature that all of a pixel's samples missed is usually hit by a
   neighbour's), is *active* in the next pass. All active pixels get the same
   batch of new samples, and the batch grows from pass to pass so that a pixel
   active in every pass multiplies its count by about ``growth`` per pass (16,
   32, 48, 73, 98, 162, 226, 347, 468, 724, ... with ``jittered`` and the
   default 1.5: smaller steps overshoot the needed count less, larger ones
   need fewer passes). A neighbour is thus refined at
   the failing pixel's rate, not by a token sample or two, and a missed sliver
   of a small bright light is found as fast as its neighbour converges. A pass
   traces only the active pixels' samples, as one compacted wavefront (lanes
   built from the active pixel ids; a second batch size only where a pixel's
   ``max_spp`` budget is nearly spent), so it costs time in proportion to its
   samples, not to the image size. A pixel whose remaining budget cannot fit
   the smallest batch is done, and no longer keeps its neighbours active; the
   loop stops when no pixel is active.

2. **Error criterion.** With ``Y`` the pixel's mean luminance (linear sRGB
   weights), ``se_Y`` its standard error, ``z`` the two-sided normal quantile of
   ``confidence`` (1.96 at 0.95) and ``Ybar`` the image's mean luminance
   (each pixel clipped at the 99th percentile, so that a small bright light
   does not set the level), a pixel stays active while::

       z * se_Y  >  threshold * max(Y, dark_floor * Ybar)

   i.e. until, at the stated confidence, its relative error is below
   ``threshold``; ``dark_floor`` turns the test into an absolute one for pixels
   darker than ``dark_floor * Ybar``, so black pixels stop too. ``se_Y`` is
   bounded by ``sum_c w_c se_c`` over the channels' standard errors
   ``se_c = sqrt(var_c / n)`` (equal for grey pixels, never smaller), where
   ``var_c`` is the i.i.d. sample variance: for stratified samplers it
   overestimates the true error, so the test is conservative. A pixel with
   fewer than two finite samples has an unknown error and stays active until
   its budget is spent.

3. **Samples across passes: independent stratified batches of growing size.**
   In every pass an active pixel receives one *complete* pattern of ``m``
   samples of the scene's sampler, where ``m`` comes from a ladder
   ``min_spp * 2^i`` rounded down to counts the sampler supports (e.g. squares
   for ``jittered``: 16, 25, 64, 121, 256, ...). Every batch is stratified on its own, and
   since batches grow geometrically, most of a converged pixel's samples come
   from its largest, best-stratified batches. (A prefix of one big pattern is
   not an option: our samplers permute strata, so the first ``k`` of ``N``
   samples are not stratified.)
   No sample repeats: with mcrt's counter-based samplers, pass ``k`` draws
   epoch ``k`` of the pixel's sequence (sample indices ``k*m .. k*m+m-1`` at
   sample count ``m``), and every epoch is a fresh, independently permuted and
   jittered pattern. Mitsuba's samplers cannot address a pixel's sequence, so
   each (pass, batch size, chunk) wavefront is seeded with its own hashed seed
   and ``set_samples_per_wavefront(m)``: each pixel's ``m`` lanes still form one
   stratified pattern (``stratified``, ``multijitter``, ``ldsampler``, ...), but
   batches are decorrelated only by distinct seeds, not by construction.
   Pass 0 equals a fixed render with ``min_spp`` samples and the same seed.

4. **Multi-level reconstruction.** Samples are binned into ``s x s`` uniform
   sub-pixels (by their position inside the pixel); each non-empty sub-pixel is
   the mean of its samples; the sub-pixels are then filtered into pixels with
   the film's reconstruction filter evaluated at the sub-pixel centres (for
   ``box``: the plain average of the pixel's non-empty sub-pixels). Empty
   sub-pixels are left out and the filter weights renormalised over the
   non-empty ones. A pixel whose samples crowd into one small region is thus
   not biased toward that region (the lecture's 80%-black example,
   :func:`reconstruct_samples`).

Per-pixel moments are float64 and merged across passes with Chan's formula
(:func:`mcrt.core.stats.chan_merge`), per pass from
:func:`mcrt.render.passes.pass_moments`, so samples that are NaN or infinite are
left out of the moments and sub-pixels, counted per pixel, and still count
toward the pixel's budget (a pixel producing only NaN stops at ``max_spp``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from statistics import NormalDist

import drjit as dr
import mitsuba as mi
import numpy as np

from ..analysis.metrics import LUMINANCE_WEIGHTS
from ..core.stats import PixelStats, chan_merge
from ..errors import McrtError
from ..samplers._hash import hash_keys_int
from ..samplers.base import is_mcrt_sampler
from .passes import pass_moments, sampling_integrator, sequential_block_sums
from .scene import quiet_sampler_warnings
from .trace import film_grid_size, pixel_of_index, trace

log = logging.getLogger(__name__)

#: Linear-sRGB (Rec. 709) luminance weights of R, G, B (the analysis layer's).
LUMINANCE = np.array(LUMINANCE_WEIGHTS)


@dataclass(frozen=True)
class AdaptiveSettings:
    """Parameters of an adaptive render (see the module docstring)."""

    #: Target relative standard error of a pixel's luminance.
    threshold: float = 0.05
    #: Confidence of the error bound (two-sided normal quantile).
    confidence: float = 0.95
    #: Dark pixels are judged against ``dark_floor * image mean luminance``.
    dark_floor: float = 0.1
    #: Samples every pixel gets in pass 0 (rounded up by the sampler if needed).
    min_spp: int = 16
    #: Budget per pixel (NaN/Inf samples included); never exceeded.
    max_spp: int = 1024
    #: A pass multiplies an active pixel's sample count by about this factor.
    growth: float = 1.5
    #: Neighbours within this Chebyshev radius of a failing pixel stay active.
    dilation: int = 1
    #: Sub-pixels per axis of the multi-level reconstruction.
    subpixels: int = 4
    #: Largest number of lanes traced in one kernel (memory bound).
    max_lanes: int = 1 << 22

    def check(self) -> AdaptiveSettings:
        """Raise :class:`McrtError` with a one-line message on invalid values."""
        def bad(name: str, rule: str) -> McrtError:
            return McrtError(f"adaptive: '{name}' must be {rule}, got {getattr(self, name)!r}")

        if not (isinstance(self.threshold, (int, float)) and 0 <= self.threshold < math.inf):
            raise bad("threshold", "a number >= 0")
        if not (isinstance(self.confidence, (int, float)) and 0 < self.confidence < 1):
            raise bad("confidence", "in (0, 1)")
        if not (isinstance(self.dark_floor, (int, float)) and 0 <= self.dark_floor < math.inf):
            raise bad("dark_floor", "a number >= 0")
        for name in ("min_spp", "max_spp", "subpixels", "max_lanes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise bad(name, "a positive integer")
        if self.min_spp < 2:
            raise bad("min_spp", "at least 2 (a variance needs two samples)")
        if self.max_spp < self.min_spp:
            raise bad("max_spp", f">= min_spp ({self.min_spp})")
        if not (isinstance(self.growth, (int, float)) and 1 < self.growth < math.inf):
            raise bad("growth", "a number > 1")
        if isinstance(self.dilation, bool) or not isinstance(self.dilation, int) \
                or self.dilation < 0:
            raise bad("dilation", "an integer >= 0")
        if self.subpixels > 64:
            raise bad("subpixels", "at most 64")
        return self

    @property
    def z(self) -> float:
        """Two-sided normal quantile of :attr:`confidence`."""
        return NormalDist().inv_cdf(0.5 + 0.5 * self.confidence)


@dataclass
class PassRecord:
    """What one pass did."""

    index: int
    #: Pixels traced in this pass.
    active_pixels: int
    #: Samples traced in this pass (lanes).
    samples: int
    #: Distinct batch sizes (one compacted wavefront each, or more if chunked).
    batch_sizes: tuple[int, ...]
    #: Wall time of the pass: lanes, trace, moments, bookkeeping (synchronised).
    seconds: float
    #: Pixels whose error test passed after this pass (before dilation).
    converged_pixels: int
    #: NaN/Inf samples met in this pass.
    nonfinite: int


@dataclass
class AdaptiveRender:
    """Result of :func:`render_adaptive`.

    Per-pixel arrays cover the film's crop window (the sampled border, if any,
    is cut off); ``stats`` are the box-binned sample moments (R, G, B) in
    float64.
    """

    image: np.ndarray  # (H, W, C) float32, the film's channels (R, G, B[, A])
    channels: list[str]
    stats: PixelStats
    #: Samples traced per pixel, NaN/Inf included, (H, W) int64.
    spp: np.ndarray
    passes: list[PassRecord]
    seconds: float
    settings: AdaptiveSettings
    sampler: str
    #: Batch sizes the sampler was used with (the ladder).
    batch_ladder: tuple[int, ...]
    #: The error test's bound on the standard error of each pixel's luminance
    #: (:func:`luminance_error`), (H, W).
    luminance_stderr: np.ndarray
    #: Pixels that pass the error test at the end (the others ran out of
    #: budget, or were only refined as neighbours), (H, W) bool.
    converged: np.ndarray

    @property
    def samples(self) -> int:
        return int(self.spp.sum())

    @property
    def rgb(self) -> np.ndarray:
        return self.image[..., :3]

    @property
    def variance(self) -> np.ndarray:
        """Per-pixel sample variance of R, G, B (float64)."""
        return self.stats.variance

    @property
    def standard_error(self) -> np.ndarray:
        """Per-pixel i.i.d. standard error of the R, G, B means (float64)."""
        return self.stats.standard_error

    @property
    def nonfinite(self) -> np.ndarray:
        return self.stats.nonfinite

    def layers(self) -> dict[str, np.ndarray]:
        """Float32 layers for :func:`mcrt.io.write_exr`."""
        return {"rgb": self.image.astype(np.float32),
                "variance": self.variance.astype(np.float32),
                "stderr": self.standard_error.astype(np.float32),
                "stderr_y": self.luminance_stderr.astype(np.float32),
                "spp": self.spp.astype(np.float32),
                "nonfinite": self.nonfinite.astype(np.float32)}

    def summary(self) -> dict:
        """Scalars for metadata and reports."""
        return {"adaptive": 1, "passes": len(self.passes), "samples": self.samples,
                "mean_spp": round(self.samples / self.spp.size, 3),
                "min_spp_used": int(self.spp.min()), "max_spp_used": int(self.spp.max()),
                "nonfinite_samples": int(self.nonfinite.sum()),
                "render_seconds": round(self.seconds, 6),
                "batch_ladder": " ".join(map(str, self.batch_ladder)),
                **{f"adaptive_{k}": v for k, v in asdict(self.settings).items()}}


# -- error criterion -----------------------------------------------------------

def luminance_error(stats: PixelStats) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel mean luminance and the bound ``sum_c w_c se_c`` on its standard
    error, ``se_c = sqrt(var_c / n)`` the channels' i.i.d. standard errors."""
    return stats.mean @ LUMINANCE, stats.standard_error @ LUMINANCE


#: Quantile above which pixel luminances are clipped before averaging ``Ybar``.
IMAGE_MEAN_QUANTILE = 0.99


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


# -- batch sizes ---------------------------------------------------------------

def _count_for(sampler: mi.Sampler, request: int) -> int | None:
    """Sample count the sampler uses for ``request`` (None if it refuses)."""
    try:
        sampler.set_sample_count(request)
    except Exception:  # noqa: BLE001 - a sampler refusing a count (too many points)
        return None
    return int(sampler.sample_count())


def batch_ladder(sampler: mi.Sampler, min_spp: int, max_spp: int) -> tuple[int, ...]:
    """Batch sizes ``min_spp * 2^i`` rounded down to counts the sampler supports.

    The first entry is the sampler's count for ``min_spp`` (rounded *up* if the
    sampler must, e.g. ``jittered`` 20 -> 25); all entries are <= ``max_spp``.
    """
    with quiet_sampler_warnings():
        first = _count_for(sampler, min_spp)
        if first is None:
            raise McrtError(f"adaptive: the sampler cannot draw min_spp = {min_spp} samples")
        if first > max_spp:
            raise McrtError(f"adaptive: the sampler rounds min_spp {min_spp} up to {first}, "
                            f"more than max_spp {max_spp}")
        ladder = [first]
        request = 2 * first
        while request <= max_spp:
            for r in range(request, ladder[-1], -1):  # largest supported count <= request
                count = _count_for(sampler, r)
                if count is not None and ladder[-1] < count <= request:
                    ladder.append(count)
                    break
            request *= 2
        sampler.set_sample_count(first)
    return tuple(ladder)


def pass_batch_size(leader: int, ladder: tuple[int, ...], settings: AdaptiveSettings) -> int:
    """Batch size of the next pass, given ``leader``, the sample count of a pixel
    that was active in every pass so far: the ladder size nearest (on a log
    scale) to ``(growth - 1) * leader``, so such a pixel's count grows by about
    ``growth`` per pass; at most what still fits ``max_spp``."""
    ladder_a = np.asarray(ladder, dtype=np.float64)
    target = max((settings.growth - 1.0) * leader, ladder_a[0])
    midpoints = np.sqrt(ladder_a[:-1] * ladder_a[1:])  # geometric midpoints
    index = int(np.searchsorted(midpoints, target, side="right"))
    fits = budget_batches(np.array([leader]), ladder, settings.max_spp)[0]
    return int(min(ladder[index], fits)) if fits else int(ladder[index])


def budget_batches(traced: np.ndarray, ladder: tuple[int, ...], max_spp: int) -> np.ndarray:
    """Largest ladder size that fits each pixel's remaining budget (0: none fits,
    the pixel is done)."""
    ladder_a = np.asarray(ladder, dtype=np.int64)
    index = np.searchsorted(ladder_a, max_spp - np.asarray(traced), side="right") - 1
    return np.where(index >= 0, ladder_a[np.maximum(index, 0)], 0)


# -- multi-level reconstruction --------------------------------------------------

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
    weights = np.array(rfilter.eval(mi.Float(offsets.astype(np.float32))), dtype=np.float64)
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
    out = np.zeros(a.shape[:axis] + (n,) + a.shape[axis + 1:])
    for i, weight in enumerate(w):
        start = before + t0 + i
        index = [slice(None)] * a.ndim
        index[axis] = slice(start, start + n * s, s)
        out += weight * padded[tuple(index)]
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
    if t0 == 0 and len(weights) == s and np.all(weights == weights[0]):
        # Box filter: the mean of the pixel's own non-empty sub-pixels.
        den = filled.sum(axis=(2, 3))
        num = mean.sum(axis=(2, 3))  # empty sub-pixels hold 0
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


# -- the render loop -------------------------------------------------------------

class _Accumulator:
    """Per-pixel float64 moments and sub-pixel sums over the sampled grid (flat)."""

    def __init__(self, pixels: int, s: int, channels: int) -> None:
        self.count = np.zeros(pixels, np.int64)
        self.mean = np.zeros((pixels, 3))
        self.m2 = np.zeros((pixels, 3))
        self.nonfinite = np.zeros(pixels, np.int64)
        self.traced = np.zeros(pixels, np.int64)
        self.sub_sum = np.zeros((pixels, s * s, channels))
        self.sub_count = np.zeros((pixels, s * s), np.int64)

    def add(self, ids: np.ndarray, m: int, count, means, m2, bad, sub_count,
            sub_sums) -> None:
        """Merge one wavefront's per-pixel moments (Chan) and sub-pixel sums (pixels
        ``ids``, ``m`` samples each; evaluated Dr.Jit arrays)."""
        s2 = self.sub_count.shape[1]
        count = np.asarray(count, dtype=np.float64).astype(np.int64)
        means = np.stack([np.asarray(x, dtype=np.float64) for x in means], -1)
        m2 = np.stack([np.asarray(x, dtype=np.float64) for x in m2], -1)
        n, mean, merged = chan_merge(self.count[ids], self.mean[ids], self.m2[ids],
                                     count, means, m2)
        self.count[ids], self.mean[ids], self.m2[ids] = n, mean, merged
        self.nonfinite[ids] += np.asarray(bad, dtype=np.float64).astype(np.int64)
        self.traced[ids] += m
        self.sub_count[ids] += np.asarray(sub_count, dtype=np.int64).reshape(ids.size, s2)
        self.sub_sum[ids] += np.stack([np.asarray(x, dtype=np.float64) for x in sub_sums],
                                      -1).reshape(ids.size, s2, -1)

    def stats(self) -> PixelStats:
        return PixelStats(self.count, self.mean, self.m2, self.nonfinite)

    FIELDS = ("count", "mean", "m2", "nonfinite", "traced", "sub_sum", "sub_count")

    def arrays(self) -> dict[str, np.ndarray]:
        """Copies of every accumulator array (a snapshot)."""
        return {name: getattr(self, name).copy() for name in self.FIELDS}

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        for name in self.FIELDS:
            mine = getattr(self, name)
            if arrays[name].shape != mine.shape:
                raise McrtError("the saved adaptive render does not match this scene")
            mine[...] = arrays[name]


@dataclass
class AdaptiveCheckpoint:
    """The engine's state after a finished pass (see :func:`render_adaptive`)."""

    arrays: dict[str, np.ndarray]  # accumulator fields, plus "active" and "batch"
    leader: int
    next_pass: int
    records: list[dict]
    seconds: float

    def save(self, path, key: str) -> None:
        """Write atomically as ``.npz`` (``key`` identifies the render)."""
        import json

        from ..core.atomic import atomic_path

        scalars = json.dumps({"key": key, "leader": self.leader, "next_pass": self.next_pass,
                              "records": self.records, "seconds": self.seconds})
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, scalars=np.array(scalars), **self.arrays)

    @classmethod
    def load(cls, path, key: str) -> AdaptiveCheckpoint | None:
        """The checkpoint at ``path`` if readable and made for ``key``, else None."""
        import json
        import zipfile

        try:
            with np.load(path, allow_pickle=False) as data:
                scalars = json.loads(str(data["scalars"]))
                if scalars.get("key") != key:
                    return None
                arrays = {name: data[name] for name in (*_Accumulator.FIELDS, "active", "batch")}
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            return None
        return cls(arrays=arrays, leader=int(scalars["leader"]),
                   next_pass=int(scalars["next_pass"]), records=list(scalars["records"]),
                   seconds=float(scalars["seconds"]))


class AdaptiveInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`render_adaptive`: the passes finished so far, developed
    (``partial``; None before the first pass ends) and a checkpoint to resume."""

    def __init__(self, partial: AdaptiveRender | None, checkpoint: AdaptiveCheckpoint) -> None:
        super().__init__("adaptive render interrupted")
        self.partial = partial
        self.checkpoint = checkpoint


def _sampler_label(sampler: mi.Sampler) -> str:
    from .scene import sampler_name

    return sampler_name(sampler)


def render_adaptive(scene: mi.Scene, sampler: mi.Sampler | None = None,
                    settings: AdaptiveSettings | None = None, seed: int = 0,
                    sensor: int | mi.Sensor = 0,
                    integrator: mi.SamplingIntegrator | None = None,
                    on_pass: Callable[[PassRecord], None] | None = None,
                    on_samples: Callable[..., None] | None = None,
                    resume: AdaptiveCheckpoint | None = None) -> AdaptiveRender:
    """Render ``scene`` adaptively (see the module docstring).

    ``sampler`` defaults to the sensor's (its type and parameters are used, not
    its sample count; it is cloned, never modified); ``integrator`` to the
    scene's (a sampling integrator; for an ``adaptive`` one, its nested
    integrator, and its settings unless ``settings`` is given). ``on_pass(record)`` runs after
    each pass; ``on_samples(pass_index, pixel_ids, position, rgb)`` receives
    every traced wavefront as numpy arrays (for tests and visualisation).

    Ctrl-C raises :class:`AdaptiveInterrupted` with the passes finished so far
    (a pass in flight is dropped whole); ``resume`` continues from its
    checkpoint. Every wavefront's samples depend only on (seed, pass, pixel), so
    a resumed render equals an uninterrupted one.
    """
    sensor_obj = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
    if integrator is None:
        integrator = sampling_integrator(scene)
    if getattr(integrator, "is_adaptive", False):  # the scene's `adaptive` plugin
        settings = settings or integrator.settings
        integrator = integrator.nested
    settings = (settings or AdaptiveSettings()).check()
    film = sensor_obj.film()
    sampler = (sampler if sampler is not None else sensor_obj.sampler()).clone()
    ladder = batch_ladder(sampler, settings.min_spp, settings.max_spp)
    first = ladder[0]
    if first != settings.min_spp:
        log.info("adaptive: %s draws %d samples per pixel in its first pass (min_spp %d)",
                 _sampler_label(sampler), first, settings.min_spp)
    ours = is_mcrt_sampler(sampler)
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    if integrator.aov_names():
        log.warning("adaptive: the nested integrator's AOVs (%s) are not kept",
                    ", ".join(integrator.aov_names()))

    grid = film_grid_size(film)
    width, height = int(grid[0]), int(grid[1])
    pixels = width * height
    s = settings.subpixels
    acc = _Accumulator(pixels, s, 4 if has_alpha else 3)
    active = np.arange(pixels, dtype=np.int64)
    batch = np.full(pixels, first, dtype=np.int64)
    leader = 0  # samples of a pixel that was active in every pass so far
    records: list[PassRecord] = []
    k, seconds_before = 0, 0.0
    if resume is not None:
        acc.restore(resume.arrays)
        active, batch = resume.arrays["active"].astype(np.int64), resume.arrays["batch"]
        leader, k, seconds_before = resume.leader, resume.next_pass, resume.seconds
        records = [PassRecord(**{**r, "batch_sizes": tuple(r["batch_sizes"])})
                   for r in resume.records]

    dr.sync_thread()
    start = time.perf_counter()

    def snapshot() -> AdaptiveCheckpoint:
        return AdaptiveCheckpoint(
            arrays={**acc.arrays(), "active": active.copy(), "batch": batch.copy()},
            leader=leader, next_pass=k, records=[asdict(r) for r in records],
            seconds=seconds_before + time.perf_counter() - start)

    def finish(state: AdaptiveCheckpoint | None = None) -> AdaptiveRender:
        if state is not None:
            acc.restore(state.arrays)
        return _result(film, acc, width, height, s, settings, records[:len(state.records)]
                       if state is not None else records, sampler, ladder, has_alpha,
                       seconds_before + time.perf_counter() - start)

    saved = snapshot()
    try:
        while active.size:
            pass_start = time.perf_counter()
            spent = int(acc.traced.sum())
            sizes = np.unique(batch[active])
            lanes = 0
            bad_total = 0
            for m in sizes.tolist():
                group = active[batch[active] == m]
                per_chunk = max(1, settings.max_lanes // m)
                for c, lo in enumerate(range(0, group.size, per_chunk)):
                    ids = group[lo:lo + per_chunk]
                    one_wavefront = k == 0 and ids.size == pixels
                    wave_seed = seed if ours or one_wavefront else hash_keys_int(seed, k, m, c)
                    bad_total += _trace_wavefront(scene, sensor_obj, sampler, integrator, film,
                                                  ids, m, k, wave_seed, ours, first, s,
                                                  has_alpha, acc, on_samples)
                    lanes += ids.size * m
            if int(acc.traced.sum()) <= spent:  # budgets only grow: the loop terminates
                raise McrtError("adaptive: a pass spent no samples; this is a bug")
            # Error test over the whole image, dilation, and next pass's batches.
            mean_y, se_y = luminance_error(acc.stats())
            ratio = error_ratio(mean_y, se_y, acc.count, settings)
            failing = ratio > 1.0
            # Every active pixel gets the pass's batch size (less only where the
            # budget is nearly spent): one wavefront per pass, and a pixel that
            # becomes active late - typically a neighbour of a failing pixel - is
            # refined at the failing pixel's rate at once.
            leader += int(sizes.max())
            step = pass_batch_size(leader, ladder, settings)
            batch = np.minimum(step, budget_batches(acc.traced, ladder, settings.max_spp))
            # Only pixels that can still be refined spread activity: a pixel that spent
            # its budget no longer keeps its neighbours busy.
            refinable = batch > 0
            wanted = dilate((failing & refinable).reshape(height, width), settings.dilation)
            active_next = np.flatnonzero(wanted.ravel() & refinable)
            dr.sync_thread()
            record = PassRecord(index=k, active_pixels=int(active.size), samples=lanes,
                                batch_sizes=tuple(sizes.tolist()),
                                seconds=time.perf_counter() - pass_start,
                                converged_pixels=int(pixels - failing.sum()),
                                nonfinite=bad_total)
            records.append(record)
            if on_pass is not None:
                on_pass(record)
            active = active_next
            k += 1
            saved = snapshot()
    except KeyboardInterrupt:
        partial = finish(saved) if saved.next_pass > 0 else None
        raise AdaptiveInterrupted(partial, saved) from None
    return finish()


def _result(film, acc, width, height, s, settings, records, sampler, ladder, has_alpha,
            seconds) -> AdaptiveRender:
    """Develop the accumulated samples into an :class:`AdaptiveRender`."""
    mean_y, se_y = luminance_error(acc.stats())
    ratio = error_ratio(mean_y, se_y, acc.count, settings)
    image, spp, stats, crop = _develop(film, acc, width, height, s)
    se_y = se_y.reshape(height, width)[crop]
    converged = (ratio <= 1.0).reshape(height, width)[crop]
    nonfinite = int(stats.nonfinite.sum())
    if nonfinite:
        empty = int((stats.count == 0).sum())
        log.warning("adaptive: %d NaN/Inf samples left out (%d pixels had no finite sample "
                    "and are 0)", nonfinite, empty)
    names = ["R", "G", "B", "A"] if has_alpha else ["R", "G", "B"]
    return AdaptiveRender(image=image.astype(np.float32), channels=names, stats=stats,
                          spp=spp, passes=records, seconds=seconds, settings=settings,
                          sampler=_sampler_label(sampler), batch_ladder=ladder,
                          luminance_stderr=se_y, converged=converged)


def _trace_wavefront(scene, sensor, sampler, integrator, film, ids: np.ndarray, m: int,
                     k: int, wave_seed: int, ours: bool, differential_spp: int, s: int,
                     has_alpha: bool, acc: _Accumulator, on_samples) -> int:
    """Trace ``m`` new samples of each pixel in ``ids`` (one compacted wavefront)."""
    lanes = ids.size * m
    if (k + 1) * m >= 1 << 32:
        raise McrtError("adaptive: too many passes for 32-bit sample indices; raise growth")
    # Lanes: m consecutive lanes per active pixel, built in the kernel from the ids.
    lane = dr.arange(mi.UInt32, lanes)
    pixel_index = dr.gather(mi.UInt32, mi.UInt32(ids.astype(np.uint32)), lane // m)
    sampler.set_sample_count(m)
    if ours:
        # Epoch k of the pixel's sequence at sample count m: a fresh pattern.
        sampler.seed_lanes(wave_seed, pixel_index, lane % m + dr.opaque(mi.UInt32, k * m))
    else:
        sampler.set_samples_per_wavefront(m)
        sampler.seed(wave_seed, lanes)
    pixel = pixel_of_index(film, pixel_index)
    # Ray differentials are scaled for the first pass's count in every pass,
    # which keeps one kernel for all passes.
    smp = trace(scene, sensor, sampler, integrator, pixel, differential_spp)
    rgb = mi.Color3f(smp.rgb)
    inside = smp.position - mi.Vector2f(pixel)
    sub = mi.Vector2u(dr.clip(dr.floor(inside * s), 0, s - 1))
    values = [rgb.x, rgb.y, rgb.z]
    if has_alpha:
        values.append(dr.select(smp.valid, mi.Float(1.0), mi.Float(0.0)))
    finite = dr.isfinite(rgb.x) & dr.isfinite(rgb.y) & dr.isfinite(rgb.z)
    # Sub-pixel of every lane among the wavefront's ids.size * s^2 sub-pixels.
    key = (lane // m) * (s * s) + sub.y * s + sub.x
    dr.eval(values, finite, key, inside if on_samples is not None else None)  # the trace
    # Sub-pixel sums and counts per pixel, looping over each pixel's m lanes in
    # order: deterministic (no atomics) and one pass over the lanes.
    s2, n_values = s * s, len(values)

    def contributions(lane: mi.UInt32) -> list[mi.Float]:
        cell = dr.gather(mi.UInt32, key, lane) % s2
        keep = dr.gather(mi.Bool, finite, lane)
        vals = [dr.gather(mi.Float, v, lane) for v in values]
        out = []
        for j in range(s2):
            hit = keep & (cell == j)
            out += [dr.select(hit, v, 0.0) for v in vals] + [dr.select(hit, 1.0, 0.0)]
        return out

    sums = sequential_block_sums(ids.size, m, contributions, s2 * (n_values + 1))
    per_cell = [sums[j * (n_values + 1):(j + 1) * (n_values + 1)] for j in range(s2)]
    # Cell-major like the Accumulator's (pixel, sub-pixel) layout.
    sub_count = np.stack([np.array(c[-1], dtype=np.float64) for c in per_cell], -1)
    sub_sums = [np.stack([np.array(c[i], dtype=np.float64) for c in per_cell], -1)
                for i in range(n_values)]
    count, means, m2, bad = pass_moments(rgb, m)
    dr.eval(count, means, m2, bad)
    acc.add(ids, m, count, means, m2, bad, sub_count, sub_sums)
    if on_samples is not None:
        on_samples(k, np.repeat(ids, m), np.array(inside, dtype=np.float64).T,
                   np.array(rgb, dtype=np.float64).T)
    return int(np.asarray(bad, dtype=np.float64).sum())


def _develop(film: mi.Film, acc: _Accumulator, width: int, height: int,
             s: int) -> tuple[np.ndarray, np.ndarray, PixelStats, tuple[slice, slice]]:
    """Reconstruct the crop window; crop per-pixel arrays to it."""
    channels = acc.sub_sum.shape[-1]
    sums = acc.sub_sum.reshape(height, width, s, s, channels)
    counts = acc.sub_count.reshape(height, width, s, s)
    image, _ = reconstruct(sums, counts, subpixel_filter(film.rfilter(), s))
    b = int(film.rfilter().border_size()) if film.sample_border() else 0
    crop = (slice(b, height - b), slice(b, width - b))
    stats = PixelStats(count=acc.count.reshape(height, width)[crop],
                       mean=acc.mean.reshape(height, width, 3)[crop],
                       m2=acc.m2.reshape(height, width, 3)[crop],
                       nonfinite=acc.nonfinite.reshape(height, width)[crop])
    return image[crop], acc.traced.reshape(height, width)[crop], stats, crop


# -- outputs -----------------------------------------------------------------------

def heatmap(spp: np.ndarray, lo: float | None = None, hi: float | None = None,
            colormap: str = "inferno") -> np.ndarray:
    """(H, W, 3) uint8 heat map of sample counts on a log2 scale from ``lo`` to ``hi``
    (default: the counts' range)."""
    from matplotlib import colormaps

    spp = np.asarray(spp, dtype=np.float64)
    lo = float(spp.min()) if lo is None else float(lo)
    hi = float(spp.max()) if hi is None else float(hi)
    lo = max(lo, 1.0)
    hi = max(hi, lo * 1.0001)
    t = (np.log2(np.maximum(spp, lo)) - math.log2(lo)) / (math.log2(hi) - math.log2(lo))
    rgba = colormaps[colormap](np.clip(t, 0.0, 1.0))
    return (rgba[..., :3] * 255.0 + 0.5).astype(np.uint8)


def write_heatmap(path, spp: np.ndarray, lo: float | None = None,
                  hi: float | None = None) -> None:
    """Write :func:`heatmap` as a PNG, atomically."""
    from PIL import Image

    from ..io import atomic_path

    with atomic_path(path) as tmp:
        Image.fromarray(heatmap(spp, lo, hi), mode="RGB").save(tmp, format="PNG")


def pass_time_fit(passes: list[PassRecord]) -> dict[str, float]:
    """Least-squares line ``seconds = intercept + slope * samples`` over passes,
    with R^2 (the check that a pass costs time in proportion to its samples)."""
    x = np.array([p.samples for p in passes], dtype=np.float64)
    y = np.array([p.seconds for p in passes], dtype=np.float64)
    if x.size < 2 or np.ptp(x) == 0:
        return {"intercept": float(y.mean()) if y.size else 0.0, "slope": 0.0, "r2": 0.0,
                "passes": float(x.size)}
    slope, intercept = np.polyfit(x, y, 1)
    residual = y - (intercept + slope * x)
    total = np.sum((y - y.mean()) ** 2)
    r2 = 1.0 - float(np.sum(residual ** 2) / total) if total > 0 else 1.0
    return {"intercept": float(intercept), "slope": float(slope), "r2": r2,
            "passes": float(x.size)}


# -- command line (`mcrt render --adaptive`) ----------------------------------------

#: ``mcrt render`` options of adaptive rendering: (flag, settings field, type, help).
CLI_OPTIONS = (
    ("--threshold", "threshold", float, "target relative standard error of a pixel's "
     "luminance (default 0.05)"),
    ("--confidence", "confidence", float, "confidence of that bound (default 0.95)"),
    ("--dark-floor", "dark_floor", float, "pixels darker than this times the image mean "
     "luminance are judged against that level (default 0.1)"),
    ("--min-spp", "min_spp", int, "samples of every pixel in the first pass (default 16)"),
    ("--max-spp", "max_spp", int, "per-pixel budget (default: --spp if given, else 1024)"),
    ("--growth", "growth", float, "a pass multiplies an active pixel's samples by about "
     "this (default 1.5)"),
    ("--dilation", "dilation", int, "neighbourhood radius kept active around failing pixels "
     "(default 1)"),
    ("--subpixels", "subpixels", int, "sub-pixels per axis of the reconstruction (default 4)"),
)


def add_cli_arguments(parser) -> None:
    """Add ``--adaptive`` and its parameters to an argparse (sub)parser."""
    group = parser.add_argument_group(
        "adaptive sampling", "with --adaptive, OUT.exr gets the layers rgb, variance, stderr, "
        "spp and nonfinite, and OUT_spp.png is a heat map of the sample counts")
    group.add_argument("--adaptive", action="store_true",
                       help="adaptive sampling (automatic if the scene's integrator is "
                            "'adaptive')")
    for flag, dest, kind, text in CLI_OPTIONS:
        group.add_argument(flag, dest=f"adaptive_{dest}", type=kind, default=None,
                           metavar="N" if kind is int else "X", help=text)


def cli_settings(args, scene: mi.Scene, plan=None) -> AdaptiveSettings | None:
    """Settings for ``mcrt render`` (None: a fixed-spp render), checked up front.

    Defaults come from the scene's ``adaptive`` integrator if it has one. ``plan``
    (the scene's render plan, :mod:`mcrt.render.plan`) is checked for effects the
    adaptive renderer does not support: motion blur needs sub-frames that move
    the geometry between passes of *all* pixels.
    """
    given = {dest: getattr(args, f"adaptive_{dest}", None) for _, dest, _, _ in CLI_OPTIONS}
    given = {k: v for k, v in given.items() if v is not None}
    integrator = scene.integrator()
    scene_adaptive = getattr(integrator, "is_adaptive", False)
    if not (getattr(args, "adaptive", False) or scene_adaptive):
        if given:
            flags = ", ".join(f"--{k.replace('_', '-')}" for k in given)
            raise McrtError(f"{flags}: only with --adaptive")
        return None
    if plan is not None and plan.on("motion"):
        raise McrtError("--adaptive does not render motion blur (it needs sub-frames of the "
                        "whole image); add --effect motion=off or drop --adaptive")
    base = integrator.settings if scene_adaptive else AdaptiveSettings()
    if "max_spp" not in given and getattr(args, "spp", None):
        given["max_spp"] = args.spp
    return AdaptiveSettings(**{**asdict(base), **given}).check()
