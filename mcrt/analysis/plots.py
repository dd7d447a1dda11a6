"""Plots of sampling patterns, convergence and studies, drawn the way the lecture shows them.

Matplotlib is used through its object interface with the Agg canvas (no
``pyplot``, no global state, no display needed), and every figure is written
atomically with :func:`mcrt.core.atomic.atomic_path`. It is imported when the
first figure is made, so commands that draw nothing never load it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .patterns import RadialSpectrum
    from .study import StudyResult

#: Display range of the power spectrum images (white noise = 1 is mid-grey).
SPECTRUM_VMAX = 2.0


def new_figure(width: float, height: float) -> Figure:
    """A figure attached to an Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Write ``fig`` as PNG to ``path`` atomically.

    Ctrl-C and termination signals wait until the file is written: raised inside
    matplotlib's drawing, where its C++ code converts Python objects, the
    ``KeyboardInterrupt`` came out as "ValueError: Invalid affine transformation
    matrix" (a killed ``mcrt compare`` printed a traceback instead of stopping)."""
    from ..core.engine import deferred_interrupts

    with deferred_interrupts(), atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)


def plot_point_set(ax: Axes, points: np.ndarray, grid: int | None = None,
                   radius: float | None = None, title: str = "") -> None:
    """One pixel's points on the unit square; ``grid`` draws ``grid x grid`` strata,
    ``radius`` draws a disc of that radius around every point (Poisson-disk)."""
    points = np.asarray(points, dtype=np.float64)
    if grid:
        for t in np.linspace(0.0, 1.0, grid + 1):
            ax.axhline(t, color="0.8", lw=0.5, zorder=0)
            ax.axvline(t, color="0.8", lw=0.5, zorder=0)
    if radius:
        from matplotlib.patches import Circle

        for x, y in points:
            ax.add_patch(Circle((x, y), radius, fill=False, lw=0.4, color="tab:blue", alpha=0.6))
    size = max(1.0, min(12.0, 3000.0 / max(len(points), 1)))
    ax.scatter(points[:, 0], points[:, 1], s=size, c="k", lw=0)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.set_xticks([0, 0.5, 1])
    ax.set_yticks([0, 0.5, 1])
    if title:
        ax.set_title(title, fontsize=9)


def plot_spectrum(ax: Axes, spectrum: np.ndarray, n_points: int, title: str = "",
                  colorbar: bool = True) -> None:
    """The averaged periodogram as a grey image, axes in units of 1 / mean spacing
    (``f = k / sqrt(N)``), DC term hidden, linear scale ``0 .. SPECTRUM_VMAX``."""
    spectrum = np.array(spectrum, dtype=np.float64)
    kmax = spectrum.shape[0] // 2
    spectrum[kmax, kmax] = np.nan
    edge = (kmax + 0.5) / math.sqrt(n_points)
    from matplotlib import colormaps

    cmap = colormaps["gray"].with_extremes(bad="black")
    image = ax.imshow(spectrum, origin="lower", cmap=cmap, vmin=0.0, vmax=SPECTRUM_VMAX,
                      extent=(-edge, edge, -edge, edge), interpolation="nearest")
    ax.set_xlabel("$f_x$ (1 / mean spacing)", fontsize=8)
    ax.set_ylabel("$f_y$", fontsize=8)
    if colorbar:
        ax.figure.colorbar(image, ax=ax, shrink=0.8, label="P(k)")
    if title:
        ax.set_title(title, fontsize=9)


def plot_radial_power(ax: Axes, radial: RadialSpectrum, label: str | None = None,
                      title: str = "") -> None:
    """Radially averaged power against ``f = |k| / sqrt(N)``; white noise = 1."""
    ax.plot(radial.frequency, radial.power, lw=1.2, label=label)
    ax.axhline(1.0, color="0.6", lw=0.8, ls="--")
    ax.set_xlim(0, radial.frequency[-1])
    ax.set_ylim(bottom=0)
    ax.set_xlabel("f (1 / mean spacing)", fontsize=8)
    ax.set_ylabel("radial power", fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)


def plot_anisotropy(ax: Axes, radial: RadialSpectrum, label: str | None = None,
                    title: str = "") -> None:
    """Anisotropy (dB) per annulus, with the white-noise floor of this many periodograms."""
    ax.plot(radial.frequency, radial.anisotropy_db, lw=1.0, label=label)
    ax.axhline(radial.floor_db, color="0.6", lw=0.8, ls="--")
    ax.text(0.02 * radial.frequency[-1], radial.floor_db, f"white noise ({radial.n_sets} sets)",
            ha="left", va="top", fontsize=7, color="0.4")
    ax.set_xlim(0, radial.frequency[-1])
    ax.set_xlabel("f (1 / mean spacing)", fontsize=8)
    ax.set_ylabel("anisotropy (dB)", fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)


def plot_convergence(ax: Axes, series: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
                     reference_slopes: Sequence[float] = (-1.0, -1.5, -2.0),
                     ylabel: str = "MSE", title: str = "") -> None:
    """Log-log MSE against N for several samplers.

    ``series``: ``(label, n, mse, se_log)`` per sampler; error bars span
    ``+-2 se`` of ``ln MSE``. Dashed guide lines with ``reference_slopes``
    start at the first series' first point.
    """
    for label, n, mse, se in series:
        n, mse, se = (np.asarray(a, dtype=np.float64) for a in (n, mse, se))
        keep = mse > 0
        lower = mse[keep] * (1.0 - np.exp(-2.0 * se[keep]))
        upper = mse[keep] * (np.exp(2.0 * se[keep]) - 1.0)
        ax.errorbar(n[keep], mse[keep], yerr=(lower, upper), marker="o", ms=3, lw=1.2,
                    capsize=2, label=label)
    if series:
        n0, m0 = float(series[0][1][0]), float(series[0][2][0])
        n_all = np.concatenate([np.asarray(s[1], dtype=np.float64) for s in series])
        xs = np.array([n0, n_all.max()])
        for slope in reference_slopes:
            ax.plot(xs, m0 * (xs / n0) ** slope, ls=":", color="0.5", lw=0.8)
            ax.text(xs[1], m0 * (xs[1] / n0) ** slope, f"$N^{{{slope:g}}}$", fontsize=7,
                    color="0.4", va="center")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("samples per pixel N", fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.grid(True, which="major", color="0.9", lw=0.5)
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title, fontsize=9)


# --------------------------------------------------------------------------- studies


def _colours(labels: list[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if len(labels) <= 10 else colormaps["tab20"]
    return {label: cmap(i % cmap.N) for i, label in enumerate(labels)}


def plot_errors(ax: Axes, result: StudyResult, scene: str, axis: str, legend: bool = True) -> None:
    """Excess MSE of every sampler of ``scene`` against ``axis`` ("spp" or
    "seconds"): means over seeds with their sd, each point labelled with its
    spp, the fitted power law, the reference's noise floor; unresolved cells
    (MSE within the reference's noise) as crosses, explained in the legend."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, NullFormatter

    labels = [s.label for s in result.config.samplers]
    colours = _colours(labels)
    unresolved = False
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
        yy = np.where(ok, y, np.where(y > 0, y, scene_floor(result, scene)))
        if (~ok).any():
            unresolved = True
            ax.scatter(x[~ok], yy[~ok], marker="x", color=colours[label], s=20)
        for xi, yi, c in zip(x, yy, cells):
            ax.annotate(str(c["spp"]), (xi, yi), xytext=(3, 3), textcoords="offset points",
                        fontsize=6, color=colours[label])
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
        handles, names = ax.get_legend_handles_labels()
        if unresolved:
            from .study import RESOLVED_FACTOR

            handles.append(Line2D([], [], marker="x", color="0.3", lw=0, markersize=5))
            names.append(f"unresolved: MSE < {RESOLVED_FACTOR:g}x floor")
        ax.legend(handles, names, fontsize=7, title="sampler (slope); labels: spp",
                  title_fontsize=7)


def error_figure(result: StudyResult, axis: str) -> Figure:
    """Excess MSE against ``axis`` ("spp" or "seconds"), one panel per scene
    (with a reference: all of them unless the study was interrupted)."""
    n = len(result.scenes)
    fig = new_figure(4.6 * n + 1.8, 4.0)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, scene in zip(axes, result.scenes):
        plot_errors(ax, result, scene, axis)
    return fig


def summary_figure(result: StudyResult, scene: str | None = None,
                   columns: int = 4) -> Figure:
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
        ax.set_title(f"{label}: {_verdict_z(cell)}\nMSE {cell['mse_excess']:.2e}, "
                     f"{cell['seconds'] * 1e3:.0f} ms", fontsize=8)
    if image is not None:
        cax = fig.add_axes(((width / 2 - 200) / width, 45 / height, 400 / width, 10 / height))
        fig.colorbar(image, cax=cax, orientation="horizontal")
        cax.tick_params(labelsize=7)
        cax.set_xlabel(f"{scene}: luminance error (render - reference) at {config.image_spp} "
                       f"spp, seed {config.seeds[0]}; aliasing verdict with its "
                       f"(ratio / peak) z-scores", fontsize=8)
    return fig


def _verdict_z(cell: dict[str, Any]) -> str:
    """A cell's aliasing verdict with its (ratio / peak) z-scores, when it has them."""
    ratio_z, peak_z = cell["aliasing_ratio_z"], cell["aliasing_peak_z"]
    if not (math.isfinite(ratio_z) and math.isfinite(peak_z)):
        return str(cell["aliasing"])
    return f"{cell['aliasing']} (z {round(ratio_z)}/{round(peak_z)})"


def scene_floor(result: StudyResult, scene: str) -> float:
    return result.references[scene].noise_floor


def images_figure(result: StudyResult, scene: str) -> Figure:
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

    def axes_at(row: int, col: int) -> Axes:
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
        ax.set_title(f"MSE {cell['mse_excess']:.2e}, {_verdict_z(cell)}", fontsize=8)
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

