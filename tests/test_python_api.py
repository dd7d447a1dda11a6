"""The Python API takes sampler names wherever it takes sampler plugins."""

from __future__ import annotations

from conftest import ROOT

from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene

MOTION = ROOT / "scenes" / "effects" / "motion.xml"


def test_schedule_accepts_a_sampler_name():
    by_name = plan_scene(MOTION)
    passes, on_pass = by_name.schedule("jittered", 64, 0)
    by_object = plan_scene(MOTION)
    expected = by_object.schedule(make_sampler("jittered", 64), 64, 0)
    assert passes == expected[0] and passes is not None and passes > 1 and on_pass is not None
    assert by_name.plan.subframe_times == by_object.plan.subframe_times
    assert (by_name.plan.sampler, by_name.plan.spp) == ("jittered", 64)
    default_spp = plan_scene(MOTION)
    default_spp.schedule("independent")  # the scene's sample count
    assert default_spp.plan.spp == default_spp.scene.sensors()[0].sampler().sample_count()
