"""Rendering leaves what the caller passes in as it was (Mitsuba's rule for its
Python plugins: inputs are copied, not mutated)."""

from __future__ import annotations

import numpy as np

from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene


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
