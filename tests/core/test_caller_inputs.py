"""Rendering leaves what the caller passes in as it was (Mitsuba's rule for its
Python plugins: inputs are copied, not mutated): a second call with the same
objects gives the bits of a call with fresh ones."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt.core import pass_replay, replay
from mcrt.core.job import Interrupted
from mcrt.core.render import render_film, render_film_pass, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene
from mcrt.samplers import McrtSampler, kit, registry
from tests.conftest import ROOT, same_film

MOTION = ROOT / "scenes" / "effects" / "motion.xml"
SMALL = {"width": "32", "height": "24", "spp": "16"}


def test_an_spp_override_changes_neither_the_sampler_nor_the_scene():
    """render_film(scene, spp=4) set the scene's own sampler to 4 spp, so the next
    render_film(scene) rendered 4 spp where the scene says 64; with a sampler given,
    the caller's sampler kept the override."""
    scene = plan_scene("scenes/cornell_box.xml", {"res": "16"}).scene
    own = scene.sensors()[0].sampler().sample_count()
    assert own != 4
    assert render_film(scene, spp=4, seed=0).spp == 4
    assert scene.sensors()[0].sampler().sample_count() == own
    assert render_stats(scene, scene.sensors()[0].sampler(), spp=4, seed=0).spp == 4
    assert scene.sensors()[0].sampler().sample_count() == own

    sampler = make_sampler("jittered", 16)
    overridden = render_film(scene, sampler, spp=4, seed=0)
    assert overridden.spp == 4 and sampler.sample_count() == 16
    again = render_film(scene, make_sampler("jittered", 4), seed=0)
    assert np.array_equal(overridden.image, again.image)  # the same render as a fresh sampler


def test_a_render_leaves_the_callers_sampler_unseeded_and_zsobol_without_a_width():
    """The sampler given was seeded for the render's last pass (its lanes and, for
    Mitsuba's, 16 bytes of random state a lane kept alive) and zsobol got the film's
    width as its parameter."""
    scene = plan_scene("scenes/cornell_box.xml", {"res": "16"}).scene
    zsobol, independent = make_sampler("zsobol", 16), make_sampler("independent", 16)
    before = (str(zsobol), str(independent), independent.wavefront_size())
    render_film(scene, zsobol, seed=1)
    render_stats(scene, zsobol, seed=1)
    render_film(scene, independent, seed=1, passes=4)
    assert (zsobol.width, zsobol.layout, zsobol.wavefront_size()) == (0, None, 0)
    assert (str(zsobol), str(independent), independent.wavefront_size()) == before
    assert render_film(scene, seed=1).image.shape == (16, 16, 3)
    assert scene.sensors()[0].sampler().layout is None  # nor the scene's own


class _Counting(McrtSampler):
    """A user's sampler whose traced code changes it: a call counter mixed in."""

    def _configure(self, props):
        self.calls = 0

    def _sample_1d(self, key, sample, active):
        return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)

    def _sample_2d(self, key, sample, active):
        self.calls += 1
        h = kit.hash_extend(kit.hash_extend(key, mi.UInt32(self.calls)), sample)
        return mi.Point2f(kit.unit_float(h), kit.unit_float(kit.mix32(h)))


def test_a_users_sampler_renders_the_same_bits_twice():
    """Its counter moved on with every render, so the second render of the same
    sampler object was another image; a clone keeps what the user set on it."""
    mcrt.register_sampler("t_counting_caller", sampler=_Counting)
    try:
        scene = plan_scene("scenes/cornell_box.xml", {"res": "16"}).scene
        sampler = make_sampler("t_counting_caller", 4)
        first = render_film(scene, sampler, seed=1)
        same_film(render_film(scene, sampler, seed=1), first)
        same_film(render_film(scene, make_sampler("t_counting_caller", 4), seed=1), first)
        assert sampler.calls == 0
        sampler.calls = 5  # set by the user: the render's clone starts from it
        moved = render_film(scene, sampler, seed=1)
        assert not np.array_equal(moved.image, first.image) and sampler.calls == 5
        assert sampler.clone().calls == 5
    finally:
        registry.unregister("t_counting_caller")


def test_schedule_leaves_the_samplers_count():
    """schedule(sampler, spp) set the count of the sampler given, or of the scene's
    own: a still render of the scene after it rendered the schedule's spp."""
    planned = plan_scene(MOTION, SMALL)
    sampler = make_sampler("jittered", 16)
    passes, _ = planned.schedule(sampler, 4, seed=1)
    assert (passes, planned.plan.spp, sampler.sample_count()) == (4, 4, 16)
    planned.schedule(None, 4, seed=1)
    assert planned.scene.sensors()[0].sampler().sample_count() == 16
    fresh = render_film(plan_scene(MOTION, SMALL).scene, seed=1)
    same_film(render_film(planned.scene, seed=1), fresh)


def _values(scene: mi.Scene) -> dict[str, np.ndarray]:
    """Copies of the scene's parameters (transforms by their matrices)."""
    params = mi.traverse(scene)
    out = {}
    for key in params.keys():
        value = params[key]
        if hasattr(value, "matrix"):
            out[key] = np.array(value.matrix)
        elif dr.is_array_v(value):
            out[key] = np.array(value).copy()
    return out


def _unchanged(scene: mi.Scene, before: dict[str, np.ndarray]) -> None:
    now = _values(scene)
    assert now.keys() == before.keys()
    moved = [k for k in now if not np.array_equal(now[k], before[k])]
    assert not moved, moved


def _blurred(planned, seed: int = 1):
    sampler = make_sampler("jittered", 16)
    passes, on_pass = planned.schedule(sampler, 16, seed)
    assert passes is not None and passes > 1
    return render_film(planned.scene, sampler, seed=seed, passes=passes, on_pass=on_pass)


def test_a_still_after_motion_blur_is_the_still_of_a_fresh_scene(monkeypatch):
    """The sub-frames left the moving shapes at the last sub-frame's pose. With
    replays on (the default), the stills and the blurred passes replayed too."""
    monkeypatch.delenv(replay.ENV, raising=False)
    replay.clear()
    replayed: list[bool] = []  # each whole render or pass: replayed (True) or traced
    render, run = replay.render, pass_replay.PassReplay.run
    monkeypatch.setattr(replay, "render", _noting(render, replayed, lambda out: out is not None))
    monkeypatch.setattr(pass_replay.PassReplay, "run", _noting(run, replayed, bool))
    planned = plan_scene(MOTION, SMALL)
    before = _values(planned.scene)

    def still():
        return render_film(planned.scene, make_sampler("jittered", 16), seed=2)

    fresh = render_film(plan_scene(MOTION, SMALL).scene, make_sampler("jittered", 16), seed=2)
    for _ in range(3):
        same_film(still(), fresh)  # traced, recorded, replayed
    blurred = _blurred(planned)
    _unchanged(planned.scene, before)
    replayed.clear()
    same_film(_blurred(planned), blurred)
    assert replayed and all(replayed)  # every sub-frame's pass
    _unchanged(planned.scene, before)
    for _ in range(2):  # (a scene update makes Dr.Jit record a frozen render once more)
        same_film(still(), fresh)
    replayed.clear()
    same_film(still(), fresh)
    assert replayed == [True]  # the whole render
    same_film(_blurred(plan_scene(MOTION, SMALL)), blurred)


def _noting(function, noted: list[bool], replayed):
    """``function``, which also appends to ``noted`` whether its call replayed."""
    def call(*args, **kwargs):
        out = function(*args, **kwargs)
        noted.append(replayed(out))
        return out
    return call


def test_an_interrupted_or_failed_motion_blur_render_puts_the_scene_back(monkeypatch):
    """Ctrl-C or an error in the middle of the sub-frames, a cluster task's pass and a
    statistics render (a reference's) left the shapes where that sub-frame had them."""
    planned = plan_scene(MOTION, SMALL)
    before = _values(planned.scene)
    sampler = make_sampler("jittered", 16)
    passes, on_pass = planned.schedule(sampler, 16, seed=1)
    move = planned.driver.on_pass

    def stop_at_3(error: BaseException):
        def hook(index: int, count: int) -> None:
            move(index, count)
            if index == 3:
                raise error
        return hook

    monkeypatch.setattr(planned.driver, "on_pass", stop_at_3(KeyboardInterrupt()))
    with pytest.raises(Interrupted) as stopped:
        render_film(planned.scene, sampler, seed=1, passes=passes, on_pass=on_pass)
    assert stopped.value.done == 3
    _unchanged(planned.scene, before)
    monkeypatch.setattr(planned.driver, "on_pass", stop_at_3(RuntimeError("lost")))
    with pytest.raises(RuntimeError, match="lost"):
        render_stats(planned.scene, sampler, seed=1, passes=passes, on_pass=on_pass)
    _unchanged(planned.scene, before)
    monkeypatch.setattr(planned.driver, "on_pass", move)
    render_film_pass(planned.scene, sampler, 5, passes, seed=1, on_pass=on_pass)
    _unchanged(planned.scene, before)
    render_stats(planned.scene, sampler, seed=1, passes=passes, on_pass=on_pass)
    _unchanged(planned.scene, before)
