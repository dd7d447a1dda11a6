"""How a film's reconstruction filter correlates the noise of neighbouring pixels.

A film with filter ``w`` (separable, ``w(x) w(y)``) develops pixel ``p`` as the
ratio ``sum_s w_ps L_s / sum_s w_ps`` over the samples within the filter's
reach. For samples spread uniformly over the film, each with independent noise
of variance ``s^2`` at density ``n`` per pixel, the linearised error of pixel
``p`` has ``Cov(e_p, e_q) = s^2 / n * prod_axes a(q - p) / (int w)^2`` with
``a(d) = int w(x) w(x - d) dx`` the filter's autocorrelation. Per axis, the
*correlation* between pixels ``d`` apart is therefore

    c(d) = a(d) / a(0)           (c(0) = 1; zero from d >= 2 x radius on)

and, by Poisson summation, the error's power spectrum is
``S(f) = sum_d c(d) cos(2 pi f d) = sum_k |W(f + k)|^2 / a(0)`` per axis
(non-negative: the filter's transfer function, aliased onto the pixel grid).

Two consequences for the metrics:

* **Means over pixels** (the bias of an image): ``Var(mean of P pixels) =
  F sum_p Var(e_p) / P^2`` with ``F = (sum_d c(d))^2 = ((int w)^2 / int w^2)^2``
  (2D), not ``1 x`` as for independent pixels: :func:`variance_factor`. Box: 1;
  tent: 2.25; gaussian (Mitsuba's default, stddev 0.5): 3.13; mitchell: 2.15;
  catmullrom: 1.51; lanczos: 1.25.
* **Spectra** (the aliasing score): filtered noise is not white but has the
  spectrum ``S(f_y) S(f_x)``: :func:`noise_spectrum`, which
  :func:`mcrt.analysis.aliasing.aliasing_score` uses for its null model.

Exact for the ``independent`` sampler (white sample noise); stratified samplers
make less noise at low frequencies, so for them the factor is an upper bound.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: Integration steps per unit length for the filter's autocorrelation.
STEPS = 512


def filter_correlation(rfilter) -> np.ndarray:
    """``c(d)`` for ``d = -R .. R`` (``R = ceil(2 radius) - 1``; length ``2R + 1``,
    ``c(0) = 1``) of a Mitsuba reconstruction filter, the name of one
    (``"gaussian"``: default parameters) or None (box: ``[1.0]``)."""
    import mitsuba as mi

    if rfilter is None or rfilter == "" or rfilter == "box":
        return np.ones(1)
    if isinstance(rfilter, str):
        return _named_correlation(rfilter)
    if rfilter.is_box_filter():
        return np.ones(1)
    radius = float(rfilter.radius())
    x = (np.arange(math.ceil(2 * radius * STEPS)) + 0.5) / STEPS - radius
    w = np.array(rfilter.eval(mi.Float(x)), dtype=np.float64)
    reach = max(math.ceil(2 * radius) - 1, 0)
    a = [float(np.dot(w[d * STEPS:], w[:w.size - d * STEPS])) if d * STEPS < w.size else 0.0
         for d in range(reach + 1)]
    c = np.array(a) / a[0]
    return np.concatenate([c[:0:-1], c])


@lru_cache(maxsize=16)
def _named_correlation(name: str) -> np.ndarray:
    import mitsuba as mi

    return filter_correlation(mi.load_dict({"type": name}))


def variance_factor(correlation: np.ndarray | None) -> float:
    """``F = (sum_d c(d))^2``: what a 2D filter with per-axis correlation ``c``
    multiplies the variance of a mean over many pixels by (module doc)."""
    if correlation is None:
        return 1.0
    return float(np.sum(correlation)) ** 2


def noise_spectrum(correlation: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``S(f_y) S(f_x)`` on the ``np.fft.fft2`` grid of ``shape`` (H, W): the
    expected power spectrum of filtered white noise, up to scale."""
    c = np.asarray(correlation, dtype=np.float64)
    lags = np.arange(c.size) - c.size // 2

    def axis(n: int) -> np.ndarray:
        f = np.fft.fftfreq(n)
        return np.maximum(np.cos(2 * np.pi * np.outer(f, lags)) @ c, 0.0)

    return np.outer(axis(int(shape[0])), axis(int(shape[1])))


__all__ = ["filter_correlation", "noise_spectrum", "variance_factor"]
