"""A render that ``$MCRT_CLUSTER`` names a cluster for, but whose passes cannot
run there, decides before any work: one note that it renders in this process,
and no cluster is started (a Dask cluster it never uses would cost seconds and
say it is there)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import CHECKERBOARD

pytest.importorskip("distributed")


def test_mcrt_cluster_with_a_stateful_sampler_starts_no_cluster(tmp_path, cache):
    out = tmp_path / "img"
    process = subprocess.run(
        [sys.executable, "-m", "mcrt", "render", str(CHECKERBOARD), "-D", "width=16",
         "-D", "height=16", "--spp", "4", "--sampler", "stratified", "-o", str(out)],
        capture_output=True, text=True, timeout=300,
        env={**os.environ, "MCRT_CLUSTER": "local:2"})
    assert process.returncode == 0 and out.with_suffix(".exr").exists(), process.stderr
    notes = process.stderr.splitlines()
    assert sum("rendering in this process, not on $MCRT_CLUSTER" in n for n in notes) == 1
    assert not [n for n in notes if "Dask" in n or "cluster:" in n], process.stderr
