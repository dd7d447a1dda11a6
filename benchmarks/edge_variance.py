"""Why Mitsuba's `multijitter` beats `sobol` on the Cornell box at 256 spp: edges.

Two measurements, side by side in one run:

1. **The Cornell box** (128x128, as in the study), per-pixel variance across seeds
   (no reference needed: the samplers are unbiased, so MSE = variance), at
   ``max_depth`` 1 (only the light seen directly: the film position is the only
   dimension, and the light's rim the only error), 2 (direct light) and 8 (the study's
   path tracer). Printed: mean over pixels and channels, and the ratio to
   ``multijitter``'s.
2. **Straight edges in one pixel**: UTK's random Heaviside integrands (an edge of
   random direction through a uniform point, exact areas; ``mcrt.analysis.peers``) and,
   for contrast, its random Gaussians, integrated by ``P`` independent point sets
   (pixels) of each sampler's film dimension, and by a *reference* Owen scrambling of
   the same Sobol' (0,2)-sequence computed here in numpy (every node of the scrambling
   tree flips with its own independent coin, by a 64-bit hash: nested uniform
   scrambling with no hash shortcuts). If ``sobol`` matched that reference but not
   ``multijitter``, the gap is the Owen-scrambled net's, not mcrt's implementation.

    python benchmarks/edge_variance.py [--seeds 12] [--sets 1024]     # ~2 min
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.analysis.peers import gaussian_family, heaviside_family  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.samplers.points import point_sets  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLERS = ("sobol", "zsobol", "multijitter", "ldsampler")
M64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def cornell(seeds: int, spp: int) -> None:
    print(f"Cornell box 128x128, {spp} spp: per-pixel variance across {seeds} seeds "
          f"(mean over pixels and channels; ratio to multijitter)\n")
    print("| max_depth | " + " | ".join(f"`{s}`" for s in SAMPLERS) + " |")
    print("|---:|" + "---:|" * len(SAMPLERS))
    for depth in (1, 2, 8):
        scene = mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res=128,
                             max_depth=depth)
        var = {}
        for name in SAMPLERS:
            params = {"width": 128} if name == "zsobol" else {}
            images = np.stack([render_film(scene, make_sampler(name, spp, **params),
                                           seed=seed).rgb for seed in range(seeds)])
            var[name] = float(images.astype(np.float64).var(axis=0, ddof=1).mean())
        print(f"| {depth} | " + " | ".join(
            f"{var[s]:.3e} ({var[s] / var['multijitter']:.2f})" for s in SAMPLERS) + " |",
            flush=True)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    x = (x + np.uint64(0x9E3779B97F4A7C15)) & M64
    x = ((x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & M64
    x = ((x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & M64
    return x ^ (x >> np.uint64(31))


def _reverse32(v: np.ndarray) -> np.ndarray:
    out = np.zeros_like(v)
    for bit in range(32):
        out |= ((v >> np.uint64(bit)) & np.uint64(1)) << np.uint64(31 - bit)
    return out


def _owen(value: np.ndarray, seed: np.ndarray, digits: int = 24) -> np.ndarray:
    """Nested uniform scrambling of 32-bit fractions: digit ``k`` flips by a coin of
    (seed, k, digits 1..k-1), independent for every node of the tree."""
    out = np.zeros_like(value)
    for k in range(digits):
        shift = np.uint64(31 - k)
        prefix = value >> (shift + np.uint64(1)) if k else np.zeros_like(value)
        coin = _splitmix64(prefix ^ (np.uint64(k) << np.uint64(40)) ^ seed) >> np.uint64(63)
        out |= (((value >> shift) & np.uint64(1)) ^ coin) << shift
    return out


def reference_owen_sobol(n: int, sets: int, seed: int = 1) -> np.ndarray:
    """``sets`` independently Owen-scrambled copies of the first ``n`` points of the
    Sobol' (0,2)-sequence (dimensions 0 and 1), shape ``(sets, n, 2)``."""
    index = np.arange(n, dtype=np.uint64)
    pascal = index.copy()  # Sobol' dimension 1: the Pascal matrix mod 2 (see samplers/_sobol)
    for step, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F),
                       (8, 0x00FF00FF), (16, 0x0000FFFF)):
        pascal ^= (pascal >> np.uint64(step)) & np.uint64(mask)
    keys = np.random.default_rng(seed).integers(0, 2**63, size=(sets, 2, 1), dtype=np.int64)
    keys = keys.astype(np.uint64)
    coords = [_owen(np.broadcast_to(_reverse32(v), (sets, n)).copy(), keys[:, d])
              for d, v in enumerate((index, pascal))]
    return np.stack([(c >> np.uint64(8)).astype(np.float64) / 2**24 for c in coords], -1)


def edges(sets: int, counts: tuple[int, ...]) -> None:
    families = {"Heaviside": heaviside_family(1024), "Gaussian": gaussian_family(256)}
    names = (*SAMPLERS, "reference Owen")
    print(f"\nOne pixel's film dimension, {sets} point sets x UTK's random integrands "
          f"(1024 Heaviside edges, 256 Gaussians): MSE (ratio to multijitter)\n")
    print("| integrands | N | " + " | ".join(f"`{s}`" if s in SAMPLERS else s
                                           for s in names) + " |")
    print("|---|---:|" + "---:|" * len(names))
    for label, family in families.items():
        for n in counts:
            mse = {}
            for name in names:
                if name == "reference Owen":
                    points = reference_owen_sobol(n, sets)
                else:
                    params = {"width": 64} if name == "zsobol" else {}
                    points = point_sets(name, range(sets), n, **params)
                mse[name] = float(np.mean((family.estimates(points) - family.exact) ** 2))
            print(f"| {label} | {n} | " + " | ".join(
                f"{mse[s]:.3e} ({mse[s] / mse['multijitter']:.2f})" for s in names) + " |",
                flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--sets", type=int, default=1024)
    args = parser.parse_args()
    cornell(args.seeds, args.spp)
    edges(args.sets, (64, 256))


if __name__ == "__main__":
    main()
