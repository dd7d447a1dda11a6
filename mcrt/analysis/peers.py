"""The peers' integration benchmarks, run on mcrt's point sets.

Two published benchmarks, re-implemented from their definitions (our own code;
constants and published figures carry their source):

UTK integration test
====================

utk-team/utk (``include/utk/metrics/Integrands/HeavisideIntegrands.hpp``,
``GaussianIntegrands.hpp``, ``include/utk/metrics/IntegrationTest.hpp``,
``examples/Evaluation``). A database of ``M`` random integrands on ``[0,1]^2``:

* **Heaviside**: ``f(x) = [n . (x - p) > 0]`` with ``n`` a uniformly random unit
  normal (a normalised Gaussian vector) and ``p`` uniform in the square: a random
  straight edge through a random point. Exact integral: the clipped area, here by
  the closed-form integral of a clamped linear function (:func:`halfplane_area`).
* **Gaussian**: ``f(x) = exp(-(x - mu)^T Sigma^-1 (x - mu) / 2)`` (unnormalised,
  peak 1), ``mu`` uniform in the square, ``Sigma = Q diag(s) Q^T`` with ``Q`` a
  random rotation and eigenvalues ``s_i ~ U(0.01, 1)`` (UTK's ``smin``/``smax``
  defaults). UTK takes the reference from 8192 Sobol' points; we use a 96 x 96
  Gauss-Legendre rule (exact to ~1e-14 for these bumps).

The figure for a point set is the mean over the database of the squared error;
UTK's published table (``examples/Readme.md``, seed 20081976, 16 point sets per
``N``, 4096 integrands) averages it over the point sets. :func:`utk_mse` does
the same and estimates the figure's standard error by the two-way decomposition
``Var(row means) / P + Var(column means) / M`` (point sets x integrands), which
also estimates the published figure's own uncertainty (same design).

Christensen's funcsamp2D
========================

perchristensen/funcsamp2D (``funcsamp2D.cpp``, Pixar 2019): 18 functions on the
unit square with reference values (:data:`FUNCSAMP`), error = mean over 100
sequences of ``|estimate - reference|``. Published curves for the quarter disk
(``errors_quarterdisk_*.data``) are in :data:`FUNCSAMP_PUBLISHED`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: UTK's published 2D table (utk-team/utk examples/Readme.md): MSE at N.
UTK_PUBLISHED: dict[str, dict[str, dict[int, float]]] = {
    "white noise": {"gaussian": {16: 2.2725382131632355e-3, 256: 2.603261545549384e-4,
                                 4096: 1.010091707784436e-5},
                    "heaviside": {16: 8.519915227374e-3, 256: 8.560392083814568e-4,
                                  4096: 3.710433769122564e-5}},
    "stratified": {"gaussian": {16: 3.2150732132570076e-4, 256: 1.400627403479704e-6,
                                4096: 5.211024300506443e-9},
                   "heaviside": {16: 2.430274168367333e-3, 256: 3.790720704501276e-5,
                                 4096: 5.980191025808278e-7}},
}

#: UTK's default eigenvalue range of the Gaussians' covariance (smin, smax).
UTK_SIGMA_RANGE = (0.01, 1.0)
UTK_COUNTS = (16, 256, 4096)
UTK_POINT_SETS = 16
UTK_INTEGRANDS = 4096

#: Which published row each mcrt / Mitsuba sampler is the same construction as.
UTK_ROW_OF = {"independent": "white noise", "jittered": "stratified", "stratified": "stratified"}


# --------------------------------------------------------------------------- UTK families

def halfplane_area(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Area of ``{(x, y) in [0,1]^2 : a x + b y + c > 0}``, vectorised, exact.

    With ``|b| >= |a|`` (else swap the axes), the set's height at ``x`` is
    ``clamp(t(x), 0, 1)`` with ``t`` linear, and ``int_0^1 clamp(alpha + beta x) dx
    = (G(alpha + beta) - G(alpha)) / beta``, ``G`` the antiderivative of the clamp.
    """
    a, b, c = (np.asarray(v, dtype=np.float64) for v in (a, b, c))
    swap = np.abs(a) > np.abs(b)
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    safe_b = np.where(b == 0.0, 1.0, b)
    # b > 0: y > -(a x + c) / b, height 1 - clamp(-(a x + c)/b); b < 0: height clamp(-(ax+c)/b)
    alpha, beta = -c / safe_b, -a / safe_b

    def prim(t: np.ndarray) -> np.ndarray:
        return np.where(t <= 0.0, 0.0, np.where(t >= 1.0, t - 0.5, 0.5 * t * t))

    small = np.abs(beta) < 1e-12
    safe_beta = np.where(small, 1.0, beta)
    mean_clamp = np.where(small, np.clip(alpha, 0.0, 1.0),
                          (prim(alpha + beta) - prim(alpha)) / safe_beta)
    area = np.where(b > 0.0, 1.0 - mean_clamp, mean_clamp)
    return np.where(b == 0.0, (c > 0.0).astype(np.float64), area)


@dataclass(frozen=True)
class IntegrandFamily:
    """``M`` integrands evaluated in bulk: ``values(points (N, 2)) -> (N, M)``."""

    name: str
    exact: np.ndarray                                  # (M,)
    values: Callable[[np.ndarray], np.ndarray]
    variance: np.ndarray                               # (M,): Var[f(U)], U uniform

    def white_noise_mse(self, n: int) -> float:
        """Expected figure of ``n`` independent uniform points on this database:
        ``mean_m Var[f_m] / n`` (exact: no point-set noise)."""
        return float(np.mean(self.variance)) / n

    def estimates(self, points: np.ndarray, chunk: int = 1 << 22) -> np.ndarray:
        """``mean_j f_m(x_j)`` per point set and integrand: points ``(P, N, 2)`` -> ``(P, M)``."""
        pts = np.asarray(points, dtype=np.float64)
        out = np.empty((pts.shape[0], self.exact.size))
        rows = max(1, chunk // max(1, self.exact.size))
        for p in range(pts.shape[0]):
            total = np.zeros(self.exact.size)
            for start in range(0, pts.shape[1], rows):
                total += self.values(pts[p, start:start + rows]).sum(axis=0)
            out[p] = total / pts.shape[1]
        return out


def heaviside_family(count: int, seed: int = 0) -> IntegrandFamily:
    """UTK's random Heaviside integrands: a uniform random edge through a uniform point."""
    rng = np.random.default_rng(seed)
    normal = rng.standard_normal((count, 2))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = -np.sum(normal * rng.random((count, 2)), axis=1)      # r = -n . p
    exact = halfplane_area(normal[:, 0], normal[:, 1], offset)

    def values(x: np.ndarray) -> np.ndarray:
        return (x @ normal.T + offset > 0.0).astype(np.float64)

    return IntegrandFamily("heaviside", exact, values, exact * (1.0 - exact))


def _gauss_legendre_square(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    t, w = np.polynomial.legendre.leggauss(nodes)
    t, w = 0.5 * (t + 1.0), 0.5 * w
    gx, gy = np.meshgrid(t, t, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1), np.outer(w, w).ravel()


def gaussian_family(count: int, seed: int = 0, sigma_range: tuple[float, float] = UTK_SIGMA_RANGE,
                    quadrature_nodes: int = 96) -> IntegrandFamily:
    """UTK's random anisotropic Gaussians; exact values by tensor Gauss-Legendre."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, math.pi, count)
    mu = rng.random((count, 2))
    inv_var = 1.0 / rng.uniform(sigma_range[0], sigma_range[1], (count, 2))
    cos, sin = np.cos(angle), np.sin(angle)
    # A = Q diag(1/s) Q^T with Q = [[cos, -sin], [sin, cos]]
    a11 = cos * cos * inv_var[:, 0] + sin * sin * inv_var[:, 1]
    a22 = sin * sin * inv_var[:, 0] + cos * cos * inv_var[:, 1]
    a12 = cos * sin * (inv_var[:, 0] - inv_var[:, 1])
    # -0.5 (x-mu)^T A (x-mu) as a linear form in (x^2, xy, y^2, x, y, 1)
    coeff = np.stack([-0.5 * a11, -a12, -0.5 * a22,
                      a11 * mu[:, 0] + a12 * mu[:, 1], a12 * mu[:, 0] + a22 * mu[:, 1],
                      -0.5 * (a11 * mu[:, 0] ** 2 + 2 * a12 * mu[:, 0] * mu[:, 1]
                              + a22 * mu[:, 1] ** 2)])                     # (6, M)

    def values(x: np.ndarray) -> np.ndarray:
        px, py = x[:, 0], x[:, 1]
        features = np.stack([px * px, px * py, py * py, px, py, np.ones_like(px)], axis=1)
        return np.exp(features @ coeff)

    nodes, weights = _gauss_legendre_square(quadrature_nodes)
    at_nodes = values(nodes)
    exact = weights @ at_nodes
    return IntegrandFamily("gaussian", exact, values, weights @ (at_nodes ** 2) - exact ** 2)


UTK_FAMILIES = {"gaussian": gaussian_family, "heaviside": heaviside_family}


@dataclass(frozen=True)
class UTKFigure:
    """UTK's figure for one sampler, family and ``N``: mean squared error over point
    sets and integrands, with its two-way standard error."""

    mse: float
    stderr: float
    point_sets: int
    integrands: int

    @property
    def rel_se(self) -> float:
        return self.stderr / self.mse if self.mse > 0 else 0.0


def utk_mse(estimates: np.ndarray, exact: np.ndarray) -> UTKFigure:
    """The figure from estimates ``(P, M)``: ``mean (est - exact)^2`` and its se."""
    sq = (np.asarray(estimates, dtype=np.float64) - exact[None, :]) ** 2
    p, m = sq.shape
    var = 0.0
    if p > 1:
        var += float(np.var(sq.mean(axis=1), ddof=1)) / p
    if m > 1:
        var += float(np.var(sq.mean(axis=0), ddof=1)) / m
    return UTKFigure(float(sq.mean()), math.sqrt(var), p, m)


# --------------------------------------------------------------------------- funcsamp2D

def _radial_ramp(r: np.ndarray, inner: float, outer: float) -> np.ndarray:
    return np.clip((outer - r) / (outer - inner), 0.0, 1.0)


def _sin_inv_r(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    r = np.hypot(x, y)
    return np.where(r > 0.0, np.sin(math.pi / np.where(r > 0.0, r, 1.0)), 1.0)


_F = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Christensen's funcsamp2D functions: name -> (f(x, y), reference value). The
#: reference values are funcsamp2D's (perchristensen/funcsamp2D, funcsamp2D.cpp);
#: the three it gives to six digits are checked by quadrature in the tests.
FUNCSAMP: dict[str, tuple[_F, float]] = {
    "quarterdisk": (lambda x, y: (x * x + y * y < 2.0 / math.pi).astype(np.float64), 0.5),
    "fulldisk": (lambda x, y: ((x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.5 / math.pi)
                 .astype(np.float64), 0.5),
    "triangle": (lambda x, y: (x + y < 1.0).astype(np.float64), 0.5),
    "quarterdiskramp": (lambda x, y: _radial_ramp(np.hypot(x, y), 0.7, 0.9), 0.505273),
    "fulldiskramp": (lambda x, y: _radial_ramp(np.hypot(x - 0.5, y - 0.5), 0.35, 0.45),
                     0.505273),
    "triangleramp": (lambda x, y: np.clip(5.0 * (y - x), -0.5, 0.5) + 0.5, 0.5),
    "quartergaussian": (lambda x, y: np.exp(-x * x - y * y), 0.55774629),
    "fullgaussian": (lambda x, y: np.exp(-(x - 0.5) ** 2 - (y - 0.5) ** 2), 0.851121),
    "bilinear": (lambda x, y: x * y, 0.25),
    "biquadratic": (lambda x, y: x * x * y * y, 1.0 / 9.0),
    "sinxy": (lambda x, y: np.sin(math.pi * (x + y)), 0.0),
    "sininvr": (_sin_inv_r, -0.220242),
    "stepx": (lambda x, y: (x < 1.0 / math.pi).astype(np.float64), 1.0 / math.pi),
    "rampx": (lambda x, y: np.clip((0.4 - x) / 0.2, 0.0, 1.0), 0.3),
    "lineary": (lambda x, y: y, 0.5),
    "gaussianx": (lambda x, y: np.exp(-x * x), 0.74682413),
    "siny": (lambda x, y: np.sin(math.pi * y), 2.0 / math.pi),
    "sin2x": (lambda x, y: np.sin(2.0 * math.pi * x), 0.0),
}

FUNCSAMP_COUNTS = (16, 64, 256, 1024)
FUNCSAMP_SEQUENCES = 100

#: Published mean absolute errors on the quarter disk (funcsamp2D's
#: errors_quarterdisk_<set>.data, 100 sequences) at FUNCSAMP_COUNTS.
FUNCSAMP_PUBLISHED: dict[str, tuple[float, ...]] = {
    "random": (0.086875, 0.050000, 0.024570, 0.012021),
    "sobol_dim01_owen": (0.034375, 0.012656, 0.004844, 0.001563),
    "pmj02": (0.036250, 0.014063, 0.005039, 0.001494),
    "halton_base23_owen": (0.038125, 0.016563, 0.005391, 0.001748),
    "irrational_rot": (0.043750, 0.014063, 0.005703, 0.001924),
    "bestcand": (0.046250, 0.021562, 0.009023, 0.004121),
}

#: Which published curve each sampler is the same construction as.
FUNCSAMP_ROW_OF = {"independent": "random", "sobol": "sobol_dim01_owen",
                   "poisson_disk": "bestcand"}


def funcsamp_errors(points: np.ndarray) -> dict[str, float]:
    """Mean absolute error over point sets ``(P, N, 2)`` for every funcsamp2D function."""
    x = points[..., 0].astype(np.float64)
    y = points[..., 1].astype(np.float64)
    return {name: float(np.mean(np.abs(np.mean(f(x, y), axis=1) - ref)))
            for name, (f, ref) in FUNCSAMP.items()}
