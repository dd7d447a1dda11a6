"""poisson_disk as Mitsuba sees it: spacing and spectrum of every pixel's set."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mcrt.analysis.patterns import power_spectrum
from mcrt.samplers.points import point_sets
from mcrt.samplers.poisson_tables import d_hex, toroidal_min_distance


@pytest.mark.parametrize("spp", [16, 64, 256])
def test_every_pixel_set_keeps_the_spacing(spp):
    """rho = d_min / d_hex >= 0.75 (toroidal) in every pixel, for the film
    dimension and a later dimension pair, and in a later epoch (pass)."""
    pixels = range(0, 4096, 64)  # 64 pixels spread over the image
    for dimension in (0, 5):
        sets = point_sets("poisson_disk", pixels, spp, dimension=dimension, seed=3)
        rho = [toroidal_min_distance(s.astype(np.float64)) / d_hex(spp) for s in sets]
        assert min(rho) >= 0.75, (dimension, min(rho))
    sampler = mi.load_dict({"type": "poisson_disk", "sample_count": spp})
    pixel = mi.UInt32(np.repeat(np.arange(8), spp).astype(np.uint32))
    sample = mi.UInt32(np.tile(np.arange(spp, 2 * spp), 8).astype(np.uint32))  # epoch 1
    sampler.seed_lanes(3, pixel, sample)
    later = np.array(sampler.next_2d(), dtype=np.float64).T.reshape(8, spp, 2)
    assert min(toroidal_min_distance(s) for s in later) >= 0.75 * d_hex(spp)


def test_pixels_and_dimensions_get_different_sets():
    a = point_sets("poisson_disk", range(16), 64, dimension=0)
    b = point_sets("poisson_disk", range(16), 64, dimension=1)
    keys = {np.sort(np.round(s, 6), axis=0).tobytes() for s in np.concatenate([a, b])}
    assert len(keys) == 32


def test_spectrum_has_no_low_frequency_energy():
    """Averaged periodogram P(k) = |sum exp(-2 pi i k.x)|^2 / N over 256 pixel
    sets of N = 256 points (mcrt.analysis.patterns). For white noise every P(k)
    has mean 1 (an average of 256 independent exponentials: sd 1/16). We require
    the mean over the low band 0 < |k| < 0.5 sqrt(N) (below the blue-noise peak
    near |k| ~ 1/d_hex ~ 0.93 sqrt(N)) to be < 0.02 (measured ~0.005; dart
    throwing alone gives ~0.075), and the band past the peak and its trough
    (|k| > 1.8 sqrt(N)) to be near 1 (0.7 .. 1.3: the band holds hundreds of
    frequencies, so its mean has sd < 0.01 for white noise; the margin allows
    the oscillating tail)."""
    n = 256
    sets = point_sets("poisson_disk", range(256), n, seed=1).astype(np.float64)
    kmax = 40
    power = power_spectrum(sets, kmax)
    ky, kx = np.mgrid[-kmax:kmax + 1, -kmax:kmax + 1]
    radius = np.hypot(kx, ky)
    low = power[(radius > 0) & (radius < 0.5 * np.sqrt(n))].mean()
    high = power[radius > 1.8 * np.sqrt(n)].mean()
    assert low < 0.02, low
    assert 0.7 < high < 1.3, high
