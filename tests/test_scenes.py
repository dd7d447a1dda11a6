"""The shipped scenes load, default to the documented settings and render sensibly
with mcrt's samplers and Mitsuba's ``independent``; the checkerboard shows
aliasing (a fixed, seed-independent error) with a regular grid and noise
(an error that averages away) with jitter."""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mcrt  # noqa: F401  (activates llvm_ad_rgb, registers the sampler plugins)

SCENES = Path(__file__).resolve().parents[1] / "scenes"
CORNELL = SCENES / "cornell_box.xml"
CHECKER = SCENES / "checkerboard.xml"

SAMPLERS = ["uniform_grid", "jittered", "poisson_disk", "independent"]

#: scene -> (small-render overrides, (W, H) they give, sensible range of the mean value)
SMALL = {
    "cornell_box": (CORNELL, {"res": 16}, (16, 16), (0.05, 0.5)),
    "checkerboard": (CHECKER, {"width": 32, "height": 24}, (32, 24), (0.2, 0.7)),
}


def load(path: Path, **params) -> mi.Scene:
    return mi.load_file(str(path), **params)


def render(scene: mi.Scene, seed: int = 0) -> np.ndarray:
    return np.asarray(mi.render(scene, seed=seed), dtype=np.float64)


# ------------------------------------------------------------------ defaults
@pytest.mark.parametrize("path, size, spp, integrator", [
    (CORNELL, [256, 256], 64, "PathIntegrator"),
    (CHECKER, [320, 240], 16, "DirectIntegrator"),
])
def test_scene_defaults(path, size, spp, integrator):
    scene = load(path)
    sensor = scene.sensors()[0]
    film = sensor.film()
    assert list(film.size()) == size
    assert "component_format = float32" in str(film)
    assert "BoxFilter" in str(film)
    sampler = sensor.sampler()
    assert isinstance(sampler, mcrt.samplers.JitteredSampler)
    assert sampler.sample_count() == spp
    assert str(scene.integrator()).startswith(integrator)


def test_cornell_box_has_an_area_light_and_path_depth_8():
    scene = load(CORNELL, res=8)
    area = [e for e in scene.emitters()
            if mi.has_flag(e.flags(), mi.EmitterFlags.Surface) and e.get_shape() is not None]
    assert len(area) == 1
    assert "max_depth = 8" in str(scene.integrator())
    bbox = scene.bbox()  # the box spans [-1, 1]^3 (the tall box pokes 0.01 below the floor)
    np.testing.assert_allclose(list(bbox.min), [-1, -1, -1], atol=0.011)
    np.testing.assert_allclose(list(bbox.max), [1, 1, 1], atol=1e-5)


def test_checkerboard_is_lit_by_a_delta_sun():
    scene = load(CHECKER, width=8, height=6)
    emitters = scene.emitters()
    assert len(emitters) == 1 and mi.has_flag(emitters[0].flags(), mi.EmitterFlags.Delta)


def test_scene_parameters_override():
    scene = load(CHECKER, spp=9, width=40, height=30, sampler="uniform_grid", checks=100)
    assert list(scene.sensors()[0].film().size()) == [40, 30]
    assert scene.sensors()[0].sampler().sample_count() == 9
    assert isinstance(scene.sensors()[0].sampler(), mcrt.samplers.UniformGridSampler)
    cornell = load(CORNELL, width=24, height=12, max_depth=2)
    assert list(cornell.sensors()[0].film().size()) == [24, 12]
    with pytest.raises(Exception, match="unused parameters"):
        load(CORNELL, no_such_parameter=1)


# ---------------------------------------------------- every scene x sampler
@pytest.mark.parametrize("sampler", SAMPLERS)
@pytest.mark.parametrize("name", list(SMALL))
def test_scene_renders_with_sampler(name, sampler):
    path, overrides, (w, h), (lo, hi) = SMALL[name]
    scene = load(path, spp=4, sampler=sampler, **overrides)
    assert scene.sensors()[0].sampler().sample_count() == 4
    image = render(scene)
    assert image.shape == (h, w, 3)
    assert np.all(np.isfinite(image))
    assert image.min() >= 0.0
    assert lo < image.mean() < hi, f"{name}/{sampler}: mean {image.mean():.4f}"
    assert image.std() > 0.2 * image.mean()  # not a flat image


# ------------------------------------------------- aliasing versus noise
def test_checkerboard_grid_aliases_jitter_is_noise():
    """At 4 spp, the uniform grid's error is a fixed pattern (moire): the same
    for every seed, so averaging renders does not reduce it. Jittered sampling's
    error is noise of similar size that averages away like 1/sqrt(renders)."""
    size = {"width": 160, "height": 120}
    reference = render(load(CHECKER, sampler="jittered", spp=256, **size))
    seeds = range(8)

    def errors(sampler):
        scene = load(CHECKER, sampler=sampler, spp=4, **size)
        images = [render(scene, seed) for seed in seeds]
        single = np.sqrt(np.mean((images[0] - reference) ** 2))
        averaged = np.sqrt(np.mean((np.mean(images, axis=0) - reference) ** 2))
        return images, single, averaged

    grid_images, grid_single, grid_avg = errors("uniform_grid")
    jit_images, jit_single, jit_avg = errors("jittered")

    # Both are visibly wrong at 4 spp, by similar amounts (RMSE over the image).
    assert grid_single > 0.03 and jit_single > 0.03
    assert 0.5 < grid_single / jit_single < 2.0
    # Aliasing: the grid's image does not depend on the seed ...
    np.testing.assert_allclose(grid_images[1], grid_images[0], atol=1e-5)
    assert grid_avg > 0.95 * grid_single
    # ... noise: jittered images differ per seed and their mean converges.
    assert np.abs(jit_images[1] - jit_images[0]).mean() > 0.01
    assert jit_avg < 0.5 * jit_single            # 1/sqrt(8) = 0.35 expected
    assert grid_avg > 2 * jit_avg
