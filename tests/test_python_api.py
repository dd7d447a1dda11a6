"""The Python API takes sampler names wherever it takes sampler plugins."""

from __future__ import annotations

from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene
from tests.conftest import ROOT

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


def test_a_python_caller_resumes_a_render_as_mcrt_render_does(tmp_path, monkeypatch):
    """The recipe of mcrt.core.render_job: a render interrupted after 2 of 4
    passes, its checkpoint kept by a CheckpointStore under the render's key,
    resumed by the same call: the bits of an uninterrupted render; another seed
    (another key) does not take it."""
    import numpy as np
    import pytest

    from mcrt.core.job import Checkpointing, CheckpointStore, Interrupted
    from mcrt.core.render import render_film
    from mcrt.core.render_job import checkpoint_paths, render_key

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    scene_path = ROOT / "scenes" / "cornell_box.xml"
    scene = plan_scene(scene_path, {"res": "16"}).scene

    def key(seed: int) -> str:
        return render_key(scene_path, {"res": "16"}, {}, "sobol", 16, seed, 4)

    store = CheckpointStore(checkpoint_paths(tmp_path / "img.exr", key(3)), key(3))

    def stop_at_2(index: int, count: int) -> None:
        if index == 2:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stopped:
        render_film(scene, make_sampler("sobol", 16), seed=3, passes=4, on_pass=stop_at_2)
    assert store.save(stopped.value.state) == tmp_path / ".img.exr.mcrt-resume.npz"
    other = CheckpointStore(checkpoint_paths(tmp_path / "img.exr", key(4)), key(4))
    assert other.load() is None
    resumed = render_film(scene, make_sampler("sobol", 16), seed=3, passes=4,
                          checkpoints=Checkpointing(store.load()))
    whole = render_film(scene, make_sampler("sobol", 16), seed=3, passes=4)
    assert np.array_equal(resumed.image, whole.image)
    store.discard()
    assert not (tmp_path / ".img.exr.mcrt-resume.npz").exists()
