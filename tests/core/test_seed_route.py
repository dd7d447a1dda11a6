"""One seed route: a render's bits depend on (scene, sampler and parameters, spp,
seed, variant, plan), not on the way the render was asked for.

Before the route was unified, `mcrt render SCENE --seed 3` (the scene's own
`jittered`) and the same command with `--sampler jittered` differed by up to 1.35
in a pixel, because `--sampler` also put the seed into the sampler's `seed`
property. These tests render one cell through every route and compare bits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler, sampler_params
from mcrt.io import read_exr
from mcrt.render.plan import plan_scene
from tests.conftest import ROOT, run_cli

CORNELL = str(ROOT / "scenes" / "cornell_box.xml")
RES = ["-D", "res=24"]


def cli_image(capsys, tmp_path, name: str, *argv: str) -> tuple[np.ndarray, dict]:
    out = tmp_path / name
    code, _, err = run_cli(capsys, "-q", "render", CORNELL, *RES, "-o", str(out), *argv)
    assert code == 0, err
    layers, meta = read_exr(out.with_suffix(".exr"))
    return layers["rgb"], meta


def test_every_route_gives_the_same_bits(capsys, tmp_path):
    own, meta = cli_image(capsys, tmp_path, "own", "--spp", "16", "--seed", "3")
    named, _ = cli_image(capsys, tmp_path, "named", "--spp", "16", "--seed", "3",
                         "--sampler", "jittered")
    planned = plan_scene(CORNELL, {"res": "24"})
    api = render_film(planned.scene, make_sampler("jittered", 16), seed=3).image
    scene_sampler = render_film(plan_scene(CORNELL, {"res": "24"}).scene, spp=16, seed=3).image
    assert meta["sampler"] == "jittered" and meta["seed"] == 3 and meta["spp"] == 16
    assert own.tobytes() == named.tobytes() == api.tobytes() == scene_sampler.tobytes()
    other_seed, _ = cli_image(capsys, tmp_path, "other", "--spp", "16", "--seed", "4")
    assert not np.array_equal(own, other_seed)  # the seed does reach the render


def test_sampler_parameters_are_recorded_and_reproduce(capsys, tmp_path):
    half, meta = cli_image(capsys, tmp_path, "half", "--spp", "16", "--sampler", "jittered",
                           "-P", "jitter=0.5")
    full, _ = cli_image(capsys, tmp_path, "full", "--spp", "16", "--sampler", "jittered")
    assert '"jitter": 0.5' in meta["sampler_params"]
    assert not np.array_equal(half, full)
    api = render_film(plan_scene(CORNELL, {"res": "24"}).scene,
                      make_sampler("jittered", 16, jitter=0.5)).image
    assert api.tobytes() == half.tobytes()


def test_a_seed_is_never_a_sampler_property():
    with pytest.raises(Exception, match="seed is a setting of the render"):
        make_sampler("jittered", 16, seed=3)
    # nor the count (-P sample_count=64 --spp 4 was accepted, the -P value silently lost)
    with pytest.raises(Exception, match=r"sample_count is a setting of the render \(--spp\)"):
        make_sampler("jittered", 4, sample_count=64)
    for name in ("jittered", "independent", "stratified", "multijitter"):
        assert "seed" not in sampler_params(make_sampler(name, 16))


def test_mcrt_render_reproduces_a_study_cell(capsys, tmp_path):
    """A study cell (sampler, spp, seed) rendered again with `mcrt render` and the
    values its results record gives the study's image bit for bit."""
    from mcrt.analysis.study import load_config, run_study

    config_path = tmp_path / "study.toml"
    config_path.write_text(
        'spp = [4, 16]\nseeds = [7, 9]\nimage_spp = 16\n'
        'samplers = [{ name = "jittered", label = "half", params = { jitter = 0.5 } }]\n'
        '[reference]\nspp = 64\n[[scenes]]\n'
        f'path = "{CORNELL}"\nname = "box"\nparams = {{ res = 32 }}\n')
    result = run_study(load_config(config_path))
    cell = result.cell("box", "half", 16)
    study_image = result.images[("box", "half")].render
    again, meta = cli_image(capsys, tmp_path, "again", "-D", "res=32", "--sampler", cell["plugin"],
                            *[f"-P{k}={v}" for k, v in cell["params"].items()],
                            "--spp", str(cell["spp"]), "--seed", str(cell["seeds"][0]))
    assert again.tobytes() == study_image.astype(np.float32).tobytes()


def test_the_adaptive_plugin_and_mcrt_render_agree(capsys, tmp_path):
    """The `adaptive` integrator through `mi.render(scene, seed=S)` and
    `mcrt render SCENE --seed S` (which runs adaptive sampling for such a scene)
    seed the same way and give the same image bits."""
    import mitsuba as mi

    text = Path(CORNELL).read_text()
    start = text.index('<integrator type="path">')
    end = text.index("</integrator>", start) + len("</integrator>")
    scene_path = tmp_path / "adaptive.xml"
    scene_path.write_text(text[:start] + (
        '<integrator type="adaptive"><float name="threshold" value="0.2"/>'
        '<integer name="max_spp" value="64"/><integrator type="path"/></integrator>')
        + text[end:])
    plugin = np.array(mi.render(mi.load_file(str(scene_path), res="32"), seed=3))
    out = tmp_path / "cli"
    code, _, err = run_cli(capsys, "-q", "render", str(scene_path), "-D", "res=32", "--seed", "3",
                           "-o", str(out))
    assert code == 0, err
    layers, meta = read_exr(out.with_suffix(".exr"))
    assert layers["rgb"].tobytes() == plugin.astype(np.float32).tobytes()
