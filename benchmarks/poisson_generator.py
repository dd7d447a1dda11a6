"""How fast is mcrt's Poisson-disk table generator, against scipy.stats.qmc.PoissonDisk?

For each N, ours generates a batch of T = n_tables(N) toroidal sets with
``poisson_tables.generate(N, T, seed)`` (the generator itself: no memory or disk
cache is involved, and the time includes the exact verification of every set);
scipy generates one set per call, ``PoissonDisk(d=2, radius=0.75 * d_hex(N),
seed=s).random(N)`` (construction included), which is scipy's Bridson sampler
at the spacing we guarantee (our sets are made at 0.76 d_hex). Both are
normalised to sets per second and points per second. Repetitions are
interleaved (ours, scipy, ours, ...) after one warm-up call of each, with fresh
seeds every time, and the table shows medians. rho = d_min / d_hex: ours is the
minimum over all generated sets of the toroidal minimum distance; scipy's sets
live on the square, not on the torus, so both its plain (Euclidean) rho and its
toroidal rho are shown. scipy may return fewer than N points: the table lists
how many it returned (min-max).

Finally times ``generate(MAX_POINTS, T)`` once (first-time table generation
for the largest supported N).

    python benchmarks/poisson_generator.py [--reps 5] [--sizes 16 64 256 1024]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import scipy
from scipy.spatial import cKDTree
from scipy.stats import qmc

from mcrt.core.timing import round_orders
from mcrt.samplers import poisson_tables as pt


def euclidean_min_distance(p: np.ndarray) -> float:
    dist, _ = cKDTree(p).query(p, k=2)
    return float(dist[:, 1].min())


def time_ours(n: int, t: int, seed: int) -> tuple[float, np.ndarray]:
    start = time.perf_counter()
    sets = pt.generate(n, t, seed)
    return time.perf_counter() - start, sets


def time_scipy(n: int, n_sets: int, seed: int) -> tuple[float, list[np.ndarray]]:
    radius = 0.75 * pt.d_hex(n)
    out = []
    start = time.perf_counter()
    for s in range(n_sets):
        out.append(qmc.PoissonDisk(d=2, radius=radius, seed=seed * 1000 + s).random(n))
    return time.perf_counter() - start, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5, help="timed repetitions per method")
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 256, 1024])
    parser.add_argument("--scipy-seconds", type=float, default=0.6,
                        help="approximate scipy time per repetition (sets per rep follow)")
    parser.add_argument("--skip-largest", action="store_true",
                        help="do not time generate(MAX_POINTS, T)")
    args = parser.parse_args()

    print(f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{os.cpu_count()} CPUs, {platform.machine()}")
    print(f"ours: poisson_tables v{pt.VERSION} (rho target {pt.RHO_TARGET}); "
          f"scipy: PoissonDisk radius 0.75 d_hex; {args.reps} interleaved reps, medians\n")

    rows = []
    for n in args.sizes:
        t = pt.n_tables(n)
        # Warm-up (imports, allocator, caches) and a rough scipy per-set time.
        time_ours(n, t, seed=10_000)
        warm, _ = time_scipy(n, 1, seed=10_000)
        scipy_sets = max(1, min(64, round(args.scipy_seconds / max(warm, 1e-4))))

        ours_rate, scipy_rate = [], []
        ours_rho, scipy_rho, scipy_rho_torus, scipy_counts = [], [], [], []
        for rep, order in enumerate(round_orders(2, args.reps)):  # the protocol's rounds
            for which in order:
                if which == 0:
                    dt, sets = time_ours(n, t, seed=rep)
                    ours_rate.append(t / dt)
                    ours_rho.append(float(pt.toroidal_min_distances(sets).min()) / pt.d_hex(n))
                    continue
                dt, sets = time_scipy(n, scipy_sets, seed=rep)
                scipy_rate.append(scipy_sets / dt)
                scipy_counts += [len(s) for s in sets]
                scipy_rho += [euclidean_min_distance(s) / pt.d_hex(n) for s in sets]
                scipy_rho_torus += [pt.toroidal_min_distance(s) / pt.d_hex(n) for s in sets]
        ours = statistics.median(ours_rate)
        theirs = statistics.median(scipy_rate)
        mean_count = statistics.fmean(scipy_counts)
        rows.append((n, t, ours, ours * n, theirs, theirs * mean_count, ours / theirs,
                     ours * n / (theirs * mean_count), min(ours_rho), min(scipy_rho),
                     min(scipy_rho_torus), f"{min(scipy_counts)}-{max(scipy_counts)}",
                     scipy_sets))

    head = ("| N | T | ours sets/s | ours pts/s | scipy sets/s | scipy pts/s | ratio (sets/s) "
            "| ratio (pts/s) | ours rho (min, torus) | scipy rho (min, plane) "
            "| scipy rho (min, torus) | scipy points returned |")
    print(head)
    print("|" + "---|" * head.count(" | ") + "---|")
    for (n, t, o, op, s, sp, r, rp, orho, srho, storus, counts, _) in rows:
        print(f"| {n} | {t} | {o:,.0f} | {op:,.0f} | {s:,.1f} | {sp:,.0f} | {r:,.0f}x | {rp:,.0f}x "
              f"| {orho:.4f} | {srho:.4f} | {storus:.4f} | {counts} |")
    print("\nscipy sets per repetition: " + ", ".join(f"N={r[0]}: {r[-1]}" for r in rows))

    if not args.skip_largest:
        n = pt.MAX_POINTS
        t = pt.n_tables(n)
        dt, sets = time_ours(n, t, seed=0)
        rho = pt.toroidal_min_distances(sets).min() / pt.d_hex(n)
        print(f"\nlargest N: generate({n}, {t}) once: {dt:.2f} s "
              f"({t * n / dt:,.0f} points/s), rho min {rho:.5f}")


if __name__ == "__main__":
    main()
