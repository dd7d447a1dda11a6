"""Faults on a real Dask cluster: workers killed (all at once, one after another)
while the scheduler lives change nothing; a scheduler or every worker gone for
good is one line.

The kills are SIGKILLs of real worker processes (``local:2``: a ``LocalCluster``
whose nannies start new ones), triggered by the job's own progress (a task's
result arrived, a pass was folded), so they land in the middle of the work.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from mcrt.analysis.reference import get_reference  # noqa: E402
from mcrt.analysis.study import load_config, run_study  # noqa: E402
from mcrt.core.cluster import DaskExecutor  # noqa: E402
from mcrt.errors import McrtError  # noqa: E402
from tests.conftest import same_stats, study_toml, untimed  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
PARAMS = {"res": "24"}
DASK = Path(sys.executable).parent / "dask"

def _worker_pids(executor: DaskExecutor) -> list[int]:
    """The process ids of the workers the scheduler knows now (one that just
    died may still be listed: it answers with an error, left out)."""
    pids = executor.client.run(os.getpid, on_error="return")
    return sorted(pid for pid in pids.values() if isinstance(pid, int))


def _kill(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):  # already gone
            os.kill(pid, signal.SIGKILL)


def _tiny_study(tmp_path: Path) -> Path:
    """Two jobs (4 and 16 spp) of 2 samplers x 2 rounds (2 seeds) each."""
    path = tmp_path / "tiny.toml"
    path.write_text(study_toml(CORNELL, name="tiny", params="{ res = 32 }",
                               extra="time_rounds = 2\nimage_spp = 16\n"))
    return path


def test_a_study_survives_all_its_workers_killed_at_once_twice(tmp_path, cache):
    """Both workers of `local:2` are SIGKILLed together as soon as the first
    result of each of the study's two jobs has arrived: the scene and the
    reference the tasks share were on those workers only. The nannies start new
    workers, Dask makes the shared inputs again and runs the lost tasks again:
    every cell equals the study run in this process (the reference comes from
    the cache both times)."""
    config = load_config(_tiny_study(tmp_path))
    here = run_study(config)
    executor = DaskExecutor.connect("local:2")
    kills: list[list[int]] = []
    stop = threading.Event()

    def kill_all_after_first_results() -> None:
        for job in ("/4spp", "/16spp"):
            while not stop.is_set():
                states = list(executor.client.futures.items())
                if any(job in str(key) and state.status == "finished"
                       for key, state in states):
                    pids = _worker_pids(executor)
                    _kill(pids)
                    kills.append(pids)
                    break
                time.sleep(0.002)

    killer = threading.Thread(target=kill_all_after_first_results, daemon=True)
    try:
        killer.start()
        there = run_study(config, executor=executor)
    finally:
        stop.set()
        killer.join(timeout=10)
        executor.close()
    assert len(kills) == 2 and all(len(pids) == 2 for pids in kills), kills
    assert untimed([dict(c) for c in there.cells]) == untimed([dict(c) for c in here.cells])


def test_a_reference_survives_workers_killed_one_after_another(cache):
    """One worker SIGKILLed after each of the first six folded passes (the
    replacements too, as soon as they are up): Dask runs the lost passes
    again, mcrt submits again a pass Dask gave up on (its workers kept dying),
    and the reference's moments are the bits of the passes run here."""
    here = get_reference(CORNELL, PARAMS, spp=128, spp_per_pass=8, cache=False)
    executor = DaskExecutor.connect("local:2")
    killed: list[int] = []

    def kill_one(index: int, passes: int) -> None:
        if index >= 6:
            return
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # a live worker to kill (replacements start)
            pids = [pid for pid in _worker_pids(executor) if pid not in killed]
            if pids:
                _kill([pids[0]])
                killed.append(pids[0])
                return
            time.sleep(0.02)

    try:
        there = get_reference(CORNELL, PARAMS, spp=128, spp_per_pass=8, cache=False,
                              executor=executor, on_pass=kill_one)
    finally:
        executor.close()
    assert len(killed) == 6, killed
    assert there.passes == here.passes == 16
    same_stats(here, there)


def _dies_first(folder: str, deaths: int, index: int) -> int:
    """A task that SIGKILLs its own worker the first ``deaths`` times task 0 runs
    (counted in files under ``folder``), and else returns ``10 * index``."""
    if index == 0:
        runs = Path(folder)
        count = len(list(runs.iterdir()))
        if count < deaths:
            (runs / str(count)).touch()
            os.kill(os.getpid(), signal.SIGKILL)
    return 10 * index


def test_a_task_whose_workers_keep_dying_is_submitted_again(tmp_path, caplog, by_value):
    """Task 0 kills the worker running it 5 times: Dask gives up on it after 4
    (``KilledWorker``: its allowed failures are 3); mcrt submits it again, with a
    note, and the 6th run returns. The other tasks' results are unaffected."""
    import functools

    executor = DaskExecutor.connect("local:2")
    try:
        with caplog.at_level("INFO", logger="mcrt"):
            results = dict(executor.map(functools.partial(_dies_first, str(tmp_path), 5), 4,
                                        name="dying"))
    finally:
        executor.close()
    assert results == {0: 0, 1: 10, 2: 20, 3: 30}
    assert len(list(tmp_path.iterdir())) == 5
    assert any("task 0 of job dying: Dask gave up on it after 4 of its workers died running "
               "it; submitting it again (1 of 3)" in r.getMessage() for r in caplog.records)


class _KillsItsLoader:
    """A shared input whose loading in a worker process SIGKILLs that worker the
    first ``deaths`` times (counted in files under ``folder``); it loads as 7
    there, and as itself in this process (where the scheduler loads it too)."""

    def __init__(self, folder: str, deaths: int, home: int) -> None:
        self.folder, self.deaths, self.home = folder, deaths, home

    def __reduce__(self):
        return _load_or_die, (self.folder, self.deaths, self.home)


def _load_or_die(folder: str, deaths: int, home: int) -> int | _KillsItsLoader:
    if os.getpid() == home:
        return _KillsItsLoader(folder, deaths, home)
    runs = Path(folder)
    count = len(list(runs.iterdir()))
    if count < deaths:
        (runs / str(count)).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return 7


def _plus_shared(index: int, shared: int) -> int:
    return 10 * index + shared


def test_a_shared_input_whose_workers_keep_dying_is_sent_again(tmp_path, caplog, by_value):
    """The shared input's task kills the worker loading it 4 times: Dask gives up
    on it (``KilledWorker``), and on every task that needs it. mcrt submits the
    tasks again with the input sent anew (it reused the failed input, so every
    task failed again at once, 4 times, and the job ended: seen once in CI in
    test_a_reference_survives_workers_killed_one_after_another), and says that
    the input was lost, not the task."""
    executor = DaskExecutor.connect("local:2")
    try:
        with caplog.at_level("INFO", logger="mcrt"):
            fragile = _KillsItsLoader(str(tmp_path), 4, os.getpid())
            results = dict(executor.map(_plus_shared, 3, name="fragile",
                                        shared={"shared": fragile}))
    finally:
        executor.close()
    assert results == {0: 7, 1: 17, 2: 27}
    assert len(list(tmp_path.iterdir())) == 4
    notes = [r.getMessage() for r in caplog.records if "submitting it again" in r.getMessage()]
    assert notes and all("its input" in note for note in notes), notes


def test_a_task_that_always_kills_its_worker_is_one_error(tmp_path, monkeypatch, by_value):
    """A task that kills every worker running it ends the job with one line
    (here after one submission: ``RESUBMITS`` 0), not with Dask's error."""
    import functools

    from mcrt.core import cluster

    monkeypatch.setattr(cluster, "RESUBMITS", 0)
    executor = DaskExecutor.connect("local:2")
    try:
        with pytest.raises(McrtError) as failed:
            list(executor.map(functools.partial(_dies_first, str(tmp_path), 99), 2,
                              name="doomed"))
    finally:
        executor.close()
    message = str(failed.value)
    assert "\n" not in message and message.startswith(
        "task 0 of job doomed on the Dask cluster at local:2: Dask gave up on it after 4 of "
        "its workers died running it (submitted 1 time; "), message


def _scheduler(tmp_path: Path) -> tuple[subprocess.Popen, str]:
    """A `dask scheduler` process of its own (so it can be SIGKILLed) and its address."""
    file = tmp_path / "scheduler.json"
    process = subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                "--dashboard-address", "127.0.0.1:0", "--scheduler-file",
                                str(file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            return process, json.loads(file.read_text())["address"]
        except (OSError, ValueError, KeyError):
            time.sleep(0.1)
    process.kill()
    raise AssertionError("the scheduler did not start")


def _worker(address: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _stop(*processes: subprocess.Popen) -> None:
    for process in processes:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=30)


@pytest.mark.skipif(not DASK.exists(), reason="no dask command")
def test_a_scheduler_killed_in_the_middle_is_one_line_without_a_traceback(tmp_path, cache):
    """`mcrt reference --cluster tcp://...` whose scheduler is SIGKILLed while a
    pass runs: exit status 2 and one line on stderr naming the scheduler, none of
    Dask's log lines or tracebacks."""
    from distributed import Client

    scheduler, address = _scheduler(tmp_path)
    worker = _worker(address)
    common = [str(CORNELL), "-D", "res=16", "--spp", "65536", "--spp-per-pass", "256",
              "-o", str(tmp_path / "ref.exr")]
    try:
        process = subprocess.Popen([sys.executable, "-m", "mcrt", "-q", "reference", *common,
                                    "--cluster", address], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
        with Client(address, timeout=30) as watcher:  # until a pass runs on the worker
            deadline = time.monotonic() + 120
            while not any(watcher.processing().values()) and process.poll() is None \
                    and time.monotonic() < deadline:
                time.sleep(0.05)
        assert process.poll() is None, process.communicate()
        scheduler.kill()
        _, err = process.communicate(timeout=120)
    finally:
        _stop(scheduler, worker)
    lines = err.strip().splitlines()
    assert process.returncode == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"mcrt: error: lost the Dask scheduler at {address} "
                               f"(the connection to it was lost); "), lines[0]
    assert "run the same command again" in lines[0]


@pytest.mark.skipif(not DASK.exists(), reason="no dask command")
def test_no_worker_coming_back_is_one_error_naming_the_workers(tmp_path, cache, monkeypatch,
                                                               caplog):
    """The one worker of a cluster (no nanny: nothing restarts it) is SIGKILLed
    after the first folded pass; the scheduler lives. mcrt notes that it waits
    for workers, then ($MCRT_CLUSTER_WORKER_WAIT seconds later) fails with one
    line saying the workers died and how many tasks were lost; the passes folded
    so far are kept, and the same reference in this process resumes after them."""
    monkeypatch.setenv("MCRT_CLUSTER_WORKER_WAIT", "2")
    scheduler, address = _scheduler(tmp_path)
    worker = _worker(address, "--no-nanny")
    try:
        executor = DaskExecutor.connect(address)
        deadline = time.monotonic() + 60
        while not executor.client.nthreads() and time.monotonic() < deadline:
            time.sleep(0.1)  # (no worker yet would start the wait for one)

        def kill_the_worker(index: int, passes: int) -> None:
            if index == 0:
                worker.kill()

        try:
            with caplog.at_level("INFO", logger="mcrt"), \
                    pytest.raises(McrtError) as lost:
                get_reference(CORNELL, PARAMS, spp=256, spp_per_pass=8, executor=executor,
                              on_pass=kill_the_worker)
        finally:
            executor.close()
    finally:
        _stop(worker, scheduler)
    message = str(lost.value)
    assert "\n" not in message, message
    assert message.startswith(f"the one Dask worker at {address} died and none came back "
                              f"within 2 s; "), message
    assert re.search(r"within 2 s; \d+ tasks? lost; the work finished so far is kept: run "
                     r"the same command again", message), message
    assert any("waiting up to 2 s for workers" in r.getMessage() for r in caplog.records)
    resumed = get_reference(CORNELL, PARAMS, spp=256, spp_per_pass=8)
    assert resumed.resumed_passes >= 1
    same_stats(resumed, get_reference(CORNELL, PARAMS, spp=256, spp_per_pass=8, cache=False))


def _other_worker(tmp_path: Path, address: str) -> subprocess.Popen:
    """A worker that imports another mcrt: a copy of this one with one line
    changed, first on its PYTHONPATH."""
    import shutil

    copy = tmp_path / "other"
    shutil.copytree(ROOT / "mcrt", copy / "mcrt", ignore=shutil.ignore_patterns("__pycache__"))
    with (copy / "mcrt" / "_version.py").open("a") as file:
        file.write("# another build\n")
    return subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--no-nanny"],
                            env={**os.environ, "PYTHONPATH": str(copy)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@pytest.mark.skipif(not DASK.exists(), reason="no dask command")
def test_a_worker_running_other_mcrt_code_is_refused_in_one_line(tmp_path):
    """A hand-started worker that imported another mcrt (here: a copy of this one
    with one line changed, first on its PYTHONPATH) is refused before any task
    runs, in one line naming it and both source digests; a worker of this
    install is accepted (the other tests here use them)."""
    from distributed import Client

    from mcrt.core.provenance import source_digest

    scheduler, address = _scheduler(tmp_path)
    worker = _other_worker(tmp_path, address)
    try:
        with Client(address, timeout=30) as watcher:
            watcher.wait_for_workers(1, timeout=60)
            (where,) = watcher.nthreads()
        with pytest.raises(McrtError) as refused:
            DaskExecutor.connect(address)
    finally:
        _stop(scheduler, worker)
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith(f"the Dask worker at {where} runs other software than this mcrt: "
                              f"mcrt source "), message
    assert message.endswith(f" where this one has {source_digest()}; its renders would not be "
                            f"this mcrt's bits: restart the workers from this install (a worker "
                            f"keeps the code it imported when it started)"), message


@pytest.mark.skipif(not DASK.exists(), reason="no dask command")
def test_a_worker_of_other_software_joining_a_job_later_has_no_result_kept(tmp_path):
    """A worker that joins after the executor checked the workers (here: the one
    left once this install's worker is stopped) is asked when its first result
    comes back, and the job ends in the same one line: none of its results is
    kept. Before, only the workers there at the start were asked."""
    from distributed import Client

    scheduler, address = _scheduler(tmp_path)
    good, other = _worker(address, "--no-nanny"), None
    try:
        with Client(address, timeout=30) as watcher:
            watcher.wait_for_workers(1, timeout=60)
            (first,) = watcher.nthreads()
            executor = DaskExecutor.connect(address)
            try:
                assert sorted(executor.map(abs, 3)) == [(0, 0), (1, 1), (2, 2)]  # accepted
                other = _other_worker(tmp_path, address)
                watcher.wait_for_workers(2, timeout=60)
                _stop(good)
                deadline = time.monotonic() + 30
                while first in watcher.nthreads() and time.monotonic() < deadline:
                    time.sleep(0.1)
                (where,) = watcher.nthreads()
                kept = []
                with pytest.raises(McrtError) as refused:
                    kept.extend(executor.map(abs, 4))
            finally:
                executor.close()
    finally:
        _stop(scheduler, good, *([other] if other else []))
    assert kept == []
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith(f"the Dask worker at {where} runs other software than this mcrt: "
                              f"mcrt source "), message


def test_the_software_line_names_at_most_three_workers_and_what_differs():
    from mcrt.core.worker_software import mismatch

    here = {"mcrt_source": "aaaa", "mitsuba_version": "3.9.1", "drjit_version": "1.5.0"}
    old = {**here, "mitsuba_version": "3.9.0"}
    workers = {f"tcp://w{i}:1": (old if i % 2 else here) for i in range(10)}
    assert mismatch(here, {"tcp://w0:1": here, "tcp://w2:1": here}) is None
    line = mismatch(here, workers)
    assert line is not None and line.startswith(
        "5 of 10 Dask workers run other software than this mcrt (tcp://w1:1, tcp://w3:1, "
        "tcp://w5:1 and 2 more; the first: Mitsuba 3.9.0 where this one has 3.9.1); "), line
