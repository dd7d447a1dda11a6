"""The files a render depends on, however they are named, are the same files when
its recorded command runs again from another folder: a point-set file a scene's
sampler names (beside the scene), one a plugin registers (beside the plugin), a
``-D`` value naming a file in the working directory (recorded by absolute path),
and a study's ``filters`` (``-D mcrt.rfilter=NAME`` in its images' commands).

Each case renders for real, runs ``mcrt render --from`` from another folder and
compares the pixels as float32 bit patterns; headers are read with OpenEXR.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from mcrt.io import read_exr
from tests.conftest import run_cli

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
MESH_LIGHT = ROOT / "scenes" / "foreign" / "mesh_light.xml"


@pytest.fixture(autouse=True)
def _here(tmp_path, monkeypatch):
    """Each test in its own folders and reference cache."""
    for name in ("made", "elsewhere"):
        (tmp_path / name).mkdir()
    monkeypatch.chdir(tmp_path / "made")
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))


def _command(path: Path) -> list[str]:
    header = OpenEXR.File(str(path), header_only=True).header()
    value = header["command"]
    return shlex.split(value.decode() if isinstance(value, bytes) else value)


def _bits(path: Path) -> np.ndarray:
    return np.asarray(read_exr(path)[0]["rgb"], np.float32).view(np.uint32)


def _again_elsewhere(capsys, monkeypatch, tmp_path, made: Path) -> str:
    """``mcrt render --from MADE`` run from ``elsewhere/``: asserts the same bits."""
    made = made.resolve()
    monkeypatch.chdir(tmp_path / "elsewhere")
    code, out, err = run_cli(capsys, "render", "--from", str(made), "-o", f"again_{made.stem}")
    assert code == 0 and "bit for bit" in out, (made, out, err)
    assert "not what they were" not in err, err  # the same scene files, by digest too
    assert np.array_equal(_bits(Path(f"again_{made.stem}.exr")), _bits(made))
    return err


def _point_sets(path: Path) -> None:
    rng = np.random.default_rng(5)
    np.save(path, (rng.random((16, 4, 2)) * 0.99).astype(np.float32))


def test_every_image_of_a_study_with_filters_renders_again(capsys, monkeypatch, tmp_path):
    """A study's ``filters`` axis: its images' commands carry the filter as ``-D
    mcrt.rfilter=NAME``, which ``mcrt render`` and ``mcrt reference`` take (they
    refused it as no parameter name: no image of such a study rendered again)."""
    config = Path("s.toml")
    config.write_text('name = "s"\nspp = [1, 4]\nseeds = 2\nimage_spp = 4\ntime_rounds = 2\n'
                      'samplers = ["jittered"]\nfilters = ["tent"]\n[reference]\nspp = 16\n'
                      f'[[scenes]]\npath = "{CORNELL}"\nname = "box"\n'
                      'params = { res = 8, max_depth = 2 }\n')
    code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", "study")
    assert code == 0, err
    files = sorted(f.resolve() for f in Path("study/exr").glob("*/*.exr"))
    assert {f.stem for f in files} == {f"jittered_{n}spp_{kind}" for n in (1, 4)
                                       for kind in ("mean", "seed0")} | {"reference"}
    for f in files:
        assert "mcrt.rfilter=tent" in _command(f), f
        _again_elsewhere(capsys, monkeypatch, tmp_path, f)
