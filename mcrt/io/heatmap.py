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


def write_heatmap(path, spp: np.ndarray, lo: float | None = None,
                  hi: float | None = None) -> None:
    """Write :func:`heatmap` as a PNG, atomically."""
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(heatmap(spp, lo, hi), mode="RGB").save(tmp, format="PNG")


__all__ = ["heatmap", "write_heatmap"]
