"""The study report's image viewer: one interactive, self-contained panel per scene.

:func:`viewer_sections` returns the HTML of every scene's viewer: a skeleton and
the scene's data as JSON, which ``viewer.js`` (inlined once into the report by
:func:`viewer_assets`, with ``viewer.css``) turns into the viewer. Nothing is
loaded from elsewhere: the report is one file that works offline.

The data of a scene are float32 arrays (the reference; per cell the first
seed's render, the mean over seeds, the per-pixel variance across seeds and
the FLIP map of the first seed), each byte-shuffled (all first bytes, then all
second bytes, ...), zlib-compressed and base64-encoded (:func:`encode_array`;
the browser inflates them with ``DecompressionStream``). The viewer shows the
true values: exposure and tone mapping (sRGB) are applied in the browser, the
readout prints the stored float32 values, and the error views are computed
there from the same floats:

* signed: ``Y(image) - Y(reference)`` (Rec. 709 luminance), blue below, red above;
* absolute: ``|Y(image) - Y(reference)|``;
* relative: ``|Y(image) - Y(reference)| / sqrt(Y(reference)^2 + 0.01)`` (relMSE's
  weighting, :data:`~mcrt.analysis.metrics.REL_MSE_EPSILON`);
* FLIP: HDR-FLIP (the ``flip-evaluator`` package, NVIDIA's reference code) of the
  first seed's render against the reference, on its own 0..1 scale;
* variance: the per-pixel variance of the estimate across seeds.

The crops of the hardest regions (:func:`hardest_regions`) are the blocks with
the largest squared luminance error of the first seed, averaged over samplers,
at the report's spp. Each cell's images are also written as EXR next to the
report (:mod:`.files`) and linked from the viewer.
"""

from __future__ import annotations

import base64
import html
import json
import os
import zlib
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from typing import TYPE_CHECKING, Any

import numpy as np

from ..metrics import error_map

if TYPE_CHECKING:
    from ..study import StudyResult

#: Side of the square crops: the image's smaller side over this, within [8, 64].
CROP_FRACTION = 5
#: How many crops per scene.
CROPS = 3


def viewer_assets() -> tuple[str, str]:
    """The viewer's CSS and JavaScript (package data next to this module)."""
    here = resources.files(__package__)
    return ((here / "viewer.css").read_text(encoding="utf-8"),
            (here / "viewer.js").read_text(encoding="utf-8"))


def encode_array(array: np.ndarray) -> str:
    """float32 little-endian, byte-shuffled, zlib, base64 (see the module doc)."""
    a = np.ascontiguousarray(array, dtype="<f4")
    shuffled = a.view(np.uint8).reshape(-1, 4).T.tobytes()
    return base64.b64encode(zlib.compress(shuffled, 6)).decode("ascii")


def decode_array(text: str, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_array` (for tests)."""
    raw = np.frombuffer(zlib.decompress(base64.b64decode(text)), dtype=np.uint8)
    return raw.reshape(4, -1).T.copy().view("<f4").reshape(shape)


def flip_map(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, float]:
    """HDR-FLIP error map (H, W) and its mean, of ``image`` against ``reference``
    (non-finite pixels taken as the reference's, negative values as 0)."""
    import flip_evaluator

    ref = np.clip(np.nan_to_num(np.asarray(reference, np.float32), nan=0.0), 0, None)
    img = np.asarray(image, np.float32)
    img = np.clip(np.where(np.isfinite(img), img, ref), 0, None).astype(np.float32)
    error, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref),
                                             np.ascontiguousarray(img), "HDR",
                                             applyMagma=False)
    return np.asarray(error, np.float32).reshape(ref.shape[:2]), float(mean)


def hardest_regions(errors: list[np.ndarray], count: int = CROPS) -> list[list[int]]:
    """``count`` non-overlapping square blocks ``[x, y, size]`` with the largest
    mean of the squared error images ``errors`` (each (H, W)), hardest first."""
    if not errors:
        return []
    sq = np.mean([np.nan_to_num(e, nan=0.0) ** 2 for e in errors], axis=0)
    h, w = sq.shape
    size = int(min(64, max(8, min(h, w) // CROP_FRACTION)))
    size = min(size, h, w)
    step = max(1, size // 4)
    integral = np.pad(sq, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    ys = list(range(0, h - size + 1, step))
    xs = list(range(0, w - size + 1, step))
    if ys[-1] != h - size:
        ys.append(h - size)
    if xs[-1] != w - size:
        xs.append(w - size)
    scored = []
    for y in ys:
        for x in xs:
            total = (integral[y + size, x + size] - integral[y, x + size]
                     - integral[y + size, x] + integral[y, x])
            scored.append((float(total), x, y))
    scored.sort(key=lambda t: (-t[0], t[2], t[1]))
    chosen: list[list[int]] = []
    for _, x, y in scored:
        if all(abs(x - cx) >= size or abs(y - cy) >= size for cx, cy, _ in chosen):
            chosen.append([x, y, size])
            if len(chosen) == count:
                break
    return chosen


def scene_data(result: StudyResult, scene: str,
               links: dict[tuple[str, str, int] | str, dict[str, str]]) -> dict[str, Any]:
    """Everything the viewer of ``scene`` shows (JSON-ready); ``links``: the EXR
    files written by :func:`mcrt.analysis.viewer.files.write_exrs`."""
    config = result.config
    ref = np.asarray(result.reference_images[scene], np.float32)
    h, w = ref.shape[:2]
    cells: dict[str, dict[str, Any]] = {}
    hard: list[np.ndarray] = []
    keys = [(scene, s.label, spp) for s in config.samplers for spp in config.spp
            if (scene, s.label, spp) in result.renders]
    # FLIP is the slow part (~0.5 s a 320x240 image); its C++ code releases the GIL.
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        flips = dict(zip(keys, pool.map(lambda k: flip_map(result.renders[k].first, ref),
                                        keys)))
    for key in keys:
        _, label, spp = key
        renders = result.renders[key]
        cell = result.cell(*key)
        flip, flip_mean = flips[key]
        cells[f"{label}/{spp}"] = {
            "first": encode_array(renders.first), "mean": encode_array(renders.mean),
            "variance": encode_array(renders.variance), "flip": encode_array(flip),
            "flip_mean": flip_mean, "spp": cell["spp"], "mse": cell["mse"],
            "mse_excess": cell["mse_excess"],
            "rel_mse": cell["rel_mse"], "exr": links.get(key, {})}
        if spp == config.image_spp:
            first = np.where(np.isfinite(renders.first), renders.first, ref)
            hard.append(error_map(first, ref))
    return {"scene": scene, "width": int(w), "height": int(h),
            "samplers": [s.label for s in config.samplers], "spp": list(config.spp),
            "image_spp": config.image_spp, "seeds": list(config.seeds),
            "reference": encode_array(ref), "reference_spp": result.references[scene].spp,
            "reference_exr": links.get(scene, {}).get("reference", ""),
            "crops": hardest_regions(hard), "cells": cells}


def _json_script(data: dict[str, Any]) -> str:
    text = json.dumps(data, allow_nan=False, separators=(",", ":"))
    return text.replace("</", "<\\/")


def _clean_floats(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _clean_floats(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_clean_floats(v) for v in data]
    if isinstance(data, float) and not np.isfinite(data):
        return None
    return data


HELP = ("Keys (hover a viewer first): 1-9 sampler, &uarr;/&darr; previous/next sampler, "
        "&larr;/&rarr; fewer/more spp, r reference, m mean over seeds / first seed, "
        "i image, s signed, a absolute, e relative error, f FLIP, v variance, "
        "+/- zoom (or the wheel), drag to pan, 0 reset the view, [ ] exposure, "
        "x exposure 0, { } error scale, g grid / one image. Hover a pixel for its values.")


def viewer_sections(result: StudyResult,
                    links: dict[tuple[str, str, int] | str, dict[str, str]]) -> list[str]:
    """The HTML of every scene's viewer (scenes with a reference and images)."""
    parts = []
    for index, scene in enumerate(result.scenes):
        if not any(key[0] == scene for key in result.renders):
            continue
        data = _clean_floats(scene_data(result, scene, links))
        parts.append(
            f"<h3 id='viewer-{index}'>{html.escape(scene)}</h3>"
            f"<div class='mcrt-viewer' tabindex='0' data-scene='{html.escape(scene)}' "
            f"data-help='{HELP}'>"
            f"<script type='application/json' class='vw-data'>{_json_script(data)}</script>"
            "<noscript>The viewer needs JavaScript.</noscript></div>")
    return parts


__all__ = ["CROPS", "HELP", "decode_array", "encode_array", "flip_map", "hardest_regions",
           "scene_data", "viewer_assets", "viewer_sections"]
