"""Replayed (frozen) adaptive wavefronts give the bits of traced ones.

Each case renders an adaptive image with ``MCRT_REPLAY=0`` (every wavefront
traced) and then, in the same process, twice with replay on (the first render
records each batch size's wavefront the second time it is traced, the second
render replays them all), and compares the images (as float32 bit patterns),
sample counts, moments, standard errors and pass records;
:func:`frozen.recordings` shows whether the replayed side was recorded or fell
back to tracing, which every case names.
"""

from __future__ import annotations

import logging
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core import replay
from mcrt.core.sampling import make_sampler
from mcrt.render.adaptive import AdaptiveSettings, frozen, render_adaptive
from mcrt.render.scene import load_scene
from tests.conftest import OUR_SAMPLERS, sampler_params
from tests.render.test_adaptive import NaNDirect

ROOT = Path(__file__).resolve().parents[2]
SETTINGS = AdaptiveSettings(threshold=0.05, max_spp=128)


@pytest.fixture(autouse=True)
def _fresh():
    frozen.clear()
    replay.clear()
    yield
    frozen.clear()
    replay.clear()


@pytest.fixture(scope="module")
def edges():
    return load_scene(ROOT / "scenes" / "edges.xml", {"width": "48", "height": "36"})


@pytest.fixture(scope="module")
def gaussian_rgba():
    """A small sphere light over a diffuse sphere and floor, an RGBA film with
    Mitsuba's default gaussian filter (a sub-pixel grid filtered across pixels)."""
    def moved(*steps):
        t = mi.ScalarTransform4f()
        for name, *args in steps:
            t = getattr(t, name)(*args)
        return t
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "light": {"type": "sphere", "radius": 0.3, "center": [1, 1, 1],
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20}}},
        "ball": {"type": "sphere", "radius": 0.5, "bsdf": {"type": "diffuse"}},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"},
                  "to_world": moved(("translate", [0, -0.5, 0]), ("rotate", [1, 0, 0], -90),
                                    ("scale", 3))},
        "sensor": {"type": "perspective",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0.5, 3],
                                                              target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 20,
                            "pixel_format": "rgba", "rfilter": {"type": "gaussian"}}}})


def _render(monkeypatch, scene, name: str, seed: int, on: bool, settings=SETTINGS, **kwargs):
    monkeypatch.setenv(replay.ENV, "1" if on else "0")
    params = {k: v for k, v in sampler_params(name, settings.min_spp).items() if k != "width"}
    sampler = make_sampler(name, settings.min_spp, **params)
    return render_adaptive(scene, sampler, settings, seed=seed, **kwargs)


def _same(a, b) -> None:
    assert a.image.shape == b.image.shape and a.channels == b.channels
    assert np.array_equal(a.image.view(np.uint32), b.image.view(np.uint32))
    assert np.array_equal(a.spp, b.spp)
    for x, y in ((a.stats.mean, b.stats.mean), (a.stats.m2, b.stats.m2),
                 (a.luminance_stderr, b.luminance_stderr)):
        assert np.array_equal(x.view(np.uint64), y.view(np.uint64))
    assert np.array_equal(a.stats.nonfinite, b.stats.nonfinite)
    assert [(p.active_pixels, p.samples, p.batch_sizes, p.nonfinite) for p in a.passes] == \
           [(p.active_pixels, p.samples, p.batch_sizes, p.nonfinite) for p in b.passes]


def _compare(monkeypatch, scene, name: str, settings=SETTINGS, **kwargs) -> int:
    """Traced, then replayed twice: the same bits; the recordings made."""
    traced = _render(monkeypatch, scene, name, 3, False, settings, **kwargs)
    assert frozen.recordings() == 0
    assert len(traced.passes) >= 3  # batch sizes repeat: something to replay
    for _ in range(2):
        _same(traced, _render(monkeypatch, scene, name, 3, True, settings, **kwargs))
    return frozen.recordings()


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_our_samplers_replay_the_bits_of_traced_wavefronts(monkeypatch, edges, name):
    """Every mcrt sampler (``sobol`` continues each pixel's sequence, the others
    draw epochs; ``poisson_disk`` and ``pointset`` read tables): recorded once per
    batch size, replayed for other counts of active pixels and the next render."""
    recorded = _compare(monkeypatch, edges, name)
    assert recorded >= 1


@pytest.mark.parametrize("name", ["independent", "stratified"])
def test_mitsubas_samplers_are_traced_and_say_why(monkeypatch, edges, caplog, name):
    with caplog.at_level(logging.DEBUG, logger="mcrt.render"):
        assert _compare(monkeypatch, edges, name) == 0
    assert f"adaptive wavefronts: Mitsuba's {name}" in caplog.text


@pytest.mark.parametrize("name", ["jittered", "sobol"])
def test_a_gaussian_filter_rgba_film_replays_the_same_bits(monkeypatch, gaussian_rgba, name):
    settings = AdaptiveSettings(threshold=0.003, max_spp=256)
    assert _compare(monkeypatch, gaussian_rgba, name, settings) >= 1


def test_several_wavefronts_per_pass_and_cell_blocks_replay_the_same_bits(monkeypatch, edges):
    """Passes split into wavefronts of 4096 lanes, and 9 x 9 sub-pixels (two
    reduction kernels per wavefront, ``CELLS_PER_KERNEL``)."""
    settings = AdaptiveSettings(threshold=0.05, max_spp=128, max_lanes=4096, subpixels=9)
    assert _compare(monkeypatch, edges, "jittered", settings) >= 1


def test_a_python_integrator_with_nan_samples_replays_the_same_bits(monkeypatch, edges):
    integrator = NaNDirect(mi.Properties())
    assert _compare(monkeypatch, edges, "sobol", integrator=integrator) >= 1


def test_on_samples_is_traced(monkeypatch, edges, caplog):
    seen: list = []
    with caplog.at_level(logging.DEBUG, logger="mcrt.render"):
        for _ in range(2):
            _render(monkeypatch, edges, "jittered", 3, True,
                    on_samples=lambda k, ids, pos, rgb: seen.append(ids.size))
    assert frozen.recordings() == 0 and seen
    assert "adaptive wavefronts: on_samples receives the samples" in caplog.text


#: A device array made outside any recording, read by the integrator below: not an
#: input of the recorded function, so Dr.Jit refuses to record it (as it does
#: Mitsuba's spectral tables in the spectral variants).
_TINT = dr.opaque(mi.Float, 0.5, 7)


class _Tinted(mi.SamplingIntegrator):
    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.inner = mi.load_dict({"type": "direct"})

    def sample(self, scene, sampler, ray, medium=None, active=True):
        spec, valid, aovs = self.inner.sample(scene, sampler, ray, medium, active)
        return spec * dr.gather(mi.Float, _TINT, mi.UInt32(3)), valid, aovs

    def to_string(self) -> str:
        return "_Tinted[]"


def test_what_fails_to_record_is_traced_with_the_same_bits(monkeypatch, edges, caplog):
    with caplog.at_level(logging.DEBUG, logger="mcrt.render"):
        assert _compare(monkeypatch, edges, "sobol", integrator=_Tinted(mi.Properties())) == 0
    assert "adaptive wavefronts of sobol: record()" in caplog.text


#: Mitsuba's ``batch`` sensor (two cameras side by side on one film) rendered adaptively
#: with a sampler whose wavefronts are replayed, then by film renders whose passes are
#: recorded; prints the recordings the adaptive renders made and whether their
#: images have the same bits.
_BATCH_SCRIPT = """
import mitsuba as mi, numpy as np
import mcrt
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from mcrt.render.adaptive import AdaptiveSettings, frozen, render_adaptive

scene = mi.cornell_box()
camera = {k: scene["sensor"][k] for k in ("to_world", "fov")}
scene["sensor"] = {"type": "batch", "left": {"type": "perspective", **camera},
                   "right": {"type": "perspective", **camera, "fov": 20.0},
                   "film": {"type": "hdrfilm", "width": 32, "height": 12,
                            "rfilter": {"type": "box"}}}
scene["integrator"] = {"type": "path", "max_depth": 3}
scene = mi.load_dict(scene)
settings = AdaptiveSettings(threshold=0.05, max_spp=128)
images = [render_adaptive(scene, "jittered", settings, seed=3).image for _ in range(2)]
for seed in range(3):
    render_film(scene, make_sampler("jittered", 16), seed=seed, passes=4)
print("recordings", frozen.recordings(), "same", np.array_equal(images[0], images[1]))
"""


def test_a_batch_sensor_is_traced_and_leaves_later_recordings_alone():
    """The batch sensor keeps a variable of its last call (its sub-sensor
    indices, from the wavefront's pixel ids). Replaying its adaptive wavefronts
    aborted the process at the first recording (``terminate called ...
    enqueue_host_func(): this function cannot be recorded!``), and a film render's
    recorded passes after an adaptive render did too: its wavefronts are now traced,
    and the sensor let go of them. A child process, as an abort ends the process."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _BATCH_SCRIPT], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "recordings 0 same True" in done.stdout
