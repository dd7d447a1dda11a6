"""Telling structured aliasing (moire) from noise in an error image.

Noise from a sampler that draws each pixel's samples independently of its
neighbours' is *uncorrelated between pixels*; moire is a spatially coherent
pattern. In the Fourier domain the first has a flat expected power spectrum,
the second concentrates its energy. Both measures below are computed on the
luminance error ``e = Y(render) - Y(reference)`` (H x W, Rec. 709 weights).

Spectrum
    ``P(f) = |DFT(w * e)|^2`` with ``w`` the separable *periodic* Hann window
    (``0.5 - 0.5 cos(2 pi n / N)`` per axis), which tapers the image edges so
    their discontinuity does not leak into every frequency. Frequencies ``f``
    are in cycles per pixel, ``|f_x|, |f_y| <= 0.5``. The periodic Hann window's
    DFT has only three non-zero taps per axis, so a constant error (a global
    bias, not a pattern) lands exactly in the 3 x 3 bins around DC: those bins
    are left out of everything below.

Low-band ratio (``ratio``)
    ``(sum_{|f| < f_c} P / sum_all P) / (n_low / n_all)``: the share of error
    energy at low spatial frequencies divided by the share of frequency bins
    in that band (``f_c`` = :data:`DEFAULT_CUTOFF` = 0.25 cycles/pixel, i.e.
    wavelengths longer than 4 pixels; the band is ~20% of the bins). For errors
    that are independent between pixels and zero-mean, whatever their per-pixel
    variances ``s_i^2``, ``E[P(f)] = sum_i w_i^2 s_i^2`` at *every* frequency,
    so the ratio is ~1 (white noise); coherent low-frequency patterns (moire)
    give >> 1; screen-space blue noise (errors anti-correlated between
    neighbours) gives < 1.

Peak-to-median (``peak``)
    The spectrum is first *whitened by its ring median*: each bin is divided
    by the median power of the ring ``|f|`` it lies in (over the stored half
    spectrum ``f_x >= 0``; rings
    :data:`RING_WIDTH` = 1/32 cycle per pixel wide), which makes every
    isotropic spectrum flat - white noise, blue noise, or noise whose level
    falls with frequency. The whitened spectrum is averaged over a grid of
    :data:`DEFAULT_CELLS` x :data:`DEFAULT_CELLS` square cells of frequency space
    (each 1/16 cycle per pixel wide); ``peak`` is the largest cell mean over the
    median cell mean. Averaging first removes the exponential scatter of single
    bins (whose max/median for white noise is ~log2 of the number of bins), so
    for any isotropic noise ``peak`` is close to 1, while a coherent pattern
    that puts its energy at a few frequencies *and directions* stands out even
    when it is not at low frequency (the ratio above would miss it). A
    pattern that is coherent but isotropic (concentric rings) is flattened by
    the whitening; at low frequency the ratio still sees it.

Calibration against the image's own noise (sign-flip null)
    How far from 1 is "far" depends on how many pixels actually carry the
    error (on the checkerboard only the band near the horizon does). Under the
    hypothesis "independent, symmetric per-pixel errors" flipping the sign of
    each pixel's error at random leaves the distribution of both statistics
    unchanged while destroying any spatial structure. ``null_draws`` such
    flips (fixed seed: deterministic) give the null mean and standard
    deviation of each statistic; ``ratio_z`` and ``peak_z`` are the observed
    values in those units. The verdict is ``aliased`` when either z exceeds
    :data:`Z_THRESHOLD`, ``blue`` when ``ratio_z < -Z_THRESHOLD``, else
    ``noise``. Why 5: the ratio's null is close to normal (a false alarm at
    z > 5 is a ~1e-6 event), the peak is a maximum over cells with a
    right-skewed null (~1e-3 for a Gumbel tail), and the null sd is itself
    estimated from the draws (to ~9% with 64, ~13% with 32), which fattens both
    tails. Measured on the full study's 224 renders by stochastic samplers
    (32 draws each): mean z ~0 and sd 0.97 for both statistics, largest
    |z| 3.9.

Filtered films (``correlation``)
    A reconstruction filter wider than a pixel (tent, gaussian, mitchell, ...)
    splats every sample into several pixels, so even unaliased noise is
    correlated between neighbours: its spectrum is the filter's aliased
    transfer function ``S(f)`` (:mod:`mcrt.analysis.filter_noise`), which is
    low-pass, and the sign-flip null above (white) would call it ``aliased``.
    Given the filter's per-axis pixel correlation ``c(d)``
    (:func:`~mcrt.analysis.filter_noise.filter_correlation`), the null draws
    are *filtered* sign flips: the error is whitened by ``1 / sqrt(S)`` (in the
    DFT, floored at :data:`WHITEN_FLOOR` of the peak), its pixels' signs are
    flipped, and the result is filtered again by ``sqrt(S)``. The draws keep
    the per-pixel error magnitudes and have exactly the filter's correlation,
    while a coherent pattern is destroyed as before; the observed statistics
    are unchanged. With a box filter (``c = [1]``) this is the white null.

:func:`white_noise_ratio_sd` gives the exact (first-order) standard deviation
of the ratio for homoscedastic white Gaussian noise, from the number of bins in
and out of the band and the window's bin-to-bin correlation: it is the
calibration the tests check the estimator against.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from .filter_noise import noise_spectrum
from .metrics import luminance

#: Low-band cutoff ``f_c`` in cycles per pixel (Nyquist is 0.5).
DEFAULT_CUTOFF = 0.25

#: Cells per axis of the frequency grid for the peak-to-median measure.
DEFAULT_CELLS = 16

#: Width of the rings (in |f|, cycles per pixel) whose median power whitens the
#: spectrum before the peak-to-median measure.
RING_WIDTH = 1.0 / 32

#: Sign-flip draws that estimate the null distribution.
DEFAULT_NULL_DRAWS = 64

#: |z| above which the error is called structured.
Z_THRESHOLD = 5.0

#: Smallest image side the measures accept (cells must hold frequency bins).
MIN_SIZE = 2 * DEFAULT_CELLS

#: The verdict of an image too small to measure (a side under :data:`MIN_SIZE`).
UNMEASURED = "n/a"


def measurable(shape: tuple[int, ...]) -> bool:
    """Whether an image of ``shape`` (H, W[, C]) is large enough to measure."""
    return min(shape[:2]) >= MIN_SIZE

#: Whitening of a filtered error: the filter's noise spectrum is floored at this
#: share of its peak (amplifies by at most 1 / sqrt of it).
WHITEN_FLOOR = 1e-3


def _hann(n: int) -> np.ndarray:
    """Periodic Hann window of length ``n``."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


@dataclass(frozen=True)
class _Layout:
    """Frequency bookkeeping for one image shape and parameters.

    Sums over the full spectrum are taken on the half spectrum of ``rfft2``
    (``P(-f) = P(f)`` for a real image): a bin whose mirror is not stored counts
    twice, once for itself and once for the mirror (and the mirror's cell).
    """

    window: np.ndarray       # (H, W)
    low_weight: np.ndarray   # (H, W//2+1): multiplicity of each stored bin in the low band
    keep_weight: np.ndarray  # (H, W//2+1): multiplicity among all kept bins
    cell_bins: np.ndarray    # flat indices into the half spectrum, grouped by cell (a
                             # bin may appear twice: for itself and for its mirror)
    cell_starts: np.ndarray  # where each cell's group starts in cell_bins
    cell_count: np.ndarray   # (n_cells,) full-spectrum bins per non-empty cell
    ring_of: np.ndarray      # (H * (W//2+1),) ring of each stored bin (-1: DC block)
    rings: tuple[np.ndarray, ...]  # the stored kept bins of each ring
    ring_n: np.ndarray       # (n_rings,) stored kept bins per ring
    keep_full: np.ndarray    # (H, W) bool: every bin but the 3x3 around DC
    low_full: np.ndarray     # (H, W) bool: kept bins with |f| < cutoff
    share: float             # n_low / n_keep over the full spectrum


@lru_cache(maxsize=16)
def _layout(shape: tuple[int, int], cutoff: float, cells: int) -> _Layout:
    h, w = shape
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    ky = np.rint(fy * h)
    kx = np.rint(fx * w)
    keep = ~((np.abs(ky) <= 1) & (np.abs(kx) <= 1))
    low = keep & (np.hypot(fx, fy) < cutoff)
    cy = np.clip(np.floor((fy + 0.5) * cells), 0, cells - 1).astype(np.int64)
    cx = np.clip(np.floor((fx + 0.5) * cells), 0, cells - 1).astype(np.int64)
    cell = np.broadcast_to(cy * cells + cx, shape)
    counts = np.bincount(cell[keep], minlength=cells * cells)
    remap = np.cumsum(counts > 0) - 1  # number the non-empty cells 0, 1, ...
    cell = np.where(keep, remap[cell], -1)

    half = w // 2 + 1
    mirrored = np.ones(half, dtype=bool)  # columns whose mirror column is not stored
    mirrored[0] = False
    if w % 2 == 0:
        mirrored[-1] = False
    multiplicity = np.where(mirrored, 2.0, 1.0)[None, :]
    rows = (-np.arange(h)) % h
    cols = (-np.arange(half)) % w
    mirror_cell = cell[rows[:, None], cols[None, :]]
    own_cell = cell[:, :half]
    flat = np.arange(h * half).reshape(h, half)
    own = own_cell >= 0
    extra = own & mirrored[None, :]
    cell_bins = np.concatenate([flat[own], flat[extra]])
    cell_ids = np.concatenate([own_cell[own], mirror_cell[extra]])
    order = np.argsort(cell_ids, kind="stable")
    starts = np.searchsorted(cell_ids[order], np.arange(int(counts.astype(bool).sum())))
    ring = np.broadcast_to(np.floor(np.hypot(fx, fy) / RING_WIDTH).astype(np.int64), shape)
    ring_of = np.where(keep, ring, -1)[:, :half].ravel()
    ring_n = np.bincount(ring_of[ring_of >= 0])
    rings = tuple(np.flatnonzero(ring_of == r) for r in range(ring_n.size))
    return _Layout(window=np.outer(_hann(h), _hann(w)),
                   low_weight=low[:, :half] * multiplicity,
                   keep_weight=keep[:, :half] * multiplicity,
                   cell_bins=cell_bins[order], cell_starts=starts,
                   cell_count=counts[counts > 0].astype(np.float64),
                   ring_of=ring_of, rings=rings, ring_n=ring_n,
                   keep_full=keep, low_full=low, share=float(low.sum() / keep.sum()))


def _check_image(error: np.ndarray) -> np.ndarray:
    e = np.asarray(error, dtype=np.float64)
    if e.ndim != 2:
        raise ValueError(f"expected a 2D error image, got shape {e.shape}")
    if min(e.shape) < MIN_SIZE:
        raise ValueError(f"aliasing measures need images of at least {MIN_SIZE} x {MIN_SIZE} "
                         f"pixels, got {e.shape[1]} x {e.shape[0]}")
    if not np.isfinite(e).all():
        raise ValueError("the error image has non-finite values")
    return e


def _half_power(x: np.ndarray) -> np.ndarray:
    """``|rfft2(x)|^2`` over the last two axes.

    (scipy's ``rfft2``: the same pocketfft transform and bits as numpy's, measured
    ~3.5x faster on a stack of images, ``benchmarks/scoring_cost.py``.)"""
    import scipy.fft

    return np.abs(scipy.fft.rfft2(x)) ** 2


def _statistics(power: np.ndarray, layout: _Layout) -> tuple[np.ndarray, np.ndarray]:
    """(ratio, peak) of one or a stack of half power spectra ``(..., H, W//2+1)``."""
    lead = power.shape[:-2]
    flat = power.reshape(-1, power.shape[-2] * power.shape[-1])
    # Row sums by numpy's own (pairwise, single-threaded) reduction, not a BLAS
    # matrix-vector product: BLAS splits the sum by its thread count, so the last
    # bits would depend on the machine (a study on a cluster would differ).
    total = (flat * layout.keep_weight.ravel()).sum(axis=1)
    low = (flat * layout.low_weight.ravel()).sum(axis=1)
    safe = np.where(total > 0, total, 1.0)
    ratio = np.where(total > 0, low / safe / layout.share, 1.0)
    # Whiten by the ring median (over the stored half spectrum): any isotropic
    # spectrum becomes flat, and a coherent peak, a few bins of its ring, does
    # not raise its own normaliser.
    # (Each ring's two middle values by a partial sort of that ring alone: the
    # same values as sorting, in half the time of one padded sort of all rings.)
    n = layout.ring_n
    median = np.full((flat.shape[0], n.size), np.inf)
    for r, members in enumerate(layout.rings):
        if members.size:
            lo, hi = (members.size - 1) // 2, members.size // 2
            values = flat[:, members]
            values.partition(sorted({lo, hi}), axis=-1)
            median[:, r] = 0.5 * (values[:, lo] + values[:, hi])
    median = np.where((n > 0) & (median > 0), median, np.inf)  # 0 power: whitened to 0
    scale = np.concatenate([median, np.full((median.shape[0], 1), np.inf)], axis=1)
    whitened = flat / scale[:, layout.ring_of]  # ring -1 (DC block) -> last column, inf
    sums = np.add.reduceat(whitened[:, layout.cell_bins], layout.cell_starts, axis=1)
    means = sums / layout.cell_count
    median = np.median(means, axis=-1)
    peak = np.where(median > 0, means.max(axis=-1) / np.where(median > 0, median, 1.0), 1.0)
    return ratio.reshape(lead), peak.reshape(lead)


def error_spectrum(error: np.ndarray) -> np.ndarray:
    """Hann-windowed power spectrum ``|DFT(w e)|^2`` of a 2D error image,
    DC at index (0, 0) (``np.fft.fftshift`` it to display)."""
    e = _check_image(error)
    window = np.outer(_hann(e.shape[0]), _hann(e.shape[1]))
    return np.abs(np.fft.fft2(window * e)) ** 2


def low_band_ratio(error: np.ndarray, cutoff: float = DEFAULT_CUTOFF) -> float:
    """Share of error energy at ``|f| < cutoff`` over that band's share of the
    frequency bins (white noise ~1, moire >> 1, blue noise < 1)."""
    e = _check_image(error)
    layout = _layout(e.shape, float(cutoff), DEFAULT_CELLS)
    ratio, _ = _statistics(_half_power(layout.window * e), layout)
    return float(ratio)


def peak_to_median(error: np.ndarray, cells: int = DEFAULT_CELLS) -> float:
    """Largest over median cell-averaged error power (noise ~1, coherent moire >> 1)."""
    e = _check_image(error)
    layout = _layout(e.shape, DEFAULT_CUTOFF, int(cells))
    _, peak = _statistics(_half_power(layout.window * e), layout)
    return float(peak)


@dataclass(frozen=True)
class AliasingScore:
    """Both measures, their sign-flip null distributions and the verdict."""

    ratio: float
    peak: float
    ratio_null_mean: float
    ratio_null_sd: float
    peak_null_mean: float
    peak_null_sd: float
    cutoff: float
    cells: int
    null_draws: int

    @property
    def ratio_z(self) -> float:
        return _z(self.ratio, self.ratio_null_mean, self.ratio_null_sd)

    @property
    def peak_z(self) -> float:
        return _z(self.peak, self.peak_null_mean, self.peak_null_sd)

    @classmethod
    def unmeasured(cls, cutoff: float = DEFAULT_CUTOFF, cells: int = DEFAULT_CELLS,
                   null_draws: int = DEFAULT_NULL_DRAWS) -> AliasingScore:
        """The score of an image too small to measure: every value NaN, verdict
        :data:`UNMEASURED`."""
        nan = float("nan")
        return cls(nan, nan, nan, nan, nan, nan, cutoff, cells, null_draws)

    @property
    def verdict(self) -> str:
        """``aliased`` (structured error), ``blue`` (low frequencies depleted) or
        ``noise``; :data:`UNMEASURED` for an image too small to measure."""
        if np.isnan(self.ratio):
            return UNMEASURED
        if self.ratio_z > Z_THRESHOLD or self.peak_z > Z_THRESHOLD:
            return "aliased"
        if self.ratio_z < -Z_THRESHOLD:
            return "blue"
        return "noise"

    def as_dict(self) -> dict:
        out = asdict(self)
        out.update(ratio_z=self.ratio_z, peak_z=self.peak_z, verdict=self.verdict)
        return out


def _z(value: float, mean: float, sd: float) -> float:
    if sd > 0:
        return (value - mean) / sd
    return 0.0 if value == mean else float(np.sign(value - mean)) * float("inf")


def _null_draws(e: np.ndarray, we: np.ndarray, window: np.ndarray,
                correlation: np.ndarray | None):
    """``signs -> windowed null image``: white sign flips of the error, or
    filtered ones for a filter's ``correlation`` (module doc)."""
    if correlation is None or np.asarray(correlation).size <= 1:
        return lambda signs: signs * we
    spectrum = noise_spectrum(np.asarray(correlation, dtype=np.float64), e.shape)
    amplitude = np.sqrt(np.maximum(spectrum, WHITEN_FLOOR * spectrum.max()))
    white = np.fft.ifft2(np.fft.fft2(e) / amplitude).real
    return lambda signs: window * np.fft.ifft2(np.fft.fft2(signs * white) * amplitude).real


def aliasing_score(error: np.ndarray, cutoff: float = DEFAULT_CUTOFF, cells: int = DEFAULT_CELLS,
                   null_draws: int = DEFAULT_NULL_DRAWS, seed: int = 0,
                   correlation: np.ndarray | None = None) -> AliasingScore:
    """Score an error image (2D, or RGB reduced to luminance): see the module doc.

    ``null_draws`` random sign flips (generator seeded with ``seed``) estimate the
    null distribution of both statistics for *this* image's error magnitudes.
    ``correlation``: the film filter's per-axis pixel correlation
    (:func:`~mcrt.analysis.filter_noise.filter_correlation`; None or ``[1]``
    for a box filter), which the null draws then share.
    """
    e = np.asarray(error, dtype=np.float64)
    if e.ndim == 3:
        e = luminance(e)
    e = _check_image(e)
    if not 0.0 < cutoff <= 0.5:
        raise ValueError(f"cutoff must lie in (0, 0.5] cycles per pixel, got {cutoff}")
    if null_draws < 2:
        raise ValueError(f"null_draws must be at least 2, got {null_draws}")
    layout = _layout(e.shape, float(cutoff), int(cells))
    we = layout.window * e
    ratio, peak = _statistics(_half_power(we), layout)
    draw = _null_draws(e, we, layout.window, correlation)
    rng = np.random.default_rng(seed)

    def batch(signs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _statistics(_half_power(draw(signs)), layout)

    # Batches of 8 bound memory. The signs are drawn here in order (the same stream
    # on any machine) and each batch's statistics computed on a second thread as
    # the next is drawn: numpy and pocketfft release the GIL, so two cores share
    # the work, and the values are those of one thread in order.
    futures = []
    with ThreadPoolExecutor(max_workers=2) as pool:
        for start in range(0, null_draws, 8):
            k = min(8, null_draws - start)
            futures.append(pool.submit(batch, rng.integers(0, 2, size=(k, *e.shape)) * 2.0 - 1.0))
            if len(futures) > 2:
                futures[-3].result()  # at most two batches wait in memory
    null_ratio = np.concatenate([f.result()[0] for f in futures])
    null_peak = np.concatenate([f.result()[1] for f in futures])
    return AliasingScore(ratio=float(ratio), peak=float(peak),
                         ratio_null_mean=float(null_ratio.mean()),
                         ratio_null_sd=float(null_ratio.std(ddof=1)),
                         peak_null_mean=float(null_peak.mean()),
                         peak_null_sd=float(null_peak.std(ddof=1)),
                         cutoff=float(cutoff), cells=int(cells), null_draws=int(null_draws))


def white_noise_ratio_sd(shape: tuple[int, int], cutoff: float = DEFAULT_CUTOFF) -> float:
    """Standard deviation of :func:`low_band_ratio` for i.i.d. Gaussian noise.

    With ``X(f) = DFT(w e)`` and ``e`` white with variance ``s^2``,
    ``Cov(P(f), P(g)) = s^4 (|V(f - g)|^2 + |V(f + g)|^2)`` where ``V`` is the DFT
    of ``w^2`` (the periodic Hann window makes ``V`` five taps wide per axis:
    neighbouring bins are correlated). Summing over the band ``L`` and over all
    kept bins ``S`` gives ``Var(E_L)``, ``Var(E_S)`` and ``Cov(E_L, E_S)``
    exactly; the ratio ``(E_L / E_S) / share`` then has, to first order,
    ``Var = ratio^2 (Var E_L / E_L^2 + Var E_S / E_S^2 - 2 Cov / (E_L E_S))``
    with expectations ``E[E_L] = n_L s^2 V(0)``. It shrinks like
    ``1 / sqrt(n_L)``: ~0.02 for 320 x 240 pixels and ``f_c = 0.25``.
    """
    h, w = (int(shape[0]), int(shape[1]))
    layout = _layout((h, w), float(cutoff), DEFAULT_CELLS)
    v = np.fft.fft2(layout.window ** 2)
    v0 = float(v[0, 0].real)
    v2 = np.abs(v) ** 2
    taps = np.argwhere(v2 > 1e-12 * v0 ** 2)  # the few non-zero offsets
    low = layout.low_full.astype(np.float64)
    keep = layout.keep_full.astype(np.float64)

    def pair_sum(a: np.ndarray, b: np.ndarray) -> float:
        """sum_{f in a, g in b} (|V(f-g)|^2 + |V(f+g)|^2)."""
        b_neg = np.roll(np.flip(b, (0, 1)), (1, 1), axis=(0, 1))  # b(-g)
        total = 0.0
        for dy, dx in taps:
            weight = v2[dy, dx]
            total += weight * float((a * np.roll(b, (dy, dx), axis=(0, 1))).sum())
            total += weight * float((a * np.roll(b_neg, (dy, dx), axis=(0, 1))).sum())
        return total

    n_low, n_keep = low.sum(), keep.sum()
    e_low, e_keep = n_low * v0, n_keep * v0
    var_low = pair_sum(low, low)
    var_keep = pair_sum(keep, keep)
    cov = pair_sum(low, keep)
    rel = var_low / e_low ** 2 + var_keep / e_keep ** 2 - 2.0 * cov / (e_low * e_keep)
    return float(np.sqrt(max(rel, 0.0)))


__all__ = ["AliasingScore", "DEFAULT_CELLS", "DEFAULT_CUTOFF", "DEFAULT_NULL_DRAWS",
           "MIN_SIZE", "UNMEASURED", "Z_THRESHOLD", "aliasing_score", "error_spectrum",
           "low_band_ratio", "measurable", "peak_to_median", "white_noise_ratio_sd"]
