"""``mcrt reference`` / :mod:`mcrt.analysis.reference`: pass plans, cache, resume, output.

Scenes are a copy of ``scenes/cornell_box.xml`` at 8x8 (2x2 for the many-pass
test) with short paths, so the whole file runs in a few seconds.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mcrt.analysis.pass_plan as pass_plan
import mcrt.analysis.reference as reference
from mcrt.analysis.reference import (
    PassPlan,
    get_reference,
    pass_seed,
    plan_passes,
    reference_key,
    reference_layers,
    reference_metadata,
    scene_digest,
)
from mcrt.analysis.reference_cache import cache_paths, load_state, save_state
from mcrt.cli import main
from mcrt.core.executor import InProcess
from mcrt.core.sampling import make_sampler
from mcrt.core.stats import PixelStats
from mcrt.errors import McrtError, SamplerError
from mcrt.io import read_exr, write_exr
from mcrt.render.scene import load_scene
from mcrt.samplers import ALL_SAMPLERS

REPO = Path(__file__).resolve().parents[2]
SMALL = {"res": "8", "max_depth": "3"}


@pytest.fixture
def scene(tmp_path) -> Path:
    """A private copy of the Cornell box (tests may edit it)."""
    path = tmp_path / "box.xml"
    shutil.copy(REPO / "scenes" / "cornell_box.xml", path)
    return path


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if anything is rendered."""
    def forbidden(*args, **kwargs):
        raise AssertionError("rendered although it should not have")

    monkeypatch.setattr(reference, "render_stats", forbidden)


def same_bits(a, b) -> bool:
    return all(np.array_equal(getattr(a.stats, f), getattr(b.stats, f))
               for f in ("count", "mean", "m2", "nonfinite"))


# --------------------------------------------------------------------------- pass plans


@pytest.mark.parametrize("sampler", ALL_SAMPLERS)
@pytest.mark.parametrize("spp", [1, 3, 40, 300, 1000])
def test_plan_uses_only_counts_the_sampler_keeps(sampler, spp, caplog, cache):
    if sampler == "poisson_disk" and spp > 40:
        pytest.skip("table generation; poisson_disk keeps every count up to 16384")
    plan = plan_passes(sampler, spp, pixels=64 * 64, spp_per_pass=100)
    for i in range(plan.passes):
        count = plan.spp_of(i)
        assert count <= 100 or plan.passes == 1
        assert make_sampler(sampler, count).sample_count() == count
    assert plan.spp_before(plan.passes) == plan.spp
    if plan.spp != spp:
        # Only orthogonal/ldsampler below 4 samples cannot be exact (their smallest
        # count is 4), and that is reported, never silent.
        assert sampler in ("orthogonal", "ldsampler") and spp < 4 and plan.spp == 4
        assert "cannot render exactly" in caplog.text


def test_plan_of_a_point_set_file_uses_its_set_sizes(tmp_path):
    """A point-set sampler refuses every count but its sets' sizes (it does not
    round): the plan is made of those sizes, exactly where they add up."""
    rng = np.random.default_rng(4)
    both = tmp_path / "both.npz"
    np.savez(both, a=rng.random((16, 16, 2)).astype(np.float32),
             b=rng.random((16, 4, 2)).astype(np.float32))
    plan = plan_passes("pointset", 1000, 64, params={"filename": str(both)})
    assert (plan.pass_spp, plan.spp, sum(plan.tail) % 4) == (16, 1000, 0)
    assert set(plan.tail) <= {4, 16}
    only16 = tmp_path / "only16.npy"
    np.save(only16, rng.random((16, 16, 2)).astype(np.float32))
    plan = plan_passes("pointset", 1000, 64, spp_per_pass=64, params={"filename": str(only16)})
    assert plan.pass_spp == 16 and plan.spp == 1008 and set(plan.tail) == {16}
    assert plan_passes("pointset", 8, 64, params={"filename": str(only16)}).spp == 16
    # The first pass's count taken, a refusal comes later (the tail's 232 spp).
    only256 = tmp_path / "only256.npy"
    np.save(only256, rng.random((16, 256, 2)).astype(np.float32))
    plan = plan_passes("pointset", 1000, 64, params={"filename": str(only256)})
    assert (plan.pass_spp, plan.spp, plan.passes) == (256, 1024, 4)
    with pytest.raises(SamplerError, match="jitter"):  # no count makes it good
        plan_passes("independent", 64, 64, params={"jitter": 0.5})


def test_plan_folds_full_passes_into_an_exact_tail():
    # orthogonal takes 4, 9, 25, 49, 121, ...: 300 = 6 x 49 + 6 has no exact tail,
    # 5 x 49 + 55 does (55 = 25 + 9 + 9 + 4 + 4 + 4).
    plan = plan_passes("orthogonal", 300, pixels=64, spp_per_pass=49)
    assert plan.spp == 300 and plan.full_passes == 5 and sum(plan.tail) == 55
    plan = plan_passes("jittered", 1000, pixels=64 * 64)
    assert plan.spp == 1000 and plan.pass_spp == 256 and plan.passes == 5  # + 196 + 36


def test_default_pass_size_bounds_the_wavefront():
    plan = plan_passes("independent", 4096, pixels=1920 * 1080)
    assert 1920 * 1080 * plan.pass_spp <= pass_plan.LANE_BUDGET
    assert plan_passes("independent", 4096, pixels=64).pass_spp == pass_plan.DEFAULT_PASS_SPP


def test_pass_seeds_are_distinct():
    seeds = {pass_seed(7, i) for i in range(20_000)}
    assert len(seeds) == 20_000
    assert pass_seed(0, 1) != pass_seed(1, 0)


# --------------------------------------------------------------------------- cache keys


def _key(path, params=SMALL, spp=64, sampler="independent", seed=0, per=None,
         sampler_params=None) -> str:
    plan = plan_passes(sampler, spp, pixels=64, spp_per_pass=per, params=sampler_params)
    return reference_key(path, params, sampler, seed, plan, sampler_params=sampler_params)


def test_key_depends_on_every_input(scene, tmp_path):
    base = _key(scene)
    assert _key(scene) == base
    copy = tmp_path / "elsewhere.xml"
    shutil.copy(scene, copy)
    assert _key(copy) == base  # content, not path
    others = [_key(scene, {**SMALL, "max_depth": "4"}), _key(scene, {**SMALL, "extra": "1"}),
              _key(scene, spp=65), _key(scene, sampler="stratified"), _key(scene, seed=1),
              _key(scene, per=16), _key(scene, sampler="stratified",
                                        sampler_params={"jitter": False})]
    assert _key(scene, sampler_params={}) == base  # (keys made before parameters stay)
    scene.write_text(scene.read_text().replace('value="39.3077"', 'value="40"'))
    others.append(_key(scene))
    assert len({base, *others}) == len(others) + 1


def test_key_follows_referenced_files(tmp_path):
    (tmp_path / "tex.png").write_bytes(b"one")
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"/>')
    xml = tmp_path / "s.xml"
    xml.write_text('<scene version="3.0.0"><default name="t" value="tex"/>'
                   '<include filename="part.xml"/>'
                   '<texture type="bitmap"><string name="filename" value="$t.png"/></texture>'
                   '</scene>')
    first = scene_digest(xml)
    (tmp_path / "tex.png").write_bytes(b"two")
    second = scene_digest(xml)
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"><!-- x --></scene>')
    third = scene_digest(xml)
    (tmp_path / "other.png").write_bytes(b"two")
    fourth = scene_digest(xml, {"t": "other"})  # $t resolved from the parameters
    assert len({first, second, third}) == 3
    assert fourth != third


# --------------------------------------------------------------------------- cache and resume


def test_cache_hit_renders_nothing(scene, cache, monkeypatch):
    first = get_reference(scene, SMALL, spp=64, spp_per_pass=16)
    assert not first.cached and first.passes == 4 and first.spp == 64
    finished, partial = cache_paths(first.key)
    assert finished.exists() and not partial.exists()
    monkeypatch.setattr(reference, "render_stats", None)  # any render would fail
    second = get_reference(scene, SMALL, spp=64, spp_per_pass=16)
    assert second.cached and second.key == first.key and same_bits(first, second)
    assert second.seconds == first.seconds


class _Waiting(InProcess):
    """This process's executor, each pass's result arriving ``delay`` s after the
    pass ended (as a cluster's do, after waiting for a worker)."""

    def __init__(self, delay: float) -> None:
        self.delay = delay

    def map(self, *args, **kwargs):
        for item in super().map(*args, **kwargs):
            time.sleep(self.delay)
            yield item


def test_seconds_are_the_wall_time_of_the_passes_not_their_sum(scene, cache):
    """A reference's time is the wall time the caller waited for its passes (4
    results 0.3 s apart: at least 1.2 s), never more than the call took; the
    passes' own times, added up, are reported apart. The cache keeps that time."""
    start = time.perf_counter()
    ref = get_reference(scene, SMALL, spp=64, spp_per_pass=16, executor=_Waiting(0.3))
    wall = time.perf_counter() - start
    assert 4 * 0.3 <= ref.seconds <= wall
    assert 0 < ref.pass_seconds < ref.seconds
    again = get_reference(scene, SMALL, spp=64, spp_per_pass=16)
    assert again.cached and again.seconds == ref.seconds


def test_no_cache_neither_reads_nor_writes(scene, cache):
    ref = get_reference(scene, SMALL, spp=16, cache=False)
    assert not cache.exists() or not any(cache.rglob("*.npz"))
    again = get_reference(scene, SMALL, spp=16, cache=False)
    assert not again.cached and same_bits(ref, again)


@pytest.mark.slow
def test_resume_after_interruption_is_bit_identical(scene, cache):
    uninterrupted = get_reference(scene, SMALL, spp=96, spp_per_pass=16, cache=False)
    assert uninterrupted.passes == 6

    def interrupt_after_pass_1(index, passes):
        if index == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        get_reference(scene, SMALL, spp=96, spp_per_pass=16, on_pass=interrupt_after_pass_1)
    finished, partial = cache_paths(uninterrupted.key)
    assert partial.exists() and not finished.exists()

    rendered = []
    resumed = get_reference(scene, SMALL, spp=96, spp_per_pass=16,
                            on_pass=lambda i, n: rendered.append(i))
    assert rendered == [2, 3, 4, 5]  # only the remaining passes
    assert resumed.resumed_passes == 2 and not resumed.cached
    assert same_bits(resumed, uninterrupted)
    assert resumed.stats.count.dtype == np.int64
    assert finished.exists() and not partial.exists()


def test_partial_state_is_never_taken_for_finished(scene, cache):
    def stop(index, passes):
        if index == 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        get_reference(scene, SMALL, spp=32, spp_per_pass=16, on_pass=stop)
    key = _key(scene, spp=32, per=16)
    finished, partial = cache_paths(key)
    plan = plan_passes("independent", 32, 64, 16)
    assert load_state(partial, key, plan, (8, 8), complete=True) is None
    assert load_state(partial, key, plan, (8, 8), complete=False)[1] == 1
    # Even under the finished file's name, a partial state is not returned as finished.
    shutil.copy(partial, finished)
    ref = get_reference(scene, SMALL, spp=32, spp_per_pass=16)
    assert not ref.cached and ref.samples == 64 * 32


def test_damaged_cache_file_is_ignored(scene, cache):
    key = _key(scene, spp=16)
    finished, _ = cache_paths(key)
    finished.parent.mkdir(parents=True)
    finished.write_bytes(b"not an npz file")
    ref = get_reference(scene, SMALL, spp=16)
    assert not ref.cached and ref.samples == 64 * 16
    assert get_reference(scene, SMALL, spp=16).cached  # replaced by a good file


# --------------------------------------------------------------------------- large totals


def test_counts_beyond_2_32_are_exact(tmp_path):
    # Two synthetic passes of 3e9 samples per pixel (4 pixels): 2.4e10 in total.
    n = 3_000_000_000
    rng = np.random.default_rng(5)

    def part():
        return PixelStats(count=np.full((2, 2), n, np.int64), mean=rng.random((2, 2, 3)),
                          m2=rng.random((2, 2, 3)) * n, nonfinite=np.zeros((2, 2), np.int64))

    plan = PassPlan(requested_spp=2 * n, pass_spp=n, full_passes=2)
    a, b = part(), part()
    path = tmp_path / "state.npz"
    save_state(path, "k", a, 1, 2, 1.0, complete=False)
    loaded, done, _ = load_state(path, "k", plan, (2, 2), complete=False)
    assert done == 1 and all(np.array_equal(getattr(loaded, f), getattr(a, f))
                             for f in ("count", "mean", "m2", "nonfinite"))
    total = loaded.merge(b)
    assert total.count.dtype == np.int64 and np.all(total.count == 2 * n)
    assert total.samples == 4 * 2 * n == 24_000_000_000
    ref = reference.Reference(stats=total, spp=2 * n, sampler="independent", seed=0, passes=2,
                              seconds=1.0, key="k", plan=plan)
    meta = reference_metadata(ref, "s.xml", {})
    write_exr(tmp_path / "r.exr", reference_layers(ref), meta)
    _, back = read_exr(tmp_path / "r.exr")
    assert int(back["samples"]) == 24_000_000_000 and int(back["spp"]) == 2 * n


@pytest.mark.slow
def test_many_passes_add_up_exactly(scene, cache):
    # 2x2 pixels, 128 passes of 8 samples: every pixel gets exactly 1024 samples.
    ref = get_reference(scene, {"res": "2", "max_depth": "2"}, spp=1024, spp_per_pass=8,
                        cache=False)
    assert ref.passes == 128
    assert np.all(ref.stats.count + ref.stats.nonfinite == 1024)
    assert ref.drawn_samples == 4 * 1024


# --------------------------------------------------------------------------- correctness


def test_agrees_with_an_independent_mi_render(scene, cache):
    """The reference's image mean lies within 4 combined standard errors of an
    independent ``mi.render`` (independent sampler, other seed, 4096 spp).

    Both are means of i.i.d. samples per pixel, so the difference of the image
    means (per channel) has variance ``sum_p sigma_p^2 / P^2 * (1/n_ref + 1/n_mi)``,
    estimated from the reference's per-pixel variance; for ~10^5 samples the
    difference is close to normal, and |z| < 4 fails with probability ~6e-5 per
    channel when the code is right. A reference that dropped, double-counted or
    mis-weighted samples (or a biased variance) shifts the mean or the bound.
    """
    params = {"res": "8", "max_depth": "4"}
    ref = get_reference(scene, params, spp=2048, cache=False)
    assert np.all(ref.variance >= 0) and np.all(np.isfinite(ref.standard_error))
    n_mi = 4096
    image = np.array(mi.render(load_scene(scene, {**params, "sampler": "independent"}),
                               spp=n_mi, seed=12345), dtype=np.float64)[..., :3]
    pixels = ref.mean.shape[0] * ref.mean.shape[1]
    var = ref.variance.sum(axis=(0, 1)) / pixels**2 * (1 / ref.spp + 1 / n_mi)
    z = (ref.mean.mean(axis=(0, 1)) - image.mean(axis=(0, 1))) / np.sqrt(var)
    assert np.all(np.abs(z) < 4), z
    # The standard error is the spread of the per-pixel mean: the per-pixel z
    # scores against mi.render have mean square ~ 1 (192 values; loose bound).
    zp = (ref.mean - image) / np.sqrt(ref.variance * (1 / ref.spp + 1 / n_mi))
    assert 0.5 < float(np.mean(zp**2)) < 2.0


# --------------------------------------------------------------------------- CLI


def test_cli_writes_layers_and_metadata(scene, cache, tmp_path, capsys):
    out = tmp_path / "ref.exr"
    argv = ["-q", "reference", str(scene), "--spp", "48", "--spp-per-pass", "16",
            "-D", "res=8", "-D", "max_depth=3", "--seed", "3", "-o", str(out)]
    assert main(argv) == 0
    first = capsys.readouterr().out
    assert "passes 3" in first and "samples 3072" in first
    layers, meta = read_exr(out)
    assert set(layers) == {"rgb", "variance", "stderr", "count"}
    assert layers["rgb"].shape == (8, 8, 3) and layers["count"].shape == (8, 8)
    ref = get_reference(scene, SMALL, spp=48, seed=3, spp_per_pass=16)
    assert ref.cached
    assert np.array_equal(layers["rgb"], ref.mean.astype(np.float32))
    assert np.array_equal(layers["variance"], ref.variance.astype(np.float32))
    assert np.array_equal(layers["stderr"], ref.standard_error.astype(np.float32))
    assert np.all(layers["count"] == 48)
    assert meta["samples"] == 3072 and meta["spp"] == 48 and meta["passes"] == 3
    assert meta["sampler"] == "independent" and meta["seed"] == 3
    assert meta["cache_key"] == ref.key and meta["scene"] == str(scene)
    assert meta["params"] == "res=8 max_depth=3"
    assert "render_seconds" not in meta  # no timings: equal references, equal files

    assert main(argv) == 0  # second time: from the cache
    assert "found in cache" in capsys.readouterr().out


def test_a_one_sample_reference_has_an_unknown_variance_not_zero(scene, cache, tmp_path):
    """At 1 spp no pixel has a spread to estimate: the EXR's ``stderr`` layer was
    NaN (unknown) but its ``variance`` layer 0, which reads as an exact
    reference. Both are NaN now; the mean and count are as rendered."""
    out = tmp_path / "ref.exr"
    assert main(["-q", "reference", str(scene), "--spp", "1", "-D", "res=8",
                 "-D", "max_depth=3", "-o", str(out)]) == 0
    layers, _ = read_exr(out)
    assert np.isnan(layers["stderr"]).all() and np.isnan(layers["variance"]).all()
    assert np.isfinite(layers["rgb"]).all() and (layers["count"] == 1).all()


@pytest.mark.parametrize("argv, message", [
    (["reference", "{scene}", "--sampler", "nope"], "unknown sampler 'nope'"),
    (["reference", "{missing}"], "scene file not found"),
    (["reference", "{scene}", "-D", "=1"], "-D expects key=value"),
    (["reference", "{scene}", "-D", "res=abc"], "cannot load scene"),
])
def test_cli_user_errors(argv, message, scene, tmp_path, cache, capsys, no_render):
    argv = [a.format(scene=scene, missing=tmp_path / "missing.xml") for a in argv]
    assert main(argv + ["-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_spp_zero(scene, capsys, no_render):
    with pytest.raises(SystemExit) as exit_info:
        main(["reference", str(scene), "--spp", "0"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "must be a positive integer" in err and err.count("\n") == 1


def test_api_user_errors(scene, cache, no_render):
    with pytest.raises(McrtError, match="at least 1 sample"):
        get_reference(scene, SMALL, spp=0)
    with pytest.raises(McrtError, match="unknown sampler"):
        get_reference(scene, SMALL, sampler="nope")
    with pytest.raises(McrtError, match="not found"):
        get_reference(scene.with_name("missing.xml"), SMALL)
