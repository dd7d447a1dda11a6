"""Is `zsobol`'s error blue over the screen? Two measures, against `sobol` and `independent`.

1. **A smooth per-pixel integrand** (the same Gaussian bump in every pixel of a 64x64
   grid, 4 points per pixel from ``point_sets`` of dimensions 0, 1 and 3): the low-band
   ratio (mcrt's aliasing measure, power at |f| < 0.25 against white noise) of the
   per-pixel error, and the variance of a 2x2 quad's summed error against four
   independent pixels' (1 for white noise, ~0 for perfectly anti-correlated pixels).
2. **The Cornell box** (``direct``, 64x64, box filter): the low-band ratio of the
   luminance error against a 4096-spp ``jittered`` reference, mean over seeds, at 4 and
   16 spp.

    python benchmarks/zsobol_blue_noise.py [--seeds 8]     # ~1 min
"""

from __future__ import annotations

import argparse

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.analysis.aliasing import low_band_ratio  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.samplers.points import point_sets  # noqa: E402

WIDTH = 64
SAMPLERS = (("zsobol", {"width": WIDTH}), ("sobol", {}), ("independent", {}))
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def bump(points: np.ndarray) -> np.ndarray:
    return np.exp(-((points[..., 0] - 0.3) ** 2 + (points[..., 1] - 0.6) ** 2) / (2 * 0.2 ** 2))


def smooth_integrand() -> None:
    exact = bump(np.random.default_rng(0).random((4_000_000, 2))).mean()
    print("| sampler | dimension | low-band ratio | 2x2 quad variance / 4 pixels' |")
    print("|---|---:|---:|---:|")
    for name, params in SAMPLERS:
        for dimension in (0, 1, 3):
            points = point_sets(name, range(WIDTH * WIDTH), 4, dimension=dimension, **params)
            error = (bump(points.astype(np.float64)).mean(axis=1) - exact).reshape(WIDTH, WIDTH)
            quad = error.reshape(WIDTH // 2, 2, WIDTH // 2, 2).sum(axis=(1, 3))
            print(f"| {name} | {dimension} | {low_band_ratio(error):.3f} | "
                  f"{quad.var() / (4 * error.var()):.3f} |", flush=True)


def cornell(seeds: int) -> None:
    desc = mi.cornell_box()
    desc["sensor"]["film"].update(width=WIDTH, height=WIDTH, rfilter={"type": "box"})
    desc["integrator"] = {"type": "direct"}
    scene = mi.load_dict(desc)
    reference = render_film(scene, make_sampler("jittered", 4096), seed=12345).rgb @ LUMINANCE
    print("\n| spp | sampler | low-band ratio (mean +- se over seeds) | MSE |")
    print("|---:|---|---:|---:|")
    for spp in (4, 16):
        for name, params in SAMPLERS:
            ratios, errors = [], []
            for seed in range(seeds):
                image = render_film(scene, make_sampler(name, spp, **params), seed=seed).rgb
                error = image @ LUMINANCE - reference
                ratios.append(low_band_ratio(error))
                errors.append(float(np.mean(error ** 2)))
            print(f"| {spp} | {name} | {np.mean(ratios):.3f} +- "
                  f"{np.std(ratios) / np.sqrt(seeds):.3f} | {np.mean(errors):.3e} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args()
    smooth_integrand()
    cornell(args.seeds)


if __name__ == "__main__":
    main()
