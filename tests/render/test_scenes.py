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
from mcrt.errors import SceneError
from mcrt.render.scene import load_scene, read_scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"
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


# ------------------------------------------------------------ mcrt's loader
NO_SENSOR = '<scene version="3.0.0"><shape type="sphere"/></scene>'


@pytest.mark.parametrize("name, text, params, message", [
    ("missing.xml", None, None, "scene file not found"),
    ("broken.xml", '<scene version="3.0.0"><shape type="sphere"></scene>', None,
     "Start-end tags mismatch"),
    ("bsdf.xml", '<bsdf version="3.0.0" type="diffuse"/>', None, "does not describe a scene"),
    ("no_sensor.xml", NO_SENSOR, None, "has no sensor to render from"),
    ("plugin.xml", '<scene version="3.0.0"><shape type="spheroid"/></scene>', None,
     'Plugin "spheroid" not found'),
    ("cornell", None, {"no_such_parameter": "1"}, "unused parameters"),
])
def test_load_scene_errors_are_one_line(tmp_path, name, text, params, message):
    path = CORNELL if name == "cornell" else tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(SceneError, match=message) as error:
        load_scene(path, params)
    assert len(str(error.value).splitlines()) == 1


def test_load_scene_matches_mitsuba(tmp_path):
    """mcrt's loader builds what mi.load_file builds, with files the scene
    names resolved from its own folder whatever the working directory."""
    ours = load_scene(CORNELL, {"res": "8"})
    theirs = load(CORNELL, res=8)
    assert str(ours.integrator()) == str(theirs.integrator())
    assert sorted(s.id() for s in ours.shapes()) == sorted(s.id() for s in theirs.shapes())
    folder = tmp_path / "scene"
    folder.mkdir()
    (folder / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "mesh.xml").write_text(
        '<scene version="3.0.0"><sensor type="perspective"/>'
        '<shape type="obj"><string name="filename" value="tri.obj"/></shape></scene>')
    resolver = [str(p) for p in mi.file_resolver()]
    assert len(load_scene(folder / "mesh.xml").shapes()) == 1
    assert [str(p) for p in mi.file_resolver()] == resolver


def test_scene_description_is_read_once_and_instantiated_afresh():
    desc = read_scene(CHECKER, {"width": "8", "height": "6"})
    a, b = desc.instantiate(), desc.instantiate()
    assert a is not b and len(b.shapes()) == len(a.shapes())
    assert list(a.sensors()[0].film().size()) == [8, 6]
    # The description stays editable after instantiating; the next scene shows the edit.
    film = next(node for node in desc.nodes if node.type == mi.ObjectType.Film)
    film.props["width"] = 4
    assert list(desc.instantiate().sensors()[0].film().size()) == [4, 6]
    assert list(a.sensors()[0].film().size()) == [8, 6]


def test_a_library_error_of_the_loader_is_retried_serially(monkeypatch):
    """Small descriptions are instantiated on the calling thread, large ones on
    Mitsuba's threads; an error of the C++ library itself (a rare
    ``basic_string::_M_create`` under parallel instantiation, which no rerun
    reproduced, so it is simulated here) is retried once serially, while an error
    in the scene is reported at once, not retried."""
    from mcrt.render import scene as scene_module

    desc = read_scene(CHECKER, {"width": "8", "height": "6"})
    calls: list[bool] = []
    build = scene_module.SceneDescription._build

    def flaky(self, parallel):
        calls.append(parallel)
        if parallel:
            raise RuntimeError("failed to instantiate sensor plugin: basic_string::_M_create")
        return build(self, parallel)

    monkeypatch.setattr(scene_module.SceneDescription, "_build", flaky)
    assert len(desc.nodes) < scene_module.PARALLEL_NODES
    assert list(desc.instantiate().sensors()[0].film().size()) == [8, 6]
    assert calls == [False]  # a small scene: serial from the start
    calls.clear()
    monkeypatch.setattr(scene_module, "PARALLEL_NODES", 1)  # as a large scene
    assert list(desc.instantiate().sensors()[0].film().size()) == [8, 6]
    assert calls == [True, False]

    def broken(self, parallel):
        calls.append(parallel)
        raise RuntimeError("Plugin \"nosuch\" not found")

    calls.clear()
    monkeypatch.setattr(scene_module.SceneDescription, "_build", broken)
    with pytest.raises(SceneError, match="nosuch"):
        desc.instantiate()
    assert calls == [True]


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
