"""Every shipped scene and every scene the test suite writes:
``mcrt render`` writes its files and agrees with ``mi.render`` of the same scene,
and ``mcrt plan`` lists exactly the effects the scene has.

Render agreement
    Each case is rendered ``SEEDS`` times by ``mcrt render`` (the CLI, in-process,
    at a tiny resolution set with ``-D`` and ``SPP`` samples per pixel) and
    ``SEEDS`` times by ``mi.render`` of the *planned* scene (what ``mcrt render``
    renders: :func:`plan_scene` at the same ``-D`` parameters; for motion blur,
    one ``mi.render`` per sub-frame of the plan's schedule, averaged), with
    disjoint seeds. The image means (over pixels and the R, G, B channels) must
    agree within ``Z_MAX = 5`` standard errors.

    The standard error comes from the per-pixel spread over the seeds. With
    per-pixel values ``x_kp`` (seed ``k``, pixel ``p``) and deviations
    ``d_kp = x_kp - mean_k x_kp``, ``Var(image mean) = sum_pq Cov(p, q) / (K P^2)``
    for the mean of ``K`` independent renders of ``P`` pixels; ``Cov(p, q)`` is
    estimated by ``sum_k d_kp d_kq / (K - 1)``. Samples are independent between
    pixels, so two pixels are correlated only through samples that the
    reconstruction filter splats into both: only pixel pairs closer than the
    filter's support (``|p - q| < 2 x radius`` on each axis) are summed. With a
    box filter that is the diagonal alone (independent pixels, thousands of
    degrees of freedom); a gaussian (radius 2) sums a 7 x 7 neighbourhood, which
    the usual per-pixel formula would leave out (it underestimates the SE of a
    filtered film by ~2x). The two SEs add in quadrature. At 5 SE a Gaussian
    false alarm has probability 6e-7 per case; the seeds are fixed, so the
    outcome is deterministic. The test is not vacuous: at 16x12 pixels, 16 spp
    and 4 seeds the SE is 0.1-1% of the mean, so a bias of a few percent (the
    old-format scene once was +4.5%) is 5-40 SE.

    Handled explicitly, not skipped:

    * ``hard/degenerate.xml`` makes NaN samples by design (panel C's NaN vertex
      colour). ``mi.render`` averages them into NaN pixels; mcrt leaves them out
      and counts them (the EXR's ``nonfinite`` layer, which must be non-empty).
      The means are compared over the pixels where neither renderer met a NaN.
    * ``hard/sky.xml`` has no variance at all (every sample is float32(0.3)):
      both images must equal it exactly (the SE is 0, a z-score is undefined).
    * ``hard/furnace.xml`` and ``hard/sky.xml`` default to 4096 x 1 pixels; they
      are rendered at 64 x 1.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.cli import main
from mcrt.io import read_exr
from mcrt.render.plan import plan_scene
from tests.conftest import ROOT, TINY_SCENE, run_cli
from tests.render.test_effects import STREAK_XML, dof_scene
from tests.render.test_plan import MOVING

SCENES = ROOT / "scenes"
SEEDS, SPP, Z_MAX = 4, 16, 5.0
SMALL = {"width": "16", "height": "12"}

#: Shipped scenes: scene parameters for a tiny render (no entry: the scene is already tiny).
SHIPPED: dict[str, dict[str, str]] = {
    "checkerboard.xml": SMALL, "cornell_box.xml": {"res": "16"}, "edges.xml": SMALL,
    "glossy_bias.xml": {"res": "12"},
    **{f"effects/{n}.xml": SMALL for n in ("aa", "combined", "dof", "glossy", "motion",
                                          "soft_shadows")},
    "filters/slanted_edge.xml": SMALL,
    "foreign/aov.xml": {}, "foreign/env_lit.xml": {}, "foreign/medium.xml": {},
    "foreign/medium_in_dielectric.xml": {"res": "12"}, "foreign/mesh_light.xml": {"res": "12"},
    "foreign/moment.xml": {}, "foreign/old_format.xml": {"res": "12"}, "foreign/sphere.xml": {},
    "foreign/irradiance_meter.xml": {},
    **{f"hard/{n}.xml": SMALL for n in ("degenerate", "dynamic_range", "fireflies", "grazing")},
    "hard/furnace.xml": {"width": "64", "height": "1"},
    "hard/sky.xml": {"width": "64", "height": "1"},
    **{f"multisample/{n}.xml": SMALL for n in ("bitmap", "checker", "polygons")},
}

#: Scenes the suite writes (XML text), from the tests that write them.
WRITTEN: dict[str, str] = {
    "conftest.TINY_SCENE": TINY_SCENE,
    "test_plan.MOVING": MOVING.format(close="1", id='id="ball"',
                                      motion='<vector name="mcrt_velocity" value="2, 0, 0"/>'),
    "test_effects.STREAK_XML": STREAK_XML,
    "test_effects.dof_scene": dof_scene(8.0),
}

#: Extra render cases: the filtered films (whose pixels are correlated).
FILTERED = [("filters/slanted_edge.xml", {**SMALL, "filter": f}) for f in ("gaussian", "mitchell")]


def all_shipped() -> set[str]:
    return {p.relative_to(SCENES).as_posix() for p in SCENES.rglob("*.xml")}


def test_every_shipped_scene_is_covered():
    assert set(SHIPPED) == all_shipped()
    assert set(PLAN_ELSEWHERE) | set(EFFECTS) >= all_shipped() | set(WRITTEN)


def scene_path(name: str, tmp_path: Path) -> Path:
    if name in WRITTEN:
        path = tmp_path / (name.replace(".", "_") + ".xml")
        path.write_text(WRITTEN[name])
        return path
    return SCENES / name


# ----------------------------------------------------------------------------
# Renders and their statistics
# ----------------------------------------------------------------------------
def mcrt_renders(path: Path, params: dict[str, str], out: Path) -> list[dict[str, np.ndarray]]:
    """``mcrt render`` at seeds 0..SEEDS-1; checks the files it writes."""
    defines = [a for k, v in params.items() for a in ("-D", f"{k}={v}")]
    layers = []
    for seed in range(SEEDS):
        stem = out / f"r{seed}"
        assert main(["-q", "render", str(path), *defines, "--spp", str(SPP), "--seed", str(seed),
                     "-o", str(stem)]) == 0
        for suffix in (".exr", ".png"):
            assert stem.with_suffix(suffix).stat().st_size > 0
        layers.append(read_exr(stem.with_suffix(".exr"))[0])
    return layers


def mitsuba_renders(path: Path, params: dict[str, str]) -> tuple[list[np.ndarray], float]:
    """``mi.render`` of the planned scene (per sub-frame for motion blur) at seeds
    apart from mcrt's; and the film's reconstruction filter radius."""
    planned = plan_scene(path, params)
    images = []
    for seed in range(SEEDS):
        passes, on_pass = planned.schedule(None, SPP, 100 + seed)
        if on_pass is None:
            images.append(np.array(mi.render(planned.scene, spp=SPP, seed=100 + seed)))
            continue
        frames = []
        for i in range(passes):
            on_pass(i, passes)  # sub-frame i of passes
            frames.append(np.array(mi.render(planned.scene, spp=SPP // passes,
                                             seed=1000 * (seed + 1) + i), dtype=np.float64))
        images.append(np.mean(frames, axis=0))
    return images, float(planned.scene.sensors()[0].film().rfilter().radius())


def mean_and_se(images: list[np.ndarray], radius: float,
                mask: np.ndarray | None = None) -> tuple[float, float]:
    """Image mean over ``K`` renders and its standard error (module doc), over
    the pixels where ``mask`` is true (default all)."""
    stack = np.stack([np.asarray(im, np.float64)[..., :3].mean(axis=-1) for im in images])
    keep = np.ones(stack.shape[1:], bool) if mask is None else mask
    k, n = stack.shape[0], int(keep.sum())
    stack = np.where(keep, stack, 0.0)  # masked pixels (NaN) count for nothing
    dev = stack - stack.mean(axis=0)
    reach = max(math.ceil(2 * radius) - 1, 0)  # largest offset of pixels sharing samples
    h, w = keep.shape
    total = 0.0
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            a = dev[:, max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)]
            b = dev[:, max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
            total += float((a * b).sum()) / (k - 1)
    return float(stack[:, keep].mean()), math.sqrt(max(total, 0.0) / k) / n


def compare(name: str, params: dict[str, str], tmp_path: Path) -> None:
    path = scene_path(name, tmp_path)
    ours = mcrt_renders(path, params, tmp_path)
    theirs, radius = mitsuba_renders(path, params)
    rgb = [layer["rgb"] for layer in ours]
    assert rgb[0].shape[:2] == theirs[0].shape[:2] and rgb[0].size <= 64 * 64 * 3
    if name == "hard/sky.xml":  # no variance by design: exact values
        for image in rgb + theirs:
            assert np.all(np.asarray(image)[..., :3] == np.float32(0.3))
        return
    mask = None
    if name == "hard/degenerate.xml":  # NaN samples by design: compare where none occurred
        nonfinite = sum(layer["nonfinite"] for layer in ours)
        assert nonfinite.sum() > 0  # mcrt counted them
        assert not all(np.isfinite(im).all() for im in theirs)  # and mi.render has NaN pixels
        mask = (nonfinite == 0) & np.all([np.isfinite(im).all(axis=-1) for im in theirs], axis=0)
        assert mask.mean() > 0.5
    else:
        for image in rgb + theirs:
            assert np.isfinite(image).all()
    a, b = mean_and_se(rgb, radius, mask), mean_and_se(theirs, radius, mask)
    z = (a[0] - b[0]) / math.hypot(a[1], b[1])
    assert abs(z) < Z_MAX, (name, params, a, b, z)
    assert a[1] > 0 and b[1] > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHIPPED) + sorted(WRITTEN))
def test_render_writes_files_and_agrees_with_mi_render(name, tmp_path):
    compare(name, SHIPPED.get(name, {}), tmp_path)


@pytest.mark.parametrize("name, params", FILTERED, ids=[p["filter"] for _, p in FILTERED])
def test_filtered_render_agrees_with_mi_render(name, params, tmp_path):
    compare(name, params, tmp_path)


def test_standard_error_accounts_for_the_filter():
    """Independent N(0, 1) samples splatted with a 1-2-1 kernel (normalised) into
    pixels: the per-pixel formula gives SE^2 = (6/16)^2 / (K P) (a pixel's variance
    is (sum of squared weights)^2); the true one is ~1 / (K P) (every sample's
    weights sum to 1; less at the border). The windowed sum finds it."""
    rng = np.random.default_rng(1)
    k, h, w = 64, 24, 24
    kernel = np.array([0.25, 0.5, 0.25])
    images = []
    for _ in range(k):
        noise = rng.standard_normal((h + 2, w + 2))
        rows = sum(kernel[i] * noise[i:i + h, :] for i in range(3))
        images.append(np.repeat(sum(kernel[j] * rows[:, j:j + w] for j in range(3))[..., None],
                                3, axis=-1))
    _, se = mean_and_se(images, radius=1.5)  # a 3-pixel splat reaches 2 pixels apart
    assert se * math.sqrt(k * h * w) == pytest.approx(1.0, rel=0.1)
    _, box = mean_and_se(images, radius=0.5)
    assert box * math.sqrt(k * h * w) == pytest.approx((6 / 16), rel=0.1)


# ----------------------------------------------------------------------------
# Plans: exactly the effects of each scene
# ----------------------------------------------------------------------------
#: Scenes whose effects other tests already assert.
PLAN_ELSEWHERE = {
    **{f"effects/{n}.xml": "test_plan.py" for n in ("aa", "combined", "dof", "glossy",
                                                   "motion", "soft_shadows")},
    "cornell_box.xml": "test_plan.py", "checkerboard.xml": "test_plan.py",
    **{f"foreign/{n}.xml": "test_third_party_scenes.py"
       for n in ("old_format", "medium_in_dielectric", "mesh_light", "env_lit")},
}

#: What each remaining scene contains, as effects (aa: every scene samples the
#: pixel area; soft_shadows: an area emitter that lights a surface; indirect:
#: an integrator deeper than direct light and something that lights something else).
EFFECTS: dict[str, set[str]] = {
    # a direct integrator; a rectangle area light over the edge objects
    "edges.xml": {"aa", "soft_shadows"},
    # a rough copper floor reflecting a tilted area light onto a diffuse wall, path max_depth 3
    "glossy_bias.xml": {"aa", "soft_shadows", "glossy", "indirect"},
    # emitting halves seen directly by path max_depth 1: their light reaches nothing
    "filters/slanted_edge.xml": {"aa"},
    # one sphere under a constant environment: path/aov/moment find no second bounce
    "foreign/aov.xml": {"aa"}, "foreign/moment.xml": {"aa"}, "foreign/sphere.xml": {"aa"},
    # an irradiance meter on a sphere under a rectangle light, path max_depth 3 (the floor
    # reflects light onto the sphere)
    "foreign/irradiance_meter.xml": {"aa", "soft_shadows", "indirect"},
    # volpath through a scattering medium: indirect light in the medium
    "foreign/medium.xml": {"aa", "indirect"},
    # path max_depth 3, floor and panels under the sky and an emitting panel D
    "hard/degenerate.xml": {"aa", "soft_shadows", "indirect"},
    # direct; the ceiling lamp is an area light (the sun is a delta light)
    "hard/dynamic_range.xml": {"aa", "soft_shadows"},
    # path max_depth 6, glass ball over a floor, a small sphere light (area)
    "hard/fireflies.xml": {"aa", "soft_shadows", "indirect"},
    # direct, constant / directional light only, smooth BSDFs, pinhole cameras
    **{f"hard/{n}.xml": {"aa"} for n in ("furnace", "grazing", "sky")},
    **{f"multisample/{n}.xml": {"aa"} for n in ("bitmap", "checker", "polygons")},
    # test scenes: constant environment, direct
    "conftest.TINY_SCENE": {"aa"},
    # direct, point light, moving ball and spinning box
    "test_plan.MOVING": {"aa", "motion"},
    # an emitting bar moving under an orthographic camera; nothing it lights
    "test_effects.STREAK_XML": {"aa", "motion"},
    # thin lens looking at two emitting planes
    "test_effects.dof_scene": {"aa", "dof"},
}


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_plan_lists_exactly_the_effects_of_each_scene(name, tmp_path, capsys):
    code, out, _ = run_cli(capsys, "plan", "--json", str(scene_path(name, tmp_path)))
    assert code == 0
    effects = json.loads(out)["effects"]
    assert {n for n, e in effects.items() if e["on"]} == EFFECTS[name]
    assert all(e["on"] == e["present"] for e in effects.values())
