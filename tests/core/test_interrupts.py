"""Nothing lost: Ctrl-C keeps partial work and resumes; outputs are deterministic."""

from __future__ import annotations

from pathlib import Path

import drjit as dr
import numpy as np
import pytest

import mcrt.cli.reference_cmd as reference_cmd
import mcrt.cli.render_cmd as render_cmd
from mcrt.analysis.reference import get_reference
from mcrt.core import atomic
from mcrt.core.job import Checkpointing, Interrupted
from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.io import read_exr
from tests.conftest import run_cli, small_cornell

CORNELL = str(Path(__file__).resolve().parents[2] / "scenes" / "cornell_box.xml")
#: 16x16 pixels, 16 spp in 4 passes of 4 (a small lane budget forces passes).
SMALL = ["-D", "res=16", "--spp", "16"]


def interrupt_at(k: int):
    """An on_pass hook that presses Ctrl-C before pass ``k`` is traced."""
    def hook(index: int, count: int) -> None:
        if index == k:
            raise KeyboardInterrupt
    return hook


@pytest.mark.parametrize("name", ["jittered", "poisson_disk"])
def test_interrupted_render_resumes_bit_identically(name):
    """mcrt's counter-based samplers continue their exact sequences, and the film
    sums are deterministic: interrupt after 2 of 4 passes, resume, and the image is
    the uninterrupted one bit for bit."""
    scene = small_cornell(16, box_filter=False)  # Gaussian filter: the hard case
    whole = render_film(scene, make_sampler(name, 16), seed=5, passes=4)
    with pytest.raises(Interrupted) as stop:
        render_film(scene, make_sampler(name, 16), seed=5, passes=4, on_pass=interrupt_at(2))
    partial, state = stop.value.partial, stop.value.state
    assert partial.spp == 8 and partial.passes == 2 and state.meta["done"] == 2
    assert np.isfinite(partial.image).all()
    resumed = render_film(scene, make_sampler(name, 16), seed=5, passes=4,
                          checkpoints=Checkpointing(state))
    assert resumed.spp == 16 and resumed.passes == 4
    assert resumed.image.tobytes() == whole.image.tobytes()


def whole_and_resumed(scene, name: str):
    """``scene`` rendered at 16 spp in 4 passes (seed 5) without interruption, and
    interrupted after 2 passes then resumed."""
    whole = render_film(scene, make_sampler(name, 16), seed=5, passes=4)
    with pytest.raises(Interrupted) as stop:
        render_film(scene, make_sampler(name, 16), seed=5, passes=4, on_pass=interrupt_at(2))
    resumed = render_film(scene, make_sampler(name, 16), seed=5, passes=4,
                          checkpoints=Checkpointing(stop.value.state))
    return whole, resumed


def test_mitsuba_independent_resumes_bit_identically():
    """Mitsuba's ``independent`` is seeded afresh from (seed, pass) by every pass,
    so the resumed passes are the uninterrupted ones, bit for bit."""
    whole, resumed = whole_and_resumed(small_cornell(16, box_filter=True), "independent")
    assert resumed.image.tobytes() == whole.image.tobytes()


def test_mitsuba_stratified_sampler_resumes_with_fresh_samples():
    """Mitsuba's stratified samplers keep their random state in C++: a resumed
    render continues with a derived seed, so the resumed passes differ from the
    interrupted ones (no repeated samples) and the result is a valid render."""
    scene = small_cornell(16, box_filter=True)
    whole, resumed = whole_and_resumed(scene, "multijitter")
    assert not np.array_equal(resumed.image, whole.image)
    # Same expectation: the image means agree within the Monte Carlo noise. The
    # standard error of an image mean comes from independent samples' per-pixel
    # variances (stratification only lowers it); their difference has sqrt(2)
    # times that, and 5 of those fail a correct render with p < 1e-6.
    var = render_stats(scene, make_sampler("independent", 16), seed=9).stats.variance_of_mean
    se = float(np.sqrt(var.mean(axis=-1).sum())) / var[..., 0].size
    assert abs(resumed.rgb.mean() - whole.rgb.mean()) < 5 * np.sqrt(2) * se


def test_interrupt_before_the_first_pass_keeps_nothing():
    scene = small_cornell(16)
    with pytest.raises(Interrupted) as stop:
        render_film(scene, make_sampler("jittered", 16), passes=4, on_pass=interrupt_at(0))
    assert stop.value.partial is None and stop.value.state.meta["done"] == 0



def with_interrupt(monkeypatch, k: int | None) -> list[int]:
    """Make the CLI's render_film press Ctrl-C before pass k (never for None);
    returns the list of passes traced (for checking what a resumed run renders)."""
    traced: list[int] = []
    real = render_cmd.render_film

    def patched(*args, on_pass=None, **kwargs):
        def hook(index, count):
            if index == k:
                raise KeyboardInterrupt
            traced.append(index)
            if on_pass is not None:
                on_pass(index, count)
        return real(*args, on_pass=hook, **kwargs)

    monkeypatch.setattr(render_cmd, "render_film", patched)
    return traced


def record_passes(monkeypatch) -> list[int]:
    """The passes the CLI's render_film traces, without interrupting."""
    return with_interrupt(monkeypatch, None)


@pytest.fixture
def four_passes(monkeypatch):
    """A lane budget that splits the CLI's 16x16, 16 spp render into 4 passes."""
    import mcrt.core.engine as engine

    monkeypatch.setattr(engine, "MAX_LANES_PER_PASS", 16 * 16 * 4)


def test_cli_ctrl_c_writes_partial_and_the_next_run_resumes(tmp_path, capsys, monkeypatch,
                                                             four_passes):
    out = tmp_path / "img"
    code, _, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(out))
    assert code == 0
    whole = (out.with_suffix(".exr")).read_bytes()

    other = tmp_path / "other"
    real_render_film = render_cmd.render_film
    with_interrupt(monkeypatch, 2)
    code, stdout, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(other))
    assert code == 130
    assert "interrupted after 2 of 4 passes" in stdout and "resume" in stdout
    layers, meta = read_exr(other.with_suffix(".exr"))
    assert meta["partial"] == 1 and meta["spp"] == 8 and meta["spp_target"] == 16
    assert np.isfinite(layers["rgb"]).all()
    assert (tmp_path / ".other.exr.mcrt-resume.npz").exists()

    monkeypatch.setattr(render_cmd, "render_film", real_render_film)
    traced = record_passes(monkeypatch)
    code, _, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(other))
    assert code == 0 and traced == [2, 3]  # only the missing passes were rendered
    assert other.with_suffix(".exr").read_bytes() == whole  # bit-identical EXR
    assert not (tmp_path / ".other.exr.mcrt-resume.npz").exists()


def test_cli_keeps_the_finished_render_when_writing_fails(tmp_path, capsys, monkeypatch,
                                                          four_passes):
    out = tmp_path / "img"
    real_write = render_cmd.write_exr

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(render_cmd, "write_exr", full_disk)
    code, _, stderr = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(out))
    assert code == 2 and len(stderr.strip().splitlines()) == 1
    assert "No space left on device" in stderr and "kept in" in stderr
    monkeypatch.setattr(render_cmd, "write_exr", real_write)
    traced = record_passes(monkeypatch)
    code, _, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(out))
    assert code == 0 and traced == []  # written without rendering again
    assert np.isfinite(read_exr(out.with_suffix(".exr"))[0]["rgb"]).all()


def test_same_command_same_exr_bytes_across_runs_and_thread_counts(tmp_path, capsys):
    """Bit-identical EXR files: the film sums are formed in a fixed order (no
    atomics) and the EXR carries no timings."""
    files = []
    for i, threads in enumerate((2, 1, 2)):
        dr.set_thread_count(threads)
        try:
            out = tmp_path / f"run{i}"
            assert run_cli(capsys, "-q", "render", CORNELL, "-D", "res=24", "--spp", "9",
                           "--sampler", "poisson_disk", "-o", str(out))[0] == 0
        finally:
            dr.set_thread_count(2)
        files.append(out.with_suffix(".exr").read_bytes())
    assert files[0] == files[1] == files[2]


def test_full_disk_is_refused_before_rendering(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(atomic, "free_bytes", lambda path: 1000)
    traced = record_passes(monkeypatch)
    code, _, stderr = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-o", str(tmp_path / "x"))
    assert code == 2 and "not enough free space" in stderr and traced == []


def test_reference_interrupt_writes_a_partial_exr_and_resumes(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    args = dict(params={"res": "8"}, spp=64, spp_per_pass=16)

    def stop_after_two(index, passes):
        if index == 1:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stop:
        get_reference(CORNELL, on_pass=stop_after_two, **args)
    assert stop.value.done == 2 and stop.value.partial.stats.count.max() == 32

    real = reference_cmd.get_reference
    monkeypatch.setattr(reference_cmd, "get_reference",
                        lambda *a, **k: (_ for _ in ()).throw(stop.value))
    out = tmp_path / "ref.exr"
    code, stdout, _ = run_cli(capsys, "-q", "reference", CORNELL, "-D", "res=8", "--spp", "64",
                              "--spp-per-pass", "16", "-o", str(out))
    assert code == 130 and "interrupted after 2 of 4 passes" in stdout
    layers, meta = read_exr(out)
    assert meta["partial"] == 1 and meta["spp"] == 32 and (layers["count"] == 32).all()
    monkeypatch.setattr(reference_cmd, "get_reference", real)
    resumed = get_reference(CORNELL, **args)
    assert resumed.resumed_passes == 2 and resumed.stats.count.min() == 64


def test_adaptive_render_resumes_to_the_uninterrupted_result():
    """Adaptive passes are a pure function of (seed, pass, pixel) and its sums are
    formed in a fixed order: interrupt after the second pass, resume, and the
    image and sample counts equal an uninterrupted render's, bit for bit."""
    from mcrt.render.adaptive import AdaptiveSettings, render_adaptive

    scene = small_cornell(24, box_filter=True)
    settings = AdaptiveSettings(threshold=0.1, min_spp=16, max_spp=256)
    whole = render_adaptive(scene, make_sampler("jittered", 16), settings, seed=3)
    again = render_adaptive(scene, make_sampler("jittered", 16), settings, seed=3)
    assert whole.image.tobytes() == again.image.tobytes()  # deterministic
    assert len(whole.passes) >= 3

    def stop_after_second_pass(record):
        if record.index == 1:
            raise KeyboardInterrupt  # pass 1 is committed before on_pass runs: kept

    with pytest.raises(Interrupted) as stop:
        render_adaptive(scene, make_sampler("jittered", 16), settings, seed=3,
                        on_pass=stop_after_second_pass)
    state = stop.value.state
    assert state.meta["next_pass"] == 2 and len(stop.value.partial.passes) == 2
    assert np.isfinite(stop.value.partial.image).all()
    resumed = render_adaptive(scene, make_sampler("jittered", 16), settings, seed=3,
                              checkpoints=Checkpointing(state))
    assert resumed.image.tobytes() == whole.image.tobytes()
    assert np.array_equal(resumed.spp, whole.spp)
    assert [r.samples for r in resumed.passes] == [r.samples for r in whole.passes]


def test_an_interrupt_while_dr_jit_traces_is_an_interrupt():
    """A signal that arrives while Dr.Jit traces a loop body reaches Python as a
    RuntimeError ('dr.while_loop(): encountered an exception') caused by the
    KeyboardInterrupt: a SIGTERM at that moment ended `mcrt render` in a
    traceback, not with its finished passes kept (tests/core/test_kill_and_resume.py
    hit it now and then). The block raises it as the interrupt it was; any other
    RuntimeError passes through."""
    import mitsuba as mi

    from mcrt.core.engine import termination_as_interrupt

    def interrupted(i):
        raise KeyboardInterrupt

    def broken(i):
        raise ValueError("a bug")

    with pytest.raises(KeyboardInterrupt), termination_as_interrupt():
        dr.while_loop((mi.UInt32(0),), lambda i: i < 3, interrupted)
    with pytest.raises(RuntimeError, match="encountered an exception"), \
            termination_as_interrupt():
        dr.while_loop((mi.UInt32(0),), lambda i: i < 3, broken)


def test_an_interrupted_adaptive_renders_seconds_are_those_of_the_passes_kept():
    """Ctrl-C 1 s into pass 2 drops that pass whole: the checkpoint's seconds (what
    a resumed render's time, and so its samples per second, builds on) cover
    passes 0 and 1 only, not the second spent on the pass dropped."""
    import time

    from mcrt.render.adaptive import AdaptiveSettings, render_adaptive

    scene = small_cornell(16, box_filter=True)
    settings = AdaptiveSettings(threshold=0.01, min_spp=16, max_spp=256)

    def slow_ctrl_c_in_pass_2(k, *wavefront):
        if k == 2:
            time.sleep(1.0)
            raise KeyboardInterrupt

    start = time.perf_counter()
    with pytest.raises(Interrupted) as stop:
        render_adaptive(scene, make_sampler("jittered", 16), settings, seed=3,
                        on_samples=slow_ctrl_c_in_pass_2)
    took = time.perf_counter() - start
    meta = stop.value.state.meta
    assert meta["next_pass"] == 2 and took >= 1.0
    kept = sum(record["seconds"] for record in meta["records"])
    assert kept <= meta["seconds"] < took - 1.0
