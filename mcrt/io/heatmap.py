"""Heat maps of per-pixel sample counts (``mcrt render --adaptive``'s ``OUT_spp.png``)."""

from __future__ import annotations

import math

import numpy as np

from ..core.atomic import atomic_path


def heatmap(spp: np.ndarray, lo: float | None = None, hi: float | None = None,
            colormap: str = "inferno") -> np.ndarray:
    """(H, W, 3) uint8 heat map of sample counts on a log2 scale from ``lo`` to ``hi``
    (default: the counts' range)."""
    from matplotlib import colormaps

    spp = np.asarray(spp, dtype=np.float64)
    lo = float(spp.min()) if lo is None else float(lo)
    hi = float(spp.max()) if hi is None else float(hi)
    lo = max(lo, 1.0)
    hi = max(hi, lo * 1.0001)
    t = (np.log2(np.maximum(spp, lo)) - math.log2(lo)) / (math.log2(hi) - math.log2(lo))
    rgba = colormaps[colormap](np.clip(t, 0.0, 1.0))
    return (rgba[..., :3] * 255.0 + 0.5).astype(np.uint8)


#: Size the heat map of a small image is enlarged to (by a whole factor, each
#: pixel a block of equal pixels: never interpolated), in screen pixels.
MIN_DISPLAY_PX = 400

#: Margins of the figure around the map, in pixels: left, right (the colour bar),
#: top (the title), bottom.
MARGINS = (12, 110, 42, 12)

#: Room added at the top for each further line of the title, in pixels.
TITLE_LINE_PX = 13


#: Side below which a thin map's rows (or columns) are drawn taller (wider) by a
#: whole factor, so the map, its title and its colour bar stay readable (a
#: 4096 x 1 film), in screen pixels.
MIN_MAP_SIDE_PX = 200


def display_scale(width: int, height: int) -> int:
    """Whole enlargement factor of a ``width`` x ``height`` map (at least 1)."""
    return max(1, MIN_DISPLAY_PX // max(width, height, 1))


def thin_stretch(extent: int, scale: int) -> int:
    """Whole factor by which the rows (columns) of a map side drawn ``extent *
    scale`` pixels long are drawn longer still, to :data:`MIN_MAP_SIDE_PX` (1: none)."""
    return max(1, math.ceil(MIN_MAP_SIDE_PX / max(extent * scale, 1)))


def spp_ticks(lo: float, hi: float) -> list[float]:
    """Colour-bar ticks of a log scale from ``lo`` to ``hi``: both ends and the
    powers of two between (at most 9, evenly thinned), so a map whose counts are
    all equal still has its one value labelled."""
    inner = [2.0 ** e for e in range(math.ceil(math.log2(lo)), math.floor(math.log2(hi)) + 1)]
    inner = [t for t in inner if lo * 1.1 < t < hi / 1.1]
    step = max(1, math.ceil(len(inner) / 7))
    ticks = [lo, *inner[::step]]
    return ticks + [hi] if round(hi) != round(lo) else ticks


def default_title(spp: np.ndarray) -> str:
    """What the sample counts were: their mean and range."""
    spp = np.asarray(spp)
    return (f"samples per pixel: mean {float(spp.mean()):.1f}, "
            f"min {int(spp.min())}, max {int(spp.max())}")


def write_heatmap(path, spp: np.ndarray, lo: float | None = None,
                  hi: float | None = None, title: str | None = None,
                  colormap: str = "inferno", png_text: dict[str, str] | None = None) -> None:
    """Write the heat map of ``spp`` as a PNG, atomically: the map at native
    resolution (small images enlarged by a whole factor, nearest neighbour), a
    ``title`` (default :func:`default_title`) and a log-scale colour bar from
    ``lo`` to ``hi`` (default: the counts' range); ``png_text`` as the PNG's
    text chunks (:func:`mcrt.core.provenance.png_text`)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import LogNorm
    from matplotlib.figure import Figure

    spp = np.asarray(spp, dtype=np.float64)
    lo = max(float(spp.min()) if lo is None else float(lo), 1.0)
    hi = max(float(spp.max()) if hi is None else float(hi), lo * 1.0001)
    height, width = spp.shape[:2]
    k = display_scale(width, height)
    tall, wide = thin_stretch(height, k), thin_stretch(width, k)
    map_w, map_h = width * k * wide, height * k * tall
    text = title if title is not None else default_title(spp)
    if map_w < 320:  # a narrow map: the title on two lines, not clipped
        text = text.replace(": ", ":\n", 1)
    stretched = [f"rows drawn {tall}x taller" if tall > 1 else "",
                 f"columns drawn {wide}x wider" if wide > 1 else ""]
    note = ", ".join(filter(None, stretched))
    text += f"\n({note})" if note else ""
    left, right, top, bottom = MARGINS
    top += TITLE_LINE_PX * text.count("\n")
    fig_w, fig_h = map_w + left + right, map_h + top + bottom
    dpi = 100
    fig = Figure(figsize=(fig_w / dpi, fig_h / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((left / fig_w, bottom / fig_h, map_w / fig_w, map_h / fig_h))
    image = ax.imshow(np.maximum(spp, lo), cmap=colormap, norm=LogNorm(vmin=lo, vmax=hi),
                      interpolation="nearest", aspect="auto")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(text, fontsize=9)
    bar = fig.add_axes(((left + map_w + 14) / fig_w, bottom / fig_h, 14 / fig_w, map_h / fig_h))
    colorbar = fig.colorbar(image, cax=bar)
    ticks = spp_ticks(lo, hi)
    colorbar.set_ticks(ticks, labels=[f"{t:.0f}" for t in ticks])
    colorbar.minorticks_off()
    colorbar.set_label("samples per pixel (log scale)", fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, metadata=png_text)


__all__ = ["default_title", "display_scale", "heatmap", "spp_ticks", "thin_stretch",
           "write_heatmap"]
