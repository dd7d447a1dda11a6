"""A study's images as EXR files next to its report, for tev or any other viewer.

``exr/<scene>/reference.exr`` (with its ``stderr``, ``variance`` and ``count``
layers, and ``effective_count`` for a filtered reference, when the reference is
in mcrt's reference cache, as a study leaves it) and, per measured cell,
``exr/<scene>/<sampler>_<spp>spp_mean.exr`` (the mean over seeds, with the
per-pixel variance across seeds as the ``variance.Y`` layer) and
``exr/<scene>/<sampler>_<spp>spp_seed<first seed>.exr`` (the first seed's render
as rendered). Float32, written atomically by :func:`mcrt.io.write_exr`, each
header saying how the file was made (scene file and digest, parameters, filter,
plan, sampler, spp, seeds, variant, versions: :mod:`.headers`).
"""

from __future__ import annotations

import hashlib
import os
import re
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

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
    from ...core.provenance import COMMAND
    from ...io import write_exr
    from ...io.parallel import write_all
    from .headers import cell_header, describe_scene, reference_file, study_header

    directory = Path(directory)
    paths = exr_paths(result, directory)
    seed = result.config.seeds[0]
    common = study_header(result)

    def link(path: Path) -> str:
        return quote(path.relative_to(directory).as_posix())

    links: Links = {}
    records = {spec.name: describe_scene(result, spec) for spec in result.config.scenes
               if spec.name in result.scenes}
    for scene, record in records.items():
        path = paths[f"{scene}/reference"]
        path.parent.mkdir(parents=True, exist_ok=True)
        layers, header = reference_file(result, record)
        write_exr(path, layers, {**common, **header, "mcrt_kind": "study_reference"})
        links[scene] = {"reference": link(path)}
    for (scene, label, spp), renders in result.renders.items():
        if f"{scene}/{label}/{spp}/mean" not in paths:
            continue
        meta = {**common, **cell_header(result, records[scene], label, spp)}
        mean = paths[f"{scene}/{label}/{spp}/mean"]
        first = paths[f"{scene}/{label}/{spp}/first"]
        write_all(partial(write_exr, mean, {"rgb": renders.mean, "variance": renders.variance},
                          {**meta, "mcrt_kind": "study_mean"}),
                  partial(write_exr, first, {"rgb": renders.first},
                          {**meta, "mcrt_kind": "study_seed", "seed": seed,
                           COMMAND: f"{meta[COMMAND]} --seed {seed}"}))
        links[(scene, label, spp)] = {"mean": link(mean), "first": link(first)}
    return links


__all__ = ["EXR_DIR", "Links", "exr_paths", "safe_name", "write_exrs"]
