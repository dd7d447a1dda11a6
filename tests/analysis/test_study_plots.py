"""The study's figures (:mod:`mcrt.analysis.study.figures`): what they show and that none of
their text overlaps.

Drawn from a synthetic :class:`~mcrt.analysis.study.StudyResult` built without
rendering (the full study's shape: 10 samplers, 4 to 256 spp, 4 seeds, the
checkerboard and the Cornell box), so these tests take seconds.
``python tests/analysis/test_study_plots.py OUT_DIR`` writes the four figures as PNG to
look at.
"""

from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mcrt.analysis import plots
from mcrt.analysis.significance import log_interval
from mcrt.analysis.study import CellImages, CellRenders, ReferenceInfo, StudyResult, parse_config
from mcrt.analysis.study import figures as study_figures

ROOT = Path(__file__).resolve().parents[2]

#: The samplers of configs/full.toml.
SAMPLERS = ("uniform_grid", "jittered", "poisson_disk", "sobol", "zsobol", "independent",
            "stratified", "multijitter", "orthogonal", "ldsampler")
#: (MSE at 4 spp, slope vs spp, ms per spp) of each sampler: made-up but of the
#: full study's magnitudes (several samplers with nearly the same error and time).
SHAPES = {"uniform_grid": (2.0e-3, -0.3, 0.30), "jittered": (1.6e-3, -1.45, 0.31),
          "poisson_disk": (1.5e-3, -1.40, 0.40), "sobol": (1.4e-3, -1.55, 0.30),
          "zsobol": (1.4e-3, -1.52, 0.31), "independent": (2.4e-3, -1.0, 0.29),
          "stratified": (1.6e-3, -1.42, 0.30), "multijitter": (1.5e-3, -1.50, 0.30),
          "orthogonal": (1.55e-3, -1.48, 0.32), "ldsampler": (1.45e-3, -1.5, 0.30)}
SCENES = {"checkerboard": (ROOT / "scenes" / "checkerboard.xml", (240, 320)),
          "cornell_box": (ROOT / "scenes" / "cornell_box.xml", (128, 128))}
FLOOR = 2e-7


def _fit(scene: str, label: str, cells: list[dict[str, Any]]) -> dict[str, Any]:
    """The (scene, sampler) fit the plots read: log-log slopes and intercepts."""
    mine = [c for c in cells if c["scene"] == scene and c["sampler"] == label
            and c["resolved"]]
    out: dict[str, Any] = {"scene": scene, "sampler": label, "points": len(mine),
                           "cells_used": len(mine), "cells": len(mine)}
    y = np.log10([c["mse_excess"] for c in mine])
    for axis in ("spp", "seconds"):
        if len(mine) < 2:
            out[f"slope_{axis}"] = out[f"intercept_{axis}"] = float("nan")
            continue
        slope, intercept = np.polyfit(np.log10([c[axis] for c in mine]), y, 1)
        out[f"slope_{axis}"], out[f"intercept_{axis}"] = float(slope), float(intercept)
    return out


def scene_image(scene: str, h: int, w: int) -> np.ndarray:
    """A made-up, smooth reference (h, w, 3): the checkerboard receding to its
    horizon under a sky, or a box's red, green and white walls lit from above."""
    y, x = (np.mgrid[0:h, 0:w] + 0.5) / np.array([h, w], float)[:, None, None]
    if scene == "checkerboard":
        depth = 0.15 / np.clip(y - 0.4, 1e-3, None)
        check = (np.floor(4 * (x - 0.5) * depth) + np.floor(4 * depth)) % 2
        ground = (0.05 + 0.7 * check) * np.exp(-0.01 * depth)
        value = np.where(y > 0.4, ground, 0.4 + 0.5 * y)
        return np.stack([value, value, np.where(y > 0.4, ground, 0.9)], axis=-1)
    light = 1.0 / (1.0 + 4.0 * ((x - 0.5) ** 2 + (y - 0.05) ** 2))
    colour = np.select([x < 0.2, x > 0.8], [np.array([0.6, 0.1, 0.1])[:, None, None],
                                            np.array([0.1, 0.6, 0.1])[:, None, None]],
                       np.array([0.7, 0.7, 0.7])[:, None, None])
    box = (np.abs(x - 0.35) < 0.1) & (y > 0.45) & (y < 0.9)
    return np.moveaxis(colour * light * np.where(box, 0.6, 1.0), 0, -1)


def _renders(result: StudyResult, seed: int) -> None:
    """Every cell's images (first seed, mean over seeds, per-pixel variance across
    them): the reference plus noise of the cell's MSE, larger where it is brighter;
    and what the report reads besides: per-seed values and the study's own fits."""
    from mcrt.analysis.study import fit_sampler

    rng = np.random.default_rng(seed)
    k = len(result.config.seeds)
    for cell in result.cells:
        cell["per_seed"] = [
            {"seed": s, "spp": cell["spp"], "seconds": cell["seconds"],
             "mse": cell["mse"] * math.exp(rng.normal(0, 0.1)), "rel_mse": cell["rel_mse"],
             "delta_e": 1.0, "mean_error": 0.0, "nonfinite": 0,
             "aliasing": {"ratio": 1.0, "ratio_z": 0.1, "peak": 2.0, "peak_z": -0.2}}
            for s in result.config.seeds]
        ref = result.reference_images[cell["scene"]]
        lum = ref.mean(axis=-1)
        sd = np.sqrt(cell["mse_excess"] * (lum + 0.05) / (lum.mean() + 0.05)).astype(np.float32)
        noise = rng.standard_normal((2, *ref.shape), dtype=np.float32) * sd[..., None]
        variance = sd ** 2 * rng.chisquare(k - 1, sd.shape).astype(np.float32) / (k - 1)
        result.renders[(cell["scene"], cell["sampler"], cell["spp_requested"])] = CellRenders(
            mean=(ref + noise[0] / math.sqrt(k)).astype(np.float32),
            first=(ref + noise[1]).astype(np.float32), variance=variance.astype(np.float32))
    result.fits = [fit_sampler(scene, s.label, result.cells) for scene in result.scenes
                   for s in result.config.samplers]


def synthetic_result(samplers: tuple[str, ...] = SAMPLERS, spp: tuple[int, ...] = (4, 16, 64, 256),
                     unstable: frozenset[tuple[str, str, int]] = frozenset(),
                     biased: frozenset[tuple[str, str, int]] = frozenset(),
                     sizes: dict[str, tuple[int, int]] | None = None,
                     mse_scale: float = 1.0, seed: int = 1, smooth: bool = False,
                     renders: bool = False) -> StudyResult:
    """A study result of made-up cells carrying every key the plots read
    (``unstable``/``biased``: (scene, sampler, spp) of cells whose timing was
    unstable / whose bias is significant); images only at ``image_spp``, of
    ``sizes`` (scene: (height, width); default: the full study's); every MSE
    times ``mse_scale``. References are noise, or with ``smooth`` made-up scenes
    (:func:`scene_image`); with ``renders`` every cell has its images for the
    report's viewer and EXR files (:func:`_renders`; no rendering either way)."""
    config = parse_config({
        "name": "synthetic", "spp": list(spp), "seeds": 4, "samplers": list(samplers),
        "image_spp": spp[1] if len(spp) > 1 else spp[0],
        "reference": {"spp": 64 * max(spp)},
        "scenes": [{"path": str(path), "name": name} for name, (path, _) in SCENES.items()]})
    rng = np.random.default_rng(seed)
    k = len(config.seeds)
    cells: list[dict[str, Any]] = []
    images: dict[tuple[str, str], CellImages] = {}
    references, reference_images = {}, {}
    for scene, (_, size) in SCENES.items():
        h, w = (sizes or {}).get(scene, size)
        ref = scene_image(scene, h, w) if smooth else rng.random((h, w, 3))
        reference_images[scene] = ref
        references[scene] = ReferenceInfo(scene, config.reference.spp, "independent", 60.0,
                                          FLOOR, 1e-5, w, h)
        yy, xx = np.mgrid[0:h, 0:w]
        for label, n in itertools.product(samplers, spp):
            m4, slope, ms = SHAPES.get(label, (1.5e-3, -1.3, 0.3))
            mse_excess = mse_scale * m4 * (n / 4) ** slope * math.exp(rng.normal(0, 0.05))
            mse = mse_excess + FLOOR
            seconds = 1e-3 * (5.0 + ms * n) * math.exp(rng.normal(0, 0.03))
            spread = 0.02 if (scene, label, n) not in unstable else 0.4
            key = (scene, label, n)
            cells.append({
                "scene": scene, "filter": "", "sampler": label, "plugin": label, "params": {},
                "spp_requested": n, "spp": n, "seeds": list(config.seeds),
                "seconds": seconds, "seconds_low": seconds * (1 - spread),
                "seconds_high": seconds * (1 + 1.5 * spread), "seconds_sd": spread * seconds,
                "seconds_min": seconds * (1 - spread), "time_problems": "spread 30% of the median" if key in unstable else "",
                "mse": mse, "mse_sd": 0.3 * mse, "mse_floor": FLOOR, "mse_excess": mse_excess,
                "mse_of_mean": mse / k, "resolved": mse > 2 * FLOOR,
                "rel_mse": 10 * mse, "rel_mse_sd": 3 * mse,
                "efficiency": 1 / (mse_excess * seconds),
                "efficiency_low": 0.8 / (mse_excess * seconds),
                "efficiency_high": 1.2 / (mse_excess * seconds),
                "variance": mse, "bias": 1e-3 if key in biased else 1e-5,
                "bias_low": -1e-5, "bias_high": 2e-5, "bias_z": 6.0 if key in biased else 0.3,
                "biased": key in biased, "delta_e": 1.0, "delta_e_sd": 0.1,
                "aliasing_ratio": 1.0, "aliasing_ratio_z": 14.0 if label == "uniform_grid"
                else 0.4, "aliasing_peak": 2.0, "aliasing_peak_z": 31.0
                if label == "uniform_grid" else -0.3,
                "aliasing": "aliased" if label == "uniform_grid" else "noise",
                "nonfinite": 0, "per_seed": [],
                # the rest of a cell's keys, for the report (mcrt.analysis.study.fields)
                "cpu_seconds": seconds, "times": [seconds] * k, "cpu_times": [seconds] * k,
                "time_others": [0] * k, "efficiency_ratio": 1.0, "efficiency_ratio_low": 0.9,
                "efficiency_ratio_high": 1.1, "efficiency_samples": 1 / (mse_excess * seconds),
                "bias_df": k - 1, "verdict": "aliased" if label == "uniform_grid" else "noise"})
            if n == config.image_spp:
                sd = math.sqrt(mse)
                error = rng.normal(0, sd, (h, w))
                if label == "uniform_grid":  # moire
                    error += 3 * sd * np.sin(0.7 * xx + 0.2 * yy) * np.sin(0.05 * yy)
                images[(scene, label)] = CellImages(
                    render=np.clip(ref + error[..., None], 0, 1).astype(np.float32),
                    error=error.astype(np.float32),
                    std=np.full((h, w), sd, np.float32) * rng.uniform(0.5, 1.5, (h, w)))
    fits = [_fit(scene, label, cells) for scene in SCENES for label in samplers]
    env = {"mcrt": "test", "mitsuba": "-", "drjit": "-", "variant": "-", "python": "-",
           "platform": "-", "cpus": 2, "started": "-"}
    result = StudyResult(config=config, references=references, cells=cells, fits=fits,
                         reference_images=reference_images, images=images, environment=env,
                         seconds=1.0)
    if renders:
        _renders(result, seed + 1)
    return result


def write_figures(result: StudyResult, out: Path) -> list[Path]:
    """The report's four kinds of figure as PNG in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    figures = {"error_vs_spp": (study_figures.error_figure(result, "spp"), 110),
               "error_vs_time": (study_figures.error_figure(result, "seconds"), 110),
               "summary": (study_figures.summary_figure(result), 100)}
    for scene in result.scenes:
        figures[f"images_{scene}"] = (study_figures.images_figure(result, scene), 100)
    paths = []
    for name, (fig, dpi) in figures.items():
        plots.save_figure(fig, out / f"{name}.png", dpi=dpi)
        paths.append(out / f"{name}.png")
    return paths


UNSTABLE = frozenset({("checkerboard", "sobol", 64), ("cornell_box", "jittered", 4)})
BIASED = frozenset({("checkerboard", "uniform_grid", 256), ("cornell_box", "sobol", 16)})


@pytest.fixture(scope="module")
def flagged() -> StudyResult:
    """The full study's shape with two timing-unstable and two biased cells."""
    return synthetic_result(unstable=UNSTABLE, biased=BIASED)


@pytest.fixture(scope="module")
def clean() -> StudyResult:
    """The full study's shape, every timing stable, no bias."""
    return synthetic_result()


def drawn_texts(fig) -> list[tuple[Any, Any]]:
    """Every non-empty text the drawn ``fig`` shows, with its box in pixels: the
    figure's texts, and per axes its texts and annotations, title, axis labels,
    the labels of the ticks inside the view, its legend's texts."""
    fig.canvas.draw()
    texts = list(fig.texts)
    for ax in fig.axes:
        texts += [*ax.texts, ax.title]
        for axis in (ax.xaxis, ax.yaxis):
            texts += [axis.label, axis.get_offset_text()]
            for tick in axis._update_ticks():  # the ticks drawn
                texts += [tick.label1, tick.label2]
        legend = ax.get_legend()
        if legend is not None:
            texts += [*legend.get_texts(), legend.get_title()]
    renderer = fig.canvas.get_renderer()
    return [(t, t.get_window_extent(renderer)) for t in texts
            if t.get_visible() and t.get_text().strip()]


def overlaps(fig, tolerance: float = 0.5) -> list[tuple[str, str]]:
    """Pairs of texts of ``fig`` whose boxes overlap by more than ``tolerance``
    pixels each way, and texts reaching out of the figure (paired with "")."""
    boxes = drawn_texts(fig)
    page = fig.bbox
    out = [(t.get_text(), "") for t, b in boxes
           if b.x0 < page.x0 - tolerance or b.x1 > page.x1 + tolerance
           or b.y0 < page.y0 - tolerance or b.y1 > page.y1 + tolerance]
    for (ta, a), (tb, b) in itertools.combinations(boxes, 2):
        if (a.x0 < b.x1 - tolerance and b.x0 < a.x1 - tolerance
                and a.y0 < b.y1 - tolerance and b.y0 < a.y1 - tolerance):
            out.append((ta.get_text(), tb.get_text()))
    return out


FIGURES = {"error_vs_spp": lambda r: study_figures.error_figure(r, "spp"),
           "error_vs_time": lambda r: study_figures.error_figure(r, "seconds"),
           "summary": study_figures.summary_figure,
           "summary_cornell": lambda r: study_figures.summary_figure(r, scene="cornell_box"),
           "images_checkerboard": lambda r: study_figures.images_figure(r, "checkerboard"),
           "images_cornell_box": lambda r: study_figures.images_figure(r, "cornell_box")}


@pytest.mark.parametrize("name", ["error_vs_time", "images_checkerboard"])
def test_a_figure_is_drawn_once_and_saved_as_matplotlib_saves_it(flagged, name, tmp_path,
                                                                   monkeypatch):
    """save_figure lays the figure out itself, then draws it once: the PNG has the
    bytes of matplotlib's own savefig, which draws a constrained-layout figure
    twice (once with its output off, to lay it out, resampling every image)."""
    from matplotlib.figure import Figure

    FIGURES[name](flagged).savefig(tmp_path / "matplotlib.png", format="png", dpi=120)
    draws = []
    draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda fig, renderer: (draws.append(1),
                                                               draw(fig, renderer))[1])
    plots.save_figure(FIGURES[name](flagged), tmp_path / "ours.png", dpi=120)
    assert len(draws) == 1
    assert (tmp_path / "ours.png").read_bytes() == (tmp_path / "matplotlib.png").read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FIGURES))
def test_no_text_overlaps(flagged, name):
    """No two texts of a study figure overlap (spp labels, legends, titles,
    tick labels of the plots and of the colour bars) and none leaves the figure."""
    fig = FIGURES[name](flagged)
    assert overlaps(fig) == []


@pytest.mark.slow
def test_no_text_overlaps_small_study():
    """Two samplers, three spp: the same holds for a small study."""
    result = synthetic_result(samplers=("jittered", "independent"), spp=(4, 16, 64))
    for make in FIGURES.values():
        assert overlaps(make(result)) == []


def test_no_text_overlaps_one_scene():
    """One scene (the other without its reference, as in an interrupted study)
    and two samplers of 64 x 48 images: the summary is as wide as its colour
    bar's label."""
    import copy

    result = copy.copy(synthetic_result(samplers=("jittered", "independent"), spp=(4, 16),
                                        sizes={"checkerboard": (48, 64)}))
    result.references = {"checkerboard": result.references["checkerboard"]}
    assert result.scenes == ["checkerboard"]
    for make in (FIGURES["error_vs_spp"], FIGURES["error_vs_time"], FIGURES["summary"]):
        assert overlaps(make(result)) == []


@pytest.mark.slow
def test_no_text_overlaps_narrow_images():
    """Images 170-200 pixels wide, shown 1:1: narrow error maps and colour bars
    (errors whose colour bar ticks were 0.000 .. 0.050 collided at 200 pixels)."""
    result = synthetic_result(sizes={"checkerboard": (150, 200), "cornell_box": (170, 170)},
                              mse_scale=0.1)
    for make in FIGURES.values():
        assert overlaps(make(result)) == []


def test_overlap_check_sees_overlaps():
    """The check itself: two texts at the same place overlap."""
    fig = plots.new_figure(3, 2)
    fig.text(0.5, 0.5, "256")
    fig.text(0.5, 0.5, "1e-05")
    assert overlaps(fig) == [("256", "1e-05")]


def _spp_labels(ax) -> list[Any]:
    return [t for t in ax.texts if t.get_text().isdigit()]


def test_time_plot_labels_spp_at_its_points(flagged):
    """The time plot labels points with their spp: every sample count is shown
    somewhere, each label near a point of that spp; labels that found no free
    place are hidden, not dropped on top of others."""
    fig = study_figures.error_figure(flagged, "seconds")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax, scene in zip(fig.axes, flagged.scenes, strict=True):
        shown = [t for t in _spp_labels(ax) if t.get_visible()]
        assert {t.get_text() for t in shown} == {"4", "16", "64", "256"}
        for t in shown:
            cell = next(c for c in flagged.cells if c["scene"] == scene
                        and str(c["spp"]) == t.get_text() and c["seconds"] == t.xy[0])
            point = ax.transData.transform((cell["seconds"], cell["mse_excess"]))
            box = t.get_window_extent(renderer)
            assert box.x0 - 30 < point[0] < box.x1 + 30 and box.y0 - 30 < point[1] < box.y1 + 30


def test_spp_plot_has_spp_ticks_and_no_point_labels(flagged):
    """Against spp the x ticks are the study's sample counts: no point labels."""
    fig = study_figures.error_figure(flagged, "spp")
    fig.canvas.draw()
    for ax in fig.axes:
        assert _spp_labels(ax) == []
        ticks = [t.label1.get_text() for t in ax.xaxis._update_ticks() if t.label1.get_text()]
        assert ticks == ["4", "16", "64", "256"]


def _errorbars(ax) -> list[Any]:
    from matplotlib.container import ErrorbarContainer

    return [c for c in ax.containers if isinstance(c, ErrorbarContainer)]


@pytest.mark.parametrize("axis", ["seconds", "spp"])
def test_error_bars(flagged, axis):
    """Vertical bars over the 95% interval of the excess MSE (the efficiency's:
    mse_sd / sqrt(K) on the log scale, t on K - 1 df) on both plots; horizontal bars
    over the 95% time interval on the time plot only; one container per sampler."""
    fig = study_figures.error_figure(flagged, axis)
    k = len(flagged.config.seeds)
    for ax, scene in zip(fig.axes, flagged.scenes, strict=True):
        containers = _errorbars(ax)
        assert len(containers) == len(SAMPLERS)
        for container in containers:
            assert container.has_yerr
            assert container.has_xerr == (axis == "seconds")
        checked = 0
        for container, label in zip(containers, SAMPLERS, strict=True):  # drawn in the study's order
            cells = [c for c in flagged.cells if c["scene"] == scene and c["sampler"] == label]
            segments = [s for coll in container.lines[2] for s in coll.get_segments()]
            vertical = [s for s in segments if s[0][0] == s[1][0]]
            horizontal = [s for s in segments if s[0][1] == s[1][1] and s[0][0] != s[1][0]]
            assert len(vertical) == len(cells)
            for ((x, y0), (_, y1)), cell in zip(vertical, cells, strict=True):
                se_log = cell["mse_sd"] / math.sqrt(k) / cell["mse_excess"]
                assert x == pytest.approx(cell[axis])
                assert (y0, y1) == pytest.approx(log_interval(cell["mse_excess"], se_log, k - 1))
                checked += 1
            if axis == "seconds":
                assert len(horizontal) == len(cells)
                for ((x0, y), (x1, _)), cell in zip(horizontal, cells, strict=True):
                    assert y == pytest.approx(cell["mse_excess"])
                    assert (x0, x1) == pytest.approx((cell["seconds_low"], cell["seconds_high"]))
            else:
                assert horizontal == []
        assert checked == len(SAMPLERS) * 4


def test_summary_headline_is_error_against_spp(flagged):
    """The summary's first plots are excess MSE against spp (log axes), one per
    scene, over the error maps titled with their time in ms."""
    fig = study_figures.summary_figure(flagged)
    for ax, scene in zip(fig.axes, flagged.scenes, strict=False):  # the maps' axes follow
        assert ax.get_title() == scene
        assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
        assert "spp" in ax.get_xlabel()
        assert len(_errorbars(ax)) == len(SAMPLERS)
        assert all(not c.has_xerr for c in _errorbars(ax))
    maps = fig.axes[len(flagged.scenes):-1]  # the last axes is the colour bar
    assert len(maps) == len(SAMPLERS)
    assert all(ax.get_title().endswith(" ms") for ax in maps)


def _hollow(ax) -> list[tuple[float, float]]:
    from matplotlib.colors import to_rgba

    return [(float(x), float(y)) for line in ax.lines
            if line.get_marker() == "o" and line.get_linestyle() == "None"
            and to_rgba(line.get_markerfacecolor()) == to_rgba("white")
            for x, y in zip(line.get_xdata(), line.get_ydata(), strict=True)]


def _rings(ax) -> list[tuple[float, float]]:
    from matplotlib.colors import to_rgba

    out = []
    for coll in ax.collections:
        edges = coll.get_edgecolor()
        if len(edges) and tuple(edges[0]) == to_rgba("red") and len(coll.get_facecolor()) == 0:
            out += [tuple(map(float, p)) for p in coll.get_offsets()]
    return out


def _same_points(got: list[tuple[float, float]], want: list[tuple[float, float]]) -> bool:
    return len(got) == len(want) and (not want or np.allclose(sorted(got), sorted(want)))


def _legend_names(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_marks_appear_only_for_flagged_cells(flagged, clean):
    """Hollow markers exactly at the timing-unstable cells (time plot only), red
    rings exactly at the biased ones (both plots), each explained once in the
    legend, and neither mark nor entry without such a cell."""
    for axis in ("seconds", "spp"):
        for ax, scene in zip(study_figures.error_figure(flagged, axis).axes, flagged.scenes, strict=True):
            cell = {(c["sampler"], c["spp"]): c for c in flagged.cells if c["scene"] == scene}
            unstable = [(cell[(s, n)][axis], cell[(s, n)]["mse_excess"])
                        for sc, s, n in UNSTABLE if sc == scene]
            biased = [(cell[(s, n)][axis], cell[(s, n)]["mse_excess"])
                      for sc, s, n in BIASED if sc == scene]
            names = _legend_names(ax)
            assert _same_points(_rings(ax), biased)
            assert sum("red ring" in name for name in names) == 1
            if axis == "seconds":
                assert _same_points(_hollow(ax), unstable)
                assert sum("hollow" in name for name in names) == 1
            else:  # timing plays no part against spp
                assert _hollow(ax) == []
                assert not any("hollow" in name for name in names)
        for ax in study_figures.error_figure(clean, axis).axes:
            assert _hollow(ax) == [] and _rings(ax) == []
            assert not any("hollow" in n or "red ring" in n for n in _legend_names(ax))


def test_cells_without_the_new_keys_still_plot(clean):
    """Cells of an earlier study (no time interval, stability or bias flag) are
    drawn as stable, unbiased, with a time bar of zero width."""
    import copy

    old = copy.copy(clean)
    old.cells = [{k: v for k, v in c.items()
                  if k not in ("seconds_low", "seconds_high", "time_problems", "biased")}
                 for c in clean.cells]
    fig = study_figures.error_figure(old, "seconds")
    fig.canvas.draw()
    assert all(_hollow(ax) == [] and _rings(ax) == [] for ax in fig.axes)


@pytest.mark.parametrize("value, text", [(0, "0"), (0.05, "0.05"), (-0.125, "-0.125"),
                                         (2e-5, "2e-5"), (1.5e-3, "0.0015"), (12345.0, "1.23e4")])
def test_compact_tick_labels(value, text):
    assert study_figures._compact(value) == text


@pytest.mark.slow
def test_colour_bars_have_few_ticks(flagged):
    """Colour bars have 3 to 6 intervals between ticks, about one per 70 pixels."""
    for fig in (study_figures.summary_figure(flagged), study_figures.images_figure(flagged, "checkerboard")):
        fig.canvas.draw()
        bars = [ax for ax in fig.axes if ax.get_xlabel().startswith(("luminance", "sd of",
                                                                    "checkerboard:"))]
        assert bars
        for cax in bars:
            labels = [t for t in cax.xaxis._update_ticks() if t.label1.get_text()]
            assert 2 <= len(labels) <= max(3, cax.bbox.width // 70) + 1


if __name__ == "__main__":
    for path in write_figures(synthetic_result(unstable=UNSTABLE, biased=BIASED),
                              Path(sys.argv[1])):
        print(path)
