"""Replayed (frozen) multisample renders give the bits and the counts of unfrozen ones.

As in tests/core/test_replay.py, each case renders a scene with the same sampler
and seeds with ``MCRT_REPLAY=0`` and with replay on: the second render of a kind
with replay on is recorded, the later ones replayed (:func:`replay.recordings`).
A replay runs none of the integrator's Python code, so what it shades and how
much (``integrator.counts``) must come from the recording's device outputs;
and the number of representatives differs between seeds (edge pixels), so a
replay shades another number of them than its recording did.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core import replay
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from tests.conftest import same_film

SEEDS = (0, 1, 7)  # 0 traced (a first render), 1 recorded, 7 replayed


@pytest.fixture(autouse=True)
def _fresh():
    replay.clear()
    yield
    replay.clear()


def _cornell(rfilter: str = "box", **multisample) -> mi.Scene:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=16, height=16, rfilter={"type": rfilter})
    d["integrator"] = {"type": "multisample", "nested": {"type": "direct"}, **multisample}
    return mi.load_dict(d)


def _render(monkeypatch, scene, seed: int, on: bool, sampler: str = "jittered", spp: int = 16):
    """A film render and the integrator's counts of it alone."""
    monkeypatch.setenv(replay.ENV, "1" if on else "0")
    scene.integrator().reset_counts()
    result = render_film(scene, make_sampler(sampler, spp), seed=seed)
    return result, scene.integrator().counts


def _same_counts(a, b) -> None:
    assert (a.samples, a.evaluations, a.wavefronts, a.samples_per_pixel) == \
        (b.samples, b.evaluations, b.wavefronts, b.samples_per_pixel)
    assert a.per_pixel is not None and np.array_equal(a.per_pixel, b.per_pixel)


@pytest.mark.parametrize("group_by", ["primitive", "shape"])
@pytest.mark.parametrize("representative", ["centre", "first"])
@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_a_replayed_multisample_render_has_the_bits_and_counts_of_an_unfrozen_one(
        monkeypatch, rfilter, representative, group_by):
    scene = _cornell(rfilter, representative=representative, group_by=group_by)
    for seed in SEEDS:
        plain, plain_counts = _render(monkeypatch, scene, seed, False)
        again, again_counts = _render(monkeypatch, scene, seed, True)
        same_film(plain, again)
        _same_counts(plain_counts, again_counts)
        assert again_counts.samples == 16 * 16 * 16 and again_counts.samples_per_pixel == [16]
    # Traced once (twice where Dr.Jit's dry run of the first recording fails): the rest replayed.
    assert 1 <= replay.recordings() < len(SEEDS)


def test_a_replay_shades_another_number_of_representatives_than_its_recording(monkeypatch):
    """Seed 1 is recorded, seeds 7 and 3 replayed: their edge pixels hold other
    numbers of surfaces, so the replays shade other numbers of representatives
    (and other pixels' counts) than the recording, with the bits of unfrozen renders."""
    scene = _cornell()
    counts = {}
    for seed in (0, 1, 7, 3):
        plain, plain_counts = _render(monkeypatch, scene, seed, False, "independent", 4)
        again, again_counts = _render(monkeypatch, scene, seed, True, "independent", 4)
        same_film(plain, again)
        _same_counts(plain_counts, again_counts)
        counts[seed] = again_counts
    assert 1 <= replay.recordings() < 3  # 3 at least replayed a recording of 1 or 7
    for seed, recorded in ((7, 1), (3, 1), (3, 7)):
        assert counts[seed].evaluations != counts[recorded].evaluations
        assert not np.array_equal(counts[seed].per_pixel, counts[recorded].per_pixel)


def test_counts_queue_until_read_and_replays_add_to_them(monkeypatch):
    """Unread counts of several renders add up, unfrozen and replayed alike;
    ``reset_counts`` drops what is queued."""
    scene = _cornell()
    integrator = scene.integrator()
    single = {}
    for seed in SEEDS:
        single[seed] = _render(monkeypatch, scene, seed, True)[1].evaluations
    integrator.reset_counts()
    monkeypatch.setenv(replay.ENV, "1")
    for seed in SEEDS:  # 7 is replayed (0 and 1 were traced and recorded above)
        render_film(scene, make_sampler("jittered", 16), seed=seed)
    monkeypatch.setenv(replay.ENV, "0")
    render_film(scene, make_sampler("jittered", 16), seed=7)
    counts = integrator.counts
    assert counts.wavefronts == 4 and counts.samples == 4 * 16 * 16 * 16
    assert counts.evaluations == sum(single.values()) + single[7]
    assert counts.per_pixel is not None and counts.per_pixel.sum() == counts.evaluations
    render_film(scene, make_sampler("jittered", 16), seed=7)
    integrator.reset_counts()
    assert integrator.counts.wavefronts == 0 and integrator.counts.per_pixel is None


def test_a_replay_runs_none_of_the_integrators_python_code(monkeypatch):
    scene = _cornell()
    for seed in (0, 1):  # traced, then recorded
        _render(monkeypatch, scene, seed, True)
    calls = []
    integrator_class = type(scene.integrator())
    original = integrator_class.sample

    def counting(self, *args, **kwargs):
        calls.append(1)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(integrator_class, "sample", counting)
    _, counts = _render(monkeypatch, scene, 7, True)
    assert calls == [] and counts.wavefronts == 1 and counts.evaluations > 16 * 16
    _render(monkeypatch, scene, 7, False)
    assert calls
