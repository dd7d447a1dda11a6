"""Full disks, read-only directories and memory limits.

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

from mcrt.core import atomic
from mcrt.core.job import Checkpointing
from mcrt.core.memory import lane_budget
from tests.conftest import (
    CHECKERBOARD,
    ROOT,
    TINY_SCENE,
    rerun_renders_nothing,
    run_cli,
    study_toml,
    tmpfs,
)

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
    rerun_renders_nothing(capsys, monkeypatch, "-q", *args)


@pytest.mark.parametrize("command", ["render", "adaptive"])
def test_a_render_that_writes_its_files_copies_its_sums_for_no_checkpoint(tmp_path, cache,
                                                                           capsys, monkeypatch,
                                                                           command):
    """The finished render's state (a float64 copy of its sums: 32 MiB for a
    1024^2 film; an adaptive render's sub-pixel sums too, which it also wrote
    to a file after its last pass) is taken only when writing the outputs
    fails (the test above)."""
    from mcrt.core.accumulators import FilmAccumulator
    from mcrt.render.adaptive.sums import PixelSums

    copies: list[str] = []
    for owner, name in ((FilmAccumulator, "state"), (PixelSums, "arrays")):
        real = getattr(owner, name)
        monkeypatch.setattr(owner, name, lambda self, real=real, name=name: (
            copies.append(name), real(self))[1])
    code, _, err = run_cli(capsys, "-q", *_commands(tmp_path)[command])
    assert code == 0, err
    assert copies == []


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



def test_cgroup_limits_are_found_now_and_then_and_usage_is_read_every_time(tmp_path,
                                                                         monkeypatch):
    """The memory a cgroup leaves: the tightest limited level (a parent's limit
    binds too), less its usage, plus its reclaimable page cache. Finding the
    limited levels reads the whole hierarchy, so it is redone only after
    LIMITS_TTL seconds; the usage is read at every call."""
    from mcrt.core import memory

    root = tmp_path / "cgroup"
    parent, leaf = root / "a", root / "a" / "b"
    leaf.mkdir(parents=True)
    (parent / "memory.max").write_text("1000000\n")
    (parent / "memory.current").write_text("400000\n")
    (parent / "memory.stat").write_text("anon 5\ninactive_file 100000\n")
    (leaf / "memory.max").write_text("max\n")  # no limit of its own
    (leaf / "memory.current").write_text("1\n")
    monkeypatch.setattr(memory, "CGROUP_ROOT", root)
    monkeypatch.setattr(memory, "_cgroup_dir", lambda: leaf)
    monkeypatch.setattr(memory, "_limits", None)
    assert memory._cgroup_left() == 1000000 - 400000 + 100000
    (parent / "memory.current").write_text("900000\n")
    assert memory._cgroup_left() == 200000  # usage read again
    (leaf / "memory.max").write_text("50000\n")
    (leaf / "memory.current").write_text("10000\n")
    assert memory._cgroup_left() == 200000  # the new limit: not yet looked for
    monkeypatch.setattr(memory, "LIMITS_TTL", 0.0)
    assert memory._cgroup_left() == 40000


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
    resumed = render_film(scene, make_sampler("jittered", 16), seed=1,
                          checkpoints=Checkpointing(state))
    assert resumed.passes == 8
    np.testing.assert_array_equal(resumed.image, half.image)


# --------------------------------------------------------------------------- a real full disk


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MiB tmpfs at ``tmp_path/disk`` (skipped where mount(2) is not allowed)."""
    with tmpfs(tmp_path / "disk", "4m") as mounted:
        yield mounted


def _fill(directory: Path, name: str = "filler") -> Path:
    """Fill ``directory``'s file system to the last byte with one file."""
    filler = directory / name
    with open(filler, "wb", buffering=0) as f:
        for block in (1 << 16, 512):
            try:
                while True:
                    f.write(b"\0" * block)
            except OSError as error:
                assert error.errno == errno.ENOSPC
    return filler


def test_a_full_disk_keeps_the_finished_render_and_the_rerun_takes_it(
        tmp_path, cache, capsys, monkeypatch, small_disk):
    """The disk of the outputs fills up after the render's first checkpoint (a
    real ENOSPC from a 4 MiB tmpfs), and again after every later one (the
    space the first one freed is taken): the later checkpoints and the finished
    render go to the cache, the message says so, and once space is freed the
    same command writes the outputs without rendering again (it used to resume
    from the first checkpoint, left next to the output, and render the rest)."""
    from mcrt.core.job import CheckpointStore

    monkeypatch.setenv("MCRT_CHECKPOINT_SECONDS", "0")  # a checkpoint after every pass
    args = ["-q", "render", str(CORNELL), "-D", "res=128", "--spp", "256", "--sampler",
            "jittered", "-o", str(small_disk / "img")]
    real_save = CheckpointStore.save_periodic
    filler: list[Path] = []

    def save_then_fill(store, checkpoint):
        real_save(store, checkpoint)
        filler.append(_fill(small_disk, f"filler{len(filler)}"))

    with monkeypatch.context() as patch:
        patch.setattr(CheckpointStore, "save_periodic", save_then_fill)
        code, _, err = run_cli(capsys, *args)
    line = _one_line(code, err)
    assert "no space left on device" in line.lower() and "free some space" in line, line
    kept = Path(line.split("kept in ")[1].split(":")[0])
    assert kept.is_file() and cache in kept.parents
    assert not list(small_disk.glob(".img.exr.mcrt-resume.npz")), \
        "the older checkpoint next to the output is left"
    for path in filler:  # "free some space"
        path.unlink()
    rerun_renders_nothing(capsys, monkeypatch, *args)
    assert (small_disk / "img.exr").is_file() and not kept.exists()


def test_a_refused_study_leaves_no_folder_on_a_small_disk(tmp_path, cache, capsys, small_disk):
    """`mcrt compare -o DIR` (and `render`, `reference`, `demo`, `pattern`,
    `integrate`) on a disk too small for the outputs is refused before any work
    and removes the folders it created for them (they used to leave DIR, empty);
    folders that were there stay."""
    config = tmp_path / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s"))
    (small_disk / "kept").mkdir()
    for args in (["compare", str(config), "-o", str(small_disk / "a" / "b")],
                 ["compare", str(config), "-o", str(small_disk / "kept" / "c")],
                 ["render", str(CORNELL), "-D", "res=512", "-o", str(small_disk / "r" / "img")],
                 ["reference", str(CORNELL), "-D", "res=1024", "-o", str(small_disk / "f" / "x")],
                 ["demo", "-o", str(small_disk / "d")],
                 ["pattern", "jittered", "-o", str(small_disk / "p")],
                 ["integrate", "disk", "--sampler", "jittered", "-o", str(small_disk / "i")]):
        code, _, err = run_cli(capsys, "-q", *args)
        assert "not enough free space" in _one_line(code, err)
        assert sorted(p.name for p in small_disk.rglob("*")) == ["kept"], err


# --------------------------------------------------------------------------- real ulimit -v

MCRT = Path(sys.executable).with_name("mcrt")  # the console script, as a user runs it

#: Thread-pool variables the test environment sets (conftest) and mcrt must set itself.
_BLAS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
         "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def _user_env(tmp: Path) -> dict[str, str]:
    """A user's environment: no BLAS thread settings, a cache of its own."""
    env = {k: v for k, v in os.environ.items() if k not in _BLAS}
    return {**env, "MCRT_CACHE_DIR": str(tmp / "cache"), "MPLBACKEND": "Agg"}


def _under_cap(tmp: Path, cap_kib: int, *args: str, timeout: float = 120
               ) -> subprocess.CompletedProcess:
    """``bash -c 'ulimit -v CAP; exec mcrt ARGS'`` in ``tmp``; a run past
    ``timeout`` (a hang) fails the test."""
    script = f"ulimit -v {cap_kib}; exec \"$0\" \"$@\""
    try:
        return subprocess.run(["bash", "-c", script, str(MCRT), *args], cwd=tmp,
                              env=_user_env(tmp), capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired as hung:
        pytest.fail(f"mcrt {' '.join(args)} under ulimit -v {cap_kib} still ran after "
                    f"{timeout} s (the OpenBLAS retry loop?): {hung.stderr!r}")


@pytest.fixture(scope="module")
def started_kib() -> int:
    """Address space (KiB) a process has once mcrt and Mitsuba are imported:
    caps are chosen relative to it (other machines load other libraries)."""
    code = ("import mcrt; from mcrt.core.memory import _status_bytes; "
            "print(_status_bytes('VmSize') // 1024)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=True)
    return int(done.stdout.split()[-1])


def _ended_in_one_line(done: subprocess.CompletedProcess, cap: int) -> str:
    """Success, or exit status 2 with one ``mcrt: error:`` line naming the
    memory: never a signal (SIGABRT, SIGSEGV), a traceback or a second line."""
    errors = [line for line in done.stderr.strip().splitlines()
              if not line.startswith("mcrt: note:") and ": passes" not in line]
    assert done.returncode in (0, 2) and "Traceback" not in done.stderr, \
        f"ulimit -v {cap}: exit {done.returncode}: {done.stderr[-3000:]}"
    if done.returncode == 0:
        return "ok"
    assert len(errors) == 1 and errors[0].startswith("mcrt: error: ") \
        and "memory" in errors[0], f"ulimit -v {cap}: {done.stderr[-3000:]}"
    return errors[0]


def test_the_command_sets_one_blas_thread_unless_the_user_did(tmp_path):
    """Before numpy loads (a plugin file sees the environment the command made):
    one thread for every BLAS/OpenMP pool the user left unset."""
    from mcrt._platform import BLAS_THREAD_VARIABLES, limit_blas_threads, running_as_command

    assert set(BLAS_THREAD_VARIABLES) == set(_BLAS)
    plugin = tmp_path / "show_env.py"
    plugin.write_text("import os, sys\n"
                      f"sys.stderr.write(repr([os.environ.get(n) for n in {_BLAS!r}]) + '\\n')\n")
    env = {**_user_env(tmp_path), "MKL_NUM_THREADS": "3"}
    for command in ([str(MCRT)], [sys.executable, "-m", "mcrt"]):
        done = subprocess.run([*command, "--plugin", str(plugin), "plan", str(CORNELL)],
                              env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert "['1', '1', '3', '1', '1', '1']" in done.stderr
    environ = {"OMP_NUM_THREADS": "4", "OPENBLAS_NUM_THREADS": " "}
    assert "OMP_NUM_THREADS" not in limit_blas_threads(environ)
    assert environ["OMP_NUM_THREADS"] == "4" and environ["OPENBLAS_NUM_THREADS"] == "1"
    assert running_as_command(["/venv/bin/mcrt"], [])
    assert running_as_command(["-m"], ["python", "-X", "importtime", "-m", "mcrt", "render"])
    assert not running_as_command(["-c"], ["python", "-c", "import mcrt"])
    assert not running_as_command(["pytest"], ["python", "-m", "pytest", "-m", "mcrt"])


def test_render_under_any_address_space_limit_ends_in_one_line(tmp_path, started_kib):
    """The issue's render (`ulimit -v 500000` aborted it: "OpenBLAS error: Memory
    allocation still failed after 10 retries", SIGABRT, at the first 4x4 matrix
    inverse; from about 460000 to 485000 KiB even with one BLAS thread) under
    caps from far too small to enough: each run succeeds or ends with exit
    status 2 and one line (`out of memory (...)`, or the lane budget's `not
    enough memory for a 256x256 render`). Caps relative to the address space
    of a process that has imported mcrt (~351 MiB here: 500000 KiB is +137 MiB)."""
    seen = {}
    for delta_mib in (-230, -150, -60, 0, 60, 100, 110, 120, 137, 160, 230):
        cap = started_kib + delta_mib * 1024
        done = _under_cap(tmp_path, cap, "-q", "render", str(CORNELL), "-D", "res=256",
                          "--spp", "256", "--sampler", "jittered", "-o", "img")
        seen[delta_mib] = _ended_in_one_line(done, cap)
    assert seen[-230].endswith("while loading numpy; raise the limit"), seen
    assert seen[-150].endswith("while loading Mitsuba and libLLVM; raise the limit"), seen
    assert seen[230] == "ok", seen  # and the render itself does fit somewhere


def test_compare_under_any_address_space_limit_ends_in_one_line(tmp_path, started_kib):
    """The issue's study (`ulimit -v 700000`, +333 MiB over mcrt's start here,
    spun at 100% CPU, SIGTERM ignored, until SIGKILL: scipy's OpenBLAS, loaded
    by colour in the middle of the study, retried its work buffer for ever;
    here from 560000 to 620000 KiB, +196 to +254 MiB) ends by itself under
    every cap, in one line or a report: the libraries are loaded before the
    first render, after a check of the address space left. (SIGTERM could not
    end the spin: the retry runs inside a library constructor, which never
    returns to Python; no retry is left to interrupt.)"""
    config = tmp_path / "small.toml"
    config.write_text(study_toml(CHECKERBOARD, name="small"))
    seen = {}
    for delta_mib in (150, 200, 230, 254, 333, 400, 600):
        cap = started_kib + delta_mib * 1024
        done = _under_cap(tmp_path, cap, "-q", "compare", str(config), "-o", f"study{delta_mib}",
                          timeout=150)
        seen[delta_mib] = _ended_in_one_line(done, cap)
        if seen[delta_mib] != "ok":
            assert not (tmp_path / f"study{delta_mib}").exists()  # refused: no folder left
    assert seen[600] == "ok", seen
    for delta_mib in (200, 230, 254):
        assert seen[delta_mib].startswith("mcrt: error: out of memory ("), seen


def test_out_of_memory_is_recognised_in_its_disguises():
    """What a failed allocation looks like when it is not a MemoryError: the
    loader's failed mapping (also as the cause of another import error), ENOMEM,
    C++'s bad_alloc; not a message of ours that merely says "out of memory"."""
    from mcrt.core.memory import is_allocation_failure, out_of_memory_message
    from mcrt.errors import McrtError

    mapped = ImportError("libmitsuba.so: failed to map segment from shared object")
    try:
        try:
            raise mapped
        except ImportError as inner:
            raise ImportError("Encountered an error while initializing the extension.") \
                from inner
    except ImportError as outer:
        assert is_allocation_failure(outer)
    assert is_allocation_failure(OSError(errno.ENOMEM, "Cannot allocate memory"))
    assert is_allocation_failure(RuntimeError("std::bad_alloc"))
    assert not is_allocation_failure(McrtError("lost the cluster (did a task run out of memory?)"))
    assert not is_allocation_failure(RuntimeError("can't start new thread")) or \
        resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY
    assert out_of_memory_message("x").startswith("out of memory (")


def test_sigterm_ends_a_study_under_a_memory_limit(tmp_path, started_kib):
    """SIGTERM at any moment of a study under `ulimit -v` (loading, the
    libraries loaded up front, rendering, writing) ends it within seconds:
    before mcrt's handler is installed by the signal itself, after it as an
    interruption (exit 130, the finished cells kept); nothing spins."""
    import signal
    import time

    config = tmp_path / "small.toml"
    config.write_text(study_toml(CHECKERBOARD, name="small"))
    cap = started_kib + 600 * 1024
    script = f"ulimit -v {cap}; exec \"$0\" \"$@\""
    for delay in (0.3, 0.8, 1.3):
        proc = subprocess.Popen(["bash", "-c", script, str(MCRT), "-q", "compare", str(config),
                                 "-o", f"study{delay}"], cwd=tmp_path, env=_user_env(tmp_path),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(delay)
        proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"SIGTERM after {delay} s under ulimit -v {cap}: still running 20 s later")
        assert proc.returncode in (0, 130, -signal.SIGTERM), (delay, proc.returncode, err)
        assert "Traceback" not in err, err
