"""`mcrt render` and friends: outputs, and user errors as one-line messages."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mcrt.cli.render_cmd as render_cmd
from mcrt.cli import COMMANDS, build_parser, command_of
from mcrt.io import read_exr
from tests.conftest import run_cli, scene_xml

SCENES = Path(__file__).resolve().parents[2] / "scenes"
CORNELL = str(SCENES / "cornell_box.xml")
SMALL = ["-D", "res=16"]



@pytest.mark.parametrize("sampler", ["jittered", "poisson_disk", "uniform_grid", "independent",
                                     "stratified", "multijitter", "orthogonal", "ldsampler"])
def test_render_writes_float32_exr_and_png(tmp_path, capsys, sampler):
    out = tmp_path / "img"
    code, stdout, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "--sampler", sampler,
                              "--spp", "4", "--seed", "2", "-o", str(out))
    assert code == 0
    layers, meta = read_exr(out.with_suffix(".exr"))
    rgb = layers["rgb"]
    assert rgb.dtype == np.float32 and rgb.shape == (16, 16, 3)
    assert np.isfinite(rgb).all() and rgb.mean() > 0.01
    assert meta["sampler"] == sampler and meta["seed"] == 2
    assert out.with_suffix(".png").stat().st_size > 0
    assert f"sampler {sampler}" in stdout and "samples/s" in stdout and "time" in stdout
    spp = int(stdout.split("spp ")[1].split()[0])
    assert spp == meta["spp"] >= 4  # orthogonal rounds 4 up to 9, the others keep 4


def test_render_defaults_come_from_the_scene(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, stdout, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "-D", "spp=9")
    assert code == 0
    assert "sampler jittered" in stdout and "spp 9" in stdout
    assert (tmp_path / "out" / "cornell_box_jittered.exr").exists()  # never in the cwd


def test_same_seed_same_image(tmp_path, capsys):
    images = []
    for name in ("a", "b"):
        run_cli(capsys, "-q", "render", CORNELL, *SMALL, "--spp", "4", "-o", str(tmp_path / name))
        images.append(read_exr(tmp_path / f"{name}.exr")[0]["rgb"])
    np.testing.assert_allclose(images[0], images[1], rtol=1e-5, atol=1e-6)


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if rendering starts: user errors must be caught before."""
    def forbidden(*args, **kwargs):
        raise AssertionError("rendering started despite a user error")
    monkeypatch.setattr(render_cmd, "render_film", forbidden)


@pytest.mark.parametrize("argv, message", [
    (["render", "missing.xml"], "scene file not found"),
    (["render", CORNELL, "--sampler", "nope"], "unknown sampler 'nope'"),
    (["render", CORNELL, "--sampler", "uniform"], "unknown sampler 'uniform'"),
    (["render", CORNELL, "--spp", "0"], "must be a positive integer"),
    (["render", CORNELL, "--spp", "-3"], "must be a positive integer"),
    (["render", CORNELL, "--spp", "many"], "expected a positive integer"),
    (["render", CORNELL, "--seed", "-1"], "must be in [0, 2^32)"),
    (["render", CORNELL, "-D", "nokey"], "-D expects key=value"),
    (["render", CORNELL, "-D", "unused=1"], "unused parameters"),
    (["render", CORNELL, "-D", "spp=abc"], "could not parse integer"),
    (["render", CORNELL, "-o", "/proc/no/such/dir/img"], "cannot create output directory"),
    (["render"], "give the scene to render (SCENE.xml), or --from FILE.exr"),
    (["nosuchcommand"], "invalid choice"),
    (["render", CORNELL, "-D", "res=0"], "the film has 0x0 pixels"),
    (["render", CORNELL, "-D", "res=0", "--adaptive"], "the film has 0x0 pixels"),
    (["reference", CORNELL, "-D", "res=0", "--spp", "16"], "the film has 0x0 pixels"),
    (["plan", str(Path(CORNELL).parent / "checkerboard.xml"), "-D", "width=0"],
     "the film has 0x240 pixels"),
])
def test_user_errors_are_one_line_before_rendering(capsys, no_render, argv, message):
    code, stdout, stderr = run_cli(capsys, *argv)
    assert code == 2
    assert message in stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert "Traceback" not in stderr


@pytest.mark.parametrize("content, message", [
    ("<scene version='3.0.0'><shape type='spheer'/></scene>", 'Plugin "spheer" not found'),
    ("<scene version='3.0.0'><integrator type='path'", "Parsing of XML file"),
    ("<sampler version='3.0.0' type='jittered'/>", "does not describe a scene"),
    ("<scene version='3.0.0'><sensor type='perspective'><sampler type='jittered'>"
     "<float name='jitter' value='2'/></sampler></sensor></scene>", "'jitter' must be"),
])
def test_malformed_scenes_are_one_line_errors(tmp_path, capsys, no_render, content, message):
    scene = tmp_path / "scene.xml"
    scene.write_text(content)
    code, _, stderr = run_cli(capsys, "render", str(scene))
    assert code == 2 and message in stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


def test_unwritable_output_file_is_refused_before_rendering(tmp_path, capsys, no_render):
    (tmp_path / "img.exr").mkdir()  # a directory where the EXR should go
    code, _, stderr = run_cli(capsys, "render", CORNELL, "-o", str(tmp_path / "img"))
    assert code == 2 and "cannot overwrite" in stderr


def test_missing_libllvm_is_a_clear_message():
    """The console script on a machine whose libLLVM cannot be loaded prints one
    line naming what to install, instead of crashing in LLVM."""
    env = dict(os.environ, DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    proc = subprocess.run([sys.executable, "-m", "mcrt", "render", CORNELL], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    lines = [line for line in proc.stderr.splitlines() if line.startswith("mcrt:")]
    assert len(lines) == 1 and "libllvm19" in lines[0] and "DRJIT_LIBLLVM_PATH" in lines[0]
    assert "Traceback" not in proc.stderr


# ------------------------------------------------------------- start-up: one subcommand at a time
@pytest.mark.parametrize("argv, command", [
    (["render", "x.xml"], "render"), (["-q", "compare", "c.toml"], "compare"),
    (["--quiet", "-q", "plan"], "plan"), ([], None), (["--help"], None), (["-h", "render"], None),
    (["rendr"], None), (["--qui", "render"], None), (["--", "render"], None),
])
def test_command_of(argv, command):
    assert command_of(argv) == command


@pytest.mark.parametrize("name", list(COMMANDS))
def test_one_command_parser_parses_like_the_full_parser(capsys, name):
    """`mcrt NAME ...` builds only NAME's parser: same help, same errors."""
    for argv, expected in (([name, "--help"], f"usage: mcrt {name}"),
                           ([name, "--no-such-option"], "error:")):
        outputs = []
        for parser in (build_parser(), build_parser([name])):
            with pytest.raises(SystemExit) as exit_:
                parser.parse_args(argv)
            captured = capsys.readouterr()
            outputs.append((exit_.value.code, captured.out, captured.err))
        assert outputs[0] == outputs[1]
        assert expected in outputs[0][1] + outputs[0][2]


def _modules_after(code: str) -> set[str]:
    """Top-level packages imported by a fresh interpreter running ``code``."""
    script = code + "\nimport sys\nprint(' '.join(sorted({m.split('.')[0] for m in sys.modules})))\n"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, check=True)
    return set(proc.stdout.split())


def test_import_mcrt_imports_nothing_heavy():
    """`import mcrt` costs about what `import mitsuba` + set_variant cost."""
    heavy = {"numpy", "matplotlib", "scipy", "colour", "tqdm", "PIL", "OpenEXR"}
    assert _modules_after("import mcrt") & heavy == set()


def test_render_command_does_not_import_the_analysis_stack():
    code = ("from mcrt.cli import main\n"
            "try:\n"
            "    main(['render', '--help'])\n"
            "except SystemExit:\n"
            "    pass\n")
    assert _modules_after(code) & {"matplotlib", "scipy", "colour"} == set()


def test_adaptive_render_notes_nothing_about_a_sample_count_it_does_not_use(tmp_path, capsys):
    """--spp is an adaptive render's budget, not a sampler's count: no rounding note."""
    edges = Path(__file__).resolve().parents[2] / "scenes" / "edges.xml"
    code, _, err = run_cli(capsys, "render", str(edges), "--adaptive", "--sampler", "jittered",
                           "--spp", "128", "-D", "width=16", "-D", "height=16",
                           "-o", str(tmp_path / "a"))
    assert code == 0 and "rounding up" not in err, err


def test_a_tiny_render_s_speed_is_not_printed_as_zero():
    from mcrt.cli._common import speed

    assert speed(1.25, 3.36e6) == "time 1.25 s  3.36 M samples/s"
    assert speed(0.00359, 4457.0) == "time 3.59 ms  4.46 k samples/s"  # was 0.00 s, 0.00 M


def test_pixels_whose_float32_sum_overflows_are_developed_finite(tmp_path, capsys):
    """A light of radiance 1e37 seen directly: each sample is finite, but 64 of
    them summed in float32 pass 3.4e38 (Mitsuba's own film then gives Inf pixels,
    which mcrt once wrote and later only reported). mcrt divides its float64 sums
    by the weights before rounding: every pixel is its samples' mean, finite, the
    light's pixels 1e37 within float32 rounding, and there is nothing to report."""
    scene = tmp_path / "hot.xml"
    scene.write_text(scene_xml(
        '<shape type="rectangle"><transform name="to_world"><scale value="0.6"/></transform>'
        '<emitter type="area"><rgb name="radiance" value="1e37"/></emitter></shape>',
        '<integrator type="direct"/>', size=32))
    code, _, err = run_cli(capsys, "render", str(scene), "--spp", "64", "-o", str(tmp_path / "a"))
    assert code == 0 and "infinite" not in err, err
    rgb = read_exr(tmp_path / "a.exr")[0]["rgb"]
    assert np.all(np.isfinite(rgb))
    assert np.max(rgb) == pytest.approx(1e37, rel=2 ** -23)  # a pixel inside the light
