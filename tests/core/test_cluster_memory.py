"""Dask workers with a memory limit, on a real ``LocalCluster`` whose nanny restarts
its worker above 95% of the limit (by resident memory: no cgroup, no ``ulimit``).

Passes are planned to fit the workers' memory (the limit less what the worker
holds), so a job whose default passes would be killed takes smaller ones and
succeeds, with the bits of the same passes run in this process; a task that still
passes the limit ends the job after Dask's 4 tries, in one line naming the limit
(it was submitted again 3 times: 16 worker restarts).
"""

from __future__ import annotations

import time
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

pytest.importorskip("distributed")

from mcrt.analysis.reference import get_reference  # noqa: E402
from mcrt.core import memory  # noqa: E402
from mcrt.core.cluster import DaskExecutor  # noqa: E402
from mcrt.core.dask_settings import SILENT, DaskSettings  # noqa: E402
from mcrt.core.worker_memory import LIMIT_NAME, MEMORY_EVENT  # noqa: E402
from mcrt.errors import McrtError  # noqa: E402
from mcrt.io import read_exr  # noqa: E402
from tests.conftest import run_cli, same_stats, scene_xml  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"


def _limited(memory_limit: str) -> DaskExecutor:
    """mcrt's executor on a one-worker ``LocalCluster`` with ``memory_limit``, set up
    as ``--cluster local:1`` sets up its own (whose limit is the machine's memory)."""
    from distributed import Client, LocalCluster

    settings = DaskSettings()
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                           memory_limit=memory_limit, dashboard_address="127.0.0.1:0",
                           silence_logs=SILENT, preload=["mcrt.core.local_workers"])
    settings.apply()
    executor = DaskExecutor(Client(cluster), cluster, "local:1", mi.variant(), 2, settings)
    executor._workers = 1
    return executor


def _memory_deaths(executor: DaskExecutor) -> int:
    """Workers the nannies restarted for memory so far."""
    return len(executor.client.get_events(MEMORY_EVENT))


def test_a_worker_counts_its_memory_limit():
    """In a worker with a 400 MiB limit, the memory available is under 95% of it
    (what the nanny allows) less what the process holds, and names the limit;
    in this process there is no such limit."""
    executor = _limited("400MiB")
    try:
        (found,) = executor.client.run(memory.available_bytes).values()
        (resident,) = executor.client.run(memory.resident_bytes).values()
        (said,) = executor.client.run(memory.describe).values()
        asked = executor.available_bytes()  # (the worker's resident memory moves a little)
    finally:
        executor.close()
    assert 0 < found <= int(0.95 * 400 * 2**20) - resident + (16 << 20), (found, resident)
    assert abs(asked - found) < 16 << 20, (asked, found)
    assert f"{LIMIT_NAME} left" in said, said
    assert LIMIT_NAME not in memory.describe()


def test_a_reference_takes_passes_that_fit_its_workers_memory_limit(caplog):
    """A 256x256 reference at 128 spp: its default pass (8.4 M lanes, ~450 MiB
    resident at its peak) passes 95% of the worker's 400 MiB limit, and the nanny
    restarted the worker (16 times, before the job failed). Its passes are planned
    to the worker's memory now (a note says so): no worker dies, and the reference
    is the bits of the same passes rendered in this process (same plan, same key)."""
    executor = _limited("400MiB")
    try:
        with caplog.at_level("INFO", logger="mcrt"):
            there = get_reference(CORNELL, {"res": "256"}, spp=128, cache=False,
                                  executor=executor)
        deaths = _memory_deaths(executor)
    finally:
        executor.close()
    assert deaths == 0
    assert there.plan is not None and there.plan.pass_spp < 128 and there.passes > 1
    assert any("fit in the memory available on the Dask workers" in r.getMessage()
               for r in caplog.records)
    here = get_reference(CORNELL, {"res": "256"}, spp=128, spp_per_pass=there.plan.pass_spp,
                         cache=False)
    assert here.key == there.key and here.passes == there.passes
    same_stats(here, there)


def test_a_reference_that_cannot_fit_its_workers_is_one_line_before_any_pass():
    """A 2048x2048 reference on a worker limited to 400 MiB: even a pass of 1 sample
    per pixel cannot fit there (it fits this process), so it is refused before any
    pass runs, in one line, and no worker dies."""
    executor = _limited("400MiB")
    try:
        with pytest.raises(McrtError) as refused:
            get_reference(CORNELL, {"res": "2048"}, spp=4, cache=False, executor=executor)
        deaths = _memory_deaths(executor)
    finally:
        executor.close()
    message = str(refused.value)
    assert deaths == 0 and "\n" not in message, message
    assert message.startswith("not enough memory for this reference: even its smallest pass "
                              "(1 sample per pixel) needs about "), message
    assert " MiB are available on a Dask worker; use a smaller image or raise the limit" \
        in message, message


def test_a_render_takes_passes_that_fit_its_workers_memory_limit(tmp_path, capsys,
                                                                 monkeypatch):
    """`mcrt render --cluster` (a scheduler whose only worker has a 450 MiB limit) of
    a 1024x1024 box-filtered film at 4 spp: in this process one pass of 4 M lanes;
    the client plans the passes the worker traces to fit the worker's memory, not
    its own: 2 passes, and the same image bits (a film's float64 sums do not
    depend on the pass size with mcrt's samplers)."""
    monkeypatch.setenv("MCRT_CHECKPOINT_SECONDS", "1e9")
    scene = tmp_path / "plane.xml"
    scene.write_text(scene_xml('<shape type="rectangle"><bsdf type="diffuse"/></shape>'
                               '<emitter type="constant"/>', size=1024))
    common = ["render", str(scene), "--spp", "4", "--sampler", "sobol"]
    code, out, err = run_cli(capsys, *common, "-o", str(tmp_path / "here.exr"))
    assert code == 0, err
    executor = _limited("450MiB")
    try:
        address = executor.client.scheduler.address
        code, out_there, err = run_cli(capsys, *common, "-o", str(tmp_path / "there.exr"),
                                       "--cluster", address)
        deaths = _memory_deaths(executor)
    finally:
        executor.close()
    assert code == 0 and deaths == 0, err
    passes = [int(text.split("passes ")[1].split()[0]) for text in (out, out_there)]
    assert passes == [1, 2], (out, out_there)
    assert "(not 4) to fit the memory available on the Dask workers" in err, err
    (a, _), (b, _) = read_exr(tmp_path / "here.exr"), read_exr(tmp_path / "there.exr")
    assert a.keys() == b.keys()
    for layer in a:
        assert np.array_equal(a[layer].view(np.uint32), b[layer].view(np.uint32)), layer


def test_a_render_that_cannot_fit_its_workers_is_one_line_before_any_pass(tmp_path, capsys):
    """`mcrt render --cluster` of a 2048x2048 film whose workers are limited to 300
    MiB: a 1-sample pass (4 M lanes) fits this process but not a worker, so it is
    refused in one line before any pass is sent, and no worker dies (the client
    checked only its own memory, and four workers died before the error)."""
    scene = tmp_path / "plane.xml"
    scene.write_text(scene_xml('<shape type="rectangle"><bsdf type="diffuse"/></shape>'
                               '<emitter type="constant"/>', size=2048))
    executor = _limited("300MiB")
    try:
        code, _, err = run_cli(capsys, "render", str(scene), "--spp", "1", "-o",
                               str(tmp_path / "there.exr"), "--cluster",
                               executor.client.scheduler.address)
        deaths = _memory_deaths(executor)
    finally:
        executor.close()
    assert code == 2 and deaths == 0, err
    (error,) = [line for line in err.splitlines() if line.startswith("mcrt: error:")]
    assert error.startswith("mcrt: error: not enough memory for a 2048x2048 render: even its "
                            "smallest pass (1 sample per pixel) needs about "), err
    assert " MiB are available on a Dask worker; " in error, err


def _hog(index: int) -> int:
    """A task that needs 1 GiB (touched, 16 MiB at a time), held for 30 s."""
    blocks = [np.ones(16 << 20, np.uint8) for _ in range(64)]
    time.sleep(30)
    return index + len(blocks)


def test_a_task_that_never_fits_its_workers_is_one_error_after_four_deaths(by_value,
                                                                            monkeypatch):
    """A task that needs more than its worker's 400 MiB limit every time: Dask
    runs it on 4 workers (each restarted by the nanny), and mcrt does not submit
    it again (it did, 3 times: 16 restarts, and the message only asked whether
    it crashed its worker or ran out of memory): one line naming the limit."""
    monkeypatch.setenv("MCRT_CLUSTER_WORKER_WAIT", "10")  # (the old code could wait 300 s)
    executor = _limited("400MiB")
    try:
        with pytest.raises(McrtError) as failed:
            list(executor.map(_hog, 1, name="hog"))
        deaths = _memory_deaths(executor)
    finally:
        executor.close()
    message = str(failed.value)
    assert deaths == 4, (deaths, message)
    assert "\n" not in message
    assert message.startswith("task 0 of job hog on the Dask cluster at local:1: Dask gave up "
                              "on it after 4 of its workers died running it, the last one "
                              "restarted by its nanny at "), message
    assert "MiB, over 95% of its 400 MiB memory limit: it needs more memory than a worker " \
           "may use; give the workers more (dask worker --memory-limit, fewer workers per " \
           "machine) or make it smaller" in message, message
