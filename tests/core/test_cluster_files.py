"""A scene's files on Dask workers that do not have the client's files.

``mcrt render --cluster`` sends each scene to the workers as a bundle of the files
it names (docs/cluster.md, "On a cluster"). These tests run real worker processes
(``local:2``) with the scene's folder moved away once the bundle is made, as on a
cluster without a shared file system.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from mcrt.cli import render_cmd  # noqa: E402
from mcrt.core.cluster import DaskExecutor  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.render.plan import plan_scene  # noqa: E402

#: Real worker processes, as every test of test_cluster.py (conftest's END_TO_END_MODULES).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"


def _jittered_sets(count: int, k: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return ((cells + rng.random((count, k * k, 2))) / k).astype(np.float32)


def test_a_scenes_point_set_file_is_the_bundles_copy_on_the_workers(tmp_path, cache):
    """A scene whose ``pointset`` sampler names a file beside it, rendered with its
    own sampler (no --sampler): the workers read the file from the scene's bundle,
    and the image is the one rendered in this process. The tasks once carried the
    sampler's parameters as the client resolved them (the file by the client's
    absolute path), so a worker without the client's files failed ("no such
    point-set file") although the bundle held the file, and one with another file
    at that path would have rendered other points."""
    folder = tmp_path / "scene"
    folder.mkdir()
    scene = folder / "pointset.xml"
    scene.write_text(CORNELL.read_text().replace(
        '<sampler type="$sampler">',
        '<sampler type="pointset"><string name="filename" value="sets.npy"/>'))
    np.save(folder / "sets.npy", _jittered_sets(64, 4))
    params = {"res": "32", "spp": "16"}
    planned = plan_scene(scene, dict(params), {})
    sampler = planned.scene.sensors()[0].sampler()
    args = argparse.Namespace(scene=str(scene), sampler=None, seed=0, multisample=False)
    tasks = render_cmd._pass_tasks(args, planned, params, {}, "pointset", sampler, 16)
    bundle = tasks.shared["scene"].bundle()
    here = render_film(planned.scene, sampler, passes=4)
    folder.rename(tmp_path / "elsewhere")  # the workers do not have the client's files
    executor = DaskExecutor.connect("local:2")
    try:
        there = render_film(planned.scene, sampler, passes=4, tasks=replace(
            tasks, shared={"scene": bundle}, executor=executor))
    finally:
        executor.close()
    assert there.passes == 4
    np.testing.assert_array_equal(here.image, there.image)
