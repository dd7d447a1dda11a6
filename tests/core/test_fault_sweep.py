"""Faults found by a sweep under real limits: a file system made read-only in
the middle of a render (a real tmpfs, remounted); a Dask worker killed while
another fetches a result from it (a real ``local:2`` cluster); a file size
limit (``ulimit -f``) below the size of a checkpoint; a terminal's Ctrl-C or
SIGHUP, sent to the whole process group of a command on a ``local:2`` cluster."""

from __future__ import annotations

import errno
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, TINY_SCENE, rerun_renders_nothing, run_cli, tmpfs

pytestmark = [pytest.mark.slow, pytest.mark.serial]

CORNELL = ROOT / "scenes" / "cornell_box.xml"


def _mount(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["mount", *args], capture_output=True, text=True)


@pytest.fixture
def disk(tmp_path):
    """A 16 MiB tmpfs at ``tmp_path/disk`` (skipped where mount(2) is not allowed)."""
    with tmpfs(tmp_path / "disk", "16m") as mounted:
        yield mounted


def _read_only(disk: Path, on: bool = True) -> None:
    done = _mount("-o", f"remount,{'ro' if on else 'rw'}", str(disk))
    assert done.returncode == 0, done.stderr


def test_an_output_directory_made_read_only_mid_render_is_noted_once(
        tmp_path, cache, capsys, monkeypatch, disk):
    """The output's file system turns read-only after the first checkpoint: the
    later checkpoints go to the cache with one note (every pass used to try the
    output directory again and print the note again: 8 passes, 8 notes), the
    finished render is kept there, and the rerun writes it without rendering."""
    from mcrt.core.job import CheckpointStore

    monkeypatch.setenv("MCRT_CHECKPOINT_SECONDS", "0")  # a checkpoint after every pass
    args = ["render", str(CORNELL), "-D", "res=64", "--spp", "2048",
            "--sampler", "sobol", "-o", str(disk / "img")]
    real_save = CheckpointStore.save_periodic
    turned: list[bool] = []

    def save_then_freeze(store, checkpoint):
        real_save(store, checkpoint)
        if not turned:
            turned.append(True)
            _read_only(disk)

    with monkeypatch.context() as patch:
        patch.setattr(CheckpointStore, "save_periodic", save_then_freeze)
        code, _, err = run_cli(capsys, *args)
    assert code == 2 and "Traceback" not in err, err
    notes = [line for line in err.splitlines() if "cannot save the checkpoint" in line]
    assert len(notes) == 1 and "read-only file system" in notes[0], err
    line = [line for line in err.splitlines() if line.startswith("mcrt: error:")]
    assert len(line) == 1 and "read-only file system" in line[0], err
    kept = Path(line[0].split("kept in ")[1].split(":")[0])
    assert kept.is_file() and cache in kept.parents
    _read_only(disk, on=False)
    rerun_renders_nothing(capsys, monkeypatch, *args)
    assert (disk / "img.exr").is_file() and not kept.exists()


def test_a_worker_killed_while_another_fetches_from_it_prints_nothing(capfd):
    """A worker's peer dies while it fetches a task's result from it (a study's
    shared input from a worker killed or out of memory): Dask's workers logged
    "distributed.worker - ERROR - Worker stream died during communication" and
    two tracebacks straight to the terminal (the worker processes' own stderr,
    which mcrt's silencing in the client does not reach). The job still gets
    its result."""
    pytest.importorskip("distributed")
    from distributed import wait

    from mcrt.core.cluster import DaskExecutor

    executor = DaskExecutor.connect("local:2")
    try:
        client = executor.client
        holder, fetcher = sorted(client.scheduler_info()["workers"])
        pid = client.run(os.getpid, workers=[holder])[holder]
        big = client.submit(np.ones, 64 << 20, workers=[holder], allow_other_workers=True,
                            pure=False)  # 512 MiB
        wait([big])
        fetched = client.submit(np.size, big, workers=[fetcher], allow_other_workers=True)
        time.sleep(0.2)  # the transfer has started (it takes about a second)
        os.kill(pid, signal.SIGKILL)
        assert fetched.result(timeout=60) == 64 << 20
        time.sleep(1)  # what the workers would print has come
    finally:
        executor.close()
    out, err = capfd.readouterr()
    assert "Traceback" not in err and "distributed." not in err, err


@pytest.mark.parametrize("command", ["render", "reference"])
def test_a_file_size_limit_below_the_checkpoint_is_refused_before_work(tmp_path, command):
    """Under ``ulimit -f`` smaller than a checkpoint, every save fails (EFBIG, in
    the cache too): the render was traced, then lost with "File too large",
    its checkpoints and outputs all refused. Now one line before any work,
    naming the limit."""
    scene = tmp_path / "tiny.xml"
    scene.write_text(TINY_SCENE)  # 32x32: a checkpoint of 40 KiB, a reference state of 64
    out = tmp_path / "out"
    args = {"render": ["render", str(scene), "--spp", "16", "-o", f"{out}/"],
            "reference": ["reference", str(scene), "--spp", "64", "-o", f"{out}/"]}[command]

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (16 << 10, resource.RLIM_INFINITY))

    done = subprocess.run([sys.executable, "-m", "mcrt", "-q", *args], cwd=tmp_path,
                          env={**os.environ, "MCRT_CACHE_DIR": str(tmp_path / "cache")},
                          preexec_fn=limit, capture_output=True, text=True, timeout=120)
    lines = [line for line in done.stderr.splitlines() if not line.startswith("mcrt: note:")]
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "file size limit (ulimit -f)" in lines[0], done.stderr
    assert not out.exists() or not [p for p in out.rglob("*") if p.is_file()]


def test_a_file_too_large_names_the_limit():
    from mcrt.core.atomic import remedy, write_error

    error = write_error("out/img.exr", OSError(errno.EFBIG, "File too large"))
    assert "ulimit -f" in str(error) and "ulimit -f" in remedy(error)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGHUP], ids=["ctrl-c", "hangup"])
def test_a_terminal_signal_to_a_local_cluster_s_group_is_one_line(tmp_path, signum):
    """Ctrl-C in a terminal (or closing it: SIGHUP) signals the command's whole
    process group, which held a ``local`` cluster's worker processes and
    multiprocessing's resource tracker: each worker printed its own
    ``KeyboardInterrupt`` traceback, and a tracker killed by SIGHUP came back
    with a warning and a ``KeyError`` traceback per resource. The command alone
    handles the signal now: the partial reference, one line, exit 130, no
    process left behind; the same command resumes it."""
    pytest.importorskip("distributed")
    scene = tmp_path / "t.xml"
    scene.write_text(TINY_SCENE.replace('value="32"', 'value="128"'))
    cache = tmp_path / "cache"
    args = [sys.executable, "-m", "mcrt", "reference", str(scene), "--spp", "65536",
            "--spp-per-pass", "256", "--cluster", "local:2", "-o", str(tmp_path / "r.exr")]
    env = {**os.environ, "MCRT_CACHE_DIR": str(cache)}
    child = subprocess.Popen(args, cwd=tmp_path, env=env, start_new_session=True,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 90
        while not list(cache.glob("reference/*.partial.npz")) and child.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = subprocess.run(["pgrep", "-P", str(child.pid)], capture_output=True,
                                 text=True).stdout.split()
        assert child.poll() is None and workers, "the reference ended before the signal"
        os.killpg(child.pid, signum)  # the terminal's way: the whole group
        out, _ = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 130 and "interrupted" in out, out
    assert "Traceback" not in out and "resource_tracker" not in out, out
    time.sleep(2)  # the workers end with the command
    left = [pid for pid in workers if Path(f"/proc/{pid}").exists()
            and "zombie" not in Path(f"/proc/{pid}/status").read_text().lower()]
    assert not left, f"processes left behind: {left}"
