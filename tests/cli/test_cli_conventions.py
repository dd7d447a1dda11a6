"""Command-line conventions: global options anywhere, -q, --version, -o DIR/,
outputs under out/, quiet broken pipes, help with examples, helpful errors,
the adaptive heat map, demo timings, first-run notes and foreign checkpoints."""

from __future__ import annotations

import logging
import shlex
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import mcrt.cli.demo_cmd as demo_cmd
from mcrt.cli import COMMANDS, EXAMPLES, _common, build_parser, version_text
from mcrt.core.job import Checkpoint, CheckpointStore
from tests.conftest import ROOT, run_cli

CORNELL = str(ROOT / "scenes" / "cornell_box.xml")
SMALL = ["-D", "res=16"]


# --------------------------------------------------------------------------- global options
@pytest.mark.parametrize("argv, quiet, variant", [
    (["render", "x.xml"], False, None),
    (["-q", "render", "x.xml"], True, None),
    (["render", "x.xml", "-q"], True, None),
    (["render", "x.xml", "--quiet", "--variant", "llvm_ad_mono"], True, "llvm_ad_mono"),
    (["--variant", "llvm_ad_mono", "compare", "c.toml"], False, "llvm_ad_mono"),
    (["-q", "--variant", "llvm_ad_mono", "plan", "x.xml"], True, "llvm_ad_mono"),
])
def test_global_options_before_or_after_the_command(argv, quiet, variant):
    args = build_parser().parse_args(argv)
    assert (args.quiet, args.variant) == (quiet, variant)


def test_compare_check_quiet_after_the_command(capsys, tmp_path):
    code, out, err = run_cli(capsys, "compare", str(ROOT / "configs" / "quick.toml"),
                             "--check", "-q")
    assert code == 0 and ": OK (" in out
    assert err == ""  # -q: not even the note that orthogonal rounds its sample counts


@pytest.mark.parametrize("argv", [["--version"], ["plan", "--version"], ["render", "--version"]])
def test_version(capsys, argv):
    code, out, _ = run_cli(capsys, *argv)
    assert code == 0 and out.strip() == version_text()
    assert out.startswith("mcrt 0.") and "Mitsuba 3." in out and "Dr.Jit 1." in out


def test_quiet_silences_notes_and_outputs_go_under_out(tmp_path, capsys, monkeypatch):
    """jittered rounds 5 spp up to 9 with a note; -q (after the command) hides it.
    Without -o the files go to out/, never the current directory."""
    monkeypatch.chdir(tmp_path)
    render = ["render", CORNELL, *SMALL, "--sampler", "jittered", "--spp", "5"]
    code, _, err = run_cli(capsys, *render)
    assert code == 0 and "mcrt: note: " in err and "rounding up to 9" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert (tmp_path / "out" / "cornell_box_jittered.exr").is_file()
    code, out, err = run_cli(capsys, *render, "-q")
    assert code == 0 and err == "" and "wrote out/cornell_box_jittered.exr" in out


@pytest.mark.parametrize("given, written", [
    ("new/", "new/cornell_box_independent"),           # ends in /: a directory, created
    ("existing", "existing/cornell_box_independent"),  # an existing directory
    ("existing/name", "existing/name"),                # a file stem
    ("existing/name.exr", "existing/name"),
])
def test_output_naming_a_directory_writes_into_it(tmp_path, capsys, given, written):
    (tmp_path / "existing").mkdir()
    code, out, _ = run_cli(capsys, "-q", "render", CORNELL, *SMALL, "--sampler", "independent",
                           "--spp", "1", "-o", str(tmp_path) + "/" + given)
    assert code == 0, out
    assert (tmp_path / (written + ".exr")).is_file() and (tmp_path / (written + ".png")).is_file()


def test_reference_output_directory(tmp_path):
    assert _common.output_stem(str(tmp_path) + "/refs/", "x_reference") == \
        tmp_path / "refs" / "x_reference"
    assert _common.output_stem(None, "x_reference") == Path("out") / "x_reference"
    assert _common.output_stem("", "x") == Path("out") / "x"


def test_a_closed_pipe_exits_quietly():
    """`mcrt plan ... | head`: the reader is gone before mcrt writes."""
    proc = subprocess.Popen([sys.executable, "-m", "mcrt", "plan", CORNELL, "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert err == ""


# --------------------------------------------------------------------------- help
def _help(capsys, *argv: str) -> str:
    code, out, _ = run_cli(capsys, *argv, "--help")
    assert code == 0
    return out


def _examples(text: str) -> list[str]:
    return [line.strip() for line in text.split("examples:\n", 1)[1].splitlines()
            if line.startswith("  mcrt")]


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_help_is_plain_text_with_examples_that_parse(capsys, command):
    text = _help(capsys, *([command] if command else []))
    for markup in ("``", "`", ":class:", ":func:", ":mod:", ":data:", "**"):
        assert markup not in text, (command, markup)
    examples = _examples(text)
    assert examples, command
    if command is None:
        assert examples == list(EXAMPLES)
    for example in examples:
        argv = shlex.split(example)[1:]
        if "--help" in argv:
            continue
        assert command is None or argv[0] == command
        build_parser().parse_args(argv)  # exits on an invalid example
        for word in argv:  # the files it names are shipped
            if word.endswith((".xml", ".toml")):
                assert (ROOT / word).is_file(), example


def test_global_options_are_in_every_command_help(capsys):
    for command in COMMANDS:
        text = _help(capsys, command)
        assert "global options:" in text and "--quiet" in text and "--version" in text


# --------------------------------------------------------------------------- helpful errors
def test_unused_define_lists_the_scene_parameters(capsys):
    code, _, err = run_cli(capsys, "plan", CORNELL, "-D", "resolution=32")
    assert code == 2 and "unused parameters" in err and "$resolution=32" in err
    assert "the scene's parameters are height, max_depth, res, sampler, spp, width" in err


@pytest.mark.parametrize("magic, kind", [(b"\x89PNG\r\n\x1a\n", "a PNG"),
                                         (b"\x76\x2f\x31\x01\x02\x00", "an OpenEXR"),
                                         (b"\xff\xd8\xff\xe0", "a JPEG")])
def test_an_image_given_as_the_scene_says_so(tmp_path, capsys, magic, kind):
    image = tmp_path / "photo.xml"  # the name does not matter: the content does
    image.write_bytes(magic + bytes(64))
    for command in ("render", "plan", "reference"):
        code, _, err = run_cli(capsys, command, str(image))
        assert code == 2 and f"is {kind} image, not a scene" in err, (command, err)
        assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("name, suggestion", [
    ("jitterd", "jittered"), ("Jittered", "jittered"), ("poisson-disk", "poisson_disk"),
    ("uniform", "uniform_grid"), ("zsobl", "zsobol"), ("nope", None), ("xyz", None)])
def test_did_you_mean_for_sampler_names(capsys, name, suggestion):
    code, _, err = run_cli(capsys, "plan", CORNELL, "--sampler", name)
    assert code == 2 and f"unknown sampler {name!r}" in err
    if suggestion:
        assert f"(did you mean {suggestion!r}?)" in err
    else:
        assert "did you mean" not in err


def test_did_you_mean_for_commands(capsys):
    code, _, err = run_cli(capsys, "rendr", "x.xml")
    assert code == 2 and "did you mean 'render'?" in err
    code, _, err = run_cli(capsys, "zzzz")
    assert code == 2 and "did you mean" not in err


# --------------------------------------------------------------------------- heat map
def test_adaptive_heat_map_has_a_title_and_a_colour_bar(tmp_path):
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm
    from PIL import Image

    from mcrt.io.heatmap import MARGINS, display_scale, write_heatmap

    spp = np.array([[4, 16, 64], [256, 1024, 4]])
    write_heatmap(tmp_path / "h.png", spp, 4, 1024, title="TITLE")
    png = np.asarray(Image.open(tmp_path / "h.png").convert("RGB")).astype(int)
    k = display_scale(3, 2)
    left, right, top, bottom = MARGINS
    assert k > 1 and png.shape == (2 * k + top + bottom, 3 * k + left + right, 3)
    expected = colormaps["inferno"](LogNorm(4, 1024)(spp.astype(float)))[..., :3] * 255
    for i in range(2):
        for j in range(3):  # each pixel is a k x k block of its colour (never interpolated)
            block = png[top + i * k + 2:top + (i + 1) * k - 2, left + j * k + 2:left + (j + 1) * k - 2]
            assert np.abs(block - expected[i, j]).max() <= 2, (i, j)
    assert (png[:top - 4, left:left + 3 * k] < 128).any()  # the title's text
    bar = png[top + 2:top + 2 * k - 2, left + 3 * k + 16]  # the colour bar: bright at the top
    assert bar[0].sum() > bar[-1].sum() + 300


# --------------------------------------------------------------------------- timings and first runs
def test_demo_times_by_the_protocol_warm_up_then_interleaved_rounds(tmp_path, capsys,
                                                                    monkeypatch):
    """Per scene: the reference, an untimed warm-up of each sampler, then 3
    rounds rendering every sampler once in the protocol's shuffled order."""
    from mcrt.core.timing import round_orders

    calls: list[tuple[str, int, bool]] = []

    def fake_render(scene, sampler, seed, progress=True):
        from mcrt.core.sampling import sampler_name

        calls.append((sampler_name(sampler), seed, progress))
        rgb = np.full((4, 4, 3), 0.5, np.float32)
        return SimpleNamespace(image=rgb, rgb=rgb, spp=sampler.sample_count(), seconds=0.25)

    monkeypatch.setattr(demo_cmd, "render_film", fake_render)
    code, out, _ = run_cli(capsys, "demo", "--samplers", "independent,jittered",
                           "--reference-factor", "1", "-o", str(tmp_path), "-q")
    assert code == 0 and "times: median of 3 interleaved rounds" in out
    names = ["independent", "jittered"]
    rounds = [(names[i], 1, False) for order in round_orders(2, 3) for i in order]
    per_scene = [("jittered", 0, False),  # the reference
                 ("independent", 1, False), ("jittered", 1, False), *rounds]
    assert calls == per_scene * len(demo_cmd.DEMO_SCENES)


def test_first_run_note(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("HOME", str(tmp_path))
    with caplog.at_level(logging.INFO, logger="mcrt"):
        _common.note_first_run()
        assert "first run: Dr.Jit compiles the render kernels" in caplog.text
        caplog.clear()
        (tmp_path / ".drjit").mkdir()
        (tmp_path / ".drjit" / "kernel.bin").write_bytes(b"x")
        _common.note_first_run()
        assert caplog.text == ""


# --------------------------------------------------------------------------- checkpoints
def test_a_checkpoint_of_another_render_is_kept_and_named(tmp_path, caplog):
    here, cache = tmp_path / ".img.exr.mcrt-resume.npz", tmp_path / "cache" / "b.npz"
    old = CheckpointStore([here, cache], "key-a", job="mcrt render s.xml --spp 16")
    assert old.save(Checkpoint({"done": 2, "settings": [16, 4, 0]},
                               {"x": np.arange(3.0)})) == here
    before = here.read_bytes()

    new = CheckpointStore([here, cache], "key-b", job="mcrt render s.xml --spp 8")
    with caplog.at_level(logging.INFO, logger="mcrt"):
        assert new.load() is None
    assert f"{here} is the checkpoint of another render (mcrt render s.xml --spp 16; 16 spp, " \
           f"2 passes done): kept, not replaced; this render keeps its checkpoint in {cache}" \
           in caplog.text
    assert new.save(Checkpoint({"done": 1, "settings": [8, 2, 0]})) == cache
    new.discard()
    assert here.read_bytes() == before and not cache.exists()
    found = CheckpointStore([here, cache], "key-a").load()  # the old render still resumes
    assert found is not None and found.meta["done"] == 2


def test_recorded_command_lines_keep_every_setting_that_changes_pixels():
    """The resume command of a study names its variant (the saved state's key
    holds it), and a render's recorded command line its variant, sampler
    parameters, multisampling and adaptive settings: run as printed, each
    reproduces its job instead of starting another."""
    import argparse
    import shlex
    from pathlib import Path

    import mitsuba as mi

    from mcrt.cli._render_record import job_text
    from mcrt.cli.compare_cmd import resume_command

    line = resume_command(argparse.Namespace(config="s.toml", quiet=True, variant=mi.variant()),
                          Path("out"))
    assert shlex.split(line) == ["mcrt", "-q", "--variant", mi.variant(), "compare", "s.toml",
                                 "-o", "out"]
    args = argparse.Namespace(scene="s.xml", sampler="jittered", seed=3, defines=["res=32"],
                              effect=None,
                              sampler_params=["jitter=0.5"], multisample=True, adaptive=True,
                              adaptive_threshold=0.02)
    words = shlex.split(job_text(args, 64, Path("o/img")))
    assert words[:3] == ["mcrt", "--variant", mi.variant()]
    for pair in (["-P", "jitter=0.5"], ["-D", "res=32"], ["--seed", "3"], ["--spp", "64"]):
        assert any(words[i:i + 2] == pair for i in range(len(words))), pair
    assert "--multisample" in words and "--adaptive" in words
    assert any(words[i] == "--threshold" and words[i + 1] == "0.02" for i in range(len(words)))


def test_progress_off_a_terminal_is_plain_lines_for_a_log(capsys, monkeypatch):
    """stderr is not a terminal here (captured): no redrawn bar, no carriage
    returns; a line at most every LOG_INTERVAL seconds and one at the end."""
    import mcrt.core.progress as progress

    with progress.Progress(10, unit="render", desc="study") as bar:
        for _ in range(10):
            bar.update()
    err = capsys.readouterr().err
    assert "\r" not in err and err.splitlines() == [err.splitlines()[-1]]
    assert err.startswith("study: 10/10 renders (100%), ")
    monkeypatch.setattr(progress, "LOG_INTERVAL", 0.0)
    with progress.Progress(4, unit="pass", desc="render") as bar:
        bar.describe("render: cornell")
        for _ in range(4):
            bar.update()
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("render: cornell: 1/4 passes (25%), ") and "left" in lines[0]
    assert lines[3].startswith("render: cornell: 4/4 passes (100%)") and len(lines) == 5
    with progress.Progress(4, enabled=False) as bar:
        bar.update(4)
    assert capsys.readouterr().err == ""


def test_heat_map_ticks_label_both_ends_and_powers_of_two():
    from mcrt.io.heatmap import spp_ticks

    assert spp_ticks(16, 64) == [16, 32, 64]
    assert spp_ticks(16, 16 * 1.0001) == [16]  # every pixel took the same count
    assert spp_ticks(3, 7) == [3, 4, 7]
    wide = spp_ticks(1, 2 ** 20)
    assert wide[0] == 1 and wide[-1] == 2 ** 20 and len(wide) <= 9
    assert all(t == 2 ** round(np.log2(t)) for t in wide)


def test_a_heat_map_of_equal_counts_labels_its_one_value(tmp_path):
    """min == max: the colour bar carries one tick label, 16, at its foot (the log
    locator alone spread nine clipped labels 1.6 x 10^1 ... 1.60016 x over the
    range 16..16.0016 that keeps the norm valid)."""
    from PIL import Image

    from mcrt.io.heatmap import MARGINS, display_scale, write_heatmap

    write_heatmap(tmp_path / "h.png", np.full((4, 4), 16.0))
    png = np.asarray(Image.open(tmp_path / "h.png").convert("L")).astype(int)
    left, _, top, bottom = MARGINS
    side = 4 * display_scale(4, 4)
    bar_right = left + side + 14 + 14
    labels = png[top:top + side, bar_right + 4:bar_right + 28] < 100  # tick labels only
    assert labels[-20:].any() and not labels[:-20].any()


def test_a_thin_film_s_heat_map_is_drawn_readable(tmp_path):
    """A 64 x 1 film: its one row is drawn taller by a whole factor (each pixel a
    block of its colour, never interpolated) to at least MIN_MAP_SIDE_PX, and
    the title says so."""
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm
    from PIL import Image

    from mcrt.io.heatmap import MARGINS, MIN_MAP_SIDE_PX, display_scale, thin_stretch, write_heatmap

    spp = (2.0 ** (np.arange(64) % 7 + 1)).reshape(1, 64)
    write_heatmap(tmp_path / "h.png", spp, 2, 128)
    png = np.asarray(Image.open(tmp_path / "h.png").convert("RGB")).astype(int)
    k = display_scale(64, 1)
    tall = thin_stretch(1, k)
    assert tall > 1 and k * tall >= MIN_MAP_SIDE_PX
    left, _, _, bottom = MARGINS
    expected = colormaps["inferno"](LogNorm(2, 128)(spp))[..., :3] * 255
    row = png.shape[0] - bottom - k * tall  # the map's first screen row
    for j in range(64):
        block = png[row + 2:row + k * tall - 2, left + j * k + 1:left + (j + 1) * k - 1]
        assert np.abs(block - expected[0, j]).max() <= 2, j
    assert (png[:row - 4, left:left + 64 * k] < 128).any()  # the title, on its lines
