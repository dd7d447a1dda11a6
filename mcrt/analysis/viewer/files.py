"""A study's images as EXR files next to its report, for tev or any other viewer.

``exr/<scene>/reference.exr`` and, per measured cell,
``exr/<scene>/<sampler>_<spp>spp_mean.exr`` (the mean over seeds, with the
per-pixel variance across seeds as the ``variance.Y`` layer) and
``exr/<scene>/<sampler>_<spp>spp_seed<first seed>.exr`` (the first seed's render
as rendered). Float32, written atomically by :func:`mcrt.io.write_exr`.
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

import numpy as np

if TYPE_CHECKING:
    from ..study import StudyResult

#: Directory of the EXR files inside the report directory.
EXR_DIR = "exr"

Links = dict[tuple[str, str, int] | str, dict[str, str]]


def safe_name(name: str) -> str:
    """``name`` as a portable file name: letters, digits, ``.-_`` (anything else
    becomes ``_``, plus a short hash so that two names cannot collide)."""
    clean = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip(".") or "_"
    if clean != name:
        clean += "-" + hashlib.sha256(name.encode()).hexdigest()[:8]
    return clean


def exr_paths(result: StudyResult, directory: str | os.PathLike[str]) -> dict[str, Path]:
    """Every EXR file :func:`write_exrs` writes for ``result``, by a readable key."""
    root = Path(directory) / EXR_DIR
    seed = result.config.seeds[0]
    paths: dict[str, Path] = {}
    for scene in result.scenes:
        folder = root / safe_name(scene)
        paths[f"{scene}/reference"] = folder / "reference.exr"
        for (s, label, spp) in result.renders:
            if s == scene:
                stem = f"{safe_name(label)}_{spp}spp"
                paths[f"{scene}/{label}/{spp}/mean"] = folder / f"{stem}_mean.exr"
                paths[f"{scene}/{label}/{spp}/first"] = folder / f"{stem}_seed{seed}.exr"
    return paths


def write_exrs(result: StudyResult, directory: str | os.PathLike[str]) -> Links:
    """Write the reference and every cell's images; returns the links (relative
    URLs) by cell key ``(scene, sampler, spp)`` -> ``{"mean", "first"}`` and by
    scene -> ``{"reference"}``."""
    from ...io import write_exr

    directory = Path(directory)
    paths = exr_paths(result, directory)
    seed = result.config.seeds[0]

    def link(path: Path) -> str:
        return quote(path.relative_to(directory).as_posix())

    links: Links = {}
    for scene in result.scenes:
        path = paths[f"{scene}/reference"]
        path.parent.mkdir(parents=True, exist_ok=True)
        info = result.references[scene]
        write_exr(path, {"rgb": np.asarray(result.reference_images[scene], np.float32)},
                  {"scene": scene, "spp": int(info.spp), "sampler": info.sampler})
        links[scene] = {"reference": link(path)}
    for (scene, label, spp), renders in result.renders.items():
        if f"{scene}/{label}/{spp}/mean" not in paths:
            continue
        meta: dict[str, str | int | float] = {"scene": scene, "sampler": label, "spp": spp,
                "spp_effective": int(result.cell(scene, label, spp)["spp"])}
        mean = paths[f"{scene}/{label}/{spp}/mean"]
        first = paths[f"{scene}/{label}/{spp}/first"]
        write_exr(mean, {"rgb": renders.mean, "variance": renders.variance},
                  {**meta, "seeds": len(result.config.seeds)})
        write_exr(first, {"rgb": renders.first}, {**meta, "seed": seed})
        links[(scene, label, spp)] = {"mean": link(mean), "first": link(first)}
    return links


__all__ = ["EXR_DIR", "Links", "exr_paths", "safe_name", "write_exrs"]
