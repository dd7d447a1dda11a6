"""The study report's image viewer: one interactive panel per scene.

:func:`viewer_sections` returns the HTML of every scene's viewer: a skeleton and
the scene's viewer data as JSON (image size, samplers, sample counts, the cells'
numbers, the colour scales and the relative URLs of its images), which the
scripts (``viewer.js``, ``loading.js``, ``pixels.js``, ``tables.js``, inlined once
into the report by :func:`viewer_assets`, with ``viewer.css``) turn into the
viewer. Nothing is loaded from elsewhere: the report directory works offline,
from ``file://``.

The images are files beside the report (:mod:`.data`: float16, deflated, one
``<script src>`` each), loaded only when a panel that shows one scrolls into
view, so that a study of many large images opens at once. The viewer shows the
values of those files: exposure and tone mapping (sRGB) are applied in the
browser, the readout prints the values, and the error views are computed there
from them:

* signed: ``Y(image) - Y(reference)`` (luminance, :mod:`mcrt.core.colour`), blue below, red above;
* absolute: ``|Y(image) - Y(reference)|``;
* relative: ``|Y(image) - Y(reference)| / sqrt(Y(reference)^2 + 0.01)`` (relMSE's
  weighting, :data:`~mcrt.analysis.metrics.REL_MSE_EPSILON`);
* FLIP: HDR-FLIP (the ``flip-evaluator`` package, NVIDIA's reference code) of the
  first seed's render against the reference, on its own 0..1 scale;
* variance: the per-pixel variance of the estimate across seeds.

The crops of the hardest regions (:func:`hardest_regions`) are the blocks with
the largest squared luminance error of the first seed, averaged over samplers,
at the report's spp. Each cell's images are also written as float32 EXR next to
the report (:mod:`.files`) and linked from the viewer.
"""

from __future__ import annotations

import html
import json
from importlib import resources
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.colour import LUMINANCE_WEIGHTS
from ...core.jsonfile import json_safe

if TYPE_CHECKING:
    from ..study import StudyResult

#: Side of the square crops: the image's smaller side over this, within [8, 64].
CROP_FRACTION = 5
#: How many crops per scene.
CROPS = 3


#: The viewer's JavaScript, in the order the page runs it, in one function scope.
SCRIPTS = ("viewer.js", "loading.js", "pixels.js", "tables.js")


def viewer_assets() -> tuple[str, str]:
    """The viewer's CSS and JavaScript (package data next to this module; the
    scripts of :data:`SCRIPTS` in one strict-mode function, after ``LUM``, the
    luminance weights :data:`~mcrt.core.colour.LUMINANCE_WEIGHTS`)."""
    here = resources.files(__package__)
    parts = [f"var LUM = {json.dumps(list(LUMINANCE_WEIGHTS))};\n"]
    parts += [(here / name).read_text(encoding="utf-8") for name in SCRIPTS]
    script = '(function () {\n"use strict";\n' + "\n".join(parts) + "})();\n"
    return (here / "viewer.css").read_text(encoding="utf-8"), script


#: HDR-FLIP takes its exposure range from the reference's largest luminance
#: ``Y_max`` and its median clamped to float32's epsilon (1.19e-7): below that
#: ``Y_max`` the range is empty and the library aborts the process (not an
#: exception). References whose largest luminance is under this bound (black
#: scenes) are compared at exposure 0, as the PNGs show them.
FLIP_DARKEST_RANGE = 1e-6

#: HDR-FLIP's parameters for a reference darker than :data:`FLIP_DARKEST_RANGE`:
#: exposure 0 alone (the library needs two exposures; one gives no error at all).
FLIP_AT_EXPOSURE_0 = {"startExposure": 0.0, "stopExposure": 0.0, "numExposures": 2}


def flip_map(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, float]:
    """HDR-FLIP error map (H, W) and its mean, of ``image`` against ``reference``
    (non-finite pixels taken as the reference's, negative values as 0; a reference
    with no light to speak of is compared at exposure 0, see
    :data:`FLIP_DARKEST_RANGE`)."""
    import flip_evaluator

    ref = np.clip(np.nan_to_num(np.asarray(reference, np.float32), nan=0.0), 0, None)
    img = np.asarray(image, np.float32)
    img = np.clip(np.where(np.isfinite(img), img, ref), 0, None).astype(np.float32)
    brightest = float(np.max(ref[..., :3] @ np.asarray(LUMINANCE_WEIGHTS, np.float32),
                             initial=0.0))
    parameters = FLIP_AT_EXPOSURE_0 if brightest < FLIP_DARKEST_RANGE else {}
    error, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref),
                                             np.ascontiguousarray(img), "HDR",
                                             applyMagma=False, parameters=parameters)
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


def _json_script(data: dict[str, Any]) -> str:
    text = json.dumps(data, allow_nan=False, separators=(",", ":"))
    return text.replace("</", "<\\/")


HELP = ("Keys (hover a viewer first): 1-9 sampler, &uarr;/&darr; previous/next sampler, "
        "&larr;/&rarr; fewer/more spp, r reference, m mean over seeds / first seed, "
        "i image, s signed, a absolute, e relative error, f FLIP, v variance, "
        "+/- zoom (or the wheel), drag to pan, 0 reset the view, [ ] exposure, "
        "x exposure 0, { } error scale, g grid / one image. Hover a pixel for its values.")


def viewer_sections(result: StudyResult, data: dict[str, dict[str, Any]]) -> list[str]:
    """The HTML of every scene's viewer; ``data``: each scene's viewer data
    (:func:`~.data.write_viewer_data`; scenes without images have none)."""
    parts = []
    for index, scene in enumerate(result.scenes):
        if scene not in data:
            continue
        scene_data = json_safe(data[scene])
        parts.append(
            f"<h3 id='viewer-{index}'>{html.escape(scene)}</h3>"
            f"<div class='mcrt-viewer' tabindex='0' data-scene='{html.escape(scene)}' "
            f"data-help='{HELP}'>"
            f"<script type='application/json' class='vw-data'>{_json_script(scene_data)}</script>"
            "<noscript>The viewer needs JavaScript.</noscript></div>")
    return parts


__all__ = ["CROPS", "HELP", "flip_map", "hardest_regions", "viewer_assets", "viewer_sections"]
