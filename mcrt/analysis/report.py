"""Writing a study's report directory.

``write_report(result, directory)`` writes, each file atomically:

* ``report.html`` - self-contained (CSS inline, every image a base64 PNG):
  what was measured and how time was taken, the slope / efficiency table,
  plots, the images side by side (render, error map, per-pixel standard
  deviation) per scene, and the full table of cells;
* ``summary.png`` - the main figure: MSE against render time per scene, over
  the error maps of every sampler on the first scene;
* ``error_vs_spp.png`` and ``error_vs_time.png`` - log-log excess MSE against
  samples per pixel and against seconds, one panel per scene, one line per
  sampler with its fitted slope (the cost curve of accuracy);
* ``images_<scene>.png`` - the image grid of each scene;
* ``results.csv`` - one row per (scene, sampler, spp) cell (means over seeds
  and their spread);
* ``results.json`` - the configuration, environment, references, every cell
  with its per-seed values, and the fits (NaN written as ``null``).

A partial result (an interrupted study, :attr:`StudyResult.partial`) is written
the same way and marked in every file: ``"partial": true`` and a ``progress``
record (cells done / total, the interrupted cell and its seeds done, the
pending cells, how to resume) in results.json; a ``status`` column (done /
interrupted / pending) with ``seeds_done`` in results.csv, pending cells as
rows with empty values; a banner in report.html. Plots and slopes use the
finished cells only.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import os
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_path, ensure_writable_dir
from .aliasing import DEFAULT_CELLS, DEFAULT_CUTOFF, Z_THRESHOLD
from .metrics import REL_MSE_EPSILON
from .plots import new_figure, save_figure
from .study import RESOLVED_FACTOR, StudyResult, cell_keys

#: Columns of results.csv, in order.
CSV_COLUMNS = (
    "scene", "sampler", "plugin", "params", "spp_requested", "spp", "seeds",
    "seconds", "seconds_sd", "seconds_min", "mse", "mse_sd", "mse_floor", "mse_excess",
    "mse_of_mean",
    "resolved", "rel_mse", "rel_mse_sd", "efficiency", "variance", "bias", "bias_low",
    "bias_high", "delta_e", "delta_e_sd", "aliasing_ratio", "aliasing_ratio_z",
    "aliasing_peak", "aliasing_peak_z", "aliasing", "nonfinite",
    "status", "seeds_done", "seeds_total",
)

TIME_NOTE = (
    "Time is the wall time of one render as measured by render_film: tracing every pass, "
    "accumulating and developing the film, between two dr.sync_thread() calls. Before the "
    "timed renders of each (scene, sampler, spp) cell one untimed warm-up render compiles "
    "(or loads from the cache) every kernel. Scene loading, sampler construction, copying "
    "the image to NumPy and computing the metrics are not included. The reference's render "
    "time is reported separately and is not part of any cell.")

DEFINITIONS = {
    "mse": "mean over pixels and channels of (render - reference)^2, averaged over seeds",
    "mse_floor": "mean squared standard error of the reference: what its own noise adds to "
                 "every MSE",
    "mse_excess": "mse - mse_floor: unbiased estimate of the MSE against the exact image "
                  "(render and reference independent); used for slopes and efficiency",
    "mse_of_mean": "MSE of the seed-averaged image; mse = mse_of_mean + (K - 1) / K x variance "
                   "(K seeds) exactly, so the two split the error into bias-like and "
                   "noise parts",
    "resolved": f"mse > {RESOLVED_FACTOR:g} x mse_floor; unresolved cells are left out of "
                "fits and get no efficiency",
    "rel_mse": f"mean (render - reference)^2 / (reference^2 + {REL_MSE_EPSILON:g})",
    "efficiency": "1 / (mse_excess x seconds)",
    "variance": "mean over pixels and channels of the per-pixel variance of the pixel "
                "estimate across seeds (Welford, float64; 0 for a deterministic sampler)",
    "bias": "mean of (seed-averaged render - reference) with a 95% normal interval, "
            "sd = sqrt(sum(var_seeds / K + se_ref^2)) / M",
    "delta_e": "mean CIEDE2000 of the displayed images (linear sRGB clipped to [0, 1], "
               "D65, Y_white = 1)",
    "aliasing_ratio": f"share of luminance-error energy at |f| < {DEFAULT_CUTOFF} "
                      "cycles/pixel over that band's share of frequency bins (Hann window, "
                      "DC excluded): white noise ~1, moire >> 1, blue noise < 1",
    "aliasing_peak": f"max / median of the error power averaged over {DEFAULT_CELLS}x"
                     f"{DEFAULT_CELLS} frequency cells: noise ~1, coherent patterns >> 1",
    "aliasing_*_z": "(value - null mean) / null sd, the null from random sign flips of the "
                    "per-pixel errors (independent pixel errors of the same magnitudes)",
    "aliasing": f"'aliased' if either z (mean over seeds) > {Z_THRESHOLD:g}, 'blue' if the "
                f"ratio's z < -{Z_THRESHOLD:g}, else 'noise'",
    "slope_spp": "least-squares slope of log10(mse_excess) vs log10(spp) over the resolved "
                 "cells' per-seed values (slope_*_se: its OLS standard error)",
    "slope_seconds": "the same against log10(seconds)",
}


# --------------------------------------------------------------------------- data files


def _clean(value):
    """JSON-safe copy: NaN/Inf -> None, numpy scalars -> Python, tuples -> lists."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    return value


def results_json(result: StudyResult) -> dict:
    """Everything a study measured, as JSON-ready data."""
    return _clean({
        "partial": result.partial,
        "progress": result.progress(),
        "study": result.config.as_dict(),
        "environment": result.environment,
        "seconds_total": result.seconds,
        "time_note": TIME_NOTE,
        "definitions": DEFINITIONS,
        "references": {name: vars(info) for name, info in result.references.items()},
        "effective_spp": [{"sampler": label, "spp_requested": spp, "spp": eff}
                          for (label, spp), eff in result.config.effective_spp.items()],
        "cells": result.cells,
        "fits": result.fits,
    })


def _csv_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else "nan"
    if isinstance(value, dict):
        return ";".join(f"{k}={v}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    return str(value)


def csv_rows(result: StudyResult) -> list[list[str]]:
    """Rows of results.csv: every cell of the study in order; a cell not (yet)
    measured has status ``pending`` (or ``interrupted``) and empty values."""
    k = len(result.config.seeds)
    done = {(c["scene"], c["sampler"], c["spp_requested"]): c for c in result.cells}
    stop = result.interrupted or {}
    plugin = {s.label: s for s in result.config.samplers}
    rows = []
    for scene, label, spp in [(c["scene"], c["sampler"], c["spp_requested"])
                              for c in result.cells] + result.pending():
        cell = done.get((scene, label, spp))
        if cell is not None:
            cell = {**cell, "status": "done", "seeds_done": len(cell["seeds"]), "seeds_total": k}
            rows.append([_csv_value(cell[c]) for c in CSV_COLUMNS])
            continue
        running = (stop.get("scene"), stop.get("sampler"), stop.get("spp")) == (scene, label, spp)
        known = {"scene": scene, "sampler": label, "plugin": plugin[label].name,
                 "params": dict(plugin[label].params), "spp_requested": spp,
                 "status": "interrupted" if running else "pending",
                 "seeds_done": stop.get("seeds_done", 0) if running else 0, "seeds_total": k}
        rows.append([_csv_value(known[c]) if c in known else "" for c in CSV_COLUMNS])
    if result.partial:  # study order, done cells first would mislead: sort like the config
        order = {key: i for i, key in enumerate(cell_keys(result.config))}
        rows.sort(key=lambda r: order[(r[0], r[1], int(r[4]))])
    return rows


def write_results_csv(result: StudyResult, path: str | os.PathLike) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(csv_rows(result))


def write_results_json(result: StudyResult, path: str | os.PathLike) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        json.dump(results_json(result), f, indent=1, allow_nan=False)
        f.write("\n")


# --------------------------------------------------------------------------- plots


def _colours(labels: list[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if len(labels) <= 10 else colormaps["tab20"]
    return {label: cmap(i % cmap.N) for i, label in enumerate(labels)}


def plot_errors(ax, result: StudyResult, scene: str, axis: str, legend: bool = True) -> None:
    """Excess MSE of every sampler of ``scene`` against ``axis`` ("spp" or
    "seconds"): means over seeds with their sd, the fitted power law, the
    reference's noise floor; unresolved cells as crosses."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    labels = [s.label for s in result.config.samplers]
    colours = _colours(labels)
    for label in labels:
        cells = [c for c in result.cells if c["scene"] == scene and c["sampler"] == label]
        if not cells:  # a partial study: nothing measured yet
            continue
        x = np.array([c["spp"] if axis == "spp" else c["seconds"] for c in cells], float)
        y = np.array([c["mse_excess"] for c in cells], float)
        sd = np.array([c["mse_sd"] for c in cells], float)
        ok = np.array([c["resolved"] for c in cells]) & (y > 0)
        fit = result.fit(scene, label)
        slope = fit[f"slope_{axis}"]
        name = f"{label} ({slope:+.2f})" if math.isfinite(slope) else f"{label} (no fit)"
        if ok.any():
            low = np.minimum(sd[ok], 0.95 * y[ok])
            ax.errorbar(x[ok], y[ok], yerr=(low, sd[ok]), color=colours[label], marker="o",
                        ms=3.5, lw=0, elinewidth=1, capsize=2, label=name)
        if (~ok).any():
            yy = np.where(y > 0, y, scene_floor(result, scene))
            ax.scatter(x[~ok], yy[~ok], marker="x", color=colours[label], s=20)
        if math.isfinite(slope) and ok.any():
            xs = np.geomspace(x[ok].min(), x[ok].max(), 20)
            ax.plot(xs, 10 ** (fit[f"intercept_{axis}"] + slope * np.log10(xs)),
                    color=colours[label], lw=1.1)
    floor = scene_floor(result, scene)
    ax.axhline(floor, color="0.5", ls=":", lw=1)
    ax.text(0.99, floor, " reference noise", transform=ax.get_yaxis_transform(),
            ha="right", va="bottom", fontsize=7, color="0.4")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("samples per pixel" if axis == "spp" else "render time (s)", fontsize=9)
    ax.set_ylabel("MSE (reference noise removed)", fontsize=9)
    ax.set_title(scene, fontsize=10)
    ax.grid(True, which="both", color="0.92", lw=0.5)
    ax.tick_params(labelsize=8)
    for a in (ax.xaxis, ax.yaxis):
        a.set_minor_formatter(NullFormatter())
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, title="sampler (slope)", title_fontsize=7)


def error_figure(result: StudyResult, axis: str):
    """Excess MSE against ``axis`` ("spp" or "seconds"), one panel per scene
    (with a reference: all of them unless the study was interrupted)."""
    n = len(result.scenes)
    fig = new_figure(4.6 * n + 1.8, 4.0)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, scene in zip(axes, result.scenes):
        plot_errors(ax, result, scene, axis)
    return fig


def summary_figure(result: StudyResult, scene: str | None = None, columns: int = 4):
    """The report's main figure: the cost curve of accuracy (MSE against render
    time) of every scene, over the error maps of every sampler on ``scene``
    (default: the first) at the report's spp, each rendered pixel exactly one
    figure pixel (or a ``zoom x zoom`` block)."""
    config = result.config
    if scene is None:  # the first scene with images (a partial study may have none)
        scene = next((s for s in result.scenes if any((s, x.label) in result.images
                                                      for x in config.samplers)),
                     result.scenes[0])
    labels = [s.label for s in config.samplers if (scene, s.label) in result.images]
    h, w = result.reference_images[scene].shape[:2]
    zoom = max(1, 240 // w)
    pw, ph = w * zoom, h * zoom
    columns = max(1, min(columns, len(labels)))
    rows = -(-len(labels) // columns)
    gap, title_h, margin = 10, 30, 20
    n = len(result.scenes)
    width = max(columns * (pw + gap) + 2 * margin, 560 * n)
    plot_h = 400
    height = plot_h + 50 + rows * (ph + title_h + gap) + 80
    fig = new_figure(width / 100, height / 100)
    fig.set_layout_engine("none")
    panel = width / n
    for i, name in enumerate(result.scenes):
        ax = fig.add_axes(((i * panel + 70) / width, (height - plot_h + 10) / height,
                           (panel - 100) / width, (plot_h - 50) / height))
        plot_errors(ax, result, name, "seconds")
    cells = [result.images[(scene, label)] for label in labels]
    lim = max((float(np.percentile(np.abs(c.error), 99.5)) for c in cells), default=0) or 1.0
    left = (width - columns * (pw + gap) + gap) / 2
    image = None
    for i, (label, c) in enumerate(zip(labels, cells)):
        r, col = divmod(i, columns)
        x = left + col * (pw + gap)
        y = height - (plot_h + 50 + r * (ph + title_h + gap) + title_h + ph)
        ax = fig.add_axes((x / width, y / height, pw / width, ph / height))
        ax.set_xticks([])
        ax.set_yticks([])
        image = ax.imshow(c.error, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        cell = result.cell(scene, label, config.image_spp)
        ax.set_title(f"{label}: {cell['aliasing']} (z {round(cell['aliasing_ratio_z'])}/"
                     f"{round(cell['aliasing_peak_z'])})\nMSE {cell['mse_excess']:.2e}, "
                     f"{cell['seconds'] * 1e3:.0f} ms", fontsize=8)
    if image is not None:
        cax = fig.add_axes(((width / 2 - 200) / width, 45 / height, 400 / width, 10 / height))
        fig.colorbar(image, cax=cax, orientation="horizontal")
        cax.tick_params(labelsize=7)
        cax.set_xlabel(f"{scene}: luminance error (render - reference) at {config.image_spp} "
                       f"spp, seed {config.seeds[0]}; aliasing verdict with its "
                       f"(ratio / peak) z-scores", fontsize=8)
    return fig


def scene_floor(result: StudyResult, scene: str) -> float:
    return result.references[scene].noise_floor


def images_figure(result: StudyResult, scene: str):
    """Reference, then per sampler: render, luminance error, per-pixel sd across seeds.

    Laid out in pixels so every rendered pixel becomes an exact ``zoom x zoom``
    block (resampling by a non-integer factor would add its own moire to a
    figure about moire).
    """
    from ..io import encode_srgb

    config = result.config
    labels = [s.label for s in config.samplers if (scene, s.label) in result.images]
    cells = [result.images[(scene, label)] for label in labels]
    ref = result.reference_images[scene]
    h, w = ref.shape[:2]
    err_lim = max(float(np.percentile(np.abs(c.error), 99.5)) for c in cells) or 1.0
    std_lim = max(float(np.percentile(c.std, 99.5)) for c in cells) or 1.0
    zoom = max(1, 320 // w)
    pw, ph = w * zoom, h * zoom
    left, gap, title_h, top, bottom = 110, 12, 22, 36, 70
    rows = len(labels) + 1
    width = left + 3 * pw + 3 * gap
    height = top + rows * (ph + title_h + gap) + bottom
    dpi = 100
    fig = new_figure(width / dpi, height / dpi)
    fig.set_layout_engine("none")

    def axes_at(row: int, col: int):
        x = left + col * (pw + gap)
        y = height - (top + row * (ph + title_h + gap) + title_h + ph)
        ax = fig.add_axes((x / width, y / height, pw / width, ph / height))
        ax.set_xticks([])
        ax.set_yticks([])
        return ax

    def row_label(row: int, text: str) -> None:
        y = height - (top + row * (ph + title_h + gap) + title_h + ph / 2)
        fig.text((left - 8) / width, y / height, text, ha="right", va="center", fontsize=9)

    k = len(config.seeds)
    fig.text(0.5, 1 - 8 / height, f"{scene}: {config.image_spp} spp, seed {config.seeds[0]}; "
             f"error = render - reference (luminance); sd of each pixel across {k} seeds",
             ha="center", va="top", fontsize=10)
    ax = axes_at(0, 0)
    ax.imshow(encode_srgb(ref), interpolation="nearest")
    ax.set_title(f"{result.references[scene].spp} spp", fontsize=8)
    row_label(0, "reference")
    err_image = std_image = None
    for row, (label, c) in enumerate(zip(labels, cells), start=1):
        cell = result.cell(scene, label, config.image_spp)
        row_label(row, label)
        ax = axes_at(row, 0)
        ax.imshow(encode_srgb(c.render), interpolation="nearest")
        ax.set_title(f"{cell['spp']} spp, {cell['seconds'] * 1e3:.0f} ms", fontsize=8)
        ax = axes_at(row, 1)
        err_image = ax.imshow(c.error, cmap="RdBu_r", vmin=-err_lim, vmax=err_lim,
                              interpolation="nearest")
        ax.set_title(f"MSE {cell['mse_excess']:.2e}, {cell['aliasing']} "
                     f"(z {round(cell['aliasing_ratio_z'])}/{round(cell['aliasing_peak_z'])})",
                     fontsize=8)
        ax = axes_at(row, 2)
        std_image = ax.imshow(c.std, cmap="magma", vmin=0, vmax=std_lim,
                              interpolation="nearest")
        ax.set_title(f"mean variance {cell['variance']:.2e}", fontsize=8)
    for col, image, text in ((1, err_image, "luminance error"),
                             (2, std_image, "sd of the pixel estimate")):
        if image is None:
            continue
        x = left + col * (pw + gap)
        cax = fig.add_axes((x / width, 40 / height, pw / width, 10 / height))
        fig.colorbar(image, cax=cax, orientation="horizontal")
        cax.tick_params(labelsize=7)
        cax.set_xlabel(text, fontsize=8)
    return fig


# --------------------------------------------------------------------------- HTML


def _png_data(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _fmt(value, digits: int = 3) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if not math.isfinite(value):
            return "&ndash;"
        if value == 0:
            return "0"
        if 1e-3 <= abs(value) < 1e4:
            return f"{value:.{digits}g}"
        return f"{value:.{digits - 1}e}"
    return html.escape(str(value))


def _table(header: list[str], rows: list[list[str]], cls: str = "") -> str:
    head = "".join(f"<th>{h}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>\n{body}\n</tbody></table>'


def summary_rows(result: StudyResult, scene: str) -> list[list[str]]:
    """Per sampler: slopes and efficiency at every spp (HTML cells)."""
    rows = []
    for sampler in result.config.samplers:
        fit = result.fit(scene, sampler.label)
        cells = [c for c in result.cells if c["scene"] == scene and c["sampler"] == sampler.label]
        row = [html.escape(sampler.label),
               f"{_fmt(fit['slope_spp'])} &plusmn; {_fmt(fit['slope_spp_se'], 2)}",
               f"{_fmt(fit['slope_seconds'])} &plusmn; {_fmt(fit['slope_seconds_se'], 2)}"]
        by_spp = {c["spp_requested"]: c for c in cells}
        row += [_fmt(by_spp[spp]["efficiency"]) if spp in by_spp else "pending"
                for spp in result.config.spp]
        aliased = [str(c["spp"]) for c in cells if c["aliasing"] == "aliased"]
        blue = [str(c["spp"]) for c in cells if c["aliasing"] == "blue"]
        verdict = []
        if aliased:
            verdict.append(f"aliased at {', '.join(aliased)} spp")
        if blue:
            verdict.append(f"blue at {', '.join(blue)} spp")
        row.append("; ".join(verdict) or "noise")
        rows.append(row)
    return rows


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em;
color:#222;max-width:1400px}
h1{font-size:1.6em}h2{font-size:1.25em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:12px;margin:0.6em 0}
th,td{border:1px solid #ccc;padding:3px 6px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
table.cells td:nth-child(2){text-align:left}
img{max-width:100%}.note{color:#555;font-size:13px;max-width:60em}
.partial{background:#fff3cd;border:2px solid #d39e00;padding:0.6em 1em;max-width:60em}
dl{font-size:13px}dt{font-weight:600;margin-top:0.4em}dd{margin-left:1.5em}
code{background:#f6f6f6;padding:0 3px}
"""


def render_html(result: StudyResult, files: dict[str, Path]) -> str:
    config = result.config
    env = result.environment
    mark = " (partial)" if result.partial else ""
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>mcrt study: {html.escape(config.name)}{mark}</title><style>{_CSS}</style>"
             f"</head><body>",
             f"<h1>mcrt study: {html.escape(config.name)}{mark}</h1>"]
    if result.partial:
        parts.append(partial_banner(result))
    if config.description:
        parts.append(f"<p>{html.escape(config.description)}</p>")
    parts.append(
        f"<p class='note'>{len(config.scenes)} scene(s) &times; {len(config.samplers)} "
        f"sampler(s) &times; spp {', '.join(map(str, config.spp))} &times; "
        f"{len(config.seeds)} seeds; reference: {html.escape(config.reference.sampler)}, "
        f"{config.reference.spp} spp. Ran {result.seconds:.0f} s on "
        f"{html.escape(str(env['platform']))}, "
        f"{env['cpus']} CPUs, Mitsuba {env['mitsuba']}, Dr.Jit {env['drjit']}, "
        f"{html.escape(env['variant'])}, mcrt {env['mcrt']}, started {env['started']}.</p>")
    if result.resumed_cells and not result.partial:
        parts.append(f"<p class='note'>{result.resumed_cells} of {config.cells} cells were "
                     "measured by an earlier, interrupted run and taken from its saved state "
                     "(same configuration, scenes and versions); their times were taken then."
                     "</p>")
    parts.append(f"<p class='note'><b>Time.</b> {html.escape(TIME_NOTE)}</p>")
    if "summary" in files:
        parts.append(f"<p><img alt='summary' src='{_png_data(files['summary'])}'></p>")

    parts.append("<h2>Convergence and efficiency</h2>")
    parts.append("<p class='note'>Slopes are least-squares fits of log MSE (reference noise "
                 "removed) against log spp and against log seconds, over every seed of the "
                 "resolved cells (&plusmn; one standard error). Efficiency is "
                 "1&nbsp;/&nbsp;(MSE &times; seconds): higher is better; a sampler twice as "
                 "efficient reaches the same error in half the time.</p>")
    for scene in result.scenes:
        spp_heads = [f"eff. @{s}" for s in config.spp]
        parts.append(f"<h3>{html.escape(scene)}</h3>")
        parts.append(_table(["sampler", "slope vs spp", "slope vs time", *spp_heads,
                             "aliasing"], summary_rows(result, scene)))
    for key, alt in (("error_vs_spp", "error vs spp"), ("error_vs_time", "error vs time")):
        if key in files:
            parts.append(f"<p><img alt='{alt}' src='{_png_data(files[key])}'></p>")

    parts.append(f"<h2>Images at {config.image_spp} spp</h2>")
    parts.append("<p class='note'>Per sampler: the render (seed "
                 f"{config.seeds[0]}), its luminance error against the reference (red: too "
                 "bright, blue: too dark; same scale for all samplers), and the standard "
                 f"deviation of each pixel's estimate across the {len(config.seeds)} seeds "
                 "(black where a sampler is deterministic, e.g. the uniform grid on a scene "
                 "where only the film position is sampled: its error is all bias).</p>")
    for scene in config.scenes:
        key = f"images_{scene.name}"
        if key in files:
            parts.append(f"<p><img alt='{html.escape(scene.name)} images' "
                         f"src='{_png_data(files[key])}'></p>")

    parts.append("<h2>References</h2>")
    ref_rows = [[html.escape(r.scene), f"{r.width}x{r.height}", str(r.spp), html.escape(r.sampler),
                 _fmt(r.seconds) + (" (cached)" if r.cached else ""), _fmt(r.noise_floor),
                 _fmt(r.rel_noise_floor)]
                for r in result.references.values()]
    parts.append(_table(["scene", "pixels", "spp", "sampler", "seconds", "MSE floor",
                         "relMSE floor"], ref_rows))

    parts.append("<h2>All cells</h2><p class='note'>Means over seeds &plusmn; sample standard "
                 "deviation. Unresolved cells (MSE below "
                 f"{RESOLVED_FACTOR:g}&times; the reference's noise floor) are marked "
                 "and excluded from fits.</p>")
    rows = []
    for c in result.cells:
        rows.append([
            html.escape(c["scene"]), html.escape(c["sampler"]), str(c["spp"]),
            f"{_fmt(c['seconds'] * 1e3)} &plusmn; {_fmt(c['seconds_sd'] * 1e3, 2)}",
            f"{_fmt(c['mse'])} &plusmn; {_fmt(c['mse_sd'], 2)}", _fmt(c["mse_excess"]),
            "" if c["resolved"] else "unresolved",
            _fmt(c["rel_mse"]), _fmt(c["variance"]),
            f"{_fmt(c['bias'])} [{_fmt(c['bias_low'])}, {_fmt(c['bias_high'])}]",
            _fmt(c["delta_e"]),
            f"{_fmt(c['aliasing_ratio'])} ({_fmt(c['aliasing_ratio_z'], 2)})",
            f"{_fmt(c['aliasing_peak'])} ({_fmt(c['aliasing_peak_z'], 2)})",
            html.escape(c["aliasing"]), _fmt(c["efficiency"])])
    stop = result.interrupted or {}
    for scene, label, spp in result.pending():  # a partial study: what is missing
        running = (stop.get("scene"), stop.get("sampler"), stop.get("spp")) == (scene, label, spp)
        status = (f"interrupted ({stop['seeds_done']}/{stop['seeds_total']} seeds)" if running
                  else "pending")
        rows.append([html.escape(scene), html.escape(label), f"({spp})", status]
                    + [""] * 11)
    parts.append(_table(["scene", "sampler", "spp", "time (ms)", "MSE", "MSE &minus; floor", "",
                         "relMSE", "variance", "bias [95%]", "&Delta;E00",
                         "alias ratio (z)", "peak (z)", "verdict", "efficiency"], rows,
                        cls="cells"))

    parts.append("<h2>Definitions</h2><dl>")
    for key, text in DEFINITIONS.items():
        parts.append(f"<dt><code>{html.escape(key)}</code></dt><dd>{html.escape(text)}</dd>")
    parts.append("</dl><p class='note'>Data: <code>results.csv</code> (one row per cell), "
                 "<code>results.json</code> (everything, with per-seed values); plots: "
                 "<code>error_vs_spp.png</code>, <code>error_vs_time.png</code>.</p>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def partial_banner(result: StudyResult) -> str:
    """The report's notice that the study is incomplete, and how to resume it."""
    total, done = result.config.cells, len(result.cells)
    text = (f"<b>Partial result.</b> The study was interrupted after {done} of {total} "
            f"cells ({len(result.config.seeds)} seeds each)")
    stop = result.interrupted
    if stop:
        text += (f"; the cell being measured ({html.escape(stop['scene'])}, "
                 f"{html.escape(stop['sampler'])}, {stop['spp']} spp) had "
                 f"{stop['seeds_done']} of {stop['seeds_total']} seeds and is not included")
    text += (". Slopes, efficiencies and plots use the finished cells only; the missing "
             "ones are marked <i>pending</i>.")
    if result.resumed_cells:
        text += f" {result.resumed_cells} cells were taken from an earlier run's saved state."
    if result.resume_command:
        text += (" Run the same command again to resume (finished cells are not rendered "
                 f"again): <code>{html.escape(result.resume_command)}</code>")
    return f"<p class='partial'>{text}</p>"


def report_files(directory: str | os.PathLike, scenes: list[str]) -> dict[str, Path]:
    """The files :func:`write_report` writes into ``directory``, by role."""
    directory = Path(directory)
    files = {"report": directory / "report.html", "csv": directory / "results.csv",
             "json": directory / "results.json",
             "summary": directory / "summary.png",
             "error_vs_spp": directory / "error_vs_spp.png",
             "error_vs_time": directory / "error_vs_time.png"}
    for scene in scenes:
        files[f"images_{scene}"] = directory / f"images_{scene}.png"
    return files


def write_report(result: StudyResult, directory: str | os.PathLike) -> dict[str, Path]:
    """Write every report file into ``directory`` (created if needed); returns them."""

    ensure_writable_dir(Path(directory))
    files = report_files(directory, [s.name for s in result.config.scenes])
    write_results_csv(result, files["csv"])
    write_results_json(result, files["json"])
    if result.scenes:
        for axis, key in (("spp", "error_vs_spp"), ("seconds", "error_vs_time")):
            save_figure(error_figure(result, axis), files[key], dpi=110)
        save_figure(summary_figure(result), files["summary"], dpi=100)
    else:  # interrupted before the first reference: nothing to plot
        for key in ("error_vs_spp", "error_vs_time", "summary"):
            files.pop(key)
    for scene in result.config.scenes:
        if any(s == scene.name for s, _ in result.images):
            save_figure(images_figure(result, scene.name), files[f"images_{scene.name}"],
                        dpi=110)
        else:
            files.pop(f"images_{scene.name}")
    text = render_html(result, files)
    with atomic_path(files["report"]) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    return files


__all__ = ["CSV_COLUMNS", "DEFINITIONS", "TIME_NOTE", "error_figure", "images_figure",
           "plot_errors", "render_html", "report_files", "results_json", "summary_figure",
           "write_report", "write_results_csv", "write_results_json"]
