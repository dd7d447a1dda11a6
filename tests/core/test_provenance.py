"""Every EXR mcrt writes says how it was made, and ``mcrt render --from FILE.exr``
renders it again from that alone, bit for bit; a default output name never
silently replaces a different render.

Headers are read back with OpenEXR itself (not mcrt's reader), pixels compared
as float32 bit patterns.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import OpenEXR
import pytest

from mcrt import __version__
from mcrt.core.provenance import png_text, source_digest
from mcrt.core.scene_files import scene_digest
from mcrt.io import read_exr, write_exr
from tests.conftest import png_text_of, run_cli

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
MOTION = ROOT / "scenes" / "effects" / "motion.xml"

#: A user's point generator, loaded with --plugin (i.i.d. points from the rng).
PLUGIN = ("import mcrt\n\n\ndef points(count, n, rng):\n    return rng.random((count, n, 2))\n\n\n"
          "mcrt.register_sampler('iid_points', points=points, sets=16)\n")


@pytest.fixture(autouse=True)
def _here(tmp_path, monkeypatch):
    """Each test in its own folder (default outputs go to ./out) and cache."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))


def _header(path: Path) -> dict:
    """The header as OpenEXR reads it (strings and numbers, standard keys too)."""
    header = OpenEXR.File(str(path), header_only=True).header()
    return {k: v.decode() if isinstance(v, bytes) else v for k, v in header.items()}


def _pixels(path: Path) -> np.ndarray:
    return np.asarray(read_exr(path)[0]["rgb"], np.float32)


def _again(capsys, path: Path, *extra: str) -> tuple[int, str, str]:
    return run_cli(capsys, "render", "--from", str(path), *extra)


def test_a_render_header_records_every_setting_that_changes_its_pixels(capsys):
    """Two renders differing only in --multisample (written to two names) differ
    in their headers exactly where the setting lives; both carry the versions,
    the scene's digest, the filter and the command."""
    base = ["render", str(CORNELL), "-D", "res=16", "--sampler", "sobol", "--spp", "4"]
    assert run_cli(capsys, *base, "-o", "plain")[0] == 0
    assert run_cli(capsys, *base, "--multisample", "-o", "ms")[0] == 0
    plain, ms = _header(Path("plain.exr")), _header(Path("ms.exr"))
    for header in (plain, ms):
        assert header["mcrt_version"] == __version__
        assert header["mcrt_source"] == source_digest()
        assert header["mitsuba_version"] == mi.__version__
        assert header["drjit_version"] == dr.__version__
        assert header["variant"] == mi.variant()
        assert header["scene_digest"] == scene_digest(CORNELL, {"res": "16"})
        assert header["filter"].startswith(
            str(mi.load_file(str(CORNELL), res=16).sensors()[0].film().rfilter())[:8])
        assert header["sampler"] == "sobol" and header["seed"] == 0
        assert header["spp_requested"] == 4 and header["defines"] == "res=16"
    assert (plain["multisample"], ms["multisample"]) == (0, 1)
    assert "--multisample" in shlex.split(ms["command"])
    assert "--multisample" not in shlex.split(plain["command"])
    assert not np.array_equal(_pixels(Path("plain.exr")), _pixels(Path("ms.exr")))


def test_a_default_name_never_replaces_a_different_render(capsys):
    """Without -o both renders would be out/cornell_box_sobol.exr: the second,
    different one is refused (the file untouched, the message names the
    setting); the same command again replaces it; -o replaces with a note."""
    base = ["render", str(CORNELL), "-D", "res=16", "--sampler", "sobol", "--spp", "4"]
    assert run_cli(capsys, *base)[0] == 0
    target = Path("out/cornell_box_sobol.exr")
    before = target.read_bytes()
    code, _, err = run_cli(capsys, *base, "--multisample")
    assert code == 2 and "multisample 0 there, 1 here" in err and "-o" in err
    assert target.read_bytes() == before
    code, _, err = run_cli(capsys, *base, "--seed", "3")
    assert code == 2 and "seed 0 there, 3 here" in err
    assert run_cli(capsys, *base)[0] == 0  # the same render: replaced without a word
    code, _, err = run_cli(capsys, *base, "--seed", "3", "-o", str(target))
    assert code == 0 and "replacing" in err and "seed 0 there, 3 here" in err
    assert _header(target)["seed"] == 3


def test_a_default_name_never_replaces_a_file_mcrt_did_not_write(capsys):
    Path("out").mkdir()
    write_exr(Path("out/cornell_box_sobol.exr"), {"rgb": np.zeros((2, 2, 3))}, {"x": 1})
    code, _, err = run_cli(capsys, "render", str(CORNELL), "-D", "res=16", "--sampler",
                           "sobol", "--spp", "4")
    assert code == 2 and "a file mcrt did not write" in err


@pytest.mark.slow
@pytest.mark.parametrize("argv", [
    ["--sampler", "jittered", "--spp", "16", "-P", "jitter=0.5", "--seed", "7"],
    ["--sampler", "zsobol", "--spp", "8", "--effect", "indirect=off"],
    ["--sampler", "independent", "--spp", "4", "--multisample"],
    ["--sampler", "sobol", "--spp", "64", "--adaptive", "--threshold", "0.2",
     "--min-spp", "4"],
    ["--spp", "4"],  # the scene's own sampler
], ids=["params-seed", "effect-override", "multisample", "adaptive", "scene-sampler"])
def test_from_renders_any_render_again_bit_for_bit(capsys, argv):
    """...and every PNG of the render (the preview; an adaptive render's heat map)
    carries the EXR's command and the software in its text chunks."""
    assert run_cli(capsys, "render", str(CORNELL), "-D", "res=16", *argv, "-o", "first")[0] == 0
    pngs = sorted(Path().glob("first*.png"))
    assert len(pngs) == (2 if "--adaptive" in argv else 1)
    for png in pngs:
        assert png_text_of(png) == png_text({"command": _header(Path("first.exr"))["command"]})
    code, out, _ = _again(capsys, Path("first.exr"))
    assert code == 0, out
    assert "the same pixels as first.exr, bit for bit" in out
    assert np.array_equal(_pixels(Path("first_again.exr")).view(np.uint32),
                          _pixels(Path("first.exr")).view(np.uint32))


def test_from_carries_the_variant_a_plugin_and_motion_blur(capsys, tmp_path):
    """The command names the variant and the user's plugin file (by absolute
    path): --from needs neither option, nor the current directory's files."""
    plugin = tmp_path / "mine.py"
    plugin.write_text(PLUGIN)
    argv = ["--variant", "llvm_ad_spectral", "--plugin", str(plugin), "render", str(CORNELL),
            "-D", "res=16", "--sampler", "iid_points", "--spp", "4", "-o", "spectral"]
    assert run_cli(capsys, *argv)[0] == 0
    header = _header(Path("spectral.exr"))
    assert header["variant"] == "llvm_ad_spectral"
    assert str(plugin) in shlex.split(header["command"])
    mi.set_variant("llvm_ad_rgb")  # --from must switch back by itself
    code, out, _ = _again(capsys, Path("spectral.exr"), "-o", "elsewhere/again")
    assert code == 0 and "bit for bit" in out, out
    assert run_cli(capsys, "render", str(MOTION), "-D", "width=24", "-D", "height=16",
                   "--spp", "4", "-o", "motion")[0] == 0
    assert "motion" in _header(Path("motion.exr"))["effects"]
    code, out, _ = _again(capsys, Path("motion.exr"))
    assert code == 0 and "bit for bit" in out, out


@pytest.mark.parametrize("pixel_format", ["xyz", "xyza", "luminance_alpha"])
def test_from_compares_a_film_s_own_channels(capsys, pixel_format):
    """Films whose channels are not R G B [A] (read back as X, Y, Z, A layers):
    --from compares those, bit for bit, and sees a changed one."""
    scene = Path("box.xml")
    scene.write_text(CORNELL.read_text().replace('name="pixel_format" value="rgb"',
                                                 f'name="pixel_format" value="{pixel_format}"'))
    assert run_cli(capsys, "render", str(scene), "-D", "res=16", "--spp", "4", "-o", "a")[0] == 0
    layers, header = read_exr(Path("a.exr"))
    assert "rgb" not in layers and "Y" in layers
    code, out, _ = _again(capsys, Path("a.exr"))
    assert code == 0 and "the same pixels as a.exr, bit for bit" in out, out
    layers["Y"][3, 5] += 1.0
    write_exr(Path("b.exr"), layers, header)
    code, out, _ = _again(capsys, Path("b.exr"))
    assert code == 1 and "1 of 256 pixels differ" in out, out


def test_from_renders_a_reference_again_without_its_cache(capsys):
    assert run_cli(capsys, "reference", str(CORNELL), "-D", "res=16", "--spp", "32",
                   "--spp-per-pass", "8", "-o", "ref")[0] == 0
    header = _header(Path("ref.exr"))
    assert header["mcrt_kind"] == "reference" and header["filter"]
    assert header["scene_digest"] == scene_digest(CORNELL, {"res": "16"})
    code, out, _ = _again(capsys, Path("ref.exr"))
    assert code == 0 and "bit for bit" in out and "found in cache" not in out, out
    layers = read_exr(Path("ref_again.exr"))[0]
    assert {"stderr", "variance", "count"} <= set(layers)


@pytest.mark.slow
def test_from_renders_every_image_of_a_study_again(capsys, tmp_path):
    """A study's seed images, its mean images (every seed rendered and folded
    in the study's order) and its reference: each reproduced bit for bit."""
    config = tmp_path / "s.toml"
    config.write_text('name = "s"\nspp = [4, 16]\nseeds = 2\nimage_spp = 4\n'
                      'samplers = ["jittered", {name = "jittered", label = "half", '
                      'params = { jitter = 0.5 }}]\n[reference]\nspp = 64\n'
                      f'[[scenes]]\npath = "{CORNELL}"\nname = "box"\nparams = {{ res = 16 }}\n')
    assert run_cli(capsys, "-q", "compare", str(config), "-o", "study")[0] == 0
    files = sorted(Path("study/exr/box").glob("*.exr"))
    kinds = {_header(f)["mcrt_kind"] for f in files}
    assert kinds == {"study_mean", "study_seed", "study_reference"}
    assert len(files) == 9
    for f in files:
        header = _header(f)
        assert json.loads(header["seeds"]) == [0, 1]
        assert header["mcrt_source"] == source_digest()
        code, out, _ = _again(capsys, f, "-o", f"again/{f.stem}")
        assert code == 0 and "bit for bit" in out, (f, out)


def test_a_point_set_file_given_by_a_relative_path_is_found_from_another_folder(
        capsys, tmp_path, monkeypatch):
    """``-P filename=sets.npz`` (the pointset sampler) is read relative to the
    working directory: a render's command, and a study image's, name the file by
    absolute path, so that ``--from`` renders it again from another folder."""
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    rng = np.random.default_rng(1)
    np.savez("sets.npz", *(rng.random((16, n, 2)).astype(np.float32) * 0.99 for n in (4, 16)))
    sets = str((tmp_path / "work" / "sets.npz").resolve())
    config = Path("s.toml")
    config.write_text('name = "s"\nspp = [4, 16]\nseeds = 2\nimage_spp = 4\n'
                      'samplers = [{name = "pointset", params = { filename = "sets.npz" }}]\n'
                      f'[reference]\nspp = 64\n[[scenes]]\npath = "{CORNELL}"\nname = "box"\n'
                      'params = { res = 8 }\n')
    assert run_cli(capsys, "-q", "render", str(CORNELL), "-D", "res=8", "--sampler", "pointset",
                   "-P", "filename=sets.npz", "--spp", "4", "-o", "r")[0] == 0
    assert run_cli(capsys, "-q", "compare", str(config), "-o", "study")[0] == 0
    made = [Path("r.exr").resolve(), Path("study/exr/box/pointset_4spp_seed0.exr").resolve()]
    monkeypatch.chdir(tmp_path)
    for f in made:
        assert f"filename={sets}" in shlex.split(_header(f)["command"]), f
        code, out, err = _again(capsys, f, "-o", f"again/{f.stem}")
        assert code == 0 and "bit for bit" in out, (f, out, err)


def test_from_says_when_pixels_differ_and_why(capsys):
    """A file whose pixels were changed after rendering: exit status 1 and the
    count of pixels that differ; a changed scene: a note before rendering."""
    scene = Path("box.xml")
    scene.write_text(CORNELL.read_text())
    assert run_cli(capsys, "render", str(scene), "-D", "res=16", "--spp", "4", "-o", "a")[0] == 0
    layers, header = read_exr(Path("a.exr"))
    layers["rgb"][3, 5, 1] += 1.0
    write_exr(Path("b.exr"), layers, header)
    code, out, _ = _again(capsys, Path("b.exr"))
    assert code == 1 and "1 of 256 pixels differ" in out
    scene.write_text(CORNELL.read_text() + "<!-- edited -->\n")
    code, out, err = _again(capsys, Path("a.exr"))
    assert "files are not what they were" in err


def test_from_says_when_a_file_was_written_by_other_code(capsys):
    """The version number stays while mcrt's code changes: the header's digest of
    mcrt's source says whether the code that wrote a file is this one. --from
    notes other code (or another Mitsuba / Dr.Jit) before rendering, and names it
    again if the pixels differ; a file without the key (older) gets no note."""
    assert run_cli(capsys, "render", str(CORNELL), "-D", "res=16", "--spp", "4", "-o", "a")[0] == 0
    layers, header = read_exr(Path("a.exr"))
    code, out, err = _again(capsys, Path("a.exr"))
    assert code == 0 and "other software" not in err
    write_exr(Path("b.exr"), layers, {**header, "mcrt_source": "0123456789abcdef"})
    code, out, err = _again(capsys, Path("b.exr"))
    assert code == 0 and "bit for bit" in out
    assert f"written by other software: mcrt_source 0123456789abcdef (now {source_digest()})" \
        in " ".join(err.split())
    layers["rgb"][0, 0, 0] += 1.0
    write_exr(Path("c.exr"), layers, {**header, "drjit_version": "0.0.1"})
    code, out, err = _again(capsys, Path("c.exr"))
    assert code == 1 and "drjit_version 0.0.1" in err and "other software" in out
    del header["mcrt_source"]
    write_exr(Path("d.exr"), read_exr(Path("a.exr"))[0], header)
    code, out, err = _again(capsys, Path("d.exr"))
    assert code == 0 and "other software" not in err


@pytest.mark.parametrize("setup, argv, message", [
    ("render", ["--spp", "8"], "drop --spp"),
    ("render", [str(CORNELL)], "drop SCENE.xml"),
    ("partial", [], "partial render"),
    ("foreign", [], "records no command to render it again"),
    ("none", [], "cannot read"),
])
def test_from_refuses_in_one_line(capsys, setup, argv, message):
    if setup in ("render", "partial"):
        assert run_cli(capsys, "render", str(CORNELL), "-D", "res=16", "--spp", "4",
                       "-o", "a")[0] == 0
    if setup == "partial":
        layers, header = read_exr(Path("a.exr"))
        write_exr(Path("a.exr"), layers, {**header, "partial": 1})
    if setup == "foreign":
        write_exr(Path("a.exr"), {"rgb": np.zeros((2, 2, 3))}, {"x": 1})
    code, _, err = run_cli(capsys, "render", "--from", "a.exr", *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.slow
def test_from_renders_a_demo_image_again(capsys):
    """`mcrt demo`'s images record the same header keys and command."""
    assert run_cli(capsys, "-q", "demo", "--samplers", "sobol", "--rounds", "1",
                   "--reference-factor", "1", "-o", "demo")[0] == 0
    for name in ("cornell_box_sobol.exr", "checkerboard_reference.exr"):
        header = _header(Path("demo") / name)
        assert header["mitsuba_version"] == mi.__version__ and header["scene_digest"]
        code, out, _ = _again(capsys, Path("demo") / name)
        assert code == 0 and "bit for bit" in out, out


def test_a_command_hashes_mcrt_s_source_when_it_starts(capsys):
    """The digest is taken when a command starts, not when its first output is
    written: an edit of mcrt's files during a long render is not credited to it.
    (``mcrt plan`` writes nothing, yet the digest is there after it.)"""
    source_digest.cache_clear()
    assert run_cli(capsys, "-q", "plan", str(CORNELL))[0] == 0
    assert source_digest.cache_info().currsize == 1
