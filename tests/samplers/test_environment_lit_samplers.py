"""Samplers on an environment-lit scene.

``uniform_grid`` used to put the same cell centres in every pixel for every
dimension, so every pixel drew the same light directions: on an
environment-lit scene that is a bias shared by all pixels (+21% to +25% at
16 spp). It now keeps the regular grid on the film and shifts the lattice of
every other dimension by a uniform offset per pixel: unbiased, still one point
per cell. Every sampler's image mean must be within 5 SE of an ``independent``
reference (the SE from the per-pixel spread across seeds, see
``test_third_party_scenes``), and the old pattern (``jittered`` with jitter 0)
must fail that check, so the check can see the bias.
"""

from __future__ import annotations

import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.core.sampling import bind_film_width, make_sampler, quiet_sampler_warnings
from mcrt.render.plan import plan_scene
from mcrt.samplers import ALL_SAMPLERS
from mcrt.samplers.points import point_sets
from tests.render.test_third_party_scenes import ENV, mean_and_se, z_score

SPP = 16
SEEDS = 6


@pytest.fixture(scope="module")
def env():
    scene = plan_scene(ENV).scene
    reference = mean_and_se([render_film(scene, make_sampler("independent", 64), spp=64,
                                         seed=1000 + s).image for s in range(SEEDS)])
    return scene, reference


def sampler_mean(scene, name: str, **params) -> tuple[float, float]:
    width = int(scene.sensors()[0].film().size()[0])
    images = []
    with quiet_sampler_warnings():  # orthogonal rounds 16 to 25
        for seed in range(SEEDS):
            sampler = make_sampler(name, SPP, **params)
            bind_film_width(sampler, width)  # zsobol needs it; the others ignore it
            images.append(render_film(scene, sampler, spp=SPP, seed=seed).image)
    return mean_and_se(images)


@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_SAMPLERS)
def test_every_sampler_is_unbiased_on_an_environment_lit_scene(env, name):
    scene, reference = env
    assert z_score(sampler_mean(scene, name), reference) < 5


def test_the_check_sees_the_bias_of_cell_centres_in_every_dimension(env):
    scene, reference = env
    old = sampler_mean(scene, "jittered", jitter=0.0)  # the former uniform_grid
    assert z_score(old, reference) > 5


def test_uniform_grid_keeps_the_film_grid_and_shifts_the_other_dimensions():
    k = 4
    centres = (np.arange(k) + 0.5) / k
    film = point_sets("uniform_grid", range(3), k * k, dimension=0, seed=5)
    for pixel in film:
        assert sorted(map(tuple, pixel.tolist())) == sorted(
            (float(x), float(y)) for x in centres for y in centres)
    for dim, ndim in ((1, 2), (2, 1), (3, 2)):
        pts = point_sets("uniform_grid", range(400), k * k, dimension=dim, ndim=ndim, seed=5)
        n = k if ndim == 2 else k * k
        cells = np.floor(pts * n).astype(int)
        offsets = pts * n - cells
        for p in range(3):  # one point per cell, all shifted by one offset
            flat = cells[p] @ (n ** np.arange(ndim))
            assert sorted(flat.tolist()) == list(range(k * k))
            assert np.allclose(offsets[p], offsets[p][0], atol=1e-5)
        # The offsets are uniform over pixels: mean 1/2, variance 1/12 (400 pixels:
        # SE of the mean 0.014, of the variance about 0.003; 5 SE margins).
        first = offsets[:, 0, :]
        assert abs(first.mean() - 0.5) < 5 * 0.29 / np.sqrt(first.size)
        assert abs(first.var() - 1 / 12) < 5 * 0.075 / np.sqrt(first.size)
