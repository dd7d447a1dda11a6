"""Print the measured figures of the "Hard cases" table of docs/hard-cases.md.

For each case of ``tests/core/test_hard_cases.py`` (same scenes, settings, seeds
and references as the tests): the non-finite samples per sampler, the largest
tile and whole-image |z| against the reference, and the smallest bias the
agreement test can see (5 standard errors, relative to the mean) per tile
(median) and for the whole image.

    python scripts/hard_cases_report.py        # ~1 min on 2 cores
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_hard_cases as hard  # noqa: E402

from mcrt.core.sampling import quiet_sampler_warnings  # noqa: E402
from mcrt.samplers import ALL_SAMPLERS  # noqa: E402


def detectable(ref, spp: int, tile: tuple[int, int]) -> tuple[float, float]:
    """(median over tiles, whole image) of Z_MAX standard errors / mean, channel 0."""
    var, mean = ref.variance[..., 0], ref.mean[..., 0]
    h, w = var.shape
    tiles = [hard.Z_MAX * np.sqrt((var[y:y + tile[0], x:x + tile[1]] / spp).sum())
             / var[y:y + tile[0], x:x + tile[1]].size / mean[y:y + tile[0], x:x + tile[1]].mean()
             for y in range(0, h, tile[0]) for x in range(0, w, tile[1])]
    whole = hard.Z_MAX * np.sqrt((var / spp).sum()) / var.size / mean.mean()
    return float(np.median(tiles)), float(whole)


def main() -> None:
    for case, (name, params, spp, ref_spp, tile) in hard.CASES.items():
        ref = hard.reference(name, ref_spp, **params).stats
        tile_bias, image_bias = detectable(ref, spp, tile)
        print(f"{case}: {spp} spp, reference {ref_spp} spp "
              f"({int(ref.nonfinite.sum())} of {int(ref.count.sum() + ref.nonfinite.sum())} "
              f"samples non-finite); 5 SE = {100 * tile_bias:.1f}% of a median tile, "
              f"{100 * image_bias:.1f}% of the image")
        for sampler in ALL_SAMPLERS:
            with quiet_sampler_warnings():
                stats = hard.render(name, sampler, spp, seed=7, **params).stats
            z_tile = np.abs(hard.agreement_z(stats, ref, tile)).max()
            z_image = np.abs(hard.agreement_z(stats, ref, stats.count.shape)).max()
            usable = (stats.count > 0) & (ref.count > 0)
            rel = stats.mean[usable].mean(0) / ref.mean[usable].mean(0) - 1
            print(f"  {sampler:13s} non-finite {int(stats.nonfinite.sum()):5d}  "
                  f"max |z| tile {z_tile:4.1f} image {z_image:4.1f}  "
                  f"image mean vs reference {100 * rel[np.argmax(np.abs(rel))]:+.2f}%")


if __name__ == "__main__":
    main()
