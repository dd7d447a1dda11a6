"""Replays with a user's own Dr.Jit sampler give the bits of tracing.

A replayed render runs the kernels recorded when the sampler was traced; the
Python values its code read then are constants in them. Each case changes such
a value between renders in one process (an attribute, a class attribute, a
module global, a class made by a factory) or
keeps state a trace changes, and compares every render with one made with
``MCRT_REPLAY=0``. Before :mod:`mcrt.core.traced_state` every case but the
first replayed the image of the first value.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import mitsuba as mi
import pytest

import mcrt
from mcrt.core import pass_replay, replay
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from mcrt.errors import SamplerError
from mcrt.samplers import McrtSampler, kit, registry
from tests.conftest import ROOT, same_film, small_cornell

#: Read by ScaledByGlobal's traced code: a user may change it between renders.
SCALE = 1.0


def _point(key, sample):
    h = kit.hash_extend(key, sample)
    return kit.unit_float(h), kit.unit_float(kit.mix32(h))


class _Base(McrtSampler):
    def _sample_1d(self, key, sample, active):
        return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)


class Scaled(_Base):
    """x * self.scale: an attribute, or a plugin parameter."""

    scale = 1.0

    def _configure(self, props):
        if "scale" in props:
            self.scale = props["scale"]

    def _parameters(self):
        return {"scale": self.scale} if self.scale != 1.0 else {}

    def _sample_2d(self, key, sample, active):
        x, y = _point(key, sample)
        return mi.Point2f(x * self.scale, y)


class Unreported(Scaled):
    """Reads a parameter its _parameters() (so fork(), clone(), workers) leaves out."""

    def _parameters(self):
        return {}


class ScaledByGlobal(_Base):
    def _sample_2d(self, key, sample, active):
        x, y = _point(key, sample)
        return mi.Point2f(x * SCALE, y)


def scaled_class(scale: float) -> type:
    """Classes with one source, differing in a closure value."""
    class Factory(_Base):
        def _sample_2d(self, key, sample, active):
            x, y = _point(key, sample)
            return mi.Point2f(x * scale, y)
    return Factory


class Counting(_Base):
    """Mixes in how many times it was traced (a counter seeding never resets)."""

    def _configure(self, props):
        self.calls = 0

    def _sample_2d(self, key, sample, active):
        self.calls += 1
        return mi.Point2f(*_point(kit.hash_extend(key, mi.UInt32(self.calls)), sample))


@pytest.fixture(autouse=True)
def _fresh():
    replay.clear()
    yield
    replay.clear()
    for name in ("t_scaled", "t_unreported", "t_global", "t_factory", "t_counting"):
        if name in registry.names():
            registry.unregister(name)


def _same_as_traced(monkeypatch, scene, make, seeds=(0, 1, 2), **kwargs) -> None:
    """Renders of ``make()`` with replay on (recorded, then replayed) against
    MCRT_REPLAY=0, seed by seed."""
    for seed in seeds:
        monkeypatch.setenv(replay.ENV, "1")
        again = render_film(scene, make(), seed=seed, **kwargs)
        monkeypatch.setenv(replay.ENV, "0")
        same_film(render_film(scene, make(), seed=seed, **kwargs), again)


def test_an_attribute_or_unreported_parameter_changed_between_renders(monkeypatch):
    mcrt.register_sampler("t_scaled", sampler=Scaled)
    mcrt.register_sampler("t_unreported", sampler=Unreported)
    scene = small_cornell(16, box_filter=True)
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_scaled", 4))
    assert replay.recordings() >= 1  # the first value recorded, and replayed

    def halved():
        sampler = make_sampler("t_scaled", 4)
        sampler.scale = 0.5
        return sampler
    _same_as_traced(monkeypatch, scene, halved)
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_scaled", 4, scale=0.25))
    with pytest.raises(SamplerError, match="_parameters"):  # unreported: a worker drops it
        make_sampler("t_unreported", 4, scale=0.25)
    monkeypatch.setattr(Scaled, "scale", 0.75)  # the class attribute
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_scaled", 4))


def test_a_module_global_the_sampler_reads_changed_between_renders(monkeypatch):
    mcrt.register_sampler("t_global", sampler=ScaledByGlobal)
    scene = small_cornell(16, box_filter=True)
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_global", 4))
    monkeypatch.setattr(sys.modules[__name__], "SCALE", 0.5)
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_global", 4))


def test_classes_of_one_source_registered_in_turn_under_one_name(monkeypatch):
    scene = small_cornell(16, box_filter=True)
    for scale in (1.0, 0.5):
        if "t_factory" in registry.names():
            registry.unregister("t_factory")
        mcrt.register_sampler("t_factory", sampler=scaled_class(scale))
        _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_factory", 4))


def test_a_sampler_a_trace_changes_replays_no_pass_of_it(monkeypatch):
    """Passes replayed one at a time (a progress bar): the recorded pass repeats
    the counter's value, where every traced pass moves it on."""
    mcrt.register_sampler("t_counting", sampler=Counting)
    scene = small_cornell(16, box_filter=True)
    _same_as_traced(monkeypatch, scene, lambda: make_sampler("t_counting", 32), seeds=(0, 1),
                    passes=8, progress=True)
    assert pass_replay.RECORDINGS.failed
    reused = {on: make_sampler("t_counting", 4) for on in (True, False)}
    for seed in range(3):  # one sampler object for every render: traced each time
        monkeypatch.setenv(replay.ENV, "1")
        again = render_film(scene, reused[True], seed=seed)
        monkeypatch.setenv(replay.ENV, "0")
        same_film(render_film(scene, reused[False], seed=seed), again)


def test_a_numpy_table_converted_while_traced_renders_unfrozen_and_does_not_abort():
    """``mi.Float(numpy_table)`` in a traced method: recording it aborted the
    process (Dr.Jit: 'enqueue_host_func(): this function cannot be recorded')."""
    script = textwrap.dedent("""
        import os, numpy as np, mitsuba as mi, drjit as dr
        import mcrt
        from mcrt.core.render import render_film
        from mcrt.core.sampling import make_sampler
        from mcrt.samplers import McrtSampler, kit
        from tests.conftest import small_cornell

        class Table(McrtSampler):
            def _configure(self, props):
                self.table = np.linspace(0, 0.5, 8).astype(np.float32)
            def _sample_1d(self, key, sample, active):
                return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)
            def _sample_2d(self, key, sample, active):
                h = kit.hash_extend(key, sample)
                o = dr.gather(mi.Float, mi.Float(self.table), key & 7)
                x = kit.unit_float(h) + o
                return mi.Point2f(x - dr.floor(x), kit.unit_float(kit.mix32(h)))

        mcrt.register_sampler("t_table", sampler=Table)
        scene = small_cornell(16, box_filter=True)
        for seed in range(3):
            os.environ["MCRT_REPLAY"] = "1"
            a = render_film(scene, make_sampler("t_table", 4), seed=seed).image
            os.environ["MCRT_REPLAY"] = "0"
            b = render_film(scene, make_sampler("t_table", 4), seed=seed).image
            assert a.tobytes() == b.tobytes(), seed
        print("same bits")
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and "same bits" in done.stdout, done.stderr[-2000:]
