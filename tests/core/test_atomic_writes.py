"""Every kind of output file survives a crash or an interrupt in the middle of its write.

For one representative writer of each kind (report HTML, CSV, JSON; matplotlib
plots; PNG and EXR images; the Poisson table cache; the study's resume state)
the serialiser is made to write part of its data and then raise
(``KeyboardInterrupt``, as Ctrl-C would, or ``OSError(ENOSPC)``, a full disk):
the previous good file must be byte-identical afterwards, no temporary file
may be left behind, and a full disk must surface as a one-line McrtError. One
test SIGKILLs a real writer process mid-write (no Python cleanup at all).
The report is written from a synthetic study result (no rendering): ~5 s.
"""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mcrt.analysis.report as report
import mcrt.analysis.study as study
import mcrt.core.jsonfile as jsonfile
import mcrt.core.state_file as state_file
from mcrt.analysis.study.summary import CellScores, ReferenceImage
from mcrt.core.stats import PixelStats
from mcrt.errors import McrtError
from tests.conftest import CHECKERBOARD, study_toml

CONFIG = study_toml(CHECKERBOARD, name="synthetic")


def synthetic_result(tmp_path: Path, done: int | None = None) -> study.StudyResult:
    """A StudyResult built by the study's own summariser from synthetic images
    (reference + Gaussian noise of sd 0.1 / sqrt(spp)): every report writer can
    run on it without rendering. ``done`` cells of the 4 (default all)."""
    path = tmp_path / "synthetic.toml"
    path.write_text(CONFIG)
    config = study.load_config(path, check_scenes=False)
    rng = np.random.default_rng(7)
    h, w = 48, 64
    ref = rng.random((h, w, 3))
    ref_var = np.full_like(ref, 1e-6)
    floor = float(ref_var.mean())
    cells, images = [], {}
    for scene, label, spp in study.cell_keys(config)[:done]:
        sampler = next(s for s in config.samplers if s.label == label)
        renders = [ref + rng.normal(0.0, 0.1 / np.sqrt(spp), ref.shape) for _ in config.seeds]
        per_seed = [{"seed": s, "spp": spp, "seconds": 1e-3 * spp * (1 + 0.1 * s),
                     "mse": float(np.mean((r - ref) ** 2)), "rel_mse": 0.1, "delta_e": 1.0,
                     "mean_error": float(np.mean(r - ref)), "nonfinite": 0,
                     "aliasing": {"ratio": 1.0, "ratio_z": 0.1, "peak": 2.0, "peak_z": -0.2}}
                    for s, r in zip(config.seeds, renders, strict=True)]
        stats = PixelStats.from_images(renders)
        cells.append(study.summarise_cell(CellScores(scene, sampler, spp, per_seed, stats),
                                          ReferenceImage(ref, ref_var, floor)))
        if spp == config.image_spp:
            images[(scene, label)] = study.CellImages(
                render=renders[0].astype(np.float32),
                error=(renders[0] - ref).mean(axis=-1).astype(np.float32),
                std=np.sqrt(stats.variance.mean(axis=-1)).astype(np.float32))
    references = {"checkerboard": study.ReferenceInfo("checkerboard", 64, "independent", 1.0,
                                                      floor, 1e-5, w, h)}
    fits = [study.fit_sampler("checkerboard", s.label, cells) for s in config.samplers]
    env = {"mcrt": "test", "mitsuba": "-", "drjit": "-", "variant": "-", "python": "-",
           "platform": "-", "cpus": 2, "started": "-"}
    return study.StudyResult(config=config, references=references, cells=cells, fits=fits,
                             reference_images={"checkerboard": ref}, images=images,
                             environment=env, seconds=1.0)


@pytest.fixture(scope="module")
def good_report(tmp_path_factory):
    """A complete report directory and the bytes of each of its files."""
    tmp = tmp_path_factory.mktemp("report")
    files = report.write_report(synthetic_result(tmp), tmp / "out")
    return tmp, files, {key: path.read_bytes() for key, path in files.items()}


def _dying(real_write, error: BaseException):
    """A write() that writes the first half of its data, then raises ``error``."""
    def write(data):
        real_write(data[: max(1, len(data) // 2)])
        raise error
    return write


class DyingFile:
    """A real file whose writes die half-way (see :func:`_dying`)."""

    def __init__(self, f, error: BaseException):
        self._f = f
        self.write = _dying(f.write, error)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()
        return False


def dying_open(error: BaseException, only: str = ""):
    """An ``open`` whose files (those whose name contains ``only``) die mid-write."""
    def fake(file, mode="r", *args, **kwargs):
        f = open(file, mode, *args, **kwargs)  # noqa: SIM115 (returned to the caller, who closes it)
        if "w" in mode and only in os.path.basename(os.fspath(file)):
            return DyingFile(f, error)
        return f
    return fake


ERRORS = [KeyboardInterrupt(), OSError(errno.ENOSPC, "No space left on device")]


def _check(directory: Path, before: dict[Path, bytes], raised, error: BaseException) -> None:
    for path, data in before.items():
        assert path.read_bytes() == data, f"{path.name} was damaged"
    assert not [p for p in directory.iterdir() if p.name.endswith(".tmp")], "temporary file left"
    if isinstance(error, KeyboardInterrupt):
        assert raised.type is KeyboardInterrupt
    else:  # a full disk is a one-line user-facing error naming the file
        assert issubclass(raised.type, McrtError)
        message = str(raised.value)
        assert "no space left on device" in message and "\n" not in message


@pytest.mark.slow
@pytest.mark.parametrize("error", ERRORS, ids=["ctrl-c", "disk-full"])
@pytest.mark.parametrize("kind, only", [("csv", "results.csv"), ("json", "results.json"),
                                        ("report", "report.html")])
def test_report_data_files(good_report, monkeypatch, kind, only, error):
    """results.csv, results.json and report.html (each written by ``open`` in
    mcrt.analysis.report or, the JSON, mcrt.core.jsonfile) die half-way: the
    previous files stay as they were."""
    tmp, files, _ = good_report
    before = {p: p.read_bytes() for p in files.values()}
    for module in (report, jsonfile):
        monkeypatch.setattr(module, "open", dying_open(error, only), raising=False)
    (tmp / kind).mkdir(exist_ok=True)
    result = synthetic_result(tmp / kind, done=2)  # different content: a partial study
    writer = {"csv": lambda: report.write_results_csv(result, files["csv"]),
              "json": lambda: report.write_results_json(result, files["json"]),
              "report": lambda: report.write_report(result, files["report"].parent)}[kind]
    with pytest.raises((KeyboardInterrupt, McrtError)) as raised:
        writer()
    if kind != "report":
        _check(files["report"].parent, before, raised, error)
        return
    # write_report writes the data and plots first, each atomically: they may be
    # new (complete) files; report.html, which died, must be the old one.
    assert files["report"].read_bytes() == before[files["report"]]
    _check(files["report"].parent, {files["report"]: before[files["report"]]}, raised, error)


@pytest.mark.parametrize("error", ERRORS, ids=["ctrl-c", "disk-full"])
def test_plot(good_report, monkeypatch, error):
    """A matplotlib figure (save_figure) dies half-way through its PNG."""
    from matplotlib.figure import Figure

    from mcrt.analysis.plots import new_figure, save_figure

    _, files, _ = good_report
    path = files["error_vs_spp"]
    before = {path: path.read_bytes()}
    real = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        real(self, fname, *args, **kwargs)
        with open(fname, "r+b") as f:  # keep half of it, as a killed writer would
            f.truncate(os.path.getsize(fname) // 2)
        raise error

    monkeypatch.setattr(Figure, "savefig", savefig)
    fig = new_figure(2, 2)
    fig.add_subplot().plot([0, 1], [1, 0])
    with pytest.raises((KeyboardInterrupt, McrtError)) as raised:
        save_figure(fig, path)
    _check(path.parent, before, raised, error)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "kill"])
def test_a_signal_in_the_middle_of_drawing_lets_the_plot_finish(tmp_path, signum):
    """The signal arrives while matplotlib draws (an artist sends it to this
    process): the PNG is still written whole, and the interrupt comes after it as
    a KeyboardInterrupt. Raised inside the drawing, it once surfaced as matplotlib's
    "ValueError: Invalid affine transformation matrix" (a traceback from a killed
    ``mcrt compare``), with no file."""
    from matplotlib.lines import Line2D
    from PIL import Image

    from mcrt.analysis.plots import new_figure, save_figure
    from mcrt.core.engine import termination_as_interrupt

    class Interrupting(Line2D):
        def draw(self, renderer):
            os.kill(os.getpid(), signum)
            for _ in range(1000):  # the handler runs between bytecodes, in here
                pass
            super().draw(renderer)

    fig = new_figure(2, 2)
    ax = fig.add_subplot()
    ax.add_line(Interrupting([0, 1], [1, 0]))
    ax.plot([0, 1], [0, 1], label="a line")
    ax.legend(loc="best")  # the drawing step that turned the interrupt into a ValueError
    path = tmp_path / "plot.png"
    with termination_as_interrupt(), pytest.raises(KeyboardInterrupt):
        save_figure(fig, path)
    with Image.open(path) as image:
        assert image.size == (240, 240)
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize("error", ERRORS, ids=["ctrl-c", "disk-full"])
def test_png_image(tmp_path, monkeypatch, error):
    import mcrt.io.png as png_module
    from mcrt.io import write_png

    path = tmp_path / "image.png"
    write_png(path, np.full((8, 8, 3), 0.5, np.float32))
    before = {path: path.read_bytes()}
    real = png_module._png_chunks

    def chunks(rgb8, text=None):  # the whole file, then the failure (before the rename)
        yield from real(rgb8, text)
        raise error

    monkeypatch.setattr(png_module, "_png_chunks", chunks)
    with pytest.raises((KeyboardInterrupt, McrtError)) as raised:
        write_png(path, np.zeros((8, 8, 3), np.float32))
    _check(tmp_path, before, raised, error)


@pytest.mark.parametrize("error", ERRORS, ids=["ctrl-c", "disk-full"])
def test_exr_image(tmp_path, monkeypatch, error):
    import OpenEXR

    from mcrt.io import read_exr, write_exr

    path = tmp_path / "image.exr"
    write_exr(path, {"rgb": np.full((8, 8, 3), 0.5, np.float32)}, {"spp": 4})
    before = {path: path.read_bytes()}

    class File:  # OpenEXR.File, whose write dies after half of the file
        def __init__(self, *args):
            self._file = OpenEXR.File(*args)

        def write(self, name):
            self._file.write(name)
            with open(name, "r+b") as f:
                f.truncate(os.path.getsize(name) // 2)
            raise error

    shim = type("OpenEXRShim", (), {k: getattr(OpenEXR, k) for k in dir(OpenEXR)
                                    if not k.startswith("__")})
    shim.File = File
    monkeypatch.setitem(sys.modules, "OpenEXR", shim)  # write_exr imports it when called
    with pytest.raises((KeyboardInterrupt, McrtError)) as raised:
        write_exr(path, {"rgb": np.zeros((8, 8, 3), np.float32)}, {"spp": 8})
    _check(tmp_path, before, raised, error)
    monkeypatch.undo()
    assert read_exr(path)[1]["spp"] == 4


@pytest.mark.parametrize("error", ERRORS, ids=["ctrl-c", "disk-full"])
def test_study_state(tmp_path, monkeypatch, error):
    """The resume state dies half-way through state.json: the saved cells stay."""
    state = study.StudyState(tmp_path / "out" / study.STATE_DIR, "key")
    state.add({"scene": "checkerboard", "sampler": "jittered", "spp_requested": 4}, None, 1.0)
    before = {state.path: state.path.read_bytes()}
    monkeypatch.setattr(state_file, "open", dying_open(error, "state.npz"), raising=False)
    with pytest.raises((KeyboardInterrupt, McrtError)) as raised:
        state.save(2.0)
    _check(state.directory, before, raised, error)


def test_poisson_table_cache(tmp_path, monkeypatch):
    """The Poisson table cache is best effort: a Ctrl-C mid-write propagates
    (the user asked to stop) but leaves neither a torn table nor a temporary file."""
    import mcrt.samplers.poisson_tables as pt

    path = tmp_path / "tables.npz"
    good = np.arange(12, dtype=np.float32).reshape(1, 6, 2) / 12
    assert pt._write(path, good)
    before = {path: path.read_bytes()}
    real = np.savez

    def dying_save(f, **arrays):
        real(f, **arrays)
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", dying_save)
    with pytest.raises(KeyboardInterrupt) as raised:
        pt._write(path, good * 0.5)
    _check(tmp_path, before, raised, KeyboardInterrupt())


_KILLED_WRITER = r"""
import sys, time
from mcrt.core.atomic import atomic_path
with atomic_path(sys.argv[1]) as tmp, open(tmp, "w") as f:
    for i in range(100000):
        f.write("new line %d\n" % i)
        f.flush()
        if i == 100:
            print("writing", flush=True)
        time.sleep(0.001)
"""


def test_sigkill_mid_write_leaves_the_previous_file(tmp_path):
    """No cleanup code runs on SIGKILL: the rename is what protects the file
    (a hidden ``.<name>.*.tmp`` may remain, never a torn ``<name>``)."""
    path = tmp_path / "results.csv"
    path.write_text("previous good content\n")
    child = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(path)],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "writing"
        temporary = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
        assert len(temporary) == 1 and temporary[0].stat().st_size > 0  # mid-write
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    assert path.read_text() == "previous good content\n"
    # The leftover temporary file is hidden and never matched by *.csv.
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == [path.name]
