"""Measures of 2D sampling patterns: spectra, anisotropy, discrepancy, spacing.

Plain functions of numpy point sets, in the style of ``scipy.stats.qmc``. A
point set is an array of shape ``(N, 2)`` with coordinates in ``[0, 1]``; most
functions also take a batch ``(B, N, 2)`` (e.g. the point sets of ``B`` pixels
from :func:`mcrt.samplers.points.point_sets`) and then average over the batch
or return one value per set. Everything is computed in float64.

Definitions
===========

Power spectrum (periodogram) [Ulichney]_ [LD08]_
    ``P(k) = |sum_j exp(-2 pi i k . x_j)|^2 / N`` at integer frequency vectors
    ``k`` (the Fourier series of the point set on the unit torus), averaged over
    the sets of a batch. The normalisation makes independent uniform points
    (white noise) have ``E[P(k)] = 1`` at every ``k != 0``; ``P(0) = N``.
    Stratified (jittered) points have ``E[P(k)] = 1 - sinc^2(pi kx / m)
    sinc^2(pi ky / m)`` with ``m = sqrt(N)`` and ``sinc(t) = sin t / t``; a
    regular ``m x m`` grid has ``P(k) = N`` at ``k`` in ``m Z^2`` and 0 elsewhere.

Radial frequency axis
    Frequencies are reported as ``f = |k| * d`` with the *mean sample spacing*
    ``d = 1 / sqrt(N)``, the side of the square each sample occupies on average
    (the stratum size of a jittered pattern). The fundamental of a regular grid
    sits at ``f = 1``, the blue-noise peak of Poisson-disk sets near
    ``f ~ 1.15`` (maximal dart throwing at ``d_min ~ 0.76 d_hex``), and
    ``f = 0.5`` is the Nyquist frequency of a grid with that spacing.

Radial average and anisotropy [Ulichney]_ [LD08]_
    The lattice frequencies are grouped into annuli ``A_r = {k : round(|k|) = r}``
    (width 1 in ``|k|``, ``r = 1, 2, ..., kmax``; only annuli that lie entirely
    inside the computed square ``|kx|, |ky| <= kmax`` are used). Since
    ``P(-k) = P(k)`` for real points, each annulus keeps one frequency of each
    pair ``+-k`` (the half plane ``kx > 0`` or ``kx = 0, ky > 0``), so its ``m_r``
    values are distinct. The radially averaged power is their mean ``Pr(r)``; the
    *anisotropy* is Ulichney's ratio of their unbiased variance to the squared
    mean, in decibels::

        A(r) = 10 log10( s^2(r) / Pr(r)^2 ),   s^2 = sum (P(k) - Pr)^2 / (m_r - 1)

    A perfectly isotropic spectrum estimated without noise has ``A = -inf``. An
    averaged periodogram of ``B`` independent white-noise sets has, at every
    ``k``, variance ``(1 - 1/N) / B`` around its mean 1, so white noise reads
    ``A ~ 10 log10((1 - 1/N) / B) ~ -10 log10(B)``: this *noise floor* depends
    on the number of averaged periodograms, not on the annulus (Lagae & Dutré
    average 10 periodograms and call -10 dB "background noise"). Values well above
    the floor mean real anisotropy (e.g. the axis-aligned structure of grids
    and jittered sampling).

L2-star discrepancy [Warnock]_
    ``D^2 = 3^-d - 2^(1-d)/N sum_i prod_k (1 - x_ik^2)
    + 1/N^2 sum_ij prod_k (1 - max(x_ik, x_jk))``, the L2 norm over anchored
    boxes ``[0, y)`` of (volume - fraction of points inside). The functions
    return ``D`` (not ``D^2``), which is what ``scipy.stats.qmc.discrepancy(x,
    method='L2-star')`` returns.

Centered L2 discrepancy [Hickernell]_
    ``CD^2 = (13/12)^d - 2/N sum_i prod_k (1 + |z_ik|/2 - z_ik^2/2)
    + 1/N^2 sum_ij prod_k (1 + |z_ik|/2 + |z_jk|/2 - |x_ik - x_jk|/2)`` with
    ``z = x - 1/2``; invariant under reflections ``x -> 1 - x``. Returned as
    ``CD``; note that ``scipy.stats.qmc.discrepancy(x, method='CD')`` returns
    ``CD^2``.

Minimum-distance ratio
    ``rho = d_min / d_hex`` with ``d_min`` the toroidal minimum distance of a
    set and ``d_hex = sqrt(2 / (sqrt(3) N))`` the spacing of a hexagonal packing
    of ``N`` points (the largest possible on the torus) [LD08]_. A regular square
    grid has ``rho = 3^(1/4) / sqrt(2) ~ 0.93``, maximal dart throwing ~0.76,
    independent points ``rho -> 0``.

References
==========

.. [Ulichney] R. Ulichney. "Dithering with blue noise". Proc. IEEE 76(1), 1988
   (radially averaged power spectrum and anisotropy); *Digital Halftoning*, MIT
   Press, 1987.
.. [LD08] A. Lagae, P. Dutré. "A comparison of methods for generating Poisson
   disk distributions". Computer Graphics Forum 27(1), 2008 (periodogram
   normalisation, radial power and anisotropy plots, rho = d_min / d_hex).
.. [Warnock] T. T. Warnock. "Computational investigations of low-discrepancy
   point sets". In *Applications of Number Theory to Numerical Analysis*,
   Academic Press, 1972 (closed form of the L2-star discrepancy).
.. [Hickernell] F. J. Hickernell. "A generalized discrepancy and quadrature
   error bound". Math. Comp. 67(221), 1998.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..samplers.poisson_tables import d_hex, toroidal_min_distances

__all__ = [
    "PatternReport", "RadialSpectrum", "analyse_points", "anisotropy_floor_db",
    "centered_discrepancy", "default_kmax", "discrepancy_work", "expected_jittered_spectrum",
    "frequency_grid", "l2_star_discrepancy", "low_frequency_power", "mean_spacing",
    "min_distance_ratio", "pooled_anisotropy_db", "power_spectrum", "radial_spectrum",
    "spectrum_work",
]

#: Elements per block in the pairwise sums and the Fourier sums (bounds memory:
#: 2^22 float64 / complex128 values are 32 / 64 MB).
_BLOCK = 1 << 22


# --------------------------------------------------------------------------- input checks

def _point_batch(points: np.ndarray, ndim: int | None = None) -> tuple[np.ndarray, bool]:
    """``points`` as a float64 ``(B, N, d)`` array in [0, 1], and whether it was a single set."""
    x = np.asarray(points, dtype=np.float64)
    single = x.ndim == 2
    if single:
        x = x[None]
    if x.ndim != 3 or x.shape[1] < 1 or x.shape[2] < 1:
        raise ValueError(f"expected points of shape (N, d) or (B, N, d), got {np.shape(points)}")
    if ndim is not None and x.shape[2] != ndim:
        raise ValueError(f"expected {ndim}-dimensional points, got d = {x.shape[2]}")
    if not np.all((x >= 0.0) & (x <= 1.0)):  # also rejects NaN
        raise ValueError("points must lie in the unit hypercube [0, 1]^d")
    return x, single


def _result(values: np.ndarray, single: bool):
    return float(values[0]) if single else values


# --------------------------------------------------------------------------- discrepancy

def _pair_sum(x: np.ndarray, kernel, d: int | None = None) -> float:
    """``sum_ij prod_k kernel_k(x_i, x_j)`` for one set ``x`` (N, columns), in row blocks.

    ``kernel(k, block, x, out)`` writes the factor of dimension ``k`` between
    the ``m`` points of ``block`` (rows of ``x``) and all ``N`` points into
    ``out`` (``(m, N)``); buffers are reused across blocks. ``d`` defaults to the
    number of columns. Block sums use numpy's pairwise summation.
    """
    n = x.shape[0]
    d = x.shape[1] if d is None else d
    rows = max(1, min(n, (_BLOCK // 4) // n))
    prod = np.empty((rows, n))
    term = np.empty((rows, n))
    total = 0.0
    for start in range(0, n, rows):
        block = x[start:start + rows]
        m = block.shape[0]
        kernel(0, block, x, prod[:m])
        for k in range(1, d):
            kernel(k, block, x, term[:m])
            np.multiply(prod[:m], term[:m], out=prod[:m])
        total += float(np.sum(prod[:m]))
    return total


def _star_kernel(k: int, block: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """``1 - max(x_ik, x_jk)``, given the points already replaced by ``1 - x``:
    ``min(a_ik, a_jk)``."""
    np.minimum(block[:, None, k], x[None, :, k], out=out)


def _centered_kernel(d: int):
    """Factor ``1 + z_i/2 + z_j/2 - |x_i - x_j|/2`` of the centered discrepancy,
    for points stored as columns ``[x (d), u (d), v (d)]`` (see the caller)."""
    def kernel(k: int, block: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
        np.minimum(block[:, None, k], x[None, :, k], out=out)
        out += block[:, None, d + k]
        out += x[None, :, 2 * d + k]
    return kernel


def l2_star_discrepancy(points: np.ndarray, squared: bool = False):
    """L2-star discrepancy ``D`` of a point set (Warnock's closed form, see module doc).

    ``points``: ``(N, d)`` in [0, 1] -> float, or ``(B, N, d)`` -> ``(B,)`` array.
    Equals ``scipy.stats.qmc.discrepancy(points, method='L2-star')``. The pair
    sum costs ``O(N^2 d)`` per set (see :func:`discrepancy_work`).
    ``squared=True`` returns ``D^2``.
    """
    x, single = _point_batch(points)
    n, d = x.shape[1], x.shape[2]
    out = np.empty(x.shape[0])
    for b, s in enumerate(x):
        single_sum = float(np.sum(np.prod(1.0 - s * s, axis=1)))
        pair = _pair_sum(1.0 - s, _star_kernel)
        out[b] = 3.0 ** -d - 2.0 ** (1 - d) / n * single_sum + pair / (n * n)
    out = np.maximum(out, 0.0)  # guard against rounding below zero
    return _result(out if squared else np.sqrt(out), single)


def centered_discrepancy(points: np.ndarray, squared: bool = False):
    """Centered L2 discrepancy ``CD`` of Hickernell (see module doc).

    ``scipy.stats.qmc.discrepancy(points, method='CD')`` returns ``CD^2``, i.e.
    this function with ``squared=True``. Same shapes and cost as
    :func:`l2_star_discrepancy`.
    """
    x, single = _point_batch(points)
    n, d = x.shape[1], x.shape[2]
    out = np.empty(x.shape[0])
    for b, s in enumerate(x):
        z = np.abs(s - 0.5)
        single_sum = float(np.sum(np.prod(1.0 + 0.5 * z - 0.5 * z * z, axis=1)))
        # |x_i - x_j| = x_i + x_j - 2 min(x_i, x_j), so the kernel is
        # min(x_i, x_j) + u_i + v_j with u = 1 + z/2 - x/2 and v = z/2 - x/2.
        u = 1.0 + 0.5 * z - 0.5 * s
        v = 0.5 * z - 0.5 * s
        pair = _pair_sum(np.concatenate([s, u, v], axis=1), _centered_kernel(d), d)
        out[b] = (13.0 / 12.0) ** d - 2.0 / n * single_sum + pair / (n * n)
    out = np.maximum(out, 0.0)
    return _result(out if squared else np.sqrt(out), single)


def discrepancy_work(n_sets: int, n: int) -> int:
    """Pair evaluations :func:`l2_star_discrepancy` does for ``n_sets`` sets of ``n`` points."""
    return int(n_sets) * int(n) * int(n)


# --------------------------------------------------------------------------- spacing

def mean_spacing(n: int) -> float:
    """Mean sample spacing ``d = 1 / sqrt(n)`` used for the radial frequency axis."""
    if n < 1:
        raise ValueError(f"mean_spacing needs n >= 1, got {n}")
    return 1.0 / math.sqrt(n)


def min_distance_ratio(points: np.ndarray):
    """``rho = d_min / d_hex(N)`` with ``d_min`` the toroidal minimum distance.

    ``(N, 2)`` -> float, ``(B, N, 2)`` -> ``(B,)``. Uses
    :func:`mcrt.samplers.poisson_tables.toroidal_min_distances` (exact, float64)
    and :func:`~mcrt.samplers.poisson_tables.d_hex`. Sets of one point give ``inf``.
    Coordinates equal to 1 are the same torus point as 0.
    """
    x, single = _point_batch(points, ndim=2)
    rho = toroidal_min_distances(x) / d_hex(x.shape[1])
    return _result(rho, single)


# --------------------------------------------------------------------------- spectra

def default_kmax(n: int) -> int:
    """Default largest frequency ``kmax = ceil(2 sqrt(N))``: the radial axis reaches
    ``f = 2`` (twice the mean-spacing frequency, past the blue-noise peak)."""
    return max(2, math.ceil(2.0 * math.sqrt(n)))


def frequency_grid(kmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer frequencies ``(kx, ky)`` of :func:`power_spectrum`'s output, each
    ``(2 kmax + 1, 2 kmax + 1)``: row ``i`` is ``ky = i - kmax``, column ``j`` is
    ``kx = j - kmax`` (image layout with ``origin='lower'``)."""
    k = np.arange(-kmax, kmax + 1)
    kx, ky = np.meshgrid(k, k)
    return kx, ky


def spectrum_work(n_sets: int, n: int, kmax: int) -> int:
    """Complex multiply-adds :func:`power_spectrum` does (to budget its cost)."""
    return int(n_sets) * int(n) * (kmax + 1) * (2 * kmax + 1)


def power_spectrum(points: np.ndarray, kmax: int) -> np.ndarray:
    """Averaged periodogram ``P(k) = |sum_j exp(-2 pi i k . x_j)|^2 / N`` (module doc).

    ``points``: ``(N, 2)`` or ``(B, N, 2)``; the result is the mean over the ``B``
    sets, a ``(2 kmax + 1, 2 kmax + 1)`` float64 array indexed as described in
    :func:`frequency_grid` (``P[kmax, kmax] = N`` is the DC term).

    The sum is separable: with ``X[j, a] = exp(-2 pi i a x_j)`` for
    ``a = 0..kmax`` and ``Y[j, b] = exp(-2 pi i b y_j)`` for ``b = -kmax..kmax``,
    ``S(a, b) = (X^T Y)[a, b]``, one matrix product per set. The half ``kx < 0``
    follows from ``P(-k) = P(k)``. Cost: :func:`spectrum_work`.
    """
    if int(kmax) != kmax or kmax < 1:
        raise ValueError(f"kmax must be a positive integer, got {kmax!r}")
    kmax = int(kmax)
    x, _ = _point_batch(points, ndim=2)
    n = x.shape[1]
    a = np.arange(0, kmax + 1)
    b = np.arange(-kmax, kmax + 1)
    half = np.zeros((kmax + 1, 2 * kmax + 1))  # [a, b + kmax]
    rows = max(1, _BLOCK // (2 * kmax + 1))  # points per block (bounds memory)
    for s in x:
        acc = np.zeros((kmax + 1, 2 * kmax + 1), dtype=np.complex128)
        for start in range(0, n, rows):
            p = s[start:start + rows]
            acc += _unit_phasors(p[:, 0], a).T @ _unit_phasors(p[:, 1], b)
        half += (acc.real ** 2 + acc.imag ** 2) / n
    half /= x.shape[0]
    full = np.empty((2 * kmax + 1, 2 * kmax + 1))
    # full[ky + kmax, kx + kmax]; half[kx, ky + kmax] for kx >= 0
    full[:, kmax:] = half.T
    full[:, :kmax] = half[:0:-1, ::-1].T  # P(-kx, -ky) = P(kx, ky)
    return full


def _unit_phasors(t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``exp(-2 pi i k t)`` for every ``t`` (any shape) and frequency ``k``: last axis ``k``.

    The phase is reduced modulo one turn on the exact product ``k t`` (an integer
    times a float64 in [0, 1]) before the trigonometric functions."""
    turns = np.multiply.outer(t, k)
    turns -= np.rint(turns)
    angle = -2.0 * np.pi * turns
    out = np.empty(angle.shape, dtype=np.complex128)
    np.cos(angle, out=out.real)
    np.sin(angle, out=out.imag)
    return out


def expected_jittered_spectrum(kmax: int, n: int) -> np.ndarray:
    """Expected periodogram of fully jittered (stratified) sampling with ``n = m^2``
    strata, ``1 - sinc^2(pi kx / m) sinc^2(pi ky / m)`` (``N`` at ``k = 0``), on
    :func:`frequency_grid`'s layout. Derivation: the ``N`` cells contribute
    independent uniform offsets; cross terms of different cells cancel except on
    the grid's reciprocal lattice, where the sinc factors vanish."""
    m = math.isqrt(n)
    if m * m != n:
        raise ValueError(f"jittered sampling needs a square n, got {n}")
    kx, ky = frequency_grid(kmax)
    out = 1.0 - (np.sinc(kx / m) * np.sinc(ky / m)) ** 2  # np.sinc(t) = sin(pi t) / (pi t)
    out[kmax, kmax] = n
    return out


@dataclass(frozen=True)
class RadialSpectrum:
    """Radially averaged power and anisotropy per annulus (see the module doc)."""

    radius: np.ndarray        # annulus centre r = round(|k|), 1..kmax (int)
    frequency: np.ndarray     # r * mean_spacing(n): radius in units of 1 / (mean spacing)
    power: np.ndarray         # mean P(k) over the annulus (half plane)
    anisotropy_db: np.ndarray  # 10 log10(unbiased variance / mean^2); nan if < 2 values
    count: np.ndarray         # distinct frequencies in the annulus
    n_points: int
    n_sets: int               # periodograms averaged (sets the noise floor)

    @property
    def floor_db(self) -> float:
        """Anisotropy of white noise for this many averaged periodograms."""
        return anisotropy_floor_db(self.n_sets, self.n_points)


def anisotropy_floor_db(n_sets: int, n: int) -> float:
    """White-noise anisotropy ``10 log10((1 - 1/N) / B)`` of ``B`` averaged periodograms."""
    if n <= 1:
        return -math.inf
    return 10.0 * math.log10((1.0 - 1.0 / n) / n_sets)


def radial_spectrum(spectrum: np.ndarray, n_points: int, n_sets: int = 1) -> RadialSpectrum:
    """Radial power and anisotropy of :func:`power_spectrum`'s output.

    ``n_points`` is ``N`` (for the frequency axis), ``n_sets`` the number of
    periodograms that were averaged (recorded for the anisotropy noise floor).
    """
    spectrum = np.asarray(spectrum, dtype=np.float64)
    size = spectrum.shape[0]
    if spectrum.ndim != 2 or spectrum.shape[1] != size or size % 2 == 0 or size < 3:
        raise ValueError(f"expected a (2 kmax + 1)^2 spectrum, got shape {spectrum.shape}")
    kmax = size // 2
    kx, ky = frequency_grid(kmax)
    half = (kx > 0) | ((kx == 0) & (ky > 0))
    ring = np.rint(np.hypot(kx, ky)).astype(np.int64)
    keep = half & (ring >= 1) & (ring <= kmax)
    r, v = ring[keep], spectrum[keep]
    count = np.bincount(r, minlength=kmax + 1)[1:]
    total = np.bincount(r, weights=v, minlength=kmax + 1)[1:]
    mean = total / count
    dev = np.bincount(r, weights=(v - mean[r - 1]) ** 2, minlength=kmax + 1)[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where(count > 1, dev / np.maximum(count - 1, 1), np.nan)
        aniso = 10.0 * np.log10(var / mean ** 2)
    radius = np.arange(1, kmax + 1)
    return RadialSpectrum(radius=radius, frequency=radius * mean_spacing(n_points), power=mean,
                          anisotropy_db=aniso, count=count, n_points=int(n_points),
                          n_sets=int(n_sets))


def low_frequency_power(radial: RadialSpectrum, cutoff: float = 0.5) -> float:
    """Mean power over all frequencies with ``0 < f < cutoff`` (``f = r d``, annuli
    weighted by their number of frequencies): 1 for white noise, near 0 for blue
    noise. ``nan`` if no annulus lies below the cutoff."""
    sel = radial.frequency < cutoff
    if not np.any(sel):
        return math.nan
    return float(np.sum(radial.power[sel] * radial.count[sel]) / np.sum(radial.count[sel]))


def pooled_anisotropy_db(radial: RadialSpectrum, fmin: float = 0.5, fmax: float = 2.0) -> float:
    """Anisotropy pooled over the annuli with ``fmin <= f <= fmax``, in dB.

    The annuli's variance ratios ``s_r^2 / Pr^2`` are averaged with weights
    ``m_r - 1`` (their degrees of freedom) before taking ``10 log10``: for white
    noise this estimates the floor with relative standard error
    ``sqrt(2 / sum (m_r - 1))``, unlike an average of dB values, which is biased
    low by the log. ``nan`` if no annulus qualifies.
    """
    sel = ((radial.frequency >= fmin) & (radial.frequency <= fmax) & (radial.count > 1)
           & np.isfinite(radial.power) & (radial.power > 0))
    if not np.any(sel):
        return math.nan
    weight = radial.count[sel] - 1
    ratio = 10.0 ** (radial.anisotropy_db[sel] / 10.0)
    with np.errstate(divide="ignore"):
        return float(10.0 * np.log10(np.sum(weight * ratio) / np.sum(weight)))


# --------------------------------------------------------------------------- all at once

@dataclass(frozen=True)
class PatternReport:
    """Every measure of a batch of point sets (see :func:`analyse_points`)."""

    n_points: int
    n_sets: int
    spectrum: np.ndarray          # averaged over the first ``spectrum_sets`` sets
    spectrum_sets: int
    radial: RadialSpectrum
    rho: np.ndarray               # (n_sets,) d_min / d_hex
    l2_star: np.ndarray           # (discrepancy_sets,)
    centered: np.ndarray          # (discrepancy_sets,)

    @property
    def low_frequency_power(self) -> float:
        return low_frequency_power(self.radial)

    def summary(self) -> dict:
        """Plain numbers for printing and JSON."""
        r = self.radial
        peak = int(np.nanargmax(r.power))
        return {
            "n_points": self.n_points,
            "sets": self.n_sets,
            "rho_mean": float(np.mean(self.rho)),
            "rho_min": float(np.min(self.rho)),
            "l2_star_mean": float(np.mean(self.l2_star)),
            "l2_star_std": float(np.std(self.l2_star, ddof=1)) if self.l2_star.size > 1 else 0.0,
            "centered_mean": float(np.mean(self.centered)),
            "discrepancy_sets": int(self.l2_star.size),
            "spectrum_sets": self.spectrum_sets,
            "kmax": int(r.radius[-1]),
            "low_frequency_power": self.low_frequency_power,
            "peak_frequency": float(r.frequency[peak]),
            "peak_power": float(r.power[peak]),
            "anisotropy_db": pooled_anisotropy_db(r, 0.5, 2.0),
            "anisotropy_floor_db": r.floor_db,
        }


def analyse_points(points: np.ndarray, kmax: int | None = None, spectrum_sets: int | None = None,
                   discrepancy_sets: int | None = None) -> PatternReport:
    """Spectrum, radial spectrum, rho and discrepancies of point sets ``(B, N, 2)``.

    The spectrum is averaged over the first ``spectrum_sets`` sets and the
    discrepancies computed for the first ``discrepancy_sets`` (default: all;
    both cost grows fast with ``N``, see :func:`spectrum_work` and
    :func:`discrepancy_work`); rho uses every set. ``kmax`` defaults to
    :func:`default_kmax`.
    """
    x, _ = _point_batch(points, ndim=2)
    b, n = x.shape[0], x.shape[1]
    kmax = default_kmax(n) if kmax is None else int(kmax)
    s_sets = b if spectrum_sets is None else max(1, min(b, int(spectrum_sets)))
    d_sets = b if discrepancy_sets is None else max(1, min(b, int(discrepancy_sets)))
    spectrum = power_spectrum(x[:s_sets], kmax)
    radial = radial_spectrum(spectrum, n, s_sets)
    return PatternReport(
        n_points=n, n_sets=b, spectrum=spectrum, spectrum_sets=s_sets, radial=radial,
        rho=np.atleast_1d(min_distance_ratio(x)),
        l2_star=np.atleast_1d(l2_star_discrepancy(x[:d_sets])),
        centered=np.atleast_1d(centered_discrepancy(x[:d_sets])))
