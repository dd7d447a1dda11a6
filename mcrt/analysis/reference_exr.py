"""What a reference's EXR file holds (``mcrt reference``, a study's report): its
layers (mean, variance, standard error, sample counts) and its header (how it
was made: :mod:`mcrt.core.provenance`, its sample totals, the film's filter)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.filtered import FilteredStats
from ..render.loaded import planned_scene

if TYPE_CHECKING:
    from .reference import Reference


def reference_layers(ref: Reference) -> dict[str, np.ndarray]:
    """EXR layers of a reference: ``rgb`` (mean), ``variance`` (per-sample),
    ``stderr`` (of the mean), ``count`` (samples per pixel; float32 in the file,
    exact up to 2^24 per pixel) and ``nonfinite`` if any sample was NaN/Inf. The
    arrays are the float64 sums' own: :func:`~mcrt.io.write_exr` stores them as
    float32 and says where a finite value overflows it (a variance past 3.4e38).
    The variance is NaN (unknown) where the standard error is: a pixel with
    fewer than two finite samples (every pixel of a 1-spp reference) has no
    spread to estimate, and the 0 its moments hold read as an exact pixel."""
    stderr = ref.standard_error
    layers = {"rgb": ref.mean, "variance": np.where(np.isnan(stderr), np.nan, ref.variance),
              "stderr": stderr, "count": ref.stats.count}
    if isinstance(ref.stats, FilteredStats):
        layers["effective_count"] = ref.stats.effective_count
    if ref.stats.nonfinite.any():
        layers["nonfinite"] = ref.stats.nonfinite
    return layers


def reference_metadata(ref: Reference, scene_path: str | Path,
                       params: dict[str, str] | None) -> dict[str, str | int | float]:
    """EXR metadata of a reference: how it was made (:mod:`mcrt.core.provenance`:
    the command that renders it again, scene digest, versions) and its sample
    totals, exact Python ints (``write_exr`` stores those beyond int32 as decimal
    strings)."""
    from ..core.provenance import (
        absolute,
        command_text,
        define_words,
        param_word,
        plugin_files,
        scene_facts,
        software,
    )

    plan = ref.plan
    params = dict(params or {})
    words = [absolute(scene_path), "--spp", plan.requested_spp if plan else ref.spp,
             "--sampler", ref.sampler, "--seed", ref.seed,
             *(["--spp-per-pass", plan.pass_spp] if plan else []),
             *(w for k, v in sorted(ref.sampler_params.items())
               for w in ("-P", param_word(f"{k}={_text(v)}"))),
             *define_words(scene_path, params)]
    return {
        **software(), "mcrt_kind": "reference",
        "command": command_text("reference", *words, plugins=plugin_files(ref.sampler)),
        "scene": str(scene_path), **scene_facts(scene_path, params),
        "params": " ".join(f"{k}={v}" for k, v in params.items()),
        **_filter_of(scene_path, params),
        "sampler": ref.sampler, "seed": ref.seed, "spp": ref.spp,
        **({"sampler_params": json.dumps(ref.sampler_params, sort_keys=True)}
           if ref.sampler_params else {}),
        "requested_spp": plan.requested_spp if plan else ref.spp,
        "passes": ref.passes, "pass_plan": plan.describe() if plan else "",
        "samples": ref.drawn_samples, "finite_samples": ref.samples,
        "nonfinite_samples": int(ref.stats.nonfinite.sum()),
        "max_pixel_count": int(ref.stats.count.max()),
        "cache_key": ref.key,
    }


def _text(value: Any) -> str:
    """A ``-P`` value as the command line gives it (booleans as true/false)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def _filter_of(scene_path: str | Path, params: dict[str, str]) -> dict[str, str]:
    """``filter``: the film's reconstruction filter the reference was developed
    with (from the scene this process planned; nothing if it cannot be had)."""
    try:
        planned = planned_scene(scene_path, params)
        return {"filter": str(planned.scene.sensors()[0].film().rfilter())}
    except Exception:  # a scene gone since: the header says what it can
        return {}
