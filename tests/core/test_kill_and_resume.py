"""SIGKILL and SIGTERM at random moments (fixed seeds) of `render`,
`render --adaptive`, `reference` and `compare` (real subprocesses on tiny
scenes): the next run resumes from the last checkpoint and ends bit-identical
to an uninterrupted run; no temporary file of a killed writer survives it."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mcrt.io import read_exr
from tests.conftest import CHECKERBOARD, TINY_SCENE, study_toml

#: (signal, seed of the delay after the first checkpoint appeared) per command.
KILLS = [(signal.SIGKILL, 1), (signal.SIGKILL, 2), (signal.SIGTERM, 3)]


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "MCRT_CACHE_DIR": str(tmp / "cache"), "MCRT_CHECKPOINT_SECONDS": "0",
            "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}


def _mcrt(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    """``mcrt ARGS`` with its notes (progress bars are off without a terminal... or
    harmless: only the notes are looked at)."""
    return subprocess.run([sys.executable, "-m", "mcrt", *args], cwd=tmp, env=_env(tmp),
                          capture_output=True, text=True, timeout=120)


def _killed(tmp: Path, args: list[str], checkpoint, sig: int, seed: int,
            span: float) -> tuple[int, str]:
    """Run ``mcrt ARGS``; once ``checkpoint()`` exists, wait a random time in
    ``[0, span)`` (seeded) and send ``sig``. Returns (exit status, its output)."""
    child = subprocess.Popen([sys.executable, "-m", "mcrt", "-q", *args], cwd=tmp,
                             env=_env(tmp), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    try:
        deadline = time.monotonic() + 60
        while checkpoint() is None and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(random.Random(seed).uniform(0.0, span))
        if child.poll() is None:
            child.send_signal(sig)
        err, _ = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    return child.returncode, err


def _check_stop(code: int, err: str, sig: int) -> None:
    assert "Traceback" not in err, err
    if sig == signal.SIGTERM:
        assert code in (0, 130), err  # 0: it finished before the signal came
        if code == 130:
            assert "interrupted" in err
    else:
        assert code in (0, -signal.SIGKILL), err


def _age_temporaries(*directories: Path) -> list[Path]:
    """Temporary files a SIGKILL left: made old enough for the next run to remove."""
    found = [p for d in directories if d.is_dir() for p in d.rglob(".*.tmp")]
    for path in found:
        os.utime(path, (time.time() - 3600, time.time() - 3600))
    return found


def _meta(path: Path | None) -> dict | None:
    if path is None or not path.is_file():
        return None
    with np.load(path) as data:
        return json.loads(str(data["meta"]))


def _first(paths) -> Path | None:
    return next(iter(sorted(paths)), None)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("scene")
    path = directory / "t128.xml"
    path.write_text(TINY_SCENE.replace('value="32"', 'value="128"'))
    return path


@pytest.mark.parametrize("adaptive", [False, True], ids=["render", "adaptive"])
def test_render_killed_resumes_bit_identically(tmp_path, scene, adaptive):
    extra = ["--adaptive", "--spp", "1024"] if adaptive else ["--spp", "1024"]
    whole = _mcrt(tmp_path, "render", str(scene), *extra, "-o", "whole")
    assert whole.returncode == 0, whole.stderr
    expected = (tmp_path / "whole.exr").read_bytes()
    stopped = 0
    for sig, seed in KILLS:
        out = tmp_path / f"k{seed}"
        ckpt = tmp_path / f".k{seed}.exr.mcrt-resume.npz"
        code, err = _killed(tmp_path, ["render", str(scene), *extra, "-o", out.name],
                            lambda p=ckpt: p if p.exists() else None, sig, seed, 0.6)
        _check_stop(code, err, sig)
        stale = _age_temporaries(tmp_path)
        meta = _meta(ckpt)
        if code != 0 and meta is None:  # killed after it finished (exiting takes a while)
            assert out.with_suffix(".exr").read_bytes() == expected, "no checkpoint kept"
        done = meta and (meta.get("done") if not adaptive else meta.get("next_pass"))
        again = _mcrt(tmp_path, "render", str(scene), *extra, "-o", out.name)
        assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
        if meta is not None and not adaptive:
            assert f"resuming after pass {done} of" in again.stderr
        if meta is not None and adaptive:
            assert f"resuming after adaptive pass {done}" in again.stderr
        assert out.with_suffix(".exr").read_bytes() == expected  # bit-identical
        assert not ckpt.exists()  # deleted once the outputs are written
        assert not [p for p in stale if p.exists()], "a killed writer's temporary file stayed"
        stopped += meta is not None
    assert stopped >= 2, "the signals came too late to test anything"


def test_reference_killed_resumes_bit_identically(tmp_path, scene):
    args = ["reference", str(scene), "--spp", "1024", "--spp-per-pass", "64"]
    whole = _mcrt(tmp_path, *args, "-o", "whole.exr", "--no-cache")
    assert whole.returncode == 0, whole.stderr
    expected, _ = read_exr(tmp_path / "whole.exr")
    cache = tmp_path / "cache" / "reference"
    stopped = 0
    for sig, seed in KILLS:
        for old in cache.glob("*.npz"):  # every kill starts a fresh reference
            old.unlink()
        code, err = _killed(tmp_path, [*args, "-o", f"k{seed}.exr"],
                            lambda: _first(cache.glob("*.partial.npz")), sig, seed, 0.6)
        _check_stop(code, err, sig)
        stale = _age_temporaries(cache, tmp_path)
        meta = _meta(_first(cache.glob("*.partial.npz")))
        again = _mcrt(tmp_path, *args, "-o", f"k{seed}.exr")
        assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
        if code != 0 and meta is not None:
            assert f"resumed after pass {meta['passes_done']} of 16" in again.stdout
        layers, _ = read_exr(tmp_path / f"k{seed}.exr")
        for name, array in expected.items():
            assert np.array_equal(layers[name], array, equal_nan=True), name
        assert not [p for p in stale if p.exists()], "a killed writer's temporary file stayed"
        stopped += code != 0 and meta is not None
    assert stopped >= 2, "the signals came too late to test anything"


#: Per-cell numbers that must not depend on interruptions (timings may).
MEASURES = ("mse", "rel_mse", "variance", "bias", "delta_e", "aliasing_ratio", "spp")


def _cells(out: Path) -> dict:
    data = json.loads((out / "results.json").read_text())
    return {(c["scene"], c["sampler"], c["spp_requested"]): [c[m] for m in MEASURES]
            for c in data["cells"]}


def test_compare_killed_resumes_to_the_same_numbers(tmp_path):
    config = tmp_path / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="s"))
    whole = _mcrt(tmp_path, "compare", str(config), "-o", "whole")
    assert whole.returncode == 0, whole.stderr
    expected = _cells(tmp_path / "whole")
    stopped = 0
    for sig, seed in [(signal.SIGKILL, 4), (signal.SIGTERM, 5)]:
        out = tmp_path / f"k{seed}"
        state = out / ".mcrt-resume" / "state.npz"
        code, err = _killed(tmp_path, ["compare", str(config), "-o", out.name],
                            lambda p=state: p if p.exists() else None, sig, seed, 0.5)
        _check_stop(code, err, sig)
        stale = _age_temporaries(out, tmp_path / "cache")
        again = _mcrt(tmp_path, "compare", str(config), "-o", out.name)
        assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
        assert _cells(out) == expected
        assert not [p for p in stale if p.exists()], "a killed writer's temporary file stayed"
        stopped += code != 0
    assert stopped >= 1, "the signals came too late to test anything"
