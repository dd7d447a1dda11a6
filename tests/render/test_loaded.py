"""Planned scenes kept per process (:mod:`mcrt.render.loaded`): one plan per scene
content and parameters, an edited file planned again."""

from __future__ import annotations

import sys
from collections import Counter, OrderedDict
from pathlib import Path

import pytest

from mcrt.errors import SceneError
from mcrt.render import loaded
from mcrt.render.plan import planner
from tests.conftest import CHECKERBOARD


def count_plans(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """Plans made from now on, by scene path: every module's name for
    :func:`~mcrt.render.plan.plan_scene` wrapped, the per-process cache emptied."""
    original = planner.plan_scene
    counts: Counter[str] = Counter()

    def counting(path, *args, **kwargs):
        counts[str(Path(path).resolve())] += 1
        return original(path, *args, **kwargs)

    for name, module in list(sys.modules.items()):
        if name.startswith("mcrt") and getattr(module, "plan_scene", None) is original:
            monkeypatch.setattr(module, "plan_scene", counting)
    monkeypatch.setattr(loaded, "_planned", OrderedDict())
    return counts


def test_a_scene_is_planned_once_until_its_file_changes(tmp_path, monkeypatch):
    counts = count_plans(monkeypatch)
    scene = tmp_path / "scene.xml"
    scene.write_text(CHECKERBOARD.read_text())
    params = {"width": "16", "height": "12"}
    first = loaded.planned_scene(scene, params)
    assert loaded.planned_scene(str(scene), dict(params)) is first  # by path, str or Path
    assert counts[str(scene)] == 1
    assert loaded.planned_scene(scene, {"width": "8", "height": "6"}) is not first
    assert counts[str(scene)] == 2  # other parameters: another scene
    scene.write_text(CHECKERBOARD.read_text().replace('value="4000"', 'value="2000"'))
    edited = loaded.planned_scene(scene, params)
    assert edited is not first and counts[str(scene)] == 3  # the content digest changed
    assert loaded.planned_scene(scene, params) is edited and counts[str(scene)] == 3


def test_a_scene_planned_in_another_variant_is_planned_again(monkeypatch):
    """A process that switches variants (the Python API, a worker of studies in
    two variants) gets the scene of the variant it renders in: one kept from
    another variant holds that variant's classes (an RGB scene's integrator is
    no sampling integrator of llvm_ad_mono, and a study refused it so)."""
    import mitsuba as mi

    import mcrt

    counts = count_plans(monkeypatch)
    params = {"width": "16", "height": "12"}
    rgb = loaded.planned_scene(CHECKERBOARD, params)
    try:
        mi.set_variant("llvm_ad_mono")
        mcrt.register()
        mono = loaded.planned_scene(CHECKERBOARD, params)
        assert mono is not rgb and counts[str(CHECKERBOARD.resolve())] == 2
        assert isinstance(mono.scene.integrator(), mi.SamplingIntegrator)
    finally:
        mi.set_variant("llvm_ad_rgb")
        mcrt.register()
    assert loaded.planned_scene(CHECKERBOARD, params) is rgb  # still kept for its variant


def test_a_missing_scene_gets_the_planners_error(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        loaded.planned_scene(tmp_path / "gone.xml")
