"""What the relaxation of the Poisson-disk tables does to their spectrum and spacing.

For each N: ``n_tables(N)`` sets from the dart-throwing engine alone, the same sets
relaxed (``mcrt.samplers._poisson_relax.relax``: particle-mesh + Gaussian-blue-noise
steps with a hard core), and the relaxed sets with the particle-mesh step switched
off. Per variant: ``mcrt pattern``'s low-frequency power (mean P(k) for f < 0.5), the
mean averaged periodogram at the lowest frequencies 0 < |k| < 8 (where a smooth
integrand's energy is), the radial peak, and rho = d_min / d_hex (min and mean).

    python benchmarks/poisson_relaxation.py [--sizes 16 64 256 1024 4096 16384]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from mcrt.analysis.patterns import analyse_points, power_spectrum
from mcrt.samplers import _poisson_relax as relaxation
from mcrt.samplers import poisson_tables as pt
from mcrt.samplers._poisson_darts import generate_batch


def dart_sets(n: int, count: int, seed: int) -> np.ndarray:
    """``count`` complete dart-throwing sets (no relaxation)."""
    rng = np.random.default_rng([seed, n])
    out: list[np.ndarray] = []
    while sum(len(o) for o in out) < count:
        pts, ok = generate_batch(n, count + 4, pt.RHO_TARGET * pt.d_hex(n), rng)
        out.append(pts[ok])
    return np.concatenate(out)[:count]


def measures(points: np.ndarray) -> str:
    n = points.shape[1]
    kmax = max(8, min(int(2.5 * math.sqrt(n)), 160))
    summary = analyse_points(points, kmax=kmax, discrepancy_sets=1).summary()
    spectrum = power_spectrum(points, 8)
    k = np.hypot(*np.meshgrid(np.arange(-8, 9), np.arange(-8, 9)))
    lowest = spectrum[(k > 0) & (k < 8)].mean()
    return (f"{summary['low_frequency_power']:.4f} | {lowest:.5f} | {summary['peak_power']:.2f} at "
            f"{summary['peak_frequency']:.2f} | {summary['rho_min']:.3f} / "
            f"{summary['rho_mean']:.3f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 256, 1024, 4096, 16384])
    args = p.parse_args()
    print("| N | sets | variant | low-freq. power (f < 0.5) | mean P(k), 0 < |k| < 8 "
          "| radial peak | rho min / mean |")
    print("|---:|---:|---|---:|---:|---|---|")
    for n in args.sizes:
        sets = dart_sets(n, pt.n_tables(n), seed=1)
        variants = [("dart throwing", sets), ("relaxed (shipped)", relaxation.relax(sets)),
                    ("relaxed, no particle-mesh step", relaxation.relax(sets, long_range=False))]
        for label, points in variants:
            print(f"| {n} | {len(sets)} | {label} | {measures(points)} |", flush=True)


if __name__ == "__main__":
    main()
