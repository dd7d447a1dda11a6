"""Replayed (frozen) film renders give the bits of unfrozen ones.

Each case renders the same scene with the same sampler and seeds twice, with
``MCRT_REPLAY=0`` and with replay on, and compares the images (as float32 bit
patterns), the non-finite counts and the checkpoint sums; :func:`replay.recordings`
shows whether the replayed side was recorded (traced once, then replayed) or fell
back to rendering unfrozen, which every case names.
"""

from __future__ import annotations

import logging

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core import replay
from mcrt.core.job import Checkpointing
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from mcrt.samplers import registry
from tests.conftest import same_film, sampler_params, small_cornell

SEEDS = (0, 1, 7)


@pytest.fixture(autouse=True)
def _fresh():
    replay.clear()
    yield
    replay.clear()


def _render(monkeypatch, scene, name: str, spp: int, seed: int, on: bool, **kwargs):
    monkeypatch.setenv(replay.ENV, "1" if on else "0")
    params = {k: v for k, v in sampler_params(name, spp).items() if k != "width"}
    return render_film(scene, make_sampler(name, spp, **params), seed=seed, **kwargs)


def _compare(monkeypatch, scene, name: str, spp: int = 4, **kwargs) -> int:
    """Render every seed unfrozen and replayed; the recordings made."""
    for seed in SEEDS:
        plain = _render(monkeypatch, scene, name, spp, seed, False, **kwargs)
        again = _render(monkeypatch, scene, name, spp, seed, True, **kwargs)
        same_film(plain, again)
    return replay.recordings()


#: Samplers whose study-sized renders are replayed (recorded once, replayed for the other seeds).
REPLAYED = ("uniform_grid", "jittered", "poisson_disk", "sobol", "zsobol", "pointset",
            "independent", "stratified", "multijitter", "orthogonal", "ldsampler")


@pytest.mark.slow
@pytest.mark.parametrize("name", registry.names("mcrt") + registry.names("mitsuba"))
def test_every_sampler_replays_the_bits_of_an_unfrozen_render(monkeypatch, name):
    scene = small_cornell(16, box_filter=True)
    recorded = _compare(monkeypatch, scene, name, 16 if name == "orthogonal" else 4)
    # Traced once (twice where Dr.Jit's dry run of the first recording fails and it
    # records again, e.g. after the sampler's tables were just loaded): the rest replayed.
    assert name in REPLAYED and 1 <= recorded < len(SEEDS)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["gaussian", "aov", "passes", "xyz"])
def test_filters_aovs_and_several_passes_replay_the_same_bits(monkeypatch, case):
    scene = small_cornell(16, box_filter=case != "gaussian")
    kwargs: dict = {}
    if case == "aov":
        d = mi.cornell_box()
        d["sensor"]["film"].update(width=16, height=16, rfilter={"type": "box"})
        d["integrator"] = {"type": "aov", "aovs": "dd.y:depth,nn:sh_normal",
                           "inner": {"type": "path", "max_depth": 3}}
        scene = mi.load_dict(d)
    if case == "xyz":
        d = mi.cornell_box()
        d["sensor"]["film"].update(width=16, height=16, pixel_format="xyz")
        scene = mi.load_dict(d)
    if case == "passes":
        kwargs["max_lanes"] = 16 * 16 * 4  # 64 spp in 16 passes
    recorded = _compare(monkeypatch, scene, "sobol", 64 if case == "passes" else 4, **kwargs)
    assert 1 <= recorded < len(SEEDS)


def test_a_scene_edited_between_renders_is_rendered_as_edited(monkeypatch):
    """A parameter changed with mi.traverse between renders: the replay uses the
    new value (the same bits as tracing, and not the image before the edit)."""
    scene = small_cornell(16, box_filter=True)
    _compare(monkeypatch, scene, "jittered")
    before = _render(monkeypatch, scene, "jittered", 4, SEEDS[0], True)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    params[key] = mi.Color3f(0.9, 0.1, 0.1)
    params.update()
    _compare(monkeypatch, scene, "jittered")
    after = _render(monkeypatch, scene, "jittered", 4, SEEDS[0], True)
    assert not np.array_equal(before.image, after.image)
    assert replay.recordings() >= 1


def test_a_mesh_moved_between_renders_is_rendered_where_it_is(monkeypatch):
    """A mesh's vertices set to a new array through mi.traverse between renders
    (an animation, a parameter sweep). A replay of the old recording read the
    vertex array at its old address: every other frame came out wrong in a
    process with a cold kernel cache (a warm one often hid it). Each move now
    makes a new recording (one per frame, its other seed replayed), and every
    render has the bits of tracing."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=24, height=24, rfilter={"type": "box"})
    d["box"] = {"type": "cube", "bsdf": {"type": "diffuse"},
                "to_world": mi.ScalarTransform4f().translate([0.2, -0.5, 0]).scale(0.3)}
    scene = mi.load_dict(d)
    params = mi.traverse(scene)
    rest = np.array(params["box.vertex_positions"]).reshape(-1, 3)
    frames = 6
    for frame in range(frames):
        params["box.vertex_positions"] = mi.Float(
            (rest + [0.05 * frame, 0.0, 0.0]).astype(np.float32).ravel())
        params.update()
        for seed in (frame, frame + 10):
            same_film(_render(monkeypatch, scene, "sobol", 4, seed, False),
                      _render(monkeypatch, scene, "sobol", 4, seed, True))
    assert replay._RECORDINGS.made == frames


def test_a_recording_is_kept_only_with_the_arrays_it_was_recorded_with():
    """Recordings.get: traced the first time, recorded the second; a call after
    a scene array was set to a new one (a new vertex buffer) drops the entry and
    is traced; the entry holds its arrays, so a new array cannot take their
    variable index."""
    made = []
    recordings = replay.Recordings(4)
    d = mi.cornell_box()
    d["box"] = {"type": "cube"}
    scene = mi.load_dict(d)
    params = mi.traverse(scene)

    def get(tag: str):
        return recordings.get(("k",), lambda: made.append(tag) or (tag,), scene=scene)

    assert get("a") is None and get("a") == ("a",) and get("a") == ("a",)
    held = params["box.vertex_positions"].index
    params["box.vertex_positions"] = mi.Float(np.array(params["box.vertex_positions"]) + 0.1)
    params.update()  # the old array: only the entry holds it now
    assert params["box.vertex_positions"].index != held
    assert get("b") is None and get("b") == ("b",) and get("b") == ("b",)
    params["white.reflectance.value"] = mi.Color3f(0.5, 0.5, 0.5)  # a single value
    params.update()
    assert get("c") == ("b",)
    assert made == ["a", "b"]


def test_a_warm_up_records_so_that_every_render_after_it_replays(monkeypatch):
    """replay.warming_up(): the first render of a kind records at once (a
    study's untimed warm-up), so the first timed render replays instead of
    recording; the same bits."""
    scene = small_cornell(16, box_filter=True)
    with replay.warming_up():
        _render(monkeypatch, scene, "sobol", 4, SEEDS[0], True)
    assert replay._RECORDINGS.made == 1 and replay.recordings() >= 1
    for seed in SEEDS[1:]:
        same_film(_render(monkeypatch, scene, "sobol", 4, seed, False),
                  _render(monkeypatch, scene, "sobol", 4, seed, True))
    assert replay._RECORDINGS.made == 1
    monkeypatch.setenv(replay.ENV, "1")
    replay.clear()
    _render(monkeypatch, scene, "sobol", 4, SEEDS[0], True)  # no warm-up: traced
    assert replay._RECORDINGS.made == 0


def test_what_cannot_be_replayed_renders_unfrozen(monkeypatch, caplog):
    """Sub-frames (the scene changes between passes) and checkpoints: no
    recording of the whole render, the same bits, a debug note (checkpointed
    renders replay their passes one at a time: tests/core/test_pass_replay.py)."""
    scene = small_cornell(16, box_filter=True)
    moves: list[int] = []
    monkeypatch.setattr(logging.getLogger("mcrt"), "propagate", True)  # to caplog's handler
    with caplog.at_level("DEBUG", logger="mcrt"):
        _compare(monkeypatch, scene, "jittered", 4, on_pass=lambda i, n: moves.append(i),
                 passes=2)
        _compare(monkeypatch, scene, "jittered", 4,
                 checkpoints=Checkpointing(save=lambda checkpoint: None))
    assert replay.recordings() == 0
    assert "rendering without replay: the render has subframes" in caplog.text
    assert "the render has checkpoints" in caplog.text


def test_a_spectral_render_falls_back_or_replays_with_the_same_bits(monkeypatch):
    mi.set_variant("llvm_ad_spectral")
    import mcrt

    mcrt.register()
    scene = small_cornell(16, box_filter=True)
    _compare(monkeypatch, scene, "sobol")  # unfrozen today: a spectral table is not an input


def test_a_replay_runs_no_python_code_of_the_render(monkeypatch):
    """A replay launches the recorded kernels only: a sampler method that counts
    its calls is not called (benchmarks/replay_cost.py measures the time saved)."""
    scene = small_cornell(16, box_filter=True)
    _render(monkeypatch, scene, "sobol", 4, 0, True)  # traced (a first render is not recorded)
    _render(monkeypatch, scene, "sobol", 4, 2, True)  # recorded
    calls = []
    sampler_class = type(make_sampler("sobol", 4))
    original = sampler_class.next_2d

    def counting(self, *args, **kwargs):
        calls.append(1)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(sampler_class, "next_2d", counting)
    _render(monkeypatch, scene, "sobol", 4, 1, True)
    assert calls == []
    _render(monkeypatch, scene, "sobol", 4, 1, False)
    assert calls
    dr.sync_thread()


@pytest.mark.slow
def test_a_study_replayed_equals_the_study_traced(tmp_path, monkeypatch, capsys):
    """A small study (two samplers, two sample counts, two seeds) with replay on
    and with MCRT_REPLAY=0: results.json equal in every field but the timings,
    and every image of the report bit for bit."""
    import json

    from mcrt.io import read_exr
    from tests.conftest import CHECKERBOARD, run_cli, study_toml, untimed

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    config = tmp_path / "s.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s", params="{ width = 48, height = 32 }"))
    results = {}
    for flag in ("0", "1"):
        monkeypatch.setenv(replay.ENV, flag)
        code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", str(tmp_path / flag))
        assert code == 0, err
        assert (replay.recordings() > 0) == (flag == "1")  # the study's renders replayed
        results[flag] = untimed(json.loads((tmp_path / flag / "results.json").read_text()))
    assert results["0"] == results["1"]
    images = sorted((tmp_path / "0" / "exr").rglob("*.exr"))
    assert len(images) == 9  # the reference, and per cell (2 x 2) a mean and a seed
    for path in images:
        a = read_exr(path)[0]["rgb"]
        b = read_exr(tmp_path / "1" / path.relative_to(tmp_path / "0"))[0]["rgb"]
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), path


@pytest.mark.slow
def test_a_study_replayed_on_a_dask_worker_equals_the_study_traced_here(tmp_path, monkeypatch,
                                                                        capsys):
    """The same small study unfrozen in this process and with replay on a real
    Dask ``LocalCluster`` worker (``--cluster ADDRESS``): results.json equal but
    for timings, and the worker did replay (its recordings, read from the worker)."""
    import json

    from distributed import Client, LocalCluster

    from tests.conftest import CHECKERBOARD, run_cli, study_toml, untimed

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    config = tmp_path / "s.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s", params="{ width = 48, height = 32 }"))
    monkeypatch.setenv(replay.ENV, "0")
    code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", str(tmp_path / "here"))
    assert code == 0, err
    monkeypatch.setenv(replay.ENV, "1")  # the worker processes inherit it
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", str(tmp_path / "there"),
                               "--cluster", cluster.scheduler_address)
        assert code == 0, err
        made = client.run(replay.recordings)
    assert list(made.values()) and all(count > 0 for count in made.values()), made
    here, there = (json.loads((tmp_path / d / "results.json").read_text())
                   for d in ("here", "there"))
    assert untimed(here) == untimed(there)
