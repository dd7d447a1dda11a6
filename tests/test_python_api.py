"""The Python API takes sampler names wherever it takes sampler plugins."""

from __future__ import annotations

import numpy as np
import pytest

from mcrt.core.sampling import make_sampler
from mcrt.errors import McrtError
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


# --------------------------------------------------------------------------- a notebook's mistakes

CORNELL = ROOT / "scenes" / "cornell_box.xml"


def _one_line(error: BaseException, *words: str) -> None:
    """An error a user can act on: mcrt's, one line, naming what it is about."""
    text = str(error)
    assert isinstance(error, McrtError) and len(text.splitlines()) == 1, repr(text)
    assert all(word in text for word in words), text


def test_the_renderers_take_a_sampler_name():
    """render_film(scene, "jittered") failed with "'str' object has no attribute
    'sample_count'" (render_adaptive: 'clone'); a name now makes that sampler,
    at ``spp`` or the scene's count: the same bits as the sampler object."""
    from mcrt.core.render import render_film, render_stats
    from mcrt.render.adaptive import AdaptiveSettings, render_adaptive

    scene = plan_scene(CORNELL, {"res": "8"}).scene
    by_name = render_film(scene, "jittered", spp=4, seed=2)
    assert np.array_equal(by_name.image,
                          render_film(scene, make_sampler("jittered", 4), seed=2).image)
    own = scene.sensors()[0].sampler().sample_count()
    assert render_film(scene, "sobol", seed=2).spp == own
    stats = render_stats(scene, "jittered", spp=4, seed=2)
    assert stats.spp == 4 and stats.stats.mean.shape == (8, 8, 3)
    settings = AdaptiveSettings(max_spp=32)
    adaptive = render_adaptive(scene, "jittered", settings, seed=1)
    again = render_adaptive(scene, make_sampler("jittered", 16), settings, seed=1)
    assert adaptive.sampler == "jittered" and np.array_equal(adaptive.image, again.image)


def test_mistaken_arguments_are_one_line_errors_naming_the_argument():
    """Each of these failed deep inside (AttributeError "'str' object has no
    attribute 'sensors'", IndexError "list index out of range", a four-line
    nanobind signature of sampler.seed()) or was truncated without a word (spp
    4.5 rendered 4 samples, a reference's seed 1.5 was seed 1, max_lanes=0 was no
    limit and a negative one a pass of one sample per pixel)."""
    from mcrt.analysis.reference import get_reference
    from mcrt.core.render import render_film, render_stats
    from mcrt.render.adaptive import AdaptiveSettings, render_adaptive
    from mcrt.render.scene import load_scene
    from mcrt.samplers.points import point_sets

    planned = plan_scene(CORNELL, {"res": "8"})
    scene = planned.scene
    jittered = make_sampler("jittered", 4)
    cases = [
        (TypeError, lambda: render_film(str(CORNELL), jittered), ("scene", "load_scene")),
        (TypeError, lambda: render_film(CORNELL, jittered), ("scene", "load_scene")),
        (TypeError, lambda: render_film(planned, jittered), ("PlannedScene", ".scene")),
        (TypeError, lambda: render_film(scene, object()), ("sampler", "make_sampler")),
        (ValueError, lambda: render_film(scene, jittered, spp=4.5), ("spp", "4.5")),
        (ValueError, lambda: render_film(scene, jittered, seed=1.5), ("seed", "1.5")),
        (ValueError, lambda: render_film(scene, jittered, seed=-1), ("seed", "2^32")),
        (ValueError, lambda: render_film(scene, jittered, sensor=1), ("sensor", "1 sensor")),
        (ValueError, lambda: render_film(scene, jittered, max_lanes=0), ("max_lanes", ">= 1")),
        (ValueError, lambda: render_film(scene, jittered, max_lanes=-64), ("max_lanes", "-64")),
        (ValueError, lambda: render_stats(scene, jittered, max_lanes=0), ("max_lanes", ">= 1")),
        (McrtError, lambda: render_adaptive(scene, None, AdaptiveSettings(max_lanes=0)),
         ("max_lanes", "positive")),
        (ValueError, lambda: render_adaptive(scene, None, None, seed=2 ** 32), ("seed",)),
        (TypeError, lambda: render_adaptive(scene, None, {"max_spp": 64}),
         ("settings", "AdaptiveSettings(**settings)")),
        (TypeError, lambda: render_adaptive(str(CORNELL)), ("scene", "load_scene")),
        (ValueError, lambda: make_sampler("jittered", 4.5), ("samples per pixel", "4.5")),
        (TypeError, lambda: make_sampler(jittered, 4), ("sampler name", "sampler object")),
        (ValueError, lambda: point_sets("jittered", 4, 16.5), ("spp", "16.5")),
        (TypeError, lambda: load_scene(CORNELL, ["res=8"]), ("params", "parse_defines")),
        (ValueError, lambda: get_reference(CORNELL, {"res": "8"}, spp=16, seed=1.5),
         ("seed", "1.5")),
        (TypeError, lambda: get_reference(scene, spp=16), ("scene file path", "mi.Scene")),
        (TypeError, lambda: get_reference(CORNELL, {"res": "8"}, spp=16, sampler=jittered),
         ("sampler name",)),
    ]
    for kind, call, words in cases:
        with pytest.raises(kind) as error:
            call()
        _one_line(error.value, *words)
    # whole numbers of other types are what they say
    assert render_film(scene, jittered, spp=4.0, seed=np.int64(3)).spp == 4
    assert render_film(scene, jittered, max_lanes=None, seed=3).spp == 4  # None: no limit
    assert render_film(scene, jittered, max_lanes=64, seed=3).spp == 4
    assert point_sets("jittered", np.int64(2), np.int32(16)).shape == (2, 16, 2)



def test_a_scene_or_sampler_of_another_variant_is_named_as_such():
    """After mi.set_variant(...) without mcrt.register(), making mcrt's sampler
    said 'Plugin "jittered" not found' and loading a scene pointed to --plugin;
    switching back to a variant after registering another built the other
    variant's class; a scene of the old variant failed as "this scene uses
    PathIntegrator", a sampler of it with a nanobind signature dump."""
    import mitsuba as mi

    import mcrt
    from mcrt.core.render import render_film
    from mcrt.render.scene import load_scene

    scene = load_scene(CORNELL, {"res": "8"})
    sampler = make_sampler("jittered", 4)
    first = render_film(scene, sampler, seed=1).image
    try:
        mi.set_variant("llvm_ad_mono")
        with pytest.raises(McrtError) as error:
            make_sampler("jittered", 4)
        _one_line(error.value, "llvm_ad_rgb", "llvm_ad_mono", "mcrt.register()")
        with pytest.raises(McrtError) as error:
            load_scene(CORNELL, {"res": "8"})
        _one_line(error.value, "mcrt.register()")
        with pytest.raises(TypeError) as error:
            render_film(scene, sampler)
        _one_line(error.value, "scene", "llvm_ad_rgb", "llvm_ad_mono")
        mcrt.register()
        mono = load_scene(CORNELL, {"res": "8"})
        with pytest.raises(TypeError) as error:
            render_film(mono, sampler)
        _one_line(error.value, "sampler", "llvm_ad_rgb")
        assert render_film(mono, make_sampler("jittered", 4), seed=1).channels == ["Y"]
        mi.set_variant("llvm_ad_rgb")  # back, without mcrt.register()
        with pytest.raises(McrtError) as error:
            make_sampler("jittered", 4)
        _one_line(error.value, "llvm_ad_mono", "mcrt.register()")
    finally:
        mi.set_variant("llvm_ad_rgb")
        mcrt.register()
    # the first scene and sampler render again in their variant: the same bits
    assert np.array_equal(render_film(scene, sampler, seed=1).image, first)



def test_a_user_sampler_missing_a_method_is_refused_when_registered():
    """A McrtSampler subclass without _sample_2d registered and then failed its
    first render with an empty NotImplementedError; a plain mi.Sampler subclass
    without seed() rendered a wrong image without a word."""
    import mitsuba as mi

    import mcrt
    from mcrt.samplers import McrtSampler, kit, registry

    class OnlyOneD(McrtSampler):
        def _sample_1d(self, key, sample, active):
            return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)

    class Bare(mi.Sampler):
        pass

    for name, cls, missing in [("only_1d", OnlyOneD, "_sample_2d"),
                               ("bare", Bare, "seed, next_1d, next_2d, clone, fork")]:
        with pytest.raises(McrtError) as error:
            mcrt.register_sampler(name, sampler=cls)
        _one_line(error.value, name, missing)
        assert name not in registry.names()
    with pytest.raises(McrtError) as error:
        mcrt.register_sampler("instance", sampler=make_sampler("jittered", 4))
    _one_line(error.value, "sampler object", "sampler=JitteredSampler")


def test_a_plain_mitsuba_sampler_subclass_renders():
    """extending.md's "a mi.Sampler subclass": one without to_string() failed in
    make_sampler (str(sampler): nanobind's "get_trampoline ... lookup failed")."""
    import mitsuba as mi

    import mcrt
    from mcrt.core.render import render_film
    from mcrt.samplers import registry

    class Pcg(mi.Sampler):
        def __init__(self, props):
            super().__init__(props)
            self.rng = mi.PCG32()

        def seed(self, seed, wavefront_size=2 ** 32 - 1):
            self.rng = mi.PCG32(size=wavefront_size, initstate=seed)

        def next_1d(self, active=True):
            return self.rng.next_float32()

        def next_2d(self, active=True):
            return mi.Point2f(self.rng.next_float32(), self.rng.next_float32())

        def clone(self):
            copy = Pcg(mi.Properties())
            copy.set_sample_count(self.sample_count())
            return copy

        def fork(self):
            return self.clone()

    mcrt.register_sampler("plain_pcg", sampler=Pcg)
    try:
        scene = plan_scene(CORNELL, {"res": "8"}).scene
        one = render_film(scene, make_sampler("plain_pcg", 4), seed=1)
        two = render_film(scene, "plain_pcg", spp=4, seed=1)
        assert one.spp == 4 and np.array_equal(one.image, two.image)
        assert 0.05 < float(one.image.mean()) < 1
    finally:
        registry.unregister("plain_pcg")
