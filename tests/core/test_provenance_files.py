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


def test_a_scene_s_point_set_file_is_read_beside_the_scene(capsys, monkeypatch, tmp_path):
    """``<sampler type="pointset"><string name="filename" value="sets.npy"/>``: found
    in the scene's folder, as every file a scene names (it was read relative to the
    working directory: the scene rendered only from its own folder, and its
    recorded command failed anywhere else)."""
    folder = tmp_path / "scene"
    folder.mkdir()
    _point_sets(folder / "sets.npy")
    text = CORNELL.read_text().replace(
        '<sampler type="$sampler">',
        '<sampler type="pointset"><string name="filename" value="sets.npy"/>')
    (folder / "box.xml").write_text(text)
    code, _, err = run_cli(capsys, "-q", "render", str(folder / "box.xml"), "-D", "res=8",
                           "-D", "spp=4", "-D", "max_depth=2", "-o", "scene_sets")
    assert code == 0, err
    _again_elsewhere(capsys, monkeypatch, tmp_path, Path("scene_sets.exr"))


def test_a_plugin_s_point_set_file_is_read_beside_the_plugin(capsys, monkeypatch, tmp_path):
    """``register_sampler("mine", file="sets.npy")`` in a plugin file: relative to
    the plugin's folder (it was relative to the working directory, so the recorded
    command, which names the plugin by absolute path, failed from anywhere else)."""
    folder = tmp_path / "plugin"
    folder.mkdir()
    _point_sets(folder / "sets.npy")
    (folder / "mine.py").write_text('import mcrt\n\nmcrt.register_sampler("file_sets", '
                                    'file="sets.npy")\n')
    code, _, err = run_cli(capsys, "-q", "--plugin", str(folder / "mine.py"), "render",
                           str(CORNELL), "-D", "res=8", "-D", "max_depth=2", "--sampler",
                           "file_sets", "--spp", "4", "-o", "plugin_sets")
    assert code == 0, err
    _again_elsewhere(capsys, monkeypatch, tmp_path, Path("plugin_sets.exr"))


@pytest.mark.parametrize("command", ["render", "reference"])
def test_a_define_naming_a_file_in_the_working_directory(capsys, monkeypatch, tmp_path,
                                                         command):
    """``-D light=my_light.obj`` with the mesh in the working directory (where
    Mitsuba looks last): the command names it by absolute path and the scene's
    digest covers it (it was recorded as typed: the command failed from another
    folder, or found another file of that name)."""
    light = (MESH_LIGHT.parent / "meshes" / "quad_light.obj").read_text()
    Path("my_light.obj").write_text(light.replace("1.9", "1.7"))
    extra = ["--spp", "4"] if command == "render" else ["--spp", "8", "--spp-per-pass", "8"]
    code, _, err = run_cli(capsys, "-q", command, str(MESH_LIGHT), "-D", "light=my_light.obj",
                           "-D", "res=8", *extra, "-o", "local_light.exr")
    assert code == 0, err
    made = Path("local_light.exr")
    assert f"light={Path('my_light.obj').resolve()}" in _command(made)
    _again_elsewhere(capsys, monkeypatch, tmp_path, made)


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


def test_a_reference_of_a_point_set_file_renders_again_and_follows_the_file(
        capsys, monkeypatch, tmp_path):
    """``mcrt reference --sampler pointset -P filename=sets.npy`` (a relative path):
    its passes use the file (it took no sampler parameter: a point-set reference
    could not be made), its command names the file by absolute path and renders it
    again from another folder bit for bit, and new points in the same file make a
    new reference, not the cached one."""
    _point_sets(Path("sets.npy"))  # 16 sets of 4 points
    argv = ["-q", "reference", str(CORNELL), "-D", "res=8", "-D", "max_depth=2", "--sampler",
            "pointset", "-P", "filename=sets.npy", "--spp", "16", "--spp-per-pass", "4"]
    code, _, err = run_cli(capsys, *argv, "-o", "ref_sets.exr")
    assert code == 0, err
    made = Path("ref_sets.exr")
    _, header = read_exr(made)
    assert header["sampler_params"] == f'{{"filename": "{Path("sets.npy").resolve()}"}}'
    assert f"filename={Path('sets.npy').resolve()}" in _command(made)
    assert header["passes"] == 4
    _again_elsewhere(capsys, monkeypatch, tmp_path, made)

    monkeypatch.chdir(tmp_path / "made")
    rng = np.random.default_rng(6)
    np.save("sets.npy", (rng.random((16, 4, 2)) * 0.99).astype(np.float32))
    code, out, err = run_cli(capsys, *argv, "-o", "ref_new_sets.exr")
    assert code == 0 and "found in cache" not in out, err
    assert read_exr(Path("ref_new_sets.exr"))[1]["cache_key"] != header["cache_key"]
    assert not np.array_equal(_bits(Path("ref_new_sets.exr")), _bits(made))


def test_a_point_set_reference_takes_passes_of_its_sets_size(capsys):
    """The default pass (64 samples here) is a count a file of 4-point sets refuses:
    the passes take 4, the largest count it renders; a parameter no count makes
    good is the error it is."""
    _point_sets(Path("sets.npy"))
    code, out, err = run_cli(capsys, "reference", str(CORNELL), "-D", "res=8", "--sampler",
                             "pointset", "-P", "filename=sets.npy", "--spp", "64")
    assert code == 0 and "passes 16 (16 x 4 spp)" in out, err
    code, _, err = run_cli(capsys, "-q", "reference", str(CORNELL), "-D", "res=8",
                           "-P", "jitter=0.5")  # independent has none
    assert code == 2 and len(err.strip().splitlines()) == 1 and "jitter" in err


def test_a_study_s_reference_with_sampler_parameters_renders_again(capsys, monkeypatch,
                                                                    tmp_path):
    """``[reference] params``: the reference is made with them, and its EXR's command
    (``-P jitter=false``) makes the same reference again, bit for bit."""
    config = Path("s.toml")
    config.write_text('name = "s"\nspp = [1, 4]\nseeds = 2\nimage_spp = 4\ntime_rounds = 2\n'
                      'samplers = ["jittered"]\n[reference]\nspp = 16\nsampler = "stratified"\n'
                      'params = { jitter = false }\n'
                      f'[[scenes]]\npath = "{CORNELL}"\nname = "box"\n'
                      'params = { res = 8, max_depth = 2 }\n')
    code, _, err = run_cli(capsys, "-q", "compare", str(config), "-o", "study")
    assert code == 0, err
    assert "reference: stratified (jitter=False), 16 spp" in Path("study/report.html").read_text()
    made = Path("study/exr/box/reference.exr").resolve()
    assert "-P jitter=false" in " ".join(_command(made))
    assert read_exr(made)[1]["sampler_params"] == '{"jitter": false}'
    _again_elsewhere(capsys, monkeypatch, tmp_path, made)
