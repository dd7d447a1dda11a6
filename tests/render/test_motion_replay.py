"""Motion blur's sub-frames replayed one at a time give the bits of traced ones.

The sub-frame hook writes moving meshes over their own memory. When it set the
vertex arrays to new ones instead, the replayed passes of
scenes/effects/motion.xml were right only where the new array landed at the
recording's address (every third sub-frame); now a new array would make every
sub-frame record again (:class:`mcrt.core.replay.SceneArrays`), which the
``made == 1`` checks catch. Each case renders with ``MCRT_REPLAY=0`` and with
replay on and compares float32 bit patterns.
"""

from __future__ import annotations

import logging
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core import pass_replay, replay
from mcrt.core.render import render_film, render_film_pass
from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene
from tests.conftest import ROOT, same_film

MOTION = ROOT / "scenes" / "effects" / "motion.xml"
SMALL = {"width": "40", "height": "30"}
SPP, SUBFRAMES = 64, 8
#: Recordings for the renders of one test: Dr.Jit records again when an input
#: turns from a literal (a first pass's zero sums) into an array.
MOST_RECORDINGS = 4

#: Every kind of moving shape mcrt moves: rigid analytic shapes (one of them a
#: light), a PLY mesh with vertex normals and Mitsuba's cube (no normals).
SHAPES = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <float name="shutter_open" value="0"/> <float name="shutter_close" value="1"/>
        <transform name="to_world"><lookat origin="0, 1.5, 6" target="0, 0.6, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="directional"><vector name="direction" value="-0.4, -1, -0.5"/></emitter>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="10"/></transform>
    </shape>
    {movers}
    {extra}
</scene>
"""
#: The moving shapes: (type, id, what the shape holds, to_world, motion property, value).
MOVERS = [
    ("rectangle", "card", "", '<scale value="0.4"/><translate x="-1.5" y="0.8"/>',
     "mcrt_velocity", "0.3, 0, 0"),
    ("disk", "plate", "", '<scale value="0.3"/><translate x="-0.5" y="1.2"/>',
     "mcrt_angular_velocity", "30, 0, 0"),
    ("cylinder", "can", "", '<scale value="0.2"/><translate x="0.3" y="0.2" z="0.5"/>',
     "mcrt_velocity", "0, 0.2, 0"),
    ("ply", "facets", '<string name="filename" value="{ply}"/><bsdf type="roughconductor"/>',
     '<scale value="0.4"/><translate x="1.2" y="0.6"/>', "mcrt_angular_velocity", "0, 40, 0"),
    ("cube", "box", "", '<scale value="0.3"/><translate x="0.2" y="0.9" z="-0.8"/>',
     "mcrt_angular_velocity", "0, 35, 10"),
    ("sphere", "lamp", '<emitter type="area"><rgb name="radiance" value="4, 4, 4"/></emitter>',
     '<scale value="0.15"/><translate y="1.5" z="1"/>', "mcrt_velocity", "0.2, 0, 0"),
]
#: A moving mesh that emits light: its update rebuilds the area distribution.
EMITTING_MESH = """<shape type="obj" id="panel">
        <string name="filename" value="{obj}"/>
        <transform name="to_world"><scale value="0.3"/><translate x="0.5" y="1.6" z="0.5"/>
        </transform>
        <emitter type="area"><rgb name="radiance" value="3, 3, 3"/></emitter>
        <vector name="mcrt_velocity" value="0.2, 0, 0"/>
    </shape>"""


@pytest.fixture(autouse=True)
def _fresh():
    replay.clear()
    yield
    replay.clear()


def _shapes(tmp_path: Path, emitting_mesh: bool = False) -> Path:
    extra = EMITTING_MESH.format(obj=ROOT / "scenes/foreign/meshes/quad_light.obj")
    path = tmp_path / "shapes.xml"
    movers = "".join(f'<shape type="{kind}" id="{ident}">{inner}<transform name="to_world">'
                     f'{to_world}</transform><vector name="{prop}" value="{value}"/></shape>'
                     for kind, ident, inner, to_world, prop, value in MOVERS)
    path.write_text(SHAPES.format(movers=movers, extra=extra if emitting_mesh else "").replace(
        "{ply}", str(ROOT / "scenes/multisample/meshes/facets.ply")))
    return path


def _planned(path: Path, sampler: str):
    planned = plan_scene(path, params=SMALL if path == MOTION else None)
    spl = make_sampler(sampler, SPP)
    _, hook = planned.schedule(spl, SPP, seed=3, subframes=SUBFRAMES)
    return planned.scene, spl, hook


def _render(monkeypatch, path: Path, sampler: str, on: bool, seed: int = 3):
    monkeypatch.setenv(replay.ENV, "1" if on else "0")
    scene, spl, hook = _planned(path, sampler)
    return render_film(scene, spl, seed=seed, passes=SUBFRAMES, on_pass=hook, progress=True)


@pytest.mark.parametrize("scene, sampler", [("motion", "sobol"), ("motion", "independent"),
                                            ("shapes", "jittered")])
def test_a_moving_scene_replays_its_subframes_with_the_same_bits(monkeypatch, tmp_path,
                                                                 scene, sampler):
    path = MOTION if scene == "motion" else _shapes(tmp_path)
    plain = _render(monkeypatch, path, sampler, False)
    assert pass_replay.RECORDINGS.count() == 0
    same_film(plain, _render(monkeypatch, path, sampler, True))
    assert 1 <= pass_replay.RECORDINGS.count() <= MOST_RECORDINGS
    assert pass_replay.RECORDINGS.made == 1  # one recording, replayed by the other sub-frames


def test_cluster_tasks_of_a_moving_scene_replay_with_the_same_bits(monkeypatch):
    """``render_film_pass`` (one pass of a render, a cluster task): each
    sub-frame's sums, traced against replayed (from the second task on)."""
    scene, spl, hook = _planned(MOTION, "sobol")
    sums = {}
    for on in (False, True):
        monkeypatch.setenv(replay.ENV, "1" if on else "0")
        sums[on] = [render_film_pass(scene, spl, i, SUBFRAMES, seed=3, on_pass=hook)
                    for i in range(SUBFRAMES)]
    assert pass_replay.RECORDINGS.made == 1
    for a, b in zip(sums[False], sums[True], strict=True):
        for key in a:
            assert np.array_equal(a[key], b[key]), key
    assert 1 <= pass_replay.RECORDINGS.count() <= MOST_RECORDINGS


def test_a_moving_mesh_stays_where_its_arrays_are(tmp_path):
    """The hook moves meshes' vertices and normals over their own memory."""
    scene, _, hook = _planned(_shapes(tmp_path), "jittered")
    params = mi.traverse(scene)
    keys = ["facets.vertex_positions", "facets.vertex_normals", "box.vertex_positions"]

    def where(key: str) -> int:
        return np.from_dlpack(params[key]).__array_interface__["data"][0]

    hook(0, SUBFRAMES)
    before = {key: (where(key), np.array(params[key])) for key in keys}
    hook(5, SUBFRAMES)
    for key in keys:
        assert where(key) == before[key][0], key
        assert not np.allclose(np.array(params[key]), before[key][1]), key  # it moved
    assert hook.replayable is True


def test_a_moving_emitting_mesh_is_traced_and_says_why(monkeypatch, tmp_path, caplog):
    path = _shapes(tmp_path, emitting_mesh=True)
    monkeypatch.setattr(logging.getLogger("mcrt"), "propagate", True)  # to caplog's handler
    with caplog.at_level("DEBUG", logger="mcrt"):
        same_film(_render(monkeypatch, path, "jittered", False),
                  _render(monkeypatch, path, "jittered", True))
    assert pass_replay.RECORDINGS.count() == 0
    assert "the moving mesh 'panel' emits light" in caplog.text
