r"""The viewer's images as files next to the report, each loaded only when shown.

:func:`write_viewer_data` writes, per scene, ``viewer/<scene>/reference.js``
and per measured cell ``viewer/<scene>/<sampler>_<spp>spp_<kind>.js`` for the
four kinds ``first`` (the first seed's render), ``mean`` (over seeds),
``variance`` (per pixel, across seeds) and ``flip`` (HDR-FLIP of the first
seed), and returns every scene's viewer data: the image size, samplers, sample
counts, the cells' numbers and the files' relative URLs (small: it goes into
report.html).

A data file is one JavaScript call, ``mcrtData(url, [h, w, c], e, "...")``, so
that the page loads it with a ``<script src>`` element: that works from
``file://``, where Chromium refuses ``fetch()`` of local files. The payload is
the image as float16 (IEEE half) of ``value * 2**e``, the power of two ``e``
chosen per image so that its largest finite value is near ``2**14`` (no
overflow above 65504, no loss in the subnormals for tiny variances), little
endian, byte-shuffled (all low bytes, then all high bytes) and deflated
(zlib), its bytes written as they are into the string literal, the file being
read as windows-1252 (the page sets the script's ``charset``), in which every
byte is one character: only ``\``, ``"``, line feed, carriage return and NUL
are escaped (``\\ \" \n \r \x00``), about 2% more than the bytes where
base64 would add 33%. The browser maps the characters back to bytes and
inflates them with ``DecompressionStream``. The viewer shows, reads out and
computes its error views from these values: 11 significant bits, a relative
rounding of at most 2^-11 for every value above 2^-27 times the image's largest
(smaller ones are float16 subnormals, rounded to 2^-37 of it; :func:`as_shown`
gives the values here). The exact float32 images are the EXR files in ``exr/``.

The error views' colour scales (the 99th percentile of each view's values over
every sampler at one sample count, as the viewer computed them when it held
every image) are computed here, from the values as shown, so that the page
needs no image it does not draw (:func:`colour_scales`).
"""

from __future__ import annotations

import json
import math
import os
import re
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from ...core.atomic import atomic_path
from ...core.colour import LUMINANCE_WEIGHTS
from ..metrics import REL_MSE_EPSILON, error_map
from .files import Links, safe_name

if TYPE_CHECKING:
    from ..study import StudyResult

#: Directory of the viewer's data files inside the report directory.
DATA_DIR = "viewer"
#: The largest finite value of an image is scaled to at most 2**TOP_EXPONENT.
TOP_EXPONENT = 14
#: The data files of one cell.
KINDS = ("first", "mean", "variance", "flip")
#: Error views with a colour scale computed from the images (FLIP's is 0..1).
SCALED_VIEWS = ("signed", "abs", "rel", "variance")
#: Pixels sampled per image for a colour scale (the viewer's former rule).
SCALE_SAMPLES = 20000
#: Luminance weights, as the viewer applies them (the page gets them from here).
LUM = LUMINANCE_WEIGHTS
#: zlib level of the data files (6: the default; 9 saves under 1% on noisy images).
LEVEL = 6

_CALL = re.compile(rb'mcrtData\(("[^"]*"),\[(\d+),(\d+),(\d+)\],(-?\d+),"(.*)"\);\n', re.S)
#: The escapes of the payload's string literal, and their inverse.
_ESCAPES = ((b"\\", b"\\\\"), (b'"', b'\\"'), (b"\n", b"\\n"), (b"\r", b"\\r"),
            (b"\x00", b"\\x00"))
_UNESCAPE = re.compile(rb'\\(x00|[nr"\\])')
_UNESCAPED = {b"x00": b"\x00", b"n": b"\n", b"r": b"\r", b'"': b'"', b"\\": b"\\"}


def half_exponent(array: np.ndarray) -> int:
    """The power of two ``e`` that brings the largest finite ``|value|`` to at
    most ``2**TOP_EXPONENT`` (0 for an image without a finite non-zero value)."""
    a = np.abs(np.asarray(array, np.float64))
    finite = a[np.isfinite(a)]
    top = float(finite.max()) if finite.size else 0.0
    if top == 0.0:
        return 0
    return TOP_EXPONENT - math.ceil(math.log2(top))


def to_half(array: np.ndarray) -> tuple[int, np.ndarray]:
    """``(e, float16 of array * 2**e)`` (NaN and +-Inf kept)."""
    e = half_exponent(array)
    return e, np.ldexp(np.asarray(array, np.float64), e).astype("<f2")


def from_half(half: np.ndarray, exponent: int) -> np.ndarray:
    """The float32 values the viewer shows for ``half`` (see :func:`to_half`)."""
    return np.ldexp(half.astype(np.float64), -exponent).astype(np.float32)


def as_shown(array: np.ndarray) -> np.ndarray:
    """``array`` as the viewer holds it: float32 of its float16 encoding."""
    e, half = to_half(array)
    return from_half(half, e)


def encode_half(array: np.ndarray) -> tuple[int, bytes, np.ndarray]:
    """``(e, payload, shown)``: the exponent, the escaped payload of a data file
    and the float32 values the viewer will show (see the module doc)."""
    e, half = to_half(array)
    shuffled = np.ascontiguousarray(half).view(np.uint8).reshape(-1, 2).T.tobytes()
    payload = zlib.compress(shuffled, LEVEL)
    for raw, escaped in _ESCAPES:  # the backslash first
        payload = payload.replace(raw, escaped)
    return e, payload, from_half(half, e)


def decode_half(payload: bytes, exponent: int, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_half`'s payload: the float32 values shown."""
    data = _UNESCAPE.sub(lambda m: _UNESCAPED[m.group(1)], payload)
    raw = np.frombuffer(zlib.decompress(data), dtype=np.uint8)
    half = raw.reshape(2, -1).T.copy().view("<f2").reshape(shape)
    return from_half(half, exponent)


def data_call(url: str, shape: tuple[int, ...], exponent: int, payload: bytes) -> bytes:
    """The bytes of a data file: one call of the page's ``mcrtData``."""
    h, w = shape[:2]
    c = shape[2] if len(shape) == 3 else 1
    head = f"mcrtData({json.dumps(url)},[{h},{w},{c}],{exponent},\""
    return head.encode("ascii") + payload + b'");\n'


def read_data_file(path: str | os.PathLike[str]) -> tuple[str, np.ndarray]:
    """``(url, values shown)`` of a data file (for tests and checks)."""
    m = _CALL.fullmatch(Path(path).read_bytes())
    if m is None:
        raise ValueError(f"{path} is not a viewer data file")
    h, w, c = (int(m.group(i)) for i in (2, 3, 4))
    shape = (h, w, c) if c > 1 else (h, w)
    return json.loads(m.group(1)), decode_half(m.group(6), int(m.group(5)), shape)


def _write(path: Path, directory: Path, array: np.ndarray) -> tuple[str, np.ndarray]:
    """Write one data file; returns its URL (relative to ``directory``) and the values shown."""
    url = quote(path.relative_to(directory).as_posix())
    e, payload, shown = encode_half(array)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data_call(url, np.shape(array), e, payload))
    return url, shown


def _luminance(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float64)
    return LUM[0] * rgb[..., 0] + LUM[1] * rgb[..., 1] + LUM[2] * rgb[..., 2]


def scale_samples(shown: dict[str, np.ndarray], ref: np.ndarray) -> dict[str, np.ndarray]:
    """|value| of each scaled error view at the sampled pixels of one cell
    (``shown``: its first, mean and variance as shown; ``ref``: the reference
    as shown), keyed ``view/source``, as the viewer computes the views."""
    n = ref.shape[0] * ref.shape[1]
    index = np.arange(0, n, max(1, n // SCALE_SAMPLES))
    y_ref = _luminance(ref.reshape(-1, 3)[index])
    out: dict[str, np.ndarray] = {}
    for source in ("first", "mean"):
        d = np.abs(_luminance(shown[source].reshape(-1, 3)[index]) - y_ref)
        out[f"signed/{source}"] = out[f"abs/{source}"] = d
        out[f"rel/{source}"] = d / np.sqrt(y_ref * y_ref + REL_MSE_EPSILON)
        out[f"variance/{source}"] = np.abs(shown["variance"].reshape(-1)[index].astype(np.float64))
    return out


def percentile(values: list[np.ndarray], q: float = 0.99) -> float:
    """The viewer's percentile: of the finite values, sorted, the one at
    ``floor(q * (n - 1))``; 1 when there is none or it is not positive."""
    a = np.concatenate(values) if values else np.zeros(0)
    a = np.sort(a[np.isfinite(a)])
    if not a.size:
        return 1.0
    p = float(a[min(a.size - 1, math.floor(q * (a.size - 1)))])
    return p if p > 0 else 1.0


def colour_scales(samples: dict[int, list[dict[str, np.ndarray]]]) -> dict[str, float]:
    """Each scaled view's colour-bar maximum per sample count and source,
    keyed ``view/spp/source``, from every sampler's :func:`scale_samples`."""
    scales = {}
    for spp, cells in samples.items():
        for view in SCALED_VIEWS:
            for source in ("first", "mean"):
                key = f"{view}/{source}"
                scales[f"{view}/{spp}/{source}"] = percentile([c[key] for c in cells])
    return scales


def write_viewer_data(result: StudyResult, directory: str | os.PathLike[str],
                      links: Links) -> dict[str, dict[str, Any]]:
    """Write every scene's data files; returns each scene's viewer data (JSON-ready;
    ``links``: the EXR files, :func:`~mcrt.analysis.viewer.files.write_exrs`)."""
    directory = Path(directory)
    out = {}
    for scene in result.scenes:
        if any(key[0] == scene for key in result.renders):
            out[scene] = _scene_data(result, scene, directory, links)
    return out


def _scene_data(result: StudyResult, scene: str, directory: Path,
                links: Links) -> dict[str, Any]:
    from . import flip_map, hardest_regions

    config = result.config
    ref = np.asarray(result.reference_images[scene], np.float32)
    h, w = ref.shape[:2]
    folder = directory / DATA_DIR / safe_name(scene)
    folder.mkdir(parents=True, exist_ok=True)
    ref_url, ref_shown = _write(folder / "reference.js", directory, ref)
    keys = [(scene, s.label, spp) for s in config.samplers for spp in config.spp
            if (scene, s.label, spp) in result.renders]

    def one(key: tuple[str, str, int]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        # FLIP is the slow part (~0.5 s a 320x240 image); it and zlib release the GIL.
        renders = result.renders[key]
        flip, flip_mean = flip_map(renders.first, ref)
        arrays = {"first": renders.first, "mean": renders.mean,
                  "variance": renders.variance, "flip": flip}
        urls, shown = {}, {}
        stem = f"{safe_name(key[1])}_{key[2]}spp"
        for kind in KINDS:
            urls[kind], shown[kind] = _write(folder / f"{stem}_{kind}.js", directory,
                                             arrays[kind])
        cell = result.cell(*key)
        entry = {"data": urls, "flip_mean": flip_mean, "spp": cell["spp"], "mse": cell["mse"],
                 "mse_excess": cell["mse_excess"], "rel_mse": cell["rel_mse"],
                 "exr": links.get(key, {})}
        return entry, scale_samples(shown, ref_shown)

    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        done = dict(zip(keys, pool.map(one, keys), strict=True))
    samples: dict[int, list[dict[str, np.ndarray]]] = {spp: [] for spp in config.spp}
    hard = []
    for key, (_, found) in done.items():
        samples[key[2]].append(found)
        if key[2] == config.image_spp:
            first = result.renders[key].first
            hard.append(error_map(np.where(np.isfinite(first), first, ref), ref))
    return {"scene": scene, "width": int(w), "height": int(h),
            "samplers": [s.label for s in config.samplers], "spp": list(config.spp),
            "image_spp": config.image_spp, "seeds": list(config.seeds),
            "reference": ref_url, "reference_spp": result.references[scene].spp,
            "reference_exr": links.get(scene, {}).get("reference", ""),
            "crops": hardest_regions(hard), "scales": colour_scales(samples),
            "cells": {f"{label}/{spp}": entry for (_, label, spp), (entry, _) in done.items()}}


__all__ = ["DATA_DIR", "KINDS", "TOP_EXPONENT", "as_shown", "colour_scales", "data_call",
           "decode_half", "encode_half", "half_exponent", "percentile", "read_data_file",
           "scale_samples", "write_viewer_data"]
