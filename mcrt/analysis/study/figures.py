"""A study's figures: excess MSE against spp and against time, the summary, the image grids.

Drawn like every figure of mcrt (:mod:`mcrt.analysis.plots`: the Agg canvas,
no ``pyplot``, written atomically); matplotlib is imported when the first
figure is made. :mod:`mcrt.analysis.report` puts them in a study's report.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..convergence import recorded_excess_mse
from ..plots import new_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from . import StudyResult
    from .fields import Cell


#: Offsets (points) tried in turn for a point's spp label on a time plot: near
#: before far, up-right first; a label that fits nowhere is left out.
_LABEL_OFFSETS = tuple((r * dx, r * dy) for r in (4.0, 8.0, 13.0)
                       for dx, dy in ((1, 1), (1, -1), (-1, 1), (-1, -1),
                                      (1, 0), (-1, 0), (0, 1), (0, -1)))
#: A point within this distance (points) of one whose label of the same text is
#: placed is not labelled again.
_LABEL_SHARED = 24.0
#: Half the size (points) of the square a marker keeps free of labels.
_MARKER_HALF = 3.5
#: Pixels kept between two texts placed by the study figures.
_TEXT_PAD = 1.0


def _colours(labels: list[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if len(labels) <= 10 else colormaps["tab20"]
    return {label: cmap(i % cmap.N) for i, label in enumerate(labels)}


def _compact(value: float, _pos: Any = None) -> str:
    """A tick value in at most three significant digits: ``0.05``, ``-0.125``, ``2e-5``."""
    if value == 0:
        return "0"
    mantissa, _, exponent = f"{value:.3g}".partition("e")
    return mantissa + (f"e{int(exponent)}" if exponent else "")


def _spaced(values: Sequence[float], n: int = 8) -> list[float]:
    """At most about ``n`` of the sorted positive ``values``, evenly spread in log
    (the spp ticks of a plot: neighbours closer than 1/n of the range are dropped)."""
    values = sorted({float(v) for v in values if v > 0})
    if len(values) <= 2:
        return values
    step = math.log10(values[-1] / values[0]) / n
    kept = [values[0]]
    for v in values[1:-1]:
        if math.log10(v / kept[-1]) >= step and math.log10(values[-1] / v) >= step:
            kept.append(v)
    return [*kept, values[-1]]


#: Mantissas of the labelled minor ticks of a log time axis, the most first, each
#: with the smallest gap (decades) between two labelled ticks it leaves.
_MINOR_LABELS = (((2, 3, 4, 5, 6, 7, 8, 9), math.log10(10 / 9)), ((2, 3, 5), math.log10(3 / 2)),
                 ((2, 5), math.log10(2)))
#: Least distance (points) between two labelled ticks of a log time axis.
_MINOR_GAP = 36.0


def _minor_log_labels(ax: Axes) -> Any:
    """A formatter of the minor ticks of ``ax``'s log x axis: as many of them
    labelled (``0.02``, ``0.05``) as leave :data:`_MINOR_GAP` points between
    labels at the drawn size, none where a decade is too short; so a time axis
    spanning less than a decade still has numbers."""
    from matplotlib.ticker import FuncFormatter

    def label(value: float, _pos: Any = None) -> str:
        low, high = ax.xaxis.get_view_interval()
        fig = ax.get_figure(root=True)
        if not (value > 0 and 0 < low < high) or fig is None:
            return ""
        per_decade = ax.bbox.width / math.log10(high / low)  # pixels
        need = _MINOR_GAP * fig.dpi / 72.0
        mantissa = round(value / 10 ** math.floor(math.log10(value) + 1e-9))
        for keep, gap in _MINOR_LABELS:
            if gap * per_decade >= need:
                return f"{value:g}" if mantissa in keep else ""
        return ""

    return FuncFormatter(label)


def _text_width(fig: Figure, text: str, fontsize: float) -> float:
    """Width of ``text`` (the widest of its lines) in figure pixels at 100 dpi."""
    artist = fig.text(0, 0, text, fontsize=fontsize)
    width = artist.get_window_extent(fig.canvas.get_renderer()).width  # type: ignore[attr-defined]
    artist.remove()
    return float(width) * 100.0 / fig.dpi


def _place_labels(ax: Axes, labels: list[Any], points: np.ndarray, renderer: Any) -> None:
    """Put every annotation of ``labels`` (offset from its point, in order) at the
    first of :data:`_LABEL_OFFSETS` where it stays inside ``ax`` and overlaps no
    other text of ``ax``, no label placed before and no marker at ``points``
    (data coordinates); hide it where none is free, and where a label of the
    same text is already placed for a point within :data:`_LABEL_SHARED` points
    (a cluster of points of one spp carries its spp once)."""
    from matplotlib.transforms import Bbox

    bounds = ax.get_window_extent(renderer)
    mine = {id(label) for label in labels}
    taken = [t.get_window_extent(renderer) for t in ax.texts
             if id(t) not in mine and t.get_visible() and t.get_text().strip()]
    half = _MARKER_HALF * renderer.points_to_pixels(1.0)
    if len(points):
        xy = ax.transData.transform(points)
        taken += [Bbox.from_extents(x - half, y - half, x + half, y + half)
                  for x, y in xy if np.isfinite(x) and np.isfinite(y)]

    def free(box: Bbox) -> bool:
        if (box.x0 < bounds.x0 or box.x1 > bounds.x1 or box.y0 < bounds.y0
                or box.y1 > bounds.y1):
            return False
        return not any(box.x0 < b.x1 + _TEXT_PAD and b.x0 < box.x1 + _TEXT_PAD
                       and box.y0 < b.y1 + _TEXT_PAD and b.y0 < box.y1 + _TEXT_PAD
                       for b in taken)

    shared = _LABEL_SHARED * renderer.points_to_pixels(1.0)
    placed: list[tuple[str, np.ndarray]] = []  # (text, its point in pixels)
    for label in labels:
        label.set_visible(True)
        at = ax.transData.transform(label.xy)
        if any(text == label.get_text() and np.hypot(*(at - p)) < shared
               for text, p in placed):
            label.set_visible(False)
            continue
        for dx, dy in _LABEL_OFFSETS:
            label.xyann = (dx, dy)
            label.set_horizontalalignment("left" if dx > 0 else "right" if dx < 0 else "center")
            label.set_verticalalignment("bottom" if dy > 0 else "top" if dy < 0 else "center")
            box = label.get_window_extent(renderer)
            if free(box):
                taken.append(box)
                placed.append((label.get_text(), at))
                break
        else:
            label.set_visible(False)


def _label_placer(ax: Axes, labels: list[Any], points: np.ndarray) -> Any:
    """An invisible artist of ``ax`` that places ``labels`` (:func:`_place_labels`)
    each time the axes is drawn, before the labels themselves: the layout and the
    limits are final then, whatever the figure's layout engine and the dpi."""
    from matplotlib.artist import Artist

    class LabelPlacer(Artist):
        def draw(self, renderer: Any) -> None:
            _place_labels(ax, labels, points, renderer)

    placer = LabelPlacer()
    placer.set_zorder(-1)  # drawn before the labels (zorder 3)
    placer.set_in_layout(False)
    ax.add_artist(placer)
    return placer


def plot_errors(ax: Axes, result: StudyResult, scene: str, axis: str, legend: bool = True) -> None:
    """Excess MSE of every sampler of ``scene`` against ``axis`` ("spp" or "seconds").

    Each point is a cell: its mean excess MSE over the K seeds with a vertical
    bar over its 95% interval on both plots (the efficiency's: Student t on K - 1
    df on the log scale, :func:`~mcrt.analysis.convergence.recorded_excess_mse`),
    with the fitted power law (its slope in the legend) and the reference's
    noise floor. Against "seconds" a point sits at the cell's median render
    time with a horizontal bar over its 95% interval (``seconds_low`` ..
    ``seconds_high``), is hollow when the cell's timing was not stable
    (a non-empty ``time_problems``) and carries its spp as a grey label placed where
    it overlaps no other text or marker (left out where no place is free, or
    where a nearby point of the same spp is labelled already);
    against "spp" the x ticks are the study's sample counts. Unresolved cells
    (MSE within the reference's noise) are crosses, cells whose bias is
    significant (``biased``) get a red ring; the legend, outside the axes on
    the right, explains each mark once where the plot has one.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    if axis not in ("spp", "seconds"):
        raise ValueError(f"axis must be 'spp' or 'seconds', got {axis!r}")
    time = axis == "seconds"
    config = result.config
    labels = [s.label for s in config.samplers]
    colours = _colours(labels)
    k = max(1, len(config.seeds))
    floor = scene_floor(result, scene)
    handles: list[Any] = []
    names: list[str] = []
    marks = {"unresolved": False, "unstable": False, "biased": False}
    spp_labels: list[tuple[int, Any]] = []  # (priority, annotation)
    points: list[tuple[float, float]] = []
    for label in labels:
        cells = sorted((c for c in result.cells if c["scene"] == scene and c["sampler"] == label),
                       key=lambda c: c["spp"])
        if not cells:  # a partial study: nothing measured yet
            continue
        colour = colours[label]
        x = np.array([c["spp"] if axis == "spp" else c["seconds"] for c in cells], float)
        y = np.array([c["mse_excess"] for c in cells], float)
        low_y, high_y = np.array([recorded_excess_mse(c["mse_excess"], c["mse_sd"], k)
                                  .interval() for c in cells], float).T
        ok = np.array([bool(c["resolved"]) for c in cells]) & (y > 0)
        stable = np.array([not time or not c.get("time_problems") for c in cells])
        biased = np.array([bool(c.get("biased", False)) for c in cells])
        yy = np.where(ok, y, np.where(y > 0, y, floor))
        if ok.any():
            xerr = None
            if time:
                low = np.array([c.get("seconds_low", c["seconds"]) for c in cells], float)
                high = np.array([c.get("seconds_high", c["seconds"]) for c in cells], float)
                xerr = np.nan_to_num(np.clip([x - low, high - x], 0.0, None))[:, ok]
            yerr = np.nan_to_num(np.clip([y - low_y, high_y - y], 0.0, None))[:, ok]
            ax.errorbar(x[ok], y[ok], xerr=xerr, yerr=yerr, fmt="none", ecolor=colour,
                        elinewidth=1, capsize=2, zorder=2)
            filled, hollow = ok & stable, ok & ~stable
            if filled.any():
                ax.plot(x[filled], y[filled], ls="none", marker="o", ms=4, color=colour,
                        zorder=2.6)
            if hollow.any():
                marks["unstable"] = True
                ax.plot(x[hollow], y[hollow], ls="none", marker="o", ms=4, mfc="white",
                        mec=colour, mew=1.2, zorder=2.6)
        if (~ok).any():
            marks["unresolved"] = True
            ax.scatter(x[~ok], yy[~ok], marker="x", color=colour, s=20, zorder=2.6)
        if biased.any():
            marks["biased"] = True
            ax.scatter(x[biased], yy[biased], s=70, facecolors="none", edgecolors="red",
                       linewidths=1.2, zorder=2.7)
        fit = result.fit(scene, label)
        slope = fit[f"slope_{axis}"]
        if math.isfinite(slope) and ok.any():
            xs = np.geomspace(x[ok].min(), x[ok].max(), 20)
            ax.plot(xs, 10 ** (fit[f"intercept_{axis}"] + slope * np.log10(xs)),
                    color=colour, lw=1.1)
        handles.append(Line2D([], [], color=colour, marker="o", ms=4, lw=1.1))
        names.append(f"{label} ({slope:+.2f})" if math.isfinite(slope) else f"{label} (no fit)")
        points += [(float(a), float(b)) for a, b in zip(x, yy, strict=True)]
        if time:
            for i, (xi, yi, c) in enumerate(zip(x, yy, cells, strict=True)):
                text = ax.annotate(str(c["spp"]), (xi, yi), xytext=(4, 4),
                                   textcoords="offset points", fontsize=6, color="0.3")
                text.set_in_layout(False)
                spp_labels.append((0 if i in (0, len(cells) - 1) else 1, text))
    ax.axhline(floor, color="0.5", ls=":", lw=1)
    # On the left, where the error is largest: the points near the floor are on the right.
    ax.text(0.01, floor, "reference noise", transform=ax.get_yaxis_transform(),
            ha="left", va="bottom", fontsize=7, color="0.4")
    if spp_labels:  # line ends first: they say where each line starts and ends
        order = [text for _, text in sorted(spp_labels, key=lambda p: p[0])]
        _label_placer(ax, order, np.array(points, float))
    ax.set_xscale("log")
    if floor > 0 or any(v > 0 for _, v in points):
        ax.set_yscale("log")
    else:  # (a black scene: no error at all, nothing a log axis could show)
        ax.text(0.5, 0.7, "every render equals the reference: MSE 0", transform=ax.transAxes,
                ha="center", va="center", fontsize=9, color="0.3")
    ax.set_xlabel("render time (s): median, 95% interval" if time else "samples per pixel (spp)",
                  fontsize=9)
    ax.set_ylabel("MSE (reference noise removed), 95% interval", fontsize=9)
    ax.set_title(scene, fontsize=10)
    ax.grid(True, which="both", color="0.92", lw=0.5)
    ax.tick_params(which="both", labelsize=8)
    for a in (ax.xaxis, ax.yaxis):
        a.set_minor_formatter(NullFormatter())
    if time:
        ax.xaxis.set_minor_formatter(_minor_log_labels(ax))
    else:
        ax.xaxis.set_major_locator(FixedLocator(_spaced(config.spp)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    if legend and handles:
        if marks["unresolved"]:
            from .fields import RESOLVED_FACTOR

            handles.append(Line2D([], [], marker="x", color="0.3", lw=0, markersize=5))
            names.append(f"unresolved: MSE < {RESOLVED_FACTOR:g}x floor")
        if marks["unstable"]:
            handles.append(Line2D([], [], marker="o", ms=4, mfc="white", mec="0.3", mew=1.2,
                                  lw=0))
            names.append("hollow: timing not stable")
        if marks["biased"]:
            handles.append(Line2D([], [], marker="o", ms=8, mfc="none", mec="red", mew=1.2,
                                  lw=0))
            names.append("red ring: significant bias")
        title = "sampler (slope vs time)\nlabels: spp" if time else "sampler (slope vs spp)"
        ax.legend(handles, names, fontsize=7, title=title, title_fontsize=7,
                  loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def error_figure(result: StudyResult, axis: str) -> Figure:
    """Excess MSE against ``axis`` ("spp" or "seconds"), one panel per scene
    (with a reference: all of them unless the study was interrupted), each with
    its legend on its right (:func:`plot_errors`)."""
    n = len(result.scenes)
    fig = new_figure(6.6 * n, 4.2)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, scene in zip(axes, result.scenes, strict=True):
        plot_errors(ax, result, scene, axis)
    return fig


def _colourbar(fig: Figure, image: Any, cax: Axes, width_px: float, label: str) -> None:
    """A horizontal colour bar ``width_px`` wide: 3 to 6 intervals between ticks,
    about one per 70 pixels, labelled compactly (:func:`_compact`), so no two
    tick labels touch."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    bar = fig.colorbar(image, cax=cax, orientation="horizontal")
    bar.locator = MaxNLocator(nbins=max(3, min(6, int(width_px // 70))))
    bar.formatter = FuncFormatter(_compact)
    cax.tick_params(labelsize=7)
    cax.set_xlabel(label, fontsize=8)


def summary_figure(result: StudyResult, scene: str | None = None,
                   columns: int = 4) -> Figure:
    """The report's main figure: the excess MSE against spp of every scene (the
    headline; :func:`plot_errors`), over the error maps of every sampler on
    ``scene`` (default: the first) at the report's spp, each rendered pixel
    exactly one figure pixel (or a ``zoom x zoom`` block), titled with its
    aliasing verdict, excess MSE and median time. Laid out in pixels from the
    measured widths of the legends and titles, so no two texts overlap."""
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
    fig = new_figure(1.0, 1.0)
    fig.set_layout_engine("none")
    titles = []
    for label in labels:
        cell = result.cell(scene, label, config.image_spp)
        titles.append(f"{label}: {_verdict_z(cell)}\nMSE {cell['mse_excess']:.2e}, "
                      f"{cell['seconds'] * 1e3:.0f} ms")
    gap, title_h, margin = 10, 30, 20
    pitch = max([pw, *(_text_width(fig, t, 8) + 6 for t in titles)]) + gap
    # The plots: y label and ticks on the left, the axes, the legend on the right.
    n = len(result.scenes)
    plot_h, plot_left, plot_axes = 400, 75, 380
    plots = []
    for name in result.scenes:
        ax = fig.add_axes((0.1, 0.1, 0.5, 0.5))
        plot_errors(ax, result, name, "spp")
        plots.append(ax)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    legends = [legend for legend in (ax.get_legend() for ax in plots) if legend is not None]
    legend_w = max((legend.get_window_extent(renderer).width * 100.0 / fig.dpi
                    for legend in legends), default=0.0)
    panel_min = plot_left + plot_axes + (legend_w + 30 if legend_w else 20)
    bar_label = (f"{scene}: luminance error (render - reference) at {config.image_spp} spp, "
                 f"seed {config.seeds[0]}; aliasing verdict with its (ratio / peak) z-scores")
    width = max(columns * pitch - gap + 2 * margin, n * panel_min,
                _text_width(fig, bar_label, 8) + 2 * margin if labels else 0.0)
    height = plot_h + 50 + rows * (ph + title_h + gap) + 80
    fig.set_size_inches(width / 100, height / 100)
    panel = width / n
    for i, ax in enumerate(plots):
        axes_w = panel - plot_left - (legend_w + 30 if legend_w else 20)
        ax.set_position(((i * panel + plot_left) / width, (height - plot_h + 10) / height,
                         axes_w / width, (plot_h - 50) / height))
    cells = [result.images[(scene, label)] for label in labels]
    lim = max((float(np.percentile(np.abs(c.error), 99.5)) for c in cells), default=0) or 1.0
    left = (width - (columns * pitch - gap)) / 2
    image = None
    for i, (title, c) in enumerate(zip(titles, cells, strict=True)):
        r, col = divmod(i, columns)
        x = left + col * pitch + (pitch - gap - pw) / 2
        y = height - (plot_h + 50 + r * (ph + title_h + gap) + title_h + ph)
        ax = fig.add_axes((x / width, y / height, pw / width, ph / height))
        ax.set_xticks([])
        ax.set_yticks([])
        image = ax.imshow(c.error, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        ax.set_title(title, fontsize=8)
    if image is not None:
        cax = fig.add_axes(((width / 2 - 200) / width, 45 / height, 400 / width, 10 / height))
        _colourbar(fig, image, cax, 400, bar_label)
    return fig


def _verdict_z(cell: Cell) -> str:
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
    figure about moire); columns and the row labels' margin are widened to the
    measured widths of their titles and labels, so no two texts overlap.
    """
    from ...io import encode_srgb

    config = result.config
    labels = [s.label for s in config.samplers if (scene, s.label) in result.images]
    cells = [result.images[(scene, label)] for label in labels]
    ref = result.reference_images[scene]
    h, w = ref.shape[:2]
    err_lim = max(float(np.percentile(np.abs(c.error), 99.5)) for c in cells) or 1.0
    std_lim = max(float(np.percentile(c.std, 99.5)) for c in cells) or 1.0
    zoom = max(1, 320 // w)
    pw, ph = w * zoom, h * zoom
    k = len(config.seeds)
    summaries = [result.cell(scene, label, config.image_spp) for label in labels]
    titles = [[f"{result.references[scene].spp} spp"]]
    titles += [[f"{cell['spp']} spp, {cell['seconds'] * 1e3:.0f} ms",
                f"MSE {cell['mse_excess']:.2e}, {_verdict_z(cell)}",
                f"mean variance {cell['variance']:.2e}"] for cell in summaries]
    header = (f"{scene}: {config.image_spp} spp, seed {config.seeds[0]}; error = render - "
              f"reference (luminance); sd of each pixel across {k} seeds")
    dpi = 100
    fig = new_figure(1.0, 1.0)
    fig.set_layout_engine("none")
    gap, title_h, bottom = 12, 22, 70
    col_w = [max([pw, *(_text_width(fig, row[col], 8) + 4 for row in titles if len(row) > col)])
             for col in range(3)]
    left = max([110.0, *(_text_width(fig, text, 9) + 16 for text in ["reference", *labels])])
    width = left + sum(col_w) + 3 * gap
    if _text_width(fig, header, 10) > width - 2 * gap:  # two lines
        header = header.replace("; ", ";\n", 1)
    top = 36 if "\n" not in header else 52
    rows = len(labels) + 1
    height = top + rows * (ph + title_h + gap) + bottom
    fig.set_size_inches(width / dpi, height / dpi)

    def column_x(col: int) -> float:
        """Left edge of the images of column ``col`` (centred in its column)."""
        return left + sum(col_w[:col]) + col * gap + (col_w[col] - pw) / 2

    def axes_at(row: int, col: int) -> Axes:
        y = height - (top + row * (ph + title_h + gap) + title_h + ph)
        ax = fig.add_axes((column_x(col) / width, y / height, pw / width, ph / height))
        ax.set_xticks([])
        ax.set_yticks([])
        return ax

    def row_label(row: int, text: str) -> None:
        y = height - (top + row * (ph + title_h + gap) + title_h + ph / 2)
        fig.text((left - 8) / width, y / height, text, ha="right", va="center", fontsize=9)

    fig.text(0.5, 1 - 8 / height, header, ha="center", va="top", fontsize=10)
    ax = axes_at(0, 0)
    ax.imshow(encode_srgb(ref), interpolation="nearest")
    ax.set_title(titles[0][0], fontsize=8)
    row_label(0, "reference")
    err_image = std_image = None
    for row, (label, c) in enumerate(zip(labels, cells, strict=True), start=1):
        row_label(row, label)
        ax = axes_at(row, 0)
        ax.imshow(encode_srgb(c.render), interpolation="nearest")
        ax.set_title(titles[row][0], fontsize=8)
        ax = axes_at(row, 1)
        err_image = ax.imshow(c.error, cmap="RdBu_r", vmin=-err_lim, vmax=err_lim,
                              interpolation="nearest")
        ax.set_title(titles[row][1], fontsize=8)
        ax = axes_at(row, 2)
        std_image = ax.imshow(c.std, cmap="magma", vmin=0, vmax=std_lim,
                              interpolation="nearest")
        ax.set_title(titles[row][2], fontsize=8)
    for col, image, text in ((1, err_image, "luminance error"),
                             (2, std_image, "sd of the pixel estimate")):
        if image is None:
            continue
        inset = min(12.0, pw / 8)  # end ticks of neighbouring bars apart
        cax = fig.add_axes(((column_x(col) + inset) / width, 40 / height,
                            (pw - 2 * inset) / width, 10 / height))
        _colourbar(fig, image, cax, pw - 2 * inset, text)
    return fig
