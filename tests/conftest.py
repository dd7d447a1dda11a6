"""Shared fixtures: mcrt imported (llvm_ad_rgb active, plugins registered)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")
# Small matrix products in the analysis tests run 10-30x slower with OpenBLAS's
# threads competing for 2 cores with Dr.Jit's; one BLAS thread is fastest here.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import mitsuba as mi  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

import mcrt  # noqa: E402,F401  (activates the variant and registers the plugins)
from mcrt.cli import main  # noqa: E402
from mcrt.samplers import registry  # noqa: E402

#: Modules that drive whole programs and real components end to end (Dask clusters, killed and
#: memory-capped processes, full disks, a browser, the notebook, whole studies, the fuzzed
#: command line): every test in them is ``slow``, left out of the everyday tier
#: (``bash scripts/test.sh --fast``, i.e. ``-m "not slow"``); CI runs everything.
END_TO_END_MODULES = frozenset({
    "test_cluster", "test_cluster_faults", "test_cluster_memory", "test_kill_and_resume",
    "test_resource_limits",
    "test_damaged_state_files", "test_report_viewer", "test_notebook", "test_extending",
    "test_fuzz_cli", "test_compare", "test_compare_resume", "test_study_state"})


#: End-to-end modules whose tests kill processes or cluster workers at moments they pick, or cap
#: a process's memory: marked ``serial`` too (as are single tests elsewhere that do so, or that
#: keep both cores busy by themselves), and CI runs them one at a time after the rest (``bash
#: scripts/test.sh``): no other test competes with them for the 2 cores, and theirs with none.
SERIAL_MODULES = frozenset({"test_cluster_faults", "test_cluster_memory", "test_kill_and_resume",
                            "test_resource_limits"})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.stem in END_TO_END_MODULES:
            item.add_marker(pytest.mark.slow)
        if item.path.stem in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)


#: Every sampler plugin mcrt ships, from the one registry: the contract tests run on each.
OUR_SAMPLERS = registry.names("mcrt")


def sampler_params(name: str, spp: int) -> dict:
    """What sampler ``name`` needs outside a render (zsobol: a width; pointset: a file)."""
    return registry.info(name).example_params(spp)

ROOT = Path(__file__).resolve().parents[1]
CHECKERBOARD = ROOT / "scenes" / "checkerboard.xml"

#: Property-based tests: the same examples on every run (derandomized, no database).
FUZZ = settings(derandomize=True, database=None, deadline=None, print_blob=False,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow, HealthCheck.filter_too_much])

#: A valid scene that renders in milliseconds ($spp, $jitter parameters).
TINY_SCENE = """<scene version="3.0.0">
    <default name="spp" value="4"/>
    <default name="jitter" value="0.5"/>
    <integrator type="direct"/>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="jittered">
            <integer name="sample_count" value="$spp"/>
            <float name="jitter" value="$jitter"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="constant"/>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
</scene>
"""


def scene_xml(body: str, integrator: str = '<integrator type="path"/>', size: int = 16,
              origin: str = "0, 0, 4", target: str = "0, 0, 0", fov: float = 40) -> str:
    """A small scene: ``integrator``, a perspective camera at ``origin`` looking at
    ``target`` onto a ``size`` x ``size`` box-filtered film, and ``body`` (shapes,
    emitters)."""
    return f"""<scene version="3.0.0">
    {integrator}
    <sensor type="perspective"><float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="{size}"/>
            <integer name="height" value="{size}"/><rfilter type="box"/></film>
    </sensor>
    {body}
</scene>"""


def study_toml(scene: str | Path, name: str | None = None,
               params: str | None = "{ width = 64, height = 48 }", seeds: int = 2,
               extra: str = "") -> str:
    """A small valid study: jittered and independent at 4 and 16 spp, ``seeds``
    seeds, a 64-spp reference, one scene (with ``params`` as its TOML table, if
    any); ``extra``: more top-level lines (``time_rounds = 2``, say)."""
    return ("\n" + (f'name = "{name}"\n' if name else "")
            + f'spp = [4, 16]\nseeds = {seeds}\nsamplers = ["jittered", "independent"]\n'
            + extra + "[reference]\nspp = 64\n[[scenes]]\n" + f'path = "{scene}"\n'
            + (f"params = {params}\n" if params else ""))


#: Fields of a study's results that are timings (they differ between any two runs).
TIMED_FIELDS = ("seconds", "efficiency", "time", "environment", "date", "cached")


def untimed(value):
    """A study's results (JSON, CSV rows, cells) without their timing fields."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items()
                if not any(word in k for word in TIMED_FIELDS)}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A private, empty mcrt cache directory (``MCRT_CACHE_DIR``)."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def same_stats(a, b) -> None:
    """Two renders' per-pixel moments are equal bit for bit."""
    import numpy as np

    for name in ("count", "mean", "m2", "nonfinite"):
        np.testing.assert_array_equal(getattr(a.stats, name), getattr(b.stats, name),
                                      err_msg=name)


def same_film(a, b) -> None:
    """Two film renders (:class:`~mcrt.core.render.FilmRender`) are equal bit for
    bit: the image (as float32 bit patterns), channels, non-finite counts, sample
    and pass counts, and the checkpoint's sums."""
    import numpy as np

    assert a.image.shape == b.image.shape and a.channels == b.channels
    assert np.array_equal(a.image.view(np.uint32), b.image.view(np.uint32))
    assert np.array_equal(a.nonfinite, b.nonfinite)
    assert (a.spp, a.passes) == (b.spp, b.passes)
    for name, array in a.checkpoint.arrays.items():
        assert np.array_equal(array, b.checkpoint.arrays[name]), name


def png_text_of(path: Path) -> dict[str, str]:
    """A PNG's text chunks (``tEXt``/``iTXt``) as Pillow reads them."""
    from PIL import Image

    with Image.open(path) as image:
        image.load()
        return dict(image.text)  # type: ignore[attr-defined]  (PNG images have .text)


def html_command_of(path: Path) -> str | None:
    """The command an HTML report says made it (the ``<code>`` of its element with
    ``id="command"``), as the standard library's HTML parser reads it."""
    from html.parser import HTMLParser

    class Finder(HTMLParser):
        depth = 0  # inside the element with id="command": the open tags' count
        code = False
        command: str | None = None

        def handle_starttag(self, tag, attrs):
            if self.depth or ("id", "command") in attrs:
                self.depth += 1
            self.code = self.code or (self.depth > 0 and tag == "code")

        def handle_endtag(self, tag):
            self.depth = max(self.depth - 1, 0)
            self.code = self.code and tag != "code"

        def handle_data(self, data):
            if self.code:
                self.command = (self.command or "") + data

    finder = Finder()
    finder.feed(path.read_text(encoding="utf-8"))
    return finder.command


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    """``mcrt ARGV`` in-process: (exit code, stdout, stderr); argparse exits included."""
    try:
        code = main(list(argv))
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def rerun_renders_nothing(capsys, monkeypatch, *argv: str) -> tuple[int, str, str]:
    """``run_cli`` of a command whose work was kept: asserts it exits 0 without
    tracing a single pass (film or adaptive wavefront) and returns its output."""
    from mcrt.core import engine

    traced: list[int] = []
    real = engine.trace_pass

    def counted(*args, **kwargs):
        traced.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(engine, "trace_pass", counted)
    monkeypatch.setattr("mcrt.render.adaptive.wavefront.trace_pass", counted)
    code, out, err = run_cli(capsys, *argv)
    assert code == 0 and traced == [], err  # written without rendering again
    return code, out, err


@contextmanager
def tmpfs(path: Path, size: str) -> Iterator[Path]:
    """A tmpfs of ``size`` (e.g. ``"4m"``) mounted at ``path`` (made), unmounted
    afterwards; the test is skipped where mount(2) is not allowed (not root)."""
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


@pytest.fixture(autouse=True)
def _variant():
    """Every test runs in llvm_ad_rgb with our plugins registered."""
    if mi.variant() != "llvm_ad_rgb":
        mi.set_variant("llvm_ad_rgb")
        mcrt.register()
    yield


def small_cornell(size: int = 32, sampler: str = "independent", spp: int = 16,
                  integrator: dict | None = None, box_filter: bool = False) -> mi.Scene:
    """Mitsuba's Cornell box at a small resolution (fast to render in tests)."""
    scene = mi.cornell_box()
    if box_filter:
        scene["sensor"]["film"]["rfilter"] = {"type": "box"}
    scene["sensor"]["film"]["width"] = size
    scene["sensor"]["film"]["height"] = size
    scene["sensor"]["film"]["component_format"] = "float32"
    # The sampler's example parameters, but the film width: mcrt sets zsobol's own.
    params = {k: v for k, v in sampler_params(sampler, spp).items() if k != "width"}
    scene["sensor"]["sampler"] = {"type": sampler, "sample_count": spp, **params}
    if integrator is not None:
        scene["integrator"] = integrator
    return mi.load_dict(scene)


def stream_lines(stream) -> queue.Queue:
    """The lines of a child process's ``stream``, read on a thread (None at its end):
    a test takes them with ``get(timeout=...)``, a bound against a hang."""
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in stream:
            lines.put(line)
        lines.put(None)
    threading.Thread(target=read, daemon=True).start()
    return lines


def end_holder(process, end: str) -> None:
    """End a child that holds a lock and waits for a line on its stdin: SIGKILL it
    (``end == "killed"``) or send the line, so that it lets go and exits."""
    if end == "killed":
        process.send_signal(signal.SIGKILL)
    else:
        process.stdin.write("\n")
        process.stdin.flush()


@pytest.fixture
def by_value(request):
    """The requesting test module's functions travel to Dask workers by value (the
    workers need not import the tests)."""
    import cloudpickle

    cloudpickle.register_pickle_by_value(request.module)
    yield
    cloudpickle.unregister_pickle_by_value(request.module)
