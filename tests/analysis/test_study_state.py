"""A study's saved state is never lost, and one process at a time writes a report directory.

* A saved state of another key (here another variant) is moved aside to
  ``.mcrt-resume-<key>``, byte for byte, with a note naming the command that resumes
  it; that command moves it back and renders nothing.
* A second ``mcrt compare`` on a directory another one is writing exits at once with
  one line naming the directory and the holder's PID and command; a holder killed
  with SIGKILL leaves no stale lock.
* A scene whose film has no pixels is refused by ``--check`` and by a run before any
  rendering.

Real processes (``python -m mcrt``, or a wrapper that counts and may slow renders)
on the tiny 64x48 checkerboard study of conftest; about 20 s for the file on 2 cores.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import mcrt.core.render as passes
from mcrt.analysis.study import STATE_DIR, StudyState, load_config
from tests.conftest import CHECKERBOARD, ROOT, run_cli, study_toml

CORNELL = ROOT / "scenes" / "cornell_box.xml"

#: ``python WRAPPER ARGS``: ``mcrt ARGS``, each render slowed by ``$SLOW`` seconds; the
#: number of renders is the last stderr line.
WRAPPER = """
import os, sys, time
import mcrt.core.render as passes
real, calls = passes.render_film, []
def counted(*args, **kwargs):
    calls.append(1)
    time.sleep(float(os.environ.get("SLOW", "0")))
    return real(*args, **kwargs)
passes.render_film = counted
from mcrt.cli import main
code = main(sys.argv[1:])
print(f"renders: {len(calls)}", file=sys.stderr)
sys.exit(code)
"""


def _env(tmp: Path, **extra: str) -> dict[str, str]:
    return {**os.environ, "MCRT_CACHE_DIR": str(tmp / "cache"), "OPENBLAS_NUM_THREADS": "1",
            "MPLBACKEND": "Agg", **extra}


def _mcrt(tmp: Path, *args: str, wrapped: bool = False) -> subprocess.CompletedProcess:
    """``mcrt ARGS`` in ``tmp`` (through the counting wrapper if ``wrapped``)."""
    command = [sys.executable, str(tmp / "wrapper.py")] if wrapped else \
        [sys.executable, "-m", "mcrt"]
    return subprocess.run([*command, *args], cwd=tmp, env=_env(tmp), capture_output=True,
                          text=True, timeout=300)


@pytest.fixture
def tmp(tmp_path: Path) -> Path:
    (tmp_path / "study.toml").write_text(study_toml(CHECKERBOARD, name="kept"))
    (tmp_path / "wrapper.py").write_text(WRAPPER)
    return tmp_path


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


def _renders(result: subprocess.CompletedProcess) -> int:
    return int(re.findall(r"^renders: (\d+)$", result.stderr, re.M)[-1])


def test_a_state_of_another_variant_is_kept_beside_and_resumed(tmp):
    spectral = ["--variant", "llvm_ad_spectral", "compare", "study.toml", "-o", "o"]
    first = _mcrt(tmp, *spectral)
    assert first.returncode == 0, first.stderr
    saved = _files(tmp / "o" / STATE_DIR)
    assert "state.npz" in saved and len(saved) > 1  # the state and its images

    # The default variant: another study. It measures its own cells; the spectral
    # state is moved aside, byte for byte, and the note says where and what resumes it.
    second = _mcrt(tmp, "compare", "study.toml", "-o", "o")
    assert second.returncode == 0, second.stderr
    assert "from the saved state" not in second.stdout
    aside = sorted((tmp / "o").glob(f"{STATE_DIR}-*"))
    assert len(aside) == 1 and _files(aside[0]) == saved
    notes = [line for line in second.stderr.splitlines() if "another study" in line]
    assert len(notes) == 1, second.stderr
    assert f"kept in {Path('o') / aside[0].name};" in notes[0]
    assert notes[0].endswith("; to resume it, run: mcrt --variant llvm_ad_spectral compare "
                             "study.toml -o o")
    default_state = _files(tmp / "o" / STATE_DIR)

    # That command resumes from it: nothing is rendered; the default variant's state
    # is set aside in turn, and resumed in turn.
    third = _mcrt(tmp, *spectral, wrapped=True)
    assert third.returncode == 0, third.stderr
    assert _renders(third) == 0 and "(4 of 4 cells from the saved state)" in third.stdout
    assert _files(tmp / "o" / STATE_DIR) == saved
    aside = sorted((tmp / "o").glob(f"{STATE_DIR}-*"))
    assert len(aside) == 1 and _files(aside[0]) == default_state
    fourth = _mcrt(tmp, "compare", "study.toml", "-o", "o", wrapped=True)
    assert fourth.returncode == 0, fourth.stderr
    assert _renders(fourth) == 0 and "(4 of 4 cells from the saved state)" in fourth.stdout
    assert _files(tmp / "o" / STATE_DIR) == default_state
    assert [_files(d) for d in (tmp / "o").glob(f"{STATE_DIR}-*")] == [saved]


def _holds_a_lock(pid: int) -> bool:
    return any(w[1:2] == ["FLOCK"] and w[4:5] == [str(pid)]
               for w in (line.split() for line in Path("/proc/locks").read_text().splitlines()))


@pytest.mark.skipif(not Path("/proc/locks").exists(), reason="needs Linux's /proc/locks")
def test_a_second_writer_is_refused_and_a_killed_ones_lock_is_not_stale(tmp):
    args = ["compare", "study.toml", "-o", "o"]
    holder = subprocess.Popen([sys.executable, "wrapper.py", "-q", *args], cwd=tmp,
                              env=_env(tmp, SLOW="0.4"), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not _holds_a_lock(holder.pid) and holder.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.02)
        assert holder.poll() is None and _holds_a_lock(holder.pid), "the run took no lock"

        start = time.monotonic()
        second = _mcrt(tmp, *args)
        took = time.monotonic() - start
        lines = [line for line in second.stderr.splitlines() if line.strip()
                 and not line.startswith("mcrt: note:")]
        assert second.returncode == 2 and len(lines) == 1, second.stderr
        assert lines[0].startswith("mcrt: error: o is in use by another study run "
                                   f"(PID {holder.pid}: wrapper.py -q compare study.toml -o o)")
        assert took < 60 and holder.poll() is None, "the refusal came late"
        assert not (tmp / "o" / "report.html").exists()  # the refused run wrote nothing
    finally:
        holder.send_signal(signal.SIGKILL)  # a crash: no cleanup runs
        holder.communicate(timeout=60)

    # The kernel dropped the lock with the process: the same command runs (and takes
    # the cells the killed run saved, if any).
    third = _mcrt(tmp, *args)
    assert third.returncode == 0, third.stderr
    assert "in use" not in third.stderr


def test_states_in_one_process_share_the_lock_and_restart_keeps_another_study(tmp_path):
    """``StudyState.open`` twice in one process: both work (the lock is the
    process's); ``--restart`` deletes this study's state only."""
    path = tmp_path / "a.toml"
    path.write_text(study_toml(CHECKERBOARD, name="a"))
    config = load_config(path)
    other = tmp_path / "b.toml"
    other.write_text(study_toml(CHECKERBOARD, name="b", params="{ width = 32, height = 24 }"))
    cell = {"scene": "checkerboard", "sampler": "jittered", "spp_requested": 4, "mse": 0.5}
    with StudyState.open(tmp_path / "o", config) as state, \
            StudyState.open(tmp_path / "o", config) as again:
        state.add(cell, None, seconds=1.0)
        assert again.directory == state.directory
    saved = _files(tmp_path / "o" / STATE_DIR)
    fresh = StudyState.open(tmp_path / "o", load_config(other), restart=True)
    assert fresh.cells == {} and not fresh.directory.exists()
    assert [_files(d) for d in (tmp_path / "o").glob(f"{STATE_DIR}-*")] == [saved]
    fresh.close()
    assert StudyState.open(tmp_path / "o", config).cells.keys() == {("checkerboard", "jittered", 4)}


def test_a_film_without_pixels_is_refused_by_check_and_by_a_run(tmp_path, capsys, monkeypatch):
    """``params = { res = 0 }`` on the second scene: ``--check`` loads every scene
    with its parameters as the run will, so both refuse it in one line, exit 2,
    before rendering anything (it used to pass --check and crash after the first scene)."""
    config = tmp_path / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="zero") + "[[scenes]]\n"
                      f'path = "{CORNELL}"\nparams = {{ res = 0 }}\n')
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    calls = []
    monkeypatch.setattr(passes, "render_film", lambda *a, **k: calls.append(a))
    for argv in (["compare", str(config), "--check"],
                 ["compare", str(config), "-o", str(tmp_path / "o")]):
        code, out, err = run_cli(capsys, *argv)
        lines = [line for line in err.splitlines() if not line.startswith("mcrt: note:")]
        assert code == 2 and len(lines) == 1, err
        assert lines[0].startswith("mcrt: error: scene 'cornell_box': ")
        assert "the film has 0x0 pixels" in lines[0]
    assert calls == [] and not (tmp_path / "o").exists()


def test_mcrt_compare_in_process_lets_go_of_its_directory(tmp_path, capsys, monkeypatch):
    """`main(["compare", ...])` from Python releases the report directory's lock
    when it returns (not when the state is collected): another process may then
    write into it."""
    import mcrt.core.file_lock as file_lock

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    path = tmp_path / "s.toml"
    path.write_text(study_toml(CHECKERBOARD, name="s", params="{ width = 32, height = 24 }"))
    kept: list = []
    original = StudyState.open

    def keep(*args, **kwargs):  # a reference that outlives the command
        kept.append(original(*args, **kwargs))
        return kept[-1]

    monkeypatch.setattr(StudyState, "open", keep)
    code, _, err = run_cli(capsys, "-q", "compare", str(path), "-o", str(tmp_path / "o"))
    assert code == 0, err
    assert kept and not any(key.startswith("dir:") for key in file_lock._HELD)
