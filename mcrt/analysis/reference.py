"""High-spp reference images with exact per-pixel statistics.

A reference is rendered in passes, each with its own seed (independent
patterns), every pass's per-pixel moments Chan-merged in float64 into the total
(:mod:`mcrt.analysis.statistics`), so the estimate, its per-sample variance and
standard error stay exact however many samples (beyond 2^32) are taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..render.passes import render_stats
from ..render.scene import load_scene, make_sampler
from ..samplers._hash import hash_keys_int
from .statistics import PixelStats

#: Default total samples per pixel of a reference.
DEFAULT_REFERENCE_SPP = 4096

#: Default samples per pixel of one reference pass (one independent seed).
DEFAULT_PASS_SPP = 256


@dataclass
class Reference:
    """A reference image: per-pixel estimate and its statistics (float64)."""

    stats: PixelStats
    spp: int
    sampler: str
    seed: int
    passes: int
    seconds: float

    @property
    def mean(self) -> np.ndarray:
        return self.stats.mean

    @property
    def variance(self) -> np.ndarray:
        return self.stats.variance

    @property
    def standard_error(self) -> np.ndarray:
        return self.stats.standard_error

    @property
    def samples(self) -> int:
        return self.stats.samples


def pass_seed(seed: int, index: int) -> int:
    """Seed of reference pass ``index``: hashed, so nearby user seeds never
    share passes."""
    return hash_keys_int(seed, index, 0x5EF)


def get_reference(scene_path: str | Path, params: dict[str, str] | None = None,
                  spp: int = DEFAULT_REFERENCE_SPP, sampler: str = "independent",
                  seed: int = 0, spp_per_pass: int | None = None,
                  progress: bool = False) -> Reference:
    """Render a reference of ``scene_path`` with ``spp`` samples per pixel."""
    scene = load_scene(scene_path, params)
    per_pass = min(spp, spp_per_pass or DEFAULT_PASS_SPP)
    passes = -(-spp // per_pass)
    total = None
    seconds = 0.0
    for index in range(passes):
        count = min(per_pass, spp - index * per_pass)
        result = render_stats(scene, make_sampler(sampler, count), seed=pass_seed(seed, index),
                              progress=progress)
        total = result.stats if total is None else total.merge(result.stats)
        seconds += result.seconds
    return Reference(stats=total, spp=spp, sampler=sampler, seed=seed, passes=passes,
                     seconds=seconds)
