"""Adaptive sampling: error test, budgets, NaN handling, samplers, multi-level
reconstruction (the lecture's 80%-black pixel), the `adaptive` plugin and the CLI."""

from __future__ import annotations

import argparse
import math
import re
import time
from dataclasses import MISSING, asdict, fields
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.analysis.metrics import rel_mse
from mcrt.cli import _adaptive_args, main
from mcrt.core.colour import LUMINANCE_WEIGHTS
from mcrt.core.render import render_film, render_stats, srgb_to_xyz_matrix
from mcrt.core.sampling import make_sampler
from mcrt.errors import McrtError
from mcrt.io import read_exr
from mcrt.render.adaptive import (
    PARAMETERS,
    AdaptiveSettings,
    budget_batches,
    dilate,
    error_ratio,
    image_mean_luminance,
    luminance_error,
    pass_batch_size,
    pass_time_fit,
    reconstruct_samples,
    render_adaptive,
)
from mcrt.render.scene import load_scene
from tests.conftest import TINY_SCENE

ROOT = Path(__file__).resolve().parents[2]
EDGES = ROOT / "scenes" / "edges.xml"
LUMA = np.array(LUMINANCE_WEIGHTS)


@pytest.fixture(scope="module")
def edges():
    """scenes/edges.xml at 48 x 36: rods, wires, sharp shadows, a small light."""
    return load_scene(EDGES, {"width": "48", "height": "36"})


@pytest.fixture(scope="module")
def edges_reference(edges):
    """4096 jittered samples per pixel in 4 passes (7M samples, about a second)."""
    return render_stats(edges, make_sampler("jittered", 4096), seed=1234, passes=4).stats


# -- multi-level reconstruction ----------------------------------------------------

def test_lecture_case_80_percent_of_samples_in_a_small_black_region():
    """A light-grey (0.8) pixel with a black square in its corner covering 1/16
    of its area: the true pixel value is 0.8 * 15/16 = 0.75. 80 of 100 samples
    land in the black square, 20 spread over the grey rest (one in each of the
    15 grey sub-pixels, 5 more at random). The naive average says 0.16; the
    multi-level reconstruction (4 x 4 sub-pixels, each the mean of its samples,
    then averaged) gives exactly 0.75."""
    rng = np.random.default_rng(7)
    black = rng.uniform(0.0, 0.25, size=(80, 2))  # the black sub-pixel [0, 1/4)^2
    cells = np.array([(i, j) for j in range(4) for i in range(4) if (i, j) != (0, 0)])
    grey = (cells + rng.uniform(0.05, 0.95, size=(15, 2))) / 4
    extra = rng.uniform(0.25, 1.0, size=(5, 2))  # more grey samples (x >= 1/4: grey)
    position = np.concatenate([black, grey, extra])
    value = np.where((position < 0.25).all(axis=1), 0.0, 0.8)[:, None]
    assert np.isclose((value == 0).mean(), 0.8)
    naive = value.mean()
    ours = reconstruct_samples(np.zeros((100, 2), int), position, value, (1, 1), s=4)
    assert naive == pytest.approx(0.16)
    assert ours[0, 0, 0] == pytest.approx(0.75, abs=1e-12)


def test_reconstruction_of_crowded_samples_is_within_the_partial_cell_bound():
    """Same case with a black square [0.1, 0.3)^2 (area 0.04, truth 0.768) that
    is not aligned with the 8 x 8 sub-pixels: 400 of 500 samples inside it, the
    other 100 outside it (one in each of the 63 sub-pixels not inside the
    square, 37 at random). Sub-pixels away from the square are exact (0.8), the
    one inside it is exactly 0; only the 8 sub-pixels its border cuts can be
    wrong, each by at most 0.8 times its weight 1/64: |error| <= 0.1, where
    the naive average (0.16) is off by 0.6."""
    rng = np.random.default_rng(3)

    def black(p):
        return ((p >= 0.1) & (p < 0.3)).all(axis=-1)

    def outside(low, high, n):
        points = rng.uniform(low, high, size=(64 * n, 2))
        return points[~black(points)][:n]

    cells = [(i, j) for j in range(8) for i in range(8) if (i, j) != (1, 1)]  # (1,1): all black
    per_cell = np.concatenate([outside(np.array(c) / 8, (np.array(c) + 1) / 8, 1) for c in cells])
    position = np.concatenate([rng.uniform(0.1, 0.3, size=(400, 2)), per_cell,
                               outside(0.0, 1.0, 37)])
    value = np.where(black(position), 0.0, 0.8)[:, None]
    assert len(position) == 500 and black(position).mean() == 0.8
    truth = 0.8 * (1 - 0.04)
    ours = reconstruct_samples(np.zeros((500, 2), int), position, value, (1, 1), s=8)[0, 0, 0]
    assert abs(ours - truth) <= 0.8 * 8 / 64
    assert abs(value.mean() - truth) > 0.5


def test_reconstruction_with_a_wide_filter_uses_neighbouring_sub_pixels():
    """A Gaussian film filter: a pixel's value takes its neighbours' sub-pixels
    into account, and a constant image stays constant (weights renormalised)."""
    rfilter = mi.load_dict({"type": "gaussian"})
    rng = np.random.default_rng(0)
    pixel = np.stack(np.meshgrid(np.arange(5), np.arange(4)), -1).reshape(-1, 2)
    pixel = np.repeat(pixel, 16, axis=0)
    position = pixel + rng.uniform(size=pixel.shape)
    flat = reconstruct_samples(pixel, position, np.full((len(pixel), 1), 0.3), (4, 5), 4,
                               rfilter)
    assert np.allclose(flat, 0.3)
    step = np.where(pixel[:, 0] >= 3, 1.0, 0.0)[:, None]  # an edge between columns 2 and 3
    image = reconstruct_samples(pixel, position, step, (4, 5), 4, rfilter)[..., 0]
    assert 0.0 < image[1, 2] < 0.5 < image[1, 3] < 1.0  # blurred across the edge


# -- error test, dilation and batch plan ---------------------------------------------

def test_error_ratio_follows_the_documented_formula():
    settings = AdaptiveSettings(threshold=0.1, confidence=0.95, dark_floor=0.5)
    mean = np.array([1.0, 0.1, 2.0, 1.0])
    se = np.array([0.1, 0.02, 0.0, 0.5])
    count = np.array([16, 16, 16, 1])
    ratio = error_ratio(mean, se, count, settings)
    ybar = image_mean_luminance(mean, count)
    assert ybar == pytest.approx(np.mean(np.minimum(mean, np.quantile(mean, 0.99))))
    assert ratio[0] == pytest.approx(1.959964 * 0.1 / (0.1 * 1.0), rel=1e-6)
    assert ratio[1] == pytest.approx(1.959964 * 0.02 / (0.1 * 0.5 * ybar), rel=1e-6)
    assert ratio[2] == 0.0  # no spread: converged
    assert ratio[3] == np.inf  # one sample: unknown error, stays active


def test_dilation_is_a_square_clipped_at_the_border():
    mask = np.zeros((6, 7), bool)
    mask[0, 0] = mask[3, 4] = True
    out = dilate(mask, 1)
    assert out.sum() == 4 + 9
    assert out[2:5, 3:6].all() and out[:2, :2].all()
    assert (dilate(mask, 0) == mask).all()


def test_batch_sizes_follow_growth_and_never_exceed_the_budget():
    settings = AdaptiveSettings(min_spp=16, max_spp=100, growth=2.0)
    ladder = (16, 25, 64)
    # A pixel active in every pass: 16 -> +16 -> +25 (nearest to 32 on a log
    # scale: sqrt(25 * 64) = 40 > 32) -> +25 (64 would exceed the budget 43).
    assert [pass_batch_size(n, ladder, settings) for n in (16, 32, 57)] == [16, 25, 25]
    grow4 = AdaptiveSettings(max_spp=1024, growth=4.0)
    assert [pass_batch_size(n, (16, 32, 64, 128), grow4) for n in (16, 32, 64)] == [64, 128, 128]
    traced = np.array([16, 60, 75, 84, 85, 100])
    assert budget_batches(traced, ladder, 100).tolist() == [64, 25, 25, 16, 0, 0]


def test_invalid_settings_are_one_line_errors():
    for bad in ({"threshold": -1}, {"confidence": 1.0}, {"min_spp": 1},
                {"max_spp": 8, "min_spp": 16}, {"growth": 1.0}, {"dilation": -1},
                {"subpixels": 0}):
        with pytest.raises(McrtError, match="adaptive"):
            AdaptiveSettings(**bad).check()


# -- the parameters: one declaration, everything else derived from it ------------------

def _off_range(p) -> list:
    """Values just outside the parameter's range, and of the wrong type."""
    step = 1 if p.kind is int else 1e-9
    bad = [True, "1", None]
    if p.low is not None:
        bad += [p.low if p.low_open else p.low - step]
    if p.high is not None:
        bad += [p.high if p.high_open else p.high + step]
    if p.kind is int:
        bad += [float(p.default)]
    else:
        bad += [math.nan, math.inf, -math.inf]
    return bad


def _in_range(p) -> list:
    """Valid values: the default, the bounds if included, and one more."""
    good = [p.default, p.default + 1 if p.kind is int else p.default * 1.01]
    if p.low is not None and not p.low_open:
        good.append(p.kind(p.low))
    if p.high is not None and not p.high_open:
        good.append(p.kind(p.high))
    return good


def test_settings_fields_are_the_declared_parameters():
    # A field's type is its annotation's text, or the class itself once a Dr.Jit frozen
    # function has traversed an instance (an adaptive integrator's settings, inside a
    # replayed scene): Dr.Jit resolves dataclass annotations in place.
    assert [(f.name, getattr(f.type, "__name__", f.type), f.default)
            for f in fields(AdaptiveSettings)] == \
        [(p.name, p.kind.__name__, p.default) for p in PARAMETERS]
    assert all(f.default is not MISSING for f in fields(AdaptiveSettings))
    assert asdict(AdaptiveSettings()) == {p.name: p.default for p in PARAMETERS}
    for p in PARAMETERS:
        assert p.kind in (int, float) and type(p.default) is p.kind
        assert p.help and p.help == p.help.strip() and not p.help.endswith(".")
    AdaptiveSettings().check()


@pytest.mark.parametrize("p", PARAMETERS, ids=lambda p: p.name)
def test_check_follows_the_declared_range(p):
    """Every value in the declared range passes, every value outside it (or of
    the wrong type) is a one-line error that states the range."""
    # Room for the one relation between parameters, max_spp >= min_spp (>= 2).
    room = {"min_spp": {"max_spp": 1 << 20}, "max_spp": {"min_spp": 2}}.get(p.name, {})
    for value in [v for v in _in_range(p) if p.name != "max_spp" or v >= 2]:
        assert getattr(AdaptiveSettings(**{**room, p.name: value}).check(), p.name) == value
    for value in _off_range(p):
        with pytest.raises(McrtError) as error:
            AdaptiveSettings(**{**room, p.name: value}).check()
        assert str(error.value) == f"adaptive: '{p.name}' must be {p.rule()}, got {value!r}"


def test_range_rules_read_as_before():
    rules = {p.name: p.rule() for p in PARAMETERS}
    assert rules["threshold"] == "a number >= 0"
    assert rules["confidence"] == "a number in (0, 1)"
    assert rules["growth"] == "a number > 1"
    assert rules["min_spp"] == "an integer >= 2 (a variance needs two samples)"
    assert rules["max_spp"] == "a positive integer"
    assert rules["dilation"] == "an integer >= 0"
    assert rules["subpixels"] == ("an integer in [1, 16] (finer grids take minutes to compile: "
                                  "16 about 14 s, 64 over 12 minutes)")
    with pytest.raises(McrtError, match=r"'max_spp' must be >= min_spp \(16\), got 8$"):
        AdaptiveSettings(max_spp=8).check()


def _cli_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    _adaptive_args.add_cli_arguments(parser)
    return parser


def test_cli_flags_follow_the_declaration():
    actions = {a.option_strings[0]: a for a in _cli_parser()._actions if a.option_strings}
    flags = [p.flag for p in PARAMETERS if p.cli]
    assert set(actions) == {"-h", "--adaptive", *flags}
    assert "--max-lanes" not in actions  # declared without a flag
    for p in PARAMETERS:
        if not p.cli:
            continue
        action = actions[p.flag]
        assert action.dest == f"adaptive_{p.name}" and action.type is p.kind
        assert action.default is None  # unset flags keep the scene's or declared default
        assert action.help.startswith(p.help)
        assert action.help.endswith(f"{p.default})")  # "(default X)", nothing hand-typed
    assert actions["--max-spp"].help.endswith("(default: --spp if given, else 1024)")


def test_cli_settings_take_every_flag_and_the_declared_defaults():
    scene = mi.load_string(TINY_SCENE)
    parser = _cli_parser()
    parser.add_argument("--spp", type=int)
    assert _adaptive_args.cli_settings(parser.parse_args(["--adaptive"]), scene) \
        == AdaptiveSettings()
    values = {p.name: _in_range(p)[1] for p in PARAMETERS if p.cli}
    argv = ["--adaptive"] + [x for p in PARAMETERS if p.cli
                             for x in (p.flag, str(values[p.name]))]
    settings = _adaptive_args.cli_settings(parser.parse_args(argv), scene)
    assert {k: getattr(settings, k) for k in values} == values
    spp = _adaptive_args.cli_settings(parser.parse_args(["--adaptive", "--spp", "64"]), scene)
    assert spp.max_spp == 64
    with pytest.raises(McrtError, match="^--threshold, --dark-floor: only with --adaptive$"):
        _adaptive_args.cli_settings(parser.parse_args(["--threshold", "0.1",
                                                       "--dark-floor", "0.2"]), scene)


@pytest.mark.parametrize("p", PARAMETERS, ids=lambda p: p.name)
def test_plugin_properties_follow_the_declaration(p):
    value = _in_range(p)[1]
    integrator = mi.load_dict({"type": "adaptive", p.name: value})
    assert getattr(integrator.settings, p.name) == value
    assert type(getattr(integrator.settings, p.name)) is p.kind
    if p.kind is float:  # an integer property of a float parameter is converted
        whole = next((n for n in range(5) if p.valid(n)), None)
        if whole is not None:
            converted = mi.load_dict({"type": "adaptive", p.name: whole}).settings
            assert type(getattr(converted, p.name)) is float
    else:
        with pytest.raises(Exception, match=f"'{p.name}' must be an integer"):
            mi.load_dict({"type": "adaptive", p.name: float(value)})
    bad = _off_range(p)[3]
    with pytest.raises(Exception, match=f"'{p.name}' must be"):
        mi.load_dict({"type": "adaptive", p.name: bad})


def test_plugin_docstring_table_is_the_declaration():
    """Rows of the ``pluginparameters`` table: name, type, text, default."""
    from mcrt.render.adaptive_integrator import AdaptiveIntegrator

    rows = re.findall(r"\* - (\S+)\n\s+- \|(\w+)\|\n\s+- (.*?)\(Default:\s+(.*?)\)\n",
                      AdaptiveIntegrator.__doc__, flags=re.S)
    assert [(name, kind, default) for name, kind, _, default in rows] == \
        [(p.name, p.kind.__name__, str(p.default)) for p in PARAMETERS]
    for (_, _, text, _), p in zip(rows, PARAMETERS, strict=True):
        assert " ".join(text.split()).lower().startswith(p.help.lower() + ".")


def test_readme_table_and_flags_are_the_declaration():
    readme = (ROOT / "docs" / "adaptive.md").read_text()
    table = readme.split("| parameter | default | meaning |\n|---|---|---|\n", 1)[1]
    rows = [line for line in table.split("\n\n", 1)[0].splitlines()]
    assert rows == [f"| `{p.name}` | {p.default} | {p.help} |" for p in PARAMETERS]
    sentence = readme.split("The command line takes them as ", 1)[1].split(".\n", 1)[0]
    assert re.findall(r"`(--[a-z-]+)`", sentence) == [p.flag for p in PARAMETERS if p.cli]


# -- the render loop -----------------------------------------------------------------

def test_first_pass_equals_a_fixed_render(edges):
    """With an unreachable threshold the render stops after pass 0, which draws
    exactly the samples of a fixed 16-spp render with the same seed: with
    `jittered`, one sample per 4 x 4 sub-pixel, so the reconstruction equals
    the film's box average (up to float32 accumulation order)."""
    result = render_adaptive(edges, make_sampler("jittered", 16),
                             AdaptiveSettings(threshold=1e9), seed=5)
    fixed = render_film(edges, make_sampler("jittered", 16), seed=5)
    assert len(result.passes) == 1 and (result.spp == 16).all()
    assert np.allclose(result.rgb, fixed.rgb, rtol=1e-5, atol=1e-6)


def test_the_render_s_seconds_include_developing_its_image(edges, monkeypatch):
    """As a film render's seconds include its film's development, an adaptive
    render's include its reconstruction: slowed down by 0.3 s, the reported
    seconds exceed the passes' by at least that (they did not before)."""
    from mcrt.render.adaptive import engine

    develop = engine.reconstruct_grid

    def slow(*args, **kwargs):
        time.sleep(0.3)
        return develop(*args, **kwargs)

    monkeypatch.setattr(engine, "reconstruct_grid", slow)
    result = render_adaptive(edges, make_sampler("jittered", 16),
                             AdaptiveSettings(threshold=1e9), seed=5)
    assert result.seconds >= sum(p.seconds for p in result.passes) + 0.3


def test_constant_scene_stops_after_the_first_pass():
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.5, 0.7]}},
        "sensor": {"type": "perspective",
                   "film": {"type": "hdrfilm", "width": 20, "height": 10,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}}})
    result = render_adaptive(scene, settings=AdaptiveSettings(threshold=0.001))
    assert len(result.passes) == 1
    assert (result.spp == 16).all()
    assert np.allclose(result.rgb, [0.3, 0.5, 0.7], rtol=1e-6)
    assert (result.variance == 0).all()


def test_min_and_max_spp_are_respected(edges):
    """threshold 0: every pixel with any variance runs until its budget cannot
    fit another minimal batch; max_spp = 100 is not a sum of ladder sizes."""
    settings = AdaptiveSettings(threshold=0.0, min_spp=16, max_spp=100)
    lanes = []
    result = render_adaptive(edges, make_sampler("jittered", 16), settings, seed=1,
                             on_samples=lambda k, ids, pos, rgb: lanes.append(ids.size))
    spp = result.spp
    assert spp.min() >= 16 and spp.max() <= 100
    noisy = result.variance.sum(-1) > 0
    assert (spp[noisy] > 100 - 16).all()  # stopped only when < 16 samples were left
    assert (spp[~noisy] == 16).all()  # exactly flat pixels (zero variance) stop at once
    assert sum(lanes) == result.samples == sum(p.samples for p in result.passes)


def test_sample_totals_count_a_sampled_border(edges):
    """A film that samples its border (gaussian, radius 2: 2 more pixels on each
    side) traces the border pixels too; the image and the `spp` layer cover the
    crop window only, but the render's sample total (the EXR header's `samples`,
    the samples per second) is what the passes traced, as a film render's is. It
    counted the crop's samples alone: 2/3 of those traced at 24 x 16."""
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "light": {"type": "sphere", "radius": 0.3, "center": [1, 1, 1],
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20}}},
        "ball": {"type": "sphere", "radius": 0.5, "bsdf": {"type": "diffuse"}},
        "sensor": {"type": "perspective",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 16,
                            "sample_border": True, "rfilter": {"type": "gaussian"}}}})
    lanes: list[int] = []
    result = render_adaptive(scene, make_sampler("jittered", 16),
                             AdaptiveSettings(threshold=0.05, max_spp=128), seed=1,
                             on_samples=lambda k, ids, pos, rgb: lanes.append(ids.size))
    assert result.spp.shape == result.image.shape[:2] == (16, 24)
    assert result.passes[0].samples == 28 * 20 * 16  # the border's pixels too
    traced = sum(p.samples for p in result.passes)
    assert sum(lanes) == traced == result.samples == result.summary()["samples"]
    assert result.samples > result.spp.sum()
    assert result.summary()["mean_spp"] == round(result.spp.mean(), 3)


def test_later_passes_trace_only_active_pixels(edges):
    """Compaction: a pass traces exactly its active pixels' new samples, each
    pixel in one contiguous batch; no later pass traces the whole image."""
    seen: dict[int, list[np.ndarray]] = {}
    result = render_adaptive(edges, make_sampler("jittered", 16),
                             AdaptiveSettings(threshold=0.05, max_spp=256), seed=2,
                             on_samples=lambda k, ids, pos, rgb: seen.setdefault(k, []).append(ids))
    pixels = result.spp.size
    for record in result.passes:
        ids = np.concatenate(seen[record.index])
        assert ids.size == record.samples
        assert np.unique(ids).size == record.active_pixels
    assert result.passes[0].active_pixels == pixels
    assert max(p.active_pixels for p in result.passes[1:]) < 0.7 * pixels
    fit = pass_time_fit(result.passes)
    assert set(fit) == {"intercept", "slope", "r2", "passes"}


def test_failing_pixels_and_their_neighbours_are_refined_at_the_same_rate(edges):
    """Pass 1 traces exactly the pixels that failed the test after pass 0 plus
    their `dilation` neighbours, all with the same batch; without dilation
    only the failing ones (pass 0 is the same with the same seed, and a
    render with max_spp = min_spp stops after it, so its `converged` mask is
    the test after pass 0)."""
    first = render_adaptive(edges, make_sampler("jittered", 16),
                            AdaptiveSettings(threshold=0.05, max_spp=16), seed=7)
    failing = ~first.converged
    assert 0 < failing.sum() < failing.size / 2
    for radius in (0, 1, 2):
        seen = {}
        render_adaptive(edges, make_sampler("jittered", 16),
                        AdaptiveSettings(threshold=0.05, max_spp=32, dilation=radius), seed=7,
                        on_samples=lambda k, ids, pos, rgb, seen=seen:
                            seen.setdefault(k, []).append(ids))
        ids = np.concatenate(seen[1])
        traced = np.zeros(failing.size, bool)
        traced[ids] = True
        assert (traced.reshape(failing.shape) == dilate(failing, radius)).all()
        assert (np.bincount(ids)[np.unique(ids)] == 16).all()  # one batch of 16 each


def test_converges_to_the_reference_within_its_error_bound(edges, edges_reference):
    """The stopping rule's promise, checked against a 4096-spp reference with
    the `independent` sampler (whose i.i.d. standard error is the true one):
    pixels that pass the error test at the end have |Y - Y_ref| <= threshold *
    max(Y_ref, floor * Ybar) (+ 1.96 reference standard errors) at least
    `confidence` = 95% of the time. With ~1700 pixels the binomial standard
    deviation of that fraction is 0.5%, so 0.95 - 3 sd = 0.934 is the bound;
    the luminance standard error is an upper bound, so 99.9-100% is typical,
    while a standard error not divided by sqrt(n), or a variance in its place,
    drops far below. The image mean must match the reference's within 3.5 of
    its combined standard errors (no bias from stopping or reconstruction)."""
    y_ref, se_ref = luminance_error(edges_reference)
    level = AdaptiveSettings().dark_floor * image_mean_luminance(y_ref, edges_reference.count)
    for threshold in (0.1, 0.025):
        settings = AdaptiveSettings(threshold=threshold, max_spp=2048)
        result = render_adaptive(edges, make_sampler("independent", 16), settings, seed=11)
        y = result.rgb.astype(np.float64) @ LUMA
        y_samples, se = luminance_error(result.stats)
        passed = error_ratio(y_samples, se, result.stats.count, settings) <= 1
        assert passed.mean() > 0.9  # not vacuous (99.8% at 0.1, 94% at 0.025)
        tolerance = threshold * np.maximum(y_ref, level) + 1.96 * se_ref
        assert np.mean(np.abs(y - y_ref)[passed] <= tolerance[passed]) >= 0.934
        z_mean = (y.mean() - y_ref.mean()) / (np.sqrt(np.sum(se ** 2 + se_ref ** 2)) / y.size)
        assert abs(z_mean) < 3.5


def test_error_falls_with_the_threshold(edges, edges_reference):
    """Quartering the threshold must cut the relMSE by at least 4x: 16x is
    the ideal for pixels the error test governs; pixels at min_spp or
    max_spp, and the light's rim (a false-negative case), give less (about
    8x measured with `jittered`, seeds 11 and 12)."""
    errors = [rel_mse(render_adaptive(edges, make_sampler("jittered", 16),
                                      AdaptiveSettings(threshold=t, max_spp=2048),
                                      seed=11).rgb, edges_reference.mean)
              for t in (0.1, 0.025)]
    assert errors[1] < errors[0] / 4


def _no_repeats(seen) -> None:
    """No sample position of a pixel occurs twice across passes."""
    ids = np.concatenate([ids for ids, _ in seen])
    pos = np.concatenate([pos for _, pos in seen])
    keys = np.column_stack([ids, np.round(pos * 2 ** 24)])
    assert np.unique(keys, axis=0).shape[0] == keys.shape[0]


@pytest.mark.parametrize("name", ["jittered", "poisson_disk", "independent"])
def test_works_with_our_samplers_and_mitsubas(edges, edges_reference, name):
    """Every sampler gives a render within 5% of the reference's image mean
    (the light's rim makes that mean noisy: a 1%-level effect here), counts
    within budget, samples that never repeat, and lower relMSE than a fixed
    render of the same sampler at the same mean sample count (rounded down)."""
    seen = []
    settings = AdaptiveSettings(threshold=0.05, max_spp=256)
    result = render_adaptive(edges, make_sampler(name, 16), settings, seed=3,
                             on_samples=lambda k, ids, pos, rgb: seen.append((ids, pos)))
    assert result.sampler == name
    assert result.spp.min() >= 16 and result.spp.max() <= 256
    assert abs(result.rgb.mean() / edges_reference.mean.mean() - 1) < 0.05
    _no_repeats(seen)
    mean_spp = result.samples / result.spp.size
    fixed_spp = {"jittered": 16, "poisson_disk": 32, "independent": 32}[name]
    assert fixed_spp <= mean_spp
    fixed = render_film(edges, make_sampler(name, fixed_spp), seed=3)
    assert rel_mse(result.rgb, edges_reference.mean) < rel_mse(fixed.rgb, edges_reference.mean)


# -- NaN handling ---------------------------------------------------------------------

class NaNDirect(mi.SamplingIntegrator):
    """`direct`, but NaN in the left quarter of the image and, in a band of
    columns, in half of the samples (a sample's own random number decides)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.inner = mi.load_dict({"type": "direct"})

    def sample(self, scene, sampler, ray, medium=None, active=True):
        spec, valid, aovs = self.inner.sample(scene, sampler, ray, medium, active)
        coin = sampler.next_1d(active) < 0.5
        x = ray.d.x / -ray.d.z  # image-plane coordinate, -tan(fov/2)..tan(fov/2)
        nan = (x < -0.2) | ((x > 0.05) & (x < 0.12) & coin)
        return dr.select(nan, mi.Color3f(dr.nan), spec), valid, aovs

    def to_string(self) -> str:
        return "NaNDirect[]"


def test_nan_pixels_do_not_stall_or_poison_the_render(edges, caplog):
    settings = AdaptiveSettings(threshold=0.05, max_spp=128)
    nan_integrator = NaNDirect(mi.Properties())
    result = render_adaptive(edges, make_sampler("jittered", 16), settings, seed=4,
                             integrator=nan_integrator)
    clean = render_adaptive(edges, make_sampler("jittered", 16), settings, seed=4)
    assert np.isfinite(result.image).all()
    dead = result.stats.count == 0  # pixels that only produced NaN
    assert dead[:, :10].all()  # the left quarter (x < -0.2) of the 48 columns
    assert (result.spp[dead] > 128 - 16).all()  # they spent their budget, then stopped
    assert (result.nonfinite[dead] == result.spp[dead]).all()
    assert (result.image[dead] == 0).all()
    partial = (result.nonfinite > 0) & ~dead
    assert partial.sum() >= 36  # the half-NaN band: at least one column of pixels
    assert (result.stats.count[partial] > 0).all()
    # Finite samples of half-NaN pixels still estimate the pixel: within 25% of
    # the clean render's value on average (direct lighting of the wall).
    ratio = result.rgb[partial].mean() / clean.rgb[partial].mean()
    assert 0.75 < ratio < 1.25
    assert sum(p.nonfinite for p in result.passes) == int(result.nonfinite.sum())
    assert len(result.passes) < 20
    assert "NaN/Inf samples left out" in caplog.text


def test_a_pixel_without_a_finite_sample_has_an_unknown_standard_error(edges, tmp_path):
    """A pixel all of whose samples were NaN is not exact: its standard errors
    (stderr per channel, stderr_y) are NaN, every other pixel's finite; the EXR,
    PNG and heat map are written and the EXR reads back with those NaNs."""
    from mcrt.io import write_exr, write_png
    from mcrt.io.heatmap import write_heatmap

    settings = AdaptiveSettings(threshold=0.05, max_spp=64)
    result = render_adaptive(edges, make_sampler("jittered", 16), settings, seed=4,
                             integrator=NaNDirect(mi.Properties()))
    dead = result.stats.count == 0
    assert dead[:, :10].all() and not dead.all()
    layers = result.layers()
    for name in ("stderr", "stderr_y"):
        unknown = ~np.isfinite(layers[name])
        assert np.array_equal(unknown if unknown.ndim == 2 else unknown.any(axis=-1), dead)
    assert np.isnan(result.standard_error[dead]).all()
    assert not result.converged[dead].any()  # an unknown error never passes the test
    write_exr(tmp_path / "a.exr", layers, {}, channels=result.film_channels())
    write_png(tmp_path / "a.png", result.rgb)
    write_heatmap(tmp_path / "a_spp.png", result.spp, settings.min_spp, settings.max_spp)
    back, _ = read_exr(tmp_path / "a.exr")
    assert np.isnan(back["stderr"][dead]).all() and np.isfinite(back["stderr"][~dead]).all()
    assert np.isfinite(back["rgb"]).all()


# -- the `adaptive` plugin and the CLI ---------------------------------------------------

def test_plugin_renders_from_xml_through_mi_render():
    xml = EDGES.read_text().replace(
        '<integrator type="direct"/>',
        '<integrator type="adaptive"><float name="threshold" value="0.1"/>'
        '<integer name="max_spp" value="128"/><integrator type="direct"/></integrator>')
    scene = mi.load_string(xml, width="32", height="24")
    integrator = scene.integrator()
    image = np.array(mi.render(scene, seed=3))
    result = integrator.last_result
    assert image.shape == (24, 32, 3)
    assert np.array_equal(image, result.image)
    assert result.spp.max() <= 128 and result.spp.min() == 16
    mi.render(scene, seed=3, spp=48)  # mi.render's spp is the per-pixel budget
    assert integrator.last_result.spp.max() <= 48


@pytest.mark.parametrize("pixel_format, channels", [("luminance", 1), ("xyza", 4)])
def test_plugin_develops_films_of_other_pixel_formats(pixel_format, channels):
    """The plugin puts linear sRGB[A] in the film, which forms its own Y or X Y Z
    on develop (it once refused such films): the same samples as an RGB film,
    converted with Mitsuba's matrix."""
    images = {}
    for fmt in ("rgba", pixel_format):
        scene = mi.cornell_box()
        scene["sensor"]["film"].update({"width": 16, "height": 16, "pixel_format": fmt,
                                        "rfilter": {"type": "box"}})
        scene["integrator"] = {"type": "adaptive", "max_spp": 32,
                               "nested": {"type": "path", "max_depth": 3}}
        images[fmt] = np.array(mi.render(mi.load_dict(scene), seed=4), np.float64)
    image, rgb = images[pixel_format], images["rgba"][..., :3]
    assert image.shape == (16, 16, channels)
    matrix = srgb_to_xyz_matrix()
    expected = rgb @ matrix[1][:, None] if channels == 1 else rgb @ matrix.T
    np.testing.assert_allclose(image[..., :3], expected, rtol=1e-4, atol=1e-5)


def test_plugin_from_a_dict_wraps_path_and_uses_the_film_filter():
    scene = mi.cornell_box()
    scene["sensor"]["film"].update({"width": 24, "height": 24})
    scene["sensor"]["sampler"] = {"type": "independent"}
    scene["integrator"] = {"type": "adaptive", "min_spp": 8, "max_spp": 64,
                           "nested": {"type": "path", "max_depth": 3}}
    scene = mi.load_dict(scene)
    image = np.array(mi.render(scene))
    assert image.shape == (24, 24, 3) and np.isfinite(image).all() and image.mean() > 0.05
    result = scene.integrator().last_result
    assert result.passes[0].samples == 24 * 24 * 8 and result.spp.max() <= 64


def test_plugin_rejects_unknown_parameters():
    with pytest.raises(Exception, match="unknown parameter 'treshold'"):
        mi.load_dict({"type": "adaptive", "treshold": 0.1})


def test_cli_writes_layers_and_heat_map(tmp_path, capsys):
    out = tmp_path / "edges"
    code = main(["render", str(EDGES), "--adaptive", "-D", "width=32", "-D", "height=24",
                 "--max-spp", "64", "--threshold", "0.1", "-o", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0
    layers, meta = read_exr(out.with_suffix(".exr"))
    assert set(layers) == {"rgb", "variance", "stderr", "stderr_y", "spp", "nonfinite"}
    spp = layers["spp"]
    assert spp.shape == (24, 32) and spp.min() >= 16 and spp.max() <= 64
    assert meta["passes"] >= 2 and meta["adaptive_threshold"] == 0.1
    assert (tmp_path / "edges_spp.png").stat().st_size > 0
    assert "pass  0  active       768 px (100.0%)" in stdout and "converged" in stdout


def test_cli_adaptive_options_need_adaptive(capsys):
    code = main(["render", str(EDGES), "-D", "width=8", "-D", "height=8", "--threshold", "0.1"])
    assert code == 2
    assert "--threshold: only with --adaptive" in capsys.readouterr().err


def test_cli_adaptive_refuses_motion_blur_before_rendering(capsys):
    """Motion blur moves the geometry between sub-frames of the whole image; the
    adaptive loop's passes cover only some pixels, so it is refused up front."""
    motion = EDGES.parent / "effects" / "motion.xml"
    code = main(["render", str(motion), "--adaptive", "-D", "width=8", "-D", "height=8"])
    assert code == 2
    assert "--adaptive does not render motion blur" in capsys.readouterr().err


# -- progressive samplers: batches continue one sequence per pixel ---------------------

def _is_net(points: np.ndarray) -> bool:
    """Every elementary interval of area 1/N (all log2 N + 1 shapes) holds one point."""
    n = points.shape[0]
    m = n.bit_length() - 1
    for a in range(m + 1):
        cells = (np.floor(points[:, 0] * 2 ** a).astype(np.int64) * 2 ** (m - a)
                 + np.floor(points[:, 1] * 2 ** (m - a)).astype(np.int64))
        if np.unique(cells).size != n:
            return False
    return True


def test_sobol_adaptive_batches_are_prefixes_of_one_sequence(edges):
    """With `sobol`, each pixel's batches are consecutive pieces of its own sequence:
    the film positions a pixel received over all passes are, in order, samples
    0, 1, 2, ... of its sequence (up to the film's float rounding, ~2e-6), and
    wherever they add up to 2^a that prefix is a (0,a,2)-net. The old k*m epoch
    offsets (batch sizes 16, 16, 16, 32, ... -> indices 0-15, 16-31, 32-47, 96-127)
    skip and fail the first check."""
    from mcrt.samplers.points import point_sets

    seen = []
    settings = AdaptiveSettings(threshold=0.02, max_spp=128)
    render_adaptive(edges, make_sampler("sobol", 4), settings, seed=3,
                    on_samples=lambda k, ids, pos, rgb: seen.append((ids, pos)))
    assert len(seen) >= 3
    ids = np.concatenate([i for i, _ in seen])
    pos = np.concatenate([p for _, p in seen])
    counts = np.bincount(ids)
    assert len(set(counts[counts > 0].tolist())) >= 3  # batches of several sizes
    nets = 0
    for pixel in np.unique(ids)[::7]:
        own = pos[ids == pixel]
        prefix = point_sets("sobol", [int(pixel)], own.shape[0], seed=3)[0].astype(np.float64)
        assert np.abs(own - prefix).max() < 1e-5, pixel
        n = own.shape[0]
        if n & (n - 1) == 0:
            assert _is_net(prefix), (pixel, n)
            nets += 1
    assert nets >= 5


def test_a_progressive_batch_past_32_bit_sample_indices_is_refused(edges):
    """A `sobol` batch continues each pixel after its samples so far, and those
    were uploaded as 32-bit indices: a pixel with 2^32 - 8 samples given a batch
    of 16 was traced with indices wrapped to 0-7, the sequence's first samples
    again, silently (the pass check only bounded k * m, not what pixels hold)."""
    from mcrt.render.adaptive.sums import PixelSums
    from mcrt.render.adaptive.wavefront import Target, trace_wavefront

    sensor = edges.sensors()[0]
    acc = PixelSums(48 * 36, 4, 3)
    ids = np.arange(4)
    acc.traced[ids] = (1 << 32) - 8
    target = Target(edges, sensor, edges.integrator(), make_sampler("sobol", 16), 16, acc)
    with pytest.raises(McrtError, match="exceed the 32-bit sample indices"):
        trace_wavefront(target, ids, 16, 1, 0, [])
    acc.traced[ids] = (1 << 32) - 32  # the last batch that fits is traced
    trace_wavefront(target, ids, 16, 1, 0, [])


@pytest.mark.parametrize("name", ["jittered", "sobol"])
def test_wavefronts_split_in_chunks_give_the_same_bits(edges, name):
    """A pass whose pixels are traced in several wavefronts (``max_lanes`` smaller
    than the pass) gives the same image, sample counts and pass records as one
    wavefront per pass: mcrt's samplers draw by (seed, pixel, sample), each pixel's
    sums are formed in order, and a pass's wavefronts are merged together at its
    end. (48 x 36 = 1728 pixels at 16 spp = 27648 lanes; 4096 lanes per wavefront
    split the first pass into 7 wavefronts.)"""
    settings = AdaptiveSettings(threshold=0.05, max_spp=256)
    whole = render_adaptive(edges, make_sampler(name, 16), settings, seed=5)
    split = render_adaptive(edges, make_sampler(name, 16),
                            AdaptiveSettings(threshold=0.05, max_spp=256, max_lanes=4096),
                            seed=5)
    assert len(whole.passes) >= 3
    assert split.image.tobytes() == whole.image.tobytes()
    assert np.array_equal(split.spp, whole.spp)
    assert [p.samples for p in split.passes] == [p.samples for p in whole.passes]


def test_a_render_that_ran_out_of_budget_says_so(tmp_path, capsys):
    """When most pixels fail the error test at max_spp the budget, not the
    threshold, made the image: the command says so and how to change it; a
    render whose pixels met the threshold says nothing of the kind."""
    small = ["-D", "width=32", "-D", "height=24"]
    assert main(["-q", "render", str(EDGES), *small, "--adaptive", "--threshold", "0.001",
                 "--max-spp", "64", "-o", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    note = next(line for line in out.splitlines() if line.startswith("note: "))
    assert "ran out of the budget of 64 spp" in note and "raise --max-spp" in note
    assert float(note.split("%")[0].split()[-1]) > 50
    assert main(["-q", "render", str(EDGES), *small, "--adaptive", "--threshold", "0.2",
                 "--max-spp", "256", "-o", str(tmp_path / "b")]) == 0
    assert "ran out of the budget" not in capsys.readouterr().out


@pytest.mark.parametrize("name", ["jittered", "orthogonal", "ldsampler", "poisson_disk", "sobol"])
def test_batch_ladder_is_the_scan_s_and_cheap_for_huge_budgets(name, monkeypatch):
    """The ladder (each batch the largest count the sampler serves within twice the
    last) equals a plain scan down from each request on small budgets, and a budget
    of 2^40 samples per pixel needs a few thousand count queries, not weeks of them."""
    from mcrt.render.adaptive import ladder as lad

    def scan(sampler, min_spp, max_spp):
        ladder = [lad._count_for(sampler, min_spp)]
        request = 2 * ladder[0]
        while request <= max_spp:
            for r in range(request, ladder[-1], -1):
                count = lad._count_for(sampler, r)
                if count is not None and ladder[-1] < count <= request:
                    ladder.append(count)
                    break
            request *= 2
        return tuple(ladder)

    sampler = make_sampler(name, 16)
    for low, high in ((16, 1024), (20, 4096), (1, 300)):
        assert lad.batch_ladder(sampler, low, high) == scan(sampler, low, high), (low, high)
    calls = []
    real = lad._count_for
    monkeypatch.setattr(lad, "_count_for", lambda s, r: calls.append(r) or real(s, r))
    huge = lad.batch_ladder(sampler, 16, 2 ** 40)
    assert len(calls) < 5000 and list(huge) == sorted(set(huge)) and huge[-1] <= 2 ** 40


def test_the_command_line_makes_an_adaptive_sampler_at_min_spp(tmp_path, monkeypatch):
    """`mcrt render --adaptive` draws batches from min_spp up, so it makes the
    sampler at min_spp: a point-set file holding only 16-point sets renders (it
    was made at the scene's 64 spp and refused, and the --spp 16 the error
    suggested also capped the budget at 16)."""
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    np.save("sets16.npy", (rng.random((64, 16, 2)) * 0.99).astype(np.float32))
    code = main(["-q", "render", str(ROOT / "scenes" / "cornell_box.xml"), "-D", "res=8",
                 "--adaptive", "--sampler", "pointset", "-P", "filename=sets16.npy",
                 "--max-spp", "48", "-o", "a"])
    assert code == 0
    layers, header = read_exr(Path("a.exr"))
    assert int(np.max(layers["spp"])) == 48 and str(header["batch_ladder"]).strip("()[], ") == "16"
