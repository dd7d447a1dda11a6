"""Issue 16: full disks, read-only directories and memory limits.

Every writing command checks free space before work (one line, exit 2) and
reports a failed write by its real cause, keeping finished work where it has a
checkpoint and saying where. Under a memory limit (``RLIMIT_AS`` in a child)
passes are sized to fit, and a render whose smallest pass cannot fit stops
with one line before rendering."""

from __future__ import annotations

import errno
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import CHECKERBOARD, ROOT, TINY_SCENE, run_cli, study_toml

from mcrt.core import atomic
from mcrt.core.memory import lane_budget

CORNELL = ROOT / "scenes" / "cornell_box.xml"


def _commands(tmp: Path) -> dict[str, list[str]]:
    scene = tmp / "tiny.xml"
    scene.write_text(TINY_SCENE)
    config = tmp / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s"))
    return {
        "render": ["render", str(scene), "--spp", "4", "-o", str(tmp / "out" / "img")],
        "adaptive": ["render", str(scene), "--adaptive", "--spp", "16", "-o",
                     str(tmp / "out" / "ada")],
        "reference": ["reference", str(scene), "--spp", "8", "-o", str(tmp / "out" / "r.exr")],
        "compare": ["compare", str(config), "-o", str(tmp / "out" / "study")],
        "demo": ["demo", "--samplers", "jittered", "--reference-factor", "1", "-o",
                 str(tmp / "out" / "demo")],
        "pattern": ["pattern", "jittered", "--spp", "16", "--pixels", "4", "--kmax", "16",
                    "-o", str(tmp / "out" / "pattern")],
        "integrate": ["integrate", "pi", "--sampler", "jittered", "--max-n", "64",
                      "--trials", "2", "-o", str(tmp / "out" / "integrate")],
    }


COMMANDS = ["render", "adaptive", "reference", "compare", "demo", "pattern", "integrate"]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _one_line(code: int, err: str) -> str:
    lines = [line for line in err.strip().splitlines() if not line.startswith("mcrt: note:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("command", COMMANDS)
def test_too_little_free_space_is_refused_before_work(tmp_path, cache, capsys, monkeypatch,
                                                      command):
    args = _commands(tmp_path)[command]
    monkeypatch.setattr(atomic, "free_bytes", lambda path: 4096)
    code, _, err = run_cli(capsys, "-q", *args)
    assert "not enough free space" in _one_line(code, err)
    out = tmp_path / "out"
    assert not [p for p in out.rglob("*") if p.is_file()]  # nothing was written


def _failing_writes(monkeypatch, code: int, names: tuple[str, ...]) -> None:
    """Every atomic write of a file named ``*names*`` fails with ``code`` (the
    cache and the checkpoints, elsewhere, still work)."""
    real = atomic._fsync_file

    def fsync(path: str) -> None:
        if any(name in os.path.basename(path) for name in names):
            raise OSError(code, os.strerror(code))
        real(path)

    monkeypatch.setattr(atomic, "_fsync_file", fsync)


CAUSES = {errno.ENOSPC: ("no space left on device", "free some space"),
          errno.EROFS: ("read-only file system", "make the file system writable"),
          errno.EACCES: ("permission denied", "fix the permissions")}


@pytest.mark.parametrize("cause", list(CAUSES), ids=["enospc", "readonly", "permission"])
@pytest.mark.parametrize("command", ["render", "adaptive", "reference"])
def test_failed_output_write_keeps_the_render(tmp_path, cache, capsys, monkeypatch, command,
                                              cause):
    args = _commands(tmp_path)[command]
    with monkeypatch.context() as patch:
        _failing_writes(patch, cause, (".exr.", ".png."))
        code, _, err = run_cli(capsys, "-q", *args)
    line = _one_line(code, err)
    reason, remedy = CAUSES[cause]
    assert reason in line and remedy in line and "kept in" in line
    assert "free some space" not in line or cause == errno.ENOSPC
    kept = Path(line.split("kept in ")[1].split(":")[0])
    assert kept.is_file()
    traced: list[int] = []
    from mcrt.core import engine
    real = engine.trace_pass
    patch_trace = lambda *a, **k: (traced.append(1), real(*a, **k))[1]  # noqa: E731
    monkeypatch.setattr(engine, "trace_pass", patch_trace)
    monkeypatch.setattr("mcrt.render.adaptive.engine.trace_pass", patch_trace)
    code, _, err = run_cli(capsys, "-q", *args)
    assert code == 0 and traced == [], err  # written without rendering again


@pytest.mark.parametrize("cause", [errno.ENOSPC, errno.EROFS], ids=["enospc", "readonly"])
def test_failed_report_write_keeps_the_cells(tmp_path, cache, capsys, monkeypatch, cause):
    args = _commands(tmp_path)["compare"]
    with monkeypatch.context() as patch:
        _failing_writes(patch, cause, ("summary.png",))
        code, _, err = run_cli(capsys, "-q", *args)
    line = _one_line(code, err)
    assert CAUSES[cause][0] in line and CAUSES[cause][1] in line
    assert "measured cells are kept in" in line
    code, out, err = run_cli(capsys, "-q", *args)
    assert code == 0 and "4 of 4 cells from the saved state" in out, out + err


@pytest.mark.parametrize("command", ["demo", "pattern", "integrate"])
@pytest.mark.parametrize("cause", [errno.ENOSPC, errno.EROFS], ids=["enospc", "readonly"])
def test_failed_write_names_its_cause(tmp_path, cache, capsys, monkeypatch, command, cause):
    args = _commands(tmp_path)[command]
    _failing_writes(monkeypatch, cause, (".png.",))
    code, _, err = run_cli(capsys, "-q", *args)
    assert CAUSES[cause][0] in _one_line(code, err)


# --------------------------------------------------------------------------- memory

_LIMITED = """
import resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from mcrt.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _limited(tmp: Path, limit_mib: int, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MCRT_CACHE_DIR": str(tmp / "cache"), "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", _LIMITED, str(limit_mib << 20), *args],
                          cwd=tmp, env=env, capture_output=True, text=True, timeout=120)


def test_reference_under_a_memory_limit_uses_smaller_passes(tmp_path):
    done = _limited(tmp_path, 800, "reference", str(CORNELL), "-D", "res=512", "--spp", "16",
                    "--no-cache", "-o", "ref.exr")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "fit in the memory available" in done.stderr and "the default 16 would not" in done.stderr
    assert (tmp_path / "ref.exr").is_file()


@pytest.mark.parametrize("command", ["render", "reference"])
def test_a_pass_that_cannot_fit_is_one_line(tmp_path, command):
    res = "2048" if command == "render" else "1024"
    done = _limited(tmp_path, 900, command, str(CORNELL), "-D", f"res={res}", "--spp", "4",
                    "-o", "out.exr")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert lines[0].startswith("mcrt: error: not enough memory for") and "ulimit -v" in lines[0]
    assert not (tmp_path / "out.exr").exists()


def test_lane_budget_follows_the_address_space_limit():
    code = ("import resource; from mcrt.core.memory import lane_budget, _status_bytes\n"
            "size = _status_bytes('VmSize'); limit = size + (100 << 20)\n"
            "resource.setrlimit(resource.RLIMIT_AS, (limit, limit))\n"
            "print(lane_budget(100, 10 << 20))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    budget = int(done.stdout.split()[-1])
    assert 0 < budget <= (int(0.8 * (100 << 20)) - (10 << 20)) // 100
    assert lane_budget(100, 0, available=10**6) == 8000
    assert lane_budget(100, 10**6, available=10**6) == 0
    if resource.getrlimit(resource.RLIMIT_AS)[0] == resource.RLIM_INFINITY:
        assert (lane_budget() or 1 << 40) > 1000



def test_render_passes_shrink_only_to_fit_memory(monkeypatch):
    """With the memory available (mcrt.core.memory.available_bytes, which reads
    ulimit -v, cgroups and the host) leaving room for passes of 2 samples per
    pixel, a 16-spp render that is one pass by default takes 8 passes with the
    same samples (equal up to float64 summation order); resuming its checkpoint
    keeps its pass size even where memory is plentiful."""
    import mitsuba as mi

    from mcrt.core import memory
    from mcrt.core.render import render_film
    from mcrt.core.sampling import make_sampler

    scene = mi.load_file(str(CORNELL), res="64")
    full = render_film(scene, make_sampler("jittered", 16), seed=1)
    assert full.passes == 1
    pixels = 64 * 64
    need = 2 * pixels * memory.BYTES_PER_LANE + memory.film_bytes(pixels, 4) \
        + memory.KERNEL_BYTES
    monkeypatch.setattr(memory, "available_bytes", lambda: int(need / memory.USABLE_SHARE) + 64)
    small = render_film(scene, make_sampler("jittered", 16), seed=1)
    assert small.passes == 8 and small.spp == 16
    np.testing.assert_allclose(small.image, full.image, rtol=1e-6, atol=1e-7)
    half = render_film(scene, make_sampler("jittered", 16), seed=1, passes=8)
    state = half.checkpoint
    assert state is not None
    monkeypatch.undo()  # plenty of memory again: the checkpoint's pass size is kept
    resumed = render_film(scene, make_sampler("jittered", 16), seed=1, resume=state)
    assert resumed.passes == 8
    np.testing.assert_array_equal(resumed.image, half.image)
