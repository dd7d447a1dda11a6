"""Plots of sampling patterns and convergence, drawn the way the lecture shows them.

Matplotlib is used through its object interface with the Agg canvas (no
``pyplot``, no global state, no display needed), and every figure is written
atomically with :func:`mcrt.core.atomic.atomic_path`. It is imported when the
first figure is made, so commands that draw nothing never load it. A study's
figures are in :mod:`mcrt.analysis.study.figures`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .patterns import RadialSpectrum

#: Display range of the power spectrum images (white noise = 1 is mid-grey).
SPECTRUM_VMAX = 2.0


def new_figure(width: float, height: float) -> Figure:
    """A figure attached to an Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 120,
                text: dict[str, str] | None = None) -> None:
    """Write ``fig`` as PNG to ``path`` atomically (a figure with a layout engine
    is laid out at ``dpi`` and left so, without the engine: drawn once), with
    ``text`` (keyword: value, e.g. :func:`mcrt.core.provenance.png_text`) as the
    PNG's text chunks.

    Ctrl-C and termination signals wait until the file is written: raised inside
    matplotlib's drawing, where its C++ code converts Python objects, the
    ``KeyboardInterrupt`` came out as "ValueError: Invalid affine transformation
    matrix" (a killed ``mcrt compare`` printed a traceback instead of stopping)."""
    from ..core.engine import deferred_interrupts

    with deferred_interrupts(), atomic_path(path) as tmp:
        engine = fig.get_layout_engine()
        if engine is not None:
            # Lay the figure out here, at the saved resolution, and save it without
            # its layout engine: savefig would otherwise draw every artist twice,
            # once (output off) to lay it out, resampling every image both times.
            fig.set_dpi(dpi)
            engine.execute(fig)
            fig.set_layout_engine(None)
        fig.savefig(tmp, format="png", dpi=dpi, metadata=text)


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


def plot_convergence(ax: Axes,
                     series: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                     reference_slopes: Sequence[float] = (-1.0, -1.5, -2.0),
                     ylabel: str = "MSE (bars: 95% interval)", title: str = "") -> None:
    """Log-log MSE against N for several samplers.

    ``series``: ``(label, n, mse, low, high)`` per sampler; error bars span
    ``low .. high``, the MSE's 95% interval
    (:meth:`mcrt.analysis.integrate.MSESummary.interval`: chi-square, skewed
    upwards like the MSE). Dashed guide lines with ``reference_slopes``
    start at the first series' first point.
    """
    for label, n, mse, low, high in series:
        n, mse, low, high = (np.asarray(a, dtype=np.float64) for a in (n, mse, low, high))
        keep = mse > 0
        below = np.nan_to_num(np.clip(mse[keep] - low[keep], 0.0, None))
        above = np.nan_to_num(np.clip(high[keep] - mse[keep], 0.0, None))
        ax.errorbar(n[keep], mse[keep], yerr=(below, above), marker="o", ms=3, lw=1.2,
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
