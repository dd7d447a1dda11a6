"""Every file mcrt persists (render and adaptive checkpoints,
reference cache states, a study's resume state and images, Poisson-disk tables)
truncated or with random bytes and bits flipped (hypothesis, derandomized) is
detected and set aside with one note, never used and never a crash; the next
run recomputes the work. Temporaries of killed writers are removed safely."""

from __future__ import annotations

import io
import json
import logging
import os
import tempfile
import time
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mcrt.analysis import study
from mcrt.analysis.pass_plan import plan_passes
from mcrt.analysis.reference_cache import load_state, save_state
from mcrt.analysis.study.summary import CellImages, CellRenders
from mcrt.core import atomic
from mcrt.core.job import Checkpoint, Checkpointing, CheckpointPacer, CheckpointStore
from mcrt.core.render import render_film
from mcrt.core.stats import PixelStats
from mcrt.render.adaptive import AdaptiveSettings, render_adaptive
from mcrt.samplers import poisson_tables as pt
from tests.conftest import CHECKERBOARD, FUZZ, TINY_SCENE, run_cli, study_toml

EXAMPLES = FUZZ.__class__(FUZZ, max_examples=40)


def _tiny(tmp: Path, size: int = 32) -> Path:
    path = tmp / "tiny.xml"
    path.write_text(TINY_SCENE.replace('value="32"', f'value="{size}"'))
    return path


def _same(a: Checkpoint, b: Checkpoint) -> bool:
    """Equal as stored: the metadata as JSON (a tuple is saved as a list)."""
    return json.dumps(a.meta, sort_keys=True) == json.dumps(b.meta, sort_keys=True) \
        and a.arrays.keys() == b.arrays.keys() and all(
        a.arrays[k].dtype == b.arrays[k].dtype
        and np.array_equal(a.arrays[k], b.arrays[k], equal_nan=True) for k in a.arrays)


# --------------------------------------------------------------------------- the files


@pytest.fixture(scope="module")
def kinds(tmp_path_factory) -> dict:
    """One valid file of every kind: ``name -> (bytes, load(path) -> content or
    None, content of the valid file, equal(a, b))``."""
    tmp = tmp_path_factory.mktemp("kinds")
    scene = mi.load_file(str(_tiny(tmp)))
    out: dict = {}

    def checkpoint_kind(name: str, checkpoint: Checkpoint, key: str) -> None:
        path = tmp / f"{name}.npz"
        checkpoint.save(path, key)
        out[name] = (path.read_bytes(), lambda p: Checkpoint.load(p, key), checkpoint, _same)

    film = render_film(scene, spp=16, max_lanes=32 * 32 * 4)
    assert film.checkpoint is not None
    checkpoint_kind("render", film.checkpoint, "render-key")
    saved: list[Checkpoint] = []
    render_adaptive(scene, settings=AdaptiveSettings(min_spp=4, max_spp=16),
                    checkpoints=Checkpointing(save=saved.append, every=0))
    checkpoint_kind("adaptive", saved[-1], "adaptive-key")

    plan = plan_passes("independent", 8, 32 * 32, 2)
    rng = np.random.default_rng(1)
    stats = PixelStats(count=np.full((4, 5), 4, np.int64), mean=rng.random((4, 5, 3)),
                       m2=rng.random((4, 5, 3)), nonfinite=np.zeros((4, 5), np.int64))
    for role, done in (("partial", 2), ("finished", 4)):
        path = tmp / f"{role}.npz"
        save_state(path, "ref-key", stats, done, 4, 1.5, complete=done == 4)
        out[f"reference-{role}"] = (
            path.read_bytes(),
            lambda p, c=done == 4: load_state(p, "ref-key", plan, (4, 5), complete=c),
            (stats, done, 1.5),
            lambda a, b: a[1:] == b[1:] and all(np.array_equal(getattr(a[0], f), getattr(
                b[0], f)) for f in ("count", "mean", "m2", "nonfinite")))

    state = study.StudyState(tmp / "study", "study-key")
    images = CellImages(render=rng.random((6, 7, 3)), error=rng.random((6, 7)),
                        std=rng.random((6, 7)))
    views = CellRenders(mean=rng.random((6, 7, 3), np.float32),
                        first=rng.random((6, 7, 3), np.float32),
                        variance=rng.random((6, 7), np.float32))
    state.add({"scene": "s", "sampler": "jittered", "spp_requested": 4, "mse": 0.0052},
              images, 1.0, renders=views)
    out["study-state"] = (state.path.read_bytes(), lambda p: Checkpoint.load(p, "study-key"),
                          Checkpoint.load(state.path, "study-key"), _same)
    image_path = state._image_path("s", "jittered")
    out["study-images"] = (image_path.read_bytes(),
                           lambda p: Checkpoint.load(p, "study-key"),
                           Checkpoint.load(image_path, "study-key"), _same)

    views_path = state._renders_path("s", "jittered", 4)
    out["study-renders"] = (views_path.read_bytes(),
                            lambda p: Checkpoint.load(p, "study-key"),
                            Checkpoint.load(views_path, "study-key"), _same)

    n = 16
    tables = pt.generate(n, pt.n_tables(n), pt.TABLE_SEED).astype(np.float32)
    path = tmp / "tables.npz"
    assert pt._write(path, tables, n)
    out["poisson"] = (path.read_bytes(), lambda p: pt._read(p, n), tables,
                      lambda a, b: a.dtype == b.dtype and np.array_equal(a, b))
    return out


def _damage(data: bytes, how: str, where: int, value: int) -> bytes:
    if how == "truncate":
        return data[:where % len(data)]
    index = where % len(data)
    flip = (1 << (value % 8)) if how == "bit" else (value % 255) + 1
    return data[:index] + bytes([data[index] ^ flip]) + data[index + 1:]


KINDS = ["render", "adaptive", "reference-partial", "reference-finished", "study-state",
         "study-images", "study-renders", "poisson"]


@pytest.mark.parametrize("kind", KINDS)
@EXAMPLES
@given(how=st.sampled_from(["truncate", "byte", "bit"]), where=st.integers(0, 2**31),
       value=st.integers(0, 2**16))
def test_damaged_file_is_never_used(kinds, kind, how, where, value):
    data, load, content, equal = kinds[kind]
    damaged = _damage(data, how, where, value)
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    logger = logging.getLogger("mcrt")
    logger.addHandler(handler)
    try:
        with tempfile.TemporaryDirectory() as directory:
            path = Path(directory) / "file.npz"
            path.write_bytes(damaged)
            found = load(path)  # never raises
            if found is None:  # detected: set aside with one note, never deleted silently
                assert (path.with_name("file.npz.damaged").read_bytes() == damaged
                        and not path.exists())
                notes = [r for r in records if r.levelno >= logging.WARNING]
                assert len(notes) == 1 and str(path) in notes[0].getMessage()
            else:  # accepted: only if its content is exactly the original's
                assert equal(found, content)
    finally:
        logger.removeHandler(handler)


def _forge(original: bytes, path: Path, **members: np.ndarray) -> None:
    """A well-formed file with the original's header (key, checksum) and some
    of its members replaced: what a changed value in a valid-looking file is."""
    with np.load(io.BytesIO(original)) as before:
        arrays = {name: before[name] for name in before.files}
    np.savez(path, **{**arrays, **members})


def test_a_changed_value_is_detected_not_used(kinds, tmp_path):
    """The issue's examples: an ``mse`` changed in a study's state and one
    changed Poisson-disk coordinate (both plausible values, well-formed files)."""
    data, load, good, _ = kinds["study-state"]
    cells = [{**good.meta["cells"][0], "mse": 0.0092}]
    _forge(data, tmp_path / "state.npz",
           meta=np.array(json.dumps({**good.meta, "cells": cells}, sort_keys=True)))
    assert load(tmp_path / "state.npz") is None
    assert (tmp_path / "state.npz.damaged").exists()

    data, load, tables, _ = kinds["poisson"]
    changed = np.array(tables)
    changed[3, 2, 0] = np.float32(changed[3, 2, 0] * 0.9999)  # still a valid spacing
    assert pt._valid(changed, 16)
    _forge(data, tmp_path / "tables.npz", a_tables=changed)
    assert load(tmp_path / "tables.npz") is None
    assert (tmp_path / "tables.npz.damaged").exists()


# --------------------------------------------------------------------------- recomputed


def test_damaged_render_checkpoints_are_recomputed(tmp_path, capsys):
    scene = _tiny(tmp_path, 128)
    for extra in ([], ["--adaptive"]):
        code, _, _ = run_cli(capsys, "-q", "render", str(scene), "--spp", "256", *extra,
                             "-o", str(tmp_path / "whole"))
        assert code == 0
        whole = (tmp_path / "whole.exr").read_bytes()
        checkpoint = tmp_path / ".out.exr.mcrt-resume.npz"
        checkpoint.write_bytes(b"")  # the 0-byte checkpoint
        code, _, err = run_cli(capsys, "render", str(scene), "--spp", "256", *extra,
                               "-o", str(tmp_path / "out"))
        assert code == 0 and "Traceback" not in err
        assert f"{checkpoint} is unreadable" in err and checkpoint.with_name(
            checkpoint.name + ".damaged").exists()
        assert (tmp_path / "out.exr").read_bytes() == whole
        checkpoint.with_name(checkpoint.name + ".damaged").unlink()


def test_damaged_study_images_are_measured_again(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    config = tmp_path / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s"))
    out = tmp_path / "report"
    assert run_cli(capsys, "-q", "compare", str(config), "-o", str(out))[0] == 0
    csv = (out / "results.csv").read_text().splitlines()
    images = sorted((out / study.STATE_DIR).glob("images_*.npz"))
    data = bytearray(images[0].read_bytes())
    data[len(data) // 2] ^= 0x10  # one flipped byte (the BadZipFile)
    images[0].write_bytes(bytes(data))
    code, _, err = run_cli(capsys, "compare", str(config), "-o", str(out))
    assert code == 0 and "Traceback" not in err
    assert f"{images[0]} is" in err and images[0].with_name(images[0].name + ".damaged").exists()
    columns = [line.split(",")[:4] for line in (out / "results.csv").read_text().splitlines()]
    assert columns == [line.split(",")[:4] for line in csv]


# --------------------------------------------------------------------------- temporaries


def test_stale_temporaries_only_ours_only_without_a_live_writer(tmp_path):
    now = time.time()
    dead = 2**22 - 3  # above pid_max's default: no such process
    files = {
        "dead_old": f".a.npz.{dead}-0123abcd.tmp",     # writer gone, untouched: removed
        "dead_fresh": f".b.npz.{dead}-0123abcd.tmp",   # writer gone a moment ago: kept
        "alive_old": f".c.npz.{os.getppid()}-0123abcd.tmp",  # live writer: kept
        "mine": f".d.npz.{os.getpid()}-0123abcd.tmp",  # this process: kept
        "abandoned": ".e.npz.0123abcd.tmp",            # no pid, a day old: removed
        "older_format": ".f.npz.89abcdef.tmp",         # no pid, recent: kept
        "not_ours": ".g.npz.tmp", "plain": "h.npz", "other": ".i.npz.xyz-0123abcd.tmp",
    }
    ages = {"dead_old": 120, "dead_fresh": 5, "alive_old": 7200, "mine": 7200,
            "abandoned": 2 * 86400, "older_format": 3600}
    for role, name in files.items():
        path = tmp_path / name
        path.write_bytes(b"x" * 100)
        age = ages.get(role, 3 * 86400)
        os.utime(path, (now - age, now - age))
    assert atomic.remove_stale_temporaries(tmp_path, now) == 2
    left = {p.name for p in tmp_path.iterdir()}
    assert left == set(files.values()) - {files["dead_old"], files["abandoned"]}


def test_temporary_names_carry_the_writer_pid(tmp_path):
    with atomic.atomic_path(tmp_path / "x.npz") as tmp:
        assert f".x.npz.{os.getpid()}-" in tmp


# --------------------------------------------------------------------------- checkpoints


def test_every_pass_is_checkpointed_when_asked(tmp_path):
    """``save_every=0``: a checkpoint after every finished pass (a kill loses at
    most the pass in flight); the checkpoints resume bit-identically."""
    scene = mi.load_file(str(_tiny(tmp_path)))
    whole = render_film(scene, spp=16, passes=8)
    saved: list[Checkpoint] = []
    render_film(scene, spp=16, passes=8, checkpoints=Checkpointing(save=saved.append, every=0))
    assert [c.meta["done"] for c in saved] == list(range(1, 8))
    for checkpoint in (saved[0], saved[4]):
        resumed = render_film(scene, spp=16, passes=8, checkpoints=Checkpointing(checkpoint))
        assert resumed.image.tobytes() == whole.image.tobytes()


def test_the_pacer_keeps_checkpoints_under_their_budget(monkeypatch):
    clock = [0.0]
    monkeypatch.setattr(time, "perf_counter", lambda: clock[0])
    pacer = CheckpointPacer()
    saves = 0

    def save(_):
        nonlocal saves
        saves += 1
        clock[0] += 0.05  # a checkpoint takes 50 ms

    for _ in range(1000):  # passes of 20 ms
        clock[0] += 0.02
        pacer.maybe(save, lambda: None)
    assert pacer.spent <= 0.02 * clock[0] and saves >= 3


def test_periodic_checkpoints_stop_after_a_failure(tmp_path, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    store = CheckpointStore([blocker / "a.npz"], "k")
    for _ in range(3):
        store.save_periodic(Checkpoint({}, {}))
    assert len([r for r in caplog.records if "checkpoints are off" in r.getMessage()]) == 1


# --------------------------------------------------------------------------- special files


def _special(path: Path, kind: str) -> None:
    """Put a FIFO, a socket, a directory or a link to a device at ``path``."""
    import socket

    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        sock.close()  # the socket file stays
    elif kind == "directory":
        path.mkdir()
    else:
        path.symlink_to("/dev/null")


def _one_error(code: int, err: str) -> str:
    lines = [line for line in err.strip().splitlines() if not line.startswith("mcrt: note:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("kind", ["fifo", "socket", "directory", "device"])
@pytest.mark.parametrize("where", [".img.exr.mcrt-resume.npz", "img.exr", "img.png",
                                   ".ada.exr.mcrt-resume.npz", "ada_spp.png"])
def test_special_files_at_a_render_s_paths_are_refused_up_front(tmp_path, capsys, monkeypatch,
                                                                 kind, where):
    """A FIFO (opening it for reading waited for ever: the render hung), a
    socket, a directory or a device where ``mcrt render`` reads or writes its
    checkpoint or an output: one line before any rendering, and the file is
    left as it was."""
    from mcrt.core import engine

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(engine, "trace_pass", lambda *a, **k: pytest.fail("rendered"))
    monkeypatch.setattr("mcrt.render.adaptive.wavefront.trace_pass",
                        lambda *a, **k: pytest.fail("rendered"))
    scene = _tiny(tmp_path)
    stem = "ada" if where.startswith((".ada", "ada")) else "img"
    extra = ["--adaptive", "--spp", "16"] if stem == "ada" else ["--spp", "4"]
    target = tmp_path / where
    _special(target, kind)
    code, _, err = run_cli(capsys, "-q", "render", str(scene), *extra, "-o", str(tmp_path / stem))
    line = _one_error(code, err)
    assert str(target.name) in line and "not a regular file" in line or \
        "cannot overwrite" in line, line
    assert os.path.lexists(target) and not (tmp_path / f"{stem}.exr.damaged").exists()


@pytest.mark.parametrize("where", [".mcrt-resume/state.npz", ".mcrt-resume/images_x.npz",
                                   ".mcrt-resume-0123/state.npz", "results.csv"])
def test_a_fifo_in_a_study_s_folder_is_refused_up_front(tmp_path, capsys, monkeypatch, where):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    config = tmp_path / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s"))
    fifo = tmp_path / "report" / where
    fifo.parent.mkdir(parents=True)
    os.mkfifo(fifo)
    code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", str(tmp_path / "report"))
    assert "FIFO (named pipe), not a regular file" in _one_error(code, err)
    assert fifo.exists()


def test_checkpoints_never_open_special_files(tmp_path, caplog):
    """Every reader of mcrt's saved state (renders, references, studies, Poisson
    tables) loads through Checkpoint.load: a FIFO there is not opened (that
    waited for ever), not used, not renamed and not replaced."""
    fifo = tmp_path / "state.npz"
    os.mkfifo(fifo)
    with caplog.at_level(logging.INFO, logger="mcrt"):
        assert Checkpoint.load(fifo, "k") is None
    assert f"{fifo} is a FIFO (named pipe), not a checkpoint: not used" in caplog.text
    with pytest.raises(atomic.ImageIOError, match="FIFO"):
        Checkpoint({"done": 1}).save(fifo, "k")
    store = CheckpointStore([fifo, tmp_path / "cache.npz"], "k")
    assert store.load() is None and store.save(Checkpoint({"done": 1})) == tmp_path / "cache.npz"
    store.discard()
    assert fifo.exists() and not (tmp_path / "cache.npz").exists()


# --------------------------------------------------------------------------- unreachable checkpoints


def test_a_checkpoint_no_command_can_resume_is_replaced_once(tmp_path, capsys, monkeypatch):
    """An interrupted render leaves its checkpoint; the scene is then edited in a
    comment only (its key changes: the scene's bytes are part of it). The same
    command line can never resume that checkpoint again, so the next run says
    so once, replaces it and removes it with its own when done; the run after
    that has nothing to say (it used to be "the checkpoint of another render,
    kept" on every run, for ever)."""
    import mcrt.cli.render_cmd as render_cmd
    from mcrt.core import engine

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(engine, "MAX_LANES_PER_PASS", 32 * 32 * 4)  # 16 spp: 4 passes
    scene = _tiny(tmp_path)
    args = ["render", "tiny.xml", "--spp", "16", "-o", "img"]
    checkpoint = tmp_path / ".img.exr.mcrt-resume.npz"
    real = render_cmd.render_film

    def interrupted(*a, on_pass=None, **k):
        def hook(index, count):
            if index == 2:
                raise KeyboardInterrupt
            if on_pass is not None:
                on_pass(index, count)
        return real(*a, on_pass=hook, **k)

    with monkeypatch.context() as patch:
        patch.setattr(render_cmd, "render_film", interrupted)
        code, _, _ = run_cli(capsys, "-q", *args)
    assert code == 130 and checkpoint.is_file()
    scene.write_text(scene.read_text().replace("<scene", "<!-- lit from the left -->\n<scene", 1))

    code, _, err = run_cli(capsys, *args)
    assert code == 0, err
    assert err.count("is the checkpoint of this same command") == 1 and "replaced" in err
    assert "checkpoint of another render" not in err and "resuming" not in err
    assert not checkpoint.exists() and not list((tmp_path / "cache").rglob("*.npz"))
    code, _, err = run_cli(capsys, *args)
    assert code == 0 and "checkpoint" not in err, err

    # Another command line's checkpoint, or this one's made in another directory
    # (its relative paths name other files there), is still kept.
    other = CheckpointStore([checkpoint], "old-key", job="mcrt render tiny.xml --spp 8")
    other.save(Checkpoint({"done": 1, "settings": [8, 2, 0]}))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for job, cwd in (("mcrt render tiny.xml --spp 8", tmp_path), ("same", elsewhere)):
        monkeypatch.chdir(cwd)
        CheckpointStore([checkpoint], "old-key", job=job).save(Checkpoint({"done": 1}))
        monkeypatch.chdir(tmp_path)
        store = CheckpointStore([checkpoint], "new-key", job="same" if cwd == elsewhere
                                else "mcrt render tiny.xml --spp 16")
        assert store.load() is None and store.foreign == {checkpoint}
        store.discard()
        assert checkpoint.exists()
