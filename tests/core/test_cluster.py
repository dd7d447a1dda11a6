"""mcrt on a real Dask ``LocalCluster``: the same bits as in this process.

References and studies are jobs of deterministic tasks folded in task order on
the client, so where a task ran (this process, one worker or another, a worker
that replaced a killed one) never changes a result. These tests run real
worker processes (``local:2``: two processes, one Dr.Jit thread each).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

import mitsuba as mi  # noqa: E402

from mcrt.analysis.reference import get_reference  # noqa: E402
from mcrt.analysis.study import load_config, run_study  # noqa: E402
from mcrt.core.cluster import DaskExecutor  # noqa: E402
from mcrt.core.job import Interrupted  # noqa: E402
from mcrt.core.scene_files import bundle_scene, materialize, scene_digest  # noqa: E402
from mcrt.io import read_exr  # noqa: E402
from tests.conftest import same_stats, study_toml, untimed  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
PARAMS = {"res": "24"}


@pytest.fixture(scope="module")
def cluster():
    executor = DaskExecutor.connect("local:2")
    yield executor
    executor.close()


def test_the_local_dashboard_listens_on_this_machine_only(cluster):
    """A local cluster's dashboard (worker addresses, task names) is bound to the
    loopback interface, not to every interface: every listening socket of its
    port in /proc/net/tcp{,6} has the local address 127.0.0.1."""
    from urllib.parse import urlparse

    link = urlparse(cluster.client.dashboard_link)
    assert link.hostname == "127.0.0.1"
    port = f"{link.port:04X}"
    bound = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                address, _, p = local.partition(":")
                if p == port and state == "0A":  # LISTEN
                    bound.append(address)
    assert bound and all(a == "0100007F" for a in bound), bound


#: Whether a 4 MiB numpy array, made after another one was freed, lives in its own
#: mmap (glibc's mallinfo2: bytes in mmapped blocks) rather than in the reused heap.
MAPPED = """
import ctypes, numpy as np
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                                               "usmblks", "fsmblks", "uordblks", "fordblks",
                                               "keepcost")]
libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = Info
np.ones(1 << 19).sum()
array = np.ones(1 << 19)
mapped = libc.mallinfo2().hblkhd >= array.nbytes
"""


def _mapped() -> bool:
    scope: dict = {}
    exec(MAPPED, scope)
    return bool(scope["mapped"])


def _glibc() -> bool:
    import ctypes

    try:
        return hasattr(ctypes.CDLL("libc.so.6"), "mallinfo2")
    except OSError:
        return False


needs_glibc = pytest.mark.skipif(not _glibc(), reason="glibc 2.33+ (mallopt, mallinfo2) only")


@needs_glibc
@pytest.mark.parametrize("lifted", [False, True])
def test_reuse_freed_memory_lifts_dasks_malloc_trim_threshold(lifted):
    """Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also fixes
    glibc's mmap threshold at 128 KiB: every array above it is mapped afresh
    (and its pages faulted in) however many were freed before. After
    reuse_freed_memory() a freed array's memory is reused."""
    code = ("from mcrt.core.memory import reuse_freed_memory\n"
            "assert reuse_freed_memory() is True\n" if lifted else "") + MAPPED \
        + "print(mapped)"
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True, cwd=ROOT)
    assert done.stdout.split()[-1] == str(not lifted)


@needs_glibc
def test_workers_reuse_the_memory_numpy_frees(cluster):
    """The workers' setup (WorkerSetup) lifts Dask's malloc trim threshold."""
    mapped = cluster.client.run(_mapped)
    assert mapped and not any(mapped.values()), mapped


def test_placement_gives_each_worker_equal_tasks_and_few_groups():
    """3 cells of 5 renders (the study's task order: round by round, cells
    shuffled) on 2 workers: 8 and 7 tasks, 2 cells each (not all 3 on both);
    no workers: no preference."""
    from mcrt.core.cluster import placement

    order = [2, 0, 1]  # round 0's cell order; tasks 3r..3r+2 are round r
    cell = {index: order[index % 3] for index in range(15)}
    where = placement(list(range(15)), cell.__getitem__, ["a", "b"])
    assert sorted(where) == list(range(15))
    tasks = {w: [i for i in where if where[i] == w] for w in "ab"}
    assert sorted(len(t) for t in tasks.values()) == [7, 8]
    assert all(len({cell[i] for i in t}) == 2 for t in tasks.values())
    assert {cell[i] for i in tasks["a"]} >= {2}  # the first cell to appear is a's whole
    assert placement([4, 5], cell.__getitem__, []) == {}
    assert set(placement([4, 5], cell.__getitem__, ["a", "b", "c"]).values()) <= {"a", "b", "c"}


def test_reference_on_a_cluster_is_bit_identical(cluster):
    """8 passes on two worker processes, folded in pass order: the same float64
    moments as the passes run one after the other here."""
    here = get_reference(CORNELL, PARAMS, spp=64, spp_per_pass=8, cache=False)
    there = get_reference(CORNELL, PARAMS, spp=64, spp_per_pass=8, cache=False,
                          executor=cluster)
    assert there.passes == here.passes == 8
    same_stats(here, there)


def test_a_cluster_references_seconds_are_its_wall_time(cluster):
    """Two workers render passes at the same time: the reference's time is the
    wall time of the call, at most, not the workers' times added up (reported
    apart as ``pass_seconds``)."""
    get_reference(CORNELL, PARAMS, spp=16, spp_per_pass=8, cache=False, executor=cluster)  # warm
    start = time.perf_counter()
    ref = get_reference(CORNELL, {"res": "32"}, spp=2048, spp_per_pass=128, cache=False,
                        executor=cluster)
    wall = time.perf_counter() - start
    assert 0 < ref.seconds <= wall
    assert ref.pass_seconds > 0


@pytest.mark.serial  # kills a worker or the cluster at a moment it picks
def test_ctrl_c_on_the_client_keeps_the_passes_and_resumes_without_a_cluster(cluster, cache):
    """Ctrl-C after 3 folded passes (raised on the client, as the terminal would):
    the partial state is in the cache, and the same reference in this process
    resumes after pass 3 and ends equal to an uninterrupted one."""
    def ctrl_c(index: int, passes: int) -> None:
        if index == 2:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stopped:
        get_reference(CORNELL, PARAMS, spp=64, spp_per_pass=8, executor=cluster,
                      on_pass=ctrl_c)
    assert stopped.value.done == 3
    resumed = get_reference(CORNELL, PARAMS, spp=64, spp_per_pass=8)
    assert resumed.resumed_passes == 3
    same_stats(resumed, get_reference(CORNELL, PARAMS, spp=64, spp_per_pass=8, cache=False))


def _tiny_study(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(study_toml(CORNELL, name="tiny", params="{ res = 32 }", seeds=3,
                               extra="image_spp = 16\n"))
    return path


def _cells(result) -> list:
    return untimed([dict(cell) for cell in result.cells])


@pytest.mark.serial  # kills a worker or the cluster at a moment it picks
def test_a_worker_killed_in_the_middle_of_a_study_changes_nothing(tmp_path, cache):
    """A study's seeds run on two workers; one worker process is SIGKILLed while
    tasks run. Dask runs its tasks again (on the other worker or the one that
    replaces it): every cell's numbers equal those of the study run here."""
    config = load_config(_tiny_study(tmp_path))
    here = run_study(config)
    executor = DaskExecutor.connect("local:2")
    killed: list[int] = []

    def kill_one_worker() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            running = [key for keys in executor.client.processing().values() for key in keys]
            if any("cornell_box/" in str(key) for key in running):  # a seed task runs
                pids = executor.client.run(os.getpid)
                pid = sorted(pids.values())[0]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_worker, daemon=True)
    try:
        killer.start()
        there = run_study(config, executor=executor)
        killer.join(timeout=5)
    finally:
        executor.close()
    assert killed, "no worker was killed: the test did not test anything"
    assert _cells(there) == _cells(here)


def _mcrt(*args: str, env: dict | None = None, cwd: Path | None = None
          ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mcrt", *args], capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})}, cwd=cwd)


def test_reference_command_writes_the_same_exr_with_a_cluster(tmp_path, cache):
    """`mcrt reference --cluster local:2` and without: the same EXR layers."""
    common = [str(CORNELL), "-D", "res=16", "--spp", "32", "--spp-per-pass", "8",
              "--no-cache"]
    here = _mcrt("-q", "reference", *common, "-o", str(tmp_path / "here.exr"))
    there = _mcrt("-q", "reference", *common, "--cluster", "local:2",
                  "-o", str(tmp_path / "there.exr"))
    assert here.returncode == 0, here.stderr
    assert there.returncode == 0, there.stderr
    (a, meta_a), (b, meta_b) = read_exr(tmp_path / "here.exr"), read_exr(tmp_path / "there.exr")
    assert a.keys() == b.keys() and meta_a == meta_b  # the header holds no timings
    for layer in a:
        np.testing.assert_array_equal(a[layer], b[layer], err_msg=layer)


@pytest.mark.parametrize("address, message", [
    ("tcp://127.0.0.1:9", "cannot reach the Dask scheduler at tcp://127.0.0.1:9"),
    ("nowhere", "expected 'local', 'local:N' or a scheduler address"),
    ("local:0", "at least 1 worker"),
])
def test_a_bad_cluster_is_one_line_before_any_work(tmp_path, cache, address, message):
    out = tmp_path / "ref.exr"
    done = _mcrt("reference", str(CORNELL), "-D", "res=16", "--spp", "16", "-o", str(out),
                 env={"MCRT_CLUSTER": address, "MCRT_CLUSTER_TIMEOUT": "2"})
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("mcrt: error: ") and message in lines[0]
    assert not out.exists() and not (cache / "references").exists()


def test_without_a_cluster_dask_is_not_imported(tmp_path, cache):
    code = ("import sys\nfrom mcrt.cli import main\n"
            f"assert main(['-q', 'reference', {str(CORNELL)!r}, '-D', 'res=8', '--spp', '4', "
            f"'--no-cache', '-o', {str(tmp_path / 'r.exr')!r}]) == 0\n"
            "assert 'distributed' not in sys.modules and 'dask' not in sys.modules\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "MCRT_CLUSTER": ""})
    assert done.returncode == 0, done.stderr


def test_a_scene_travels_with_its_files(tmp_path):
    """A scene naming a mesh in a sibling folder (``../meshes/...``) is bundled
    with it; written elsewhere, it has the same content digest (what a worker
    without the client's files renders)."""
    (tmp_path / "scene").mkdir()
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    xml = tmp_path / "scene" / "s.xml"
    xml.write_text('<scene version="3.0.0"><default name="mesh" value="tri"/>'
                   '<shape type="obj"><string name="filename" '
                   'value="../meshes/$mesh.obj"/></shape></scene>')
    bundle = bundle_scene(xml)
    assert sorted(name for name, _ in bundle.files) == ["meshes/tri.obj", "scene/s.xml"]
    copy = materialize(bundle, tmp_path / "worker")
    assert copy != xml and copy.name == "s.xml"
    assert scene_digest(copy) == scene_digest(xml) == bundle.digest
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    assert scene_digest(xml) != bundle.digest  # a changed mesh is another scene


def test_files_found_through_a_search_path_travel_too(tmp_path):
    """A mesh named by its bare file name and found through ``<path value="meshes"/>``
    (Mitsuba looks in such folders before the scene's own) is in the bundle and in
    the digest, and the copy finds it the same way: Mitsuba builds it."""
    (tmp_path / "scene" / "meshes").mkdir(parents=True)
    (tmp_path / "scene" / "tri.obj").write_text("v 0 0 0\nv 9 0 0\nv 0 9 0\nf 1 2 3\n")
    (tmp_path / "scene" / "meshes" / "tri.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    xml = tmp_path / "scene" / "s.xml"
    xml.write_text('<scene version="3.0.0"><path value="meshes"/><shape type="obj" id="t">'
                   '<string name="filename" value="tri.obj"/></shape></scene>')
    bundle = bundle_scene(xml)
    assert sorted(name for name, _ in bundle.files) == ["meshes/tri.obj", "s.xml"]
    copy = materialize(bundle, tmp_path / "worker")
    assert scene_digest(copy) == scene_digest(xml) == bundle.digest
    area = mi.load_file(str(copy)).shapes()[0].surface_area()
    assert float(area[0]) == pytest.approx(0.5)  # the search path's triangle, not 9x9
    (tmp_path / "scene" / "meshes" / "tri.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    assert scene_digest(xml) != bundle.digest


def test_an_included_files_mesh_is_the_main_scenes_folders(tmp_path):
    """Mitsuba resolves a nested ``<include>`` relative to the file that includes it,
    but a mesh an included file names relative to the main scene's folder; the walk
    behind digests and bundles does the same (a same-named file beside the include
    is not the scene's)."""
    for folder in ("scene", "parts"):
        (tmp_path / folder).mkdir()
    (tmp_path / "scene" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "parts" / "tri.obj").write_text("v 0 0 0\nv 9 0 0\nv 0 9 0\nf 1 2 3\n")
    (tmp_path / "parts" / "inner.xml").write_text(
        '<scene version="3.0.0"><shape type="obj"><string name="filename" value="tri.obj"/>'
        '</shape></scene>')
    (tmp_path / "parts" / "outer.xml").write_text(
        '<scene version="3.0.0"><include filename="inner.xml"/></scene>')
    xml = tmp_path / "scene" / "s.xml"
    xml.write_text('<scene version="3.0.0"><include filename="../parts/outer.xml"/></scene>')
    area = mi.load_file(str(xml)).shapes()[0].surface_area()
    assert float(area[0]) == pytest.approx(0.5)  # scene/tri.obj
    bundle = bundle_scene(xml)
    assert sorted(name for name, _ in bundle.files) == [
        "parts/inner.xml", "parts/outer.xml", "scene/s.xml", "scene/tri.obj"]
    before = scene_digest(xml)
    (tmp_path / "parts" / "tri.obj").write_text("v 0 0 0\nv 8 0 0\nv 0 9 0\nf 1 2 3\n")
    assert scene_digest(xml) == before
    (tmp_path / "scene" / "tri.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    assert scene_digest(xml) != before


def test_the_quick_study_on_local_2_equals_in_process(tmp_path, cache):
    """The quick study's scenes and samplers (configs/quick.toml, at a smaller size:
    two sample counts, two seeds, smaller images and reference) in this process and
    on `local:2` (references shared through the cache): results.json and results.csv
    equal apart from times, every other column bit for bit (as written: repr of floats)."""
    text = (ROOT / "configs" / "quick.toml").read_text()
    for old, new in (("spp = [4, 16, 64]", "spp = [4, 16]"), ("seeds = 3", "seeds = 2"),
                     ("spp = 1024 ", "spp = 256 "), ("params = { res = 64 }",
                                                      "params = { res = 24 }"),
                     ('checkerboard.xml"', 'checkerboard.xml"\nparams = { width = 80, height = 60 }'),
                     ('"../scenes/', f'"{ROOT / "scenes"}/')):
        assert old in text, old
        text = text.replace(old, new)
    quick = tmp_path / "quick.toml"
    quick.write_text(text)
    here = _mcrt("-q", "compare", str(quick), "-o", str(tmp_path / "here"))
    assert here.returncode == 0, here.stderr[-2000:]
    there = _mcrt("-q", "compare", str(quick), "-o", str(tmp_path / "there"), "--cluster",
                  "local:2")
    assert there.returncode == 0, there.stderr[-2000:]
    a = json.loads((tmp_path / "here" / "results.json").read_text())
    b = json.loads((tmp_path / "there" / "results.json").read_text())
    assert untimed(a) == untimed(b)
    rows = [untimed(list(csv.DictReader((tmp_path / d / "results.csv").open())))
            for d in ("here", "there")]
    assert len(rows[0]) == 20 and rows[0] == rows[1]  # 2 scenes x 5 samplers x 2 spp
    untimed_columns = set(rows[0][0])
    assert {"aliasing_ratio", "aliasing_ratio_z", "mse", "bias", "verdict"} <= untimed_columns


@pytest.mark.serial  # kills a worker or the cluster at a moment it picks
def test_a_scheduler_that_goes_away_is_one_error_and_the_passes_are_kept(cache):
    """The cluster closes after the reference's second pass is folded: the job
    ends with one McrtError naming the cluster; the folded passes are in the
    cache and the same reference in this process resumes after them.

    The one worker runs the passes in an order Dask picks, and a client that
    already holds every result when it closes the cluster has nothing left to
    lose (the job then rightly finishes). So the passes are many and not tiny
    (32 of 64x64 pixels x 8 spp): at the close most of them are still to run,
    which the test checks before it looks at the error."""
    from distributed import LocalCluster

    from mcrt.errors import McrtError

    local = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                         dashboard_address=":0")
    executor = DaskExecutor.connect(local.scheduler_address)
    params = {"res": "64"}
    left_at_close: list[int] = []

    def close_cluster(index: int, passes: int) -> None:
        if index == 1:
            futures = executor.client.futures.values()
            left_at_close.append(sum(f.status != "finished" for f in futures))
            local.close()

    try:
        with pytest.raises(McrtError, match="lost the Dask scheduler") as lost:
            get_reference(CORNELL, params, spp=256, spp_per_pass=8, executor=executor,
                          on_pass=close_cluster)
        assert "\n" not in str(lost.value) and "run the same command again" in str(lost.value)
    finally:
        executor.close()
        local.close()
        assert left_at_close and left_at_close[0] > 0, "every pass had run before the close"
    resumed = get_reference(CORNELL, params, spp=256, spp_per_pass=8)
    assert resumed.resumed_passes >= 2
    same_stats(resumed, get_reference(CORNELL, params, spp=256, spp_per_pass=8, cache=False))


@pytest.mark.parametrize("sampler", ["sobol", "independent", "scene's seeded jittered"])
def test_render_passes_on_a_cluster_write_the_same_exr(tmp_path, cache, sampler):
    """`mcrt render --cluster local:2`: each pass is a task whose sums the client
    adds in pass order: the same EXR (layers and header) as in one process. Mitsuba's
    `independent` is seeded afresh by every pass, so a worker starts any pass too
    (the default sampler of most scenes; it was once refused). A scene's own
    sampler with an authored seed property renders with it on the workers too."""
    common = [str(CORNELL), "-D", "res=128", "--spp", "256", "--sampler", sampler]
    if sampler.startswith("scene"):
        seeded = tmp_path / "seeded.xml"
        seeded.write_text(CORNELL.read_text().replace(
            '<integer name="sample_count" value="$spp"/>',
            '<integer name="sample_count" value="$spp"/><integer name="seed" value="5"/>'))
        common = [str(seeded), "-D", "res=128", "--spp", "256"]
    here = _mcrt("-q", "render", *common, "-o", str(tmp_path / "here"))
    there = _mcrt("-q", "render", *common, "--cluster", "local:2", "-o", str(tmp_path / "there"))
    assert here.returncode == 0, here.stderr
    assert there.returncode == 0, there.stderr
    assert "passes 4" in there.stdout  # 4 tasks of 2^20 lanes
    (a, meta_a), (b, meta_b) = read_exr(tmp_path / "here.exr"), read_exr(tmp_path / "there.exr")
    assert a.keys() == b.keys() and meta_a == meta_b
    for layer in a:
        np.testing.assert_array_equal(a[layer], b[layer], err_msg=layer)


def test_an_interrupted_cluster_render_resumes_without_the_cluster(tmp_path, cache):
    """SIGINT to `mcrt render --cluster local:2` once a checkpoint is written
    (after every pass here); the same command without --cluster resumes from it
    and writes the image an uninterrupted render writes."""
    common = [str(CORNELL), "-D", "res=128", "--spp", "1024", "--sampler", "jittered"]
    env = {**os.environ, "MCRT_CHECKPOINT_SECONDS": "0"}
    out = tmp_path / "img"
    process = subprocess.Popen([sys.executable, "-m", "mcrt", "-q", "render", *common,
                                "--cluster", "local:2", "-o", str(out)], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    checkpoint = tmp_path / ".img.exr.mcrt-resume.npz"
    deadline = time.monotonic() + 300
    while not checkpoint.exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 130, err
    assert checkpoint.exists()
    resumed = _mcrt("-q", "render", *common, "-o", str(out), env=env)
    assert resumed.returncode == 0, resumed.stderr
    full = _mcrt("-q", "render", *common, "-o", str(tmp_path / "full"))
    assert full.returncode == 0, full.stderr
    a, b = read_exr(out.with_suffix(".exr"))[0], read_exr(tmp_path / "full.exr")[0]
    for layer in b:
        np.testing.assert_array_equal(a[layer], b[layer], err_msg=layer)


def test_a_sampler_with_random_state_is_refused_on_a_cluster(tmp_path, cache):
    """Mitsuba's samplers cannot start at pass k: --cluster refuses them in one
    line before any work; $MCRT_CLUSTER alone renders them here, with a note."""
    common = [str(CORNELL), "-D", "res=16", "--spp", "4", "--sampler", "stratified"]
    refused = _mcrt("render", *common, "--cluster", "local:2", "-o", str(tmp_path / "a"))
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 2 and len(lines) == 1, refused.stderr
    assert "stratified carries its random state" in lines[0]
    assert not (tmp_path / "a.exr").exists()
    here = _mcrt("render", *common, "-o", str(tmp_path / "b"), env={"MCRT_CLUSTER": "local:2"})
    assert here.returncode == 0 and (tmp_path / "b.exr").exists(), here.stderr
    assert "rendering in this process, not on $MCRT_CLUSTER" in here.stderr
