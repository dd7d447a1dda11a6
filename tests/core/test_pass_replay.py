"""Passes replayed one at a time give the bits of traced passes.

Renders that a whole-render replay refuses (a progress bar over several passes,
checkpoints, a resumed render, a cluster task's one pass) replay their passes
one at a time (:mod:`mcrt.core.pass_replay`). Each case renders the same thing
with ``MCRT_REPLAY=0`` and with replay on and compares the images (float32 bit
patterns), the non-finite counts and the sums; :attr:`pass_replay.RECORDINGS`
shows that the replayed side did record (and so replayed the other passes).
"""

from __future__ import annotations

import logging

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core import pass_replay, replay
from mcrt.core.job import Checkpointing
from mcrt.core.render import render_film, render_film_pass
from mcrt.core.sampling import make_sampler
from mcrt.samplers import registry
from tests.conftest import same_film, sampler_params, small_cornell

SEEDS = (0, 5)
RES = 16
PASSES = 8
#: Recordings of a render's pass for 2 renders of 8 passes: Dr.Jit records again
#: when an input turns from a literal (the zero sums of a first pass) into an
#: array, or where its dry run of a new recording fails; 16 passes are still
#: mostly replayed.
MOST_RECORDINGS = 4


@pytest.fixture(autouse=True)
def _fresh():
    replay.clear()  # (every kind of recording)
    yield
    replay.clear()


def _sampler(name: str, spp: int):
    params = {k: v for k, v in sampler_params(name, spp).items() if k != "width"}
    return make_sampler(name, spp, **params)


def _render(monkeypatch, scene, name: str, seed: int, on: bool, spp: int = 8 * PASSES,
            **kwargs):
    monkeypatch.setenv(replay.ENV, "1" if on else "0")
    return render_film(scene, _sampler(name, spp), seed=seed, passes=PASSES, **kwargs)


#: mcrt's samplers and Mitsuba's independent (seeded afresh by each pass).
REPLAYED = [*registry.names("mcrt"), "independent"]


@pytest.mark.parametrize("name", REPLAYED)
def test_a_render_with_a_progress_bar_replays_its_passes_with_the_same_bits(monkeypatch,
                                                                           name):
    """A progress bar over 8 passes: no whole-render replay, each pass replayed
    but the first (recorded), for two seeds: one recording serves both."""
    scene = small_cornell(RES, box_filter=True)
    for seed in SEEDS:
        same_film(_render(monkeypatch, scene, name, seed, False, progress=True),
              _render(monkeypatch, scene, name, seed, True, progress=True))
    assert replay.recordings() == 0
    assert 1 <= pass_replay.RECORDINGS.count() <= MOST_RECORDINGS


@pytest.mark.parametrize("case", ["gaussian", "aov"])
def test_filters_and_aovs_replay_their_passes_with_the_same_bits(monkeypatch, case):
    scene = small_cornell(RES, box_filter=False)
    if case == "aov":
        d = mi.cornell_box()
        d["sensor"]["film"].update(width=RES, height=RES, rfilter={"type": "box"})
        d["integrator"] = {"type": "aov", "aovs": "dd.y:depth,nn:sh_normal",
                           "inner": {"type": "path", "max_depth": 3}}
        scene = mi.load_dict(d)
    for seed in SEEDS:
        same_film(_render(monkeypatch, scene, "sobol", seed, False, progress=True),
              _render(monkeypatch, scene, "sobol", seed, True, progress=True))
    assert pass_replay.RECORDINGS.count() >= 1


def test_checkpoints_and_a_resumed_render_replay_with_the_same_bits(monkeypatch):
    """Checkpoints after every pass, and a render resumed from the one saved
    after pass 3: the checkpoints and the finished images equal the traced ones."""
    scene = small_cornell(RES, box_filter=True)
    saved: dict[bool, list] = {False: [], True: []}
    results = {}
    for on in (False, True):
        results[on] = _render(monkeypatch, scene, "jittered", 3, on,
                              checkpoints=Checkpointing(save=saved[on].append, every=0))
    same_film(results[False], results[True])
    assert len(saved[True]) == len(saved[False]) == PASSES - 1
    for a, b in zip(saved[False], saved[True], strict=True):
        assert {**a.meta, "seconds": 0} == {**b.meta, "seconds": 0}
        for key, array in a.arrays.items():
            assert np.array_equal(array, b.arrays[key]), key
    middle = saved[False][2]  # after 3 passes
    assert middle.meta["done"] == 3
    resumed = _render(monkeypatch, scene, "jittered", 3, True,
                      checkpoints=Checkpointing(resume=middle))
    same_film(results[False], resumed)
    assert pass_replay.RECORDINGS.count() >= 1


@pytest.mark.parametrize("name", ["sobol", "independent"])
def test_a_cluster_task_replays_its_pass_with_the_same_sums(monkeypatch, name):
    """The passes of a distributed render rendered one by one as tasks are
    (traced, then recorded, then replayed): the same sums as traced."""
    scene = small_cornell(RES, box_filter=True)
    sums: dict[bool, list] = {}
    for on in (False, True):
        monkeypatch.setenv(replay.ENV, "1" if on else "0")
        sums[on] = [render_film_pass(scene, _sampler(name, 8 * PASSES), index, PASSES, seed=2)
                    for index in range(PASSES)]
    for a, b in zip(sums[False], sums[True], strict=True):
        assert a.keys() == b.keys()
        for key in a:
            assert np.array_equal(a[key], b[key]), key
    assert 1 <= pass_replay.RECORDINGS.count() <= MOST_RECORDINGS


def test_what_cannot_replay_its_passes_is_traced_and_says_why(monkeypatch, caplog):
    """Mitsuba's stratified samplers carry random state from pass to pass,
    motion blur's sub-frames change the scene between passes, and a large
    film's sums cost more to copy than a pass to trace: traced, the same bits,
    a debug note."""
    scene = small_cornell(RES, box_filter=True)
    monkeypatch.setattr(logging.getLogger("mcrt"), "propagate", True)  # to caplog's handler
    with caplog.at_level("DEBUG", logger="mcrt"):
        same_film(_render(monkeypatch, scene, "stratified", 1, False,
                      progress=True),
              _render(monkeypatch, scene, "stratified", 1, True,
                      progress=True))
        same_film(_render(monkeypatch, scene, "sobol", 1, False, on_pass=lambda i, n: None),
              _render(monkeypatch, scene, "sobol", 1, True, on_pass=lambda i, n: None))
        monkeypatch.setattr(pass_replay, "MAX_SUMS", RES * RES * 4 - 1)  # this film's, less 1
        same_film(_render(monkeypatch, scene, "sobol", 1, False, progress=True),
              _render(monkeypatch, scene, "sobol", 1, True, progress=True))
    assert pass_replay.RECORDINGS.count() == 0
    assert "passes: Mitsuba's stratified keeps random state per lane" in caplog.text
    assert f"passes: a film of more than {RES * RES * 4 - 1} sums" in caplog.text
    assert "passes: the scene moves between passes" in caplog.text


def test_a_recording_that_fails_after_adding_its_pass_leaves_the_sums_alone(monkeypatch,
                                                                            caplog):
    """A recording that fails once the pass was traced and folded in: the pass
    is traced again (said once), and the render still has each pass once."""
    real = pass_replay._body

    def failing(*args):
        out = real(*args)
        dr.eval(out)  # the pass is added (into the body's copy of the sums)
        raise RuntimeError("cannot record this")

    scene = small_cornell(RES, box_filter=True)
    plain = _render(monkeypatch, scene, "sobol", 4, False, progress=True)
    monkeypatch.setattr(pass_replay, "_body", failing)
    monkeypatch.setattr(logging.getLogger("mcrt"), "propagate", True)  # to caplog's handler
    with caplog.at_level("DEBUG", logger="mcrt"):
        same_film(plain, _render(monkeypatch, scene, "sobol", 4, True, progress=True))
    assert "passes of sobol: cannot record this" in caplog.text
