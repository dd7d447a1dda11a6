"""What do mcrt's Python/Dr.Jit samplers cost inside Mitsuba, against Mitsuba's C++ ones?

Renders the Cornell box (256x256, path tracer, 64 spp) with each mcrt plugin
and with its Mitsuba equivalent, through ``mi.render`` (so Mitsuba drives the
sampler exactly as in any user scene). Runs are interleaved (ours, theirs,
ours, ...) after a warm-up that compiles and caches every kernel, each timed
with ``dr.sync_thread()`` around it; the script prints per-pair medians, the
median of the per-round wall-time ratios (ours / Mitsuba's) with their
interquartile range, and the median of the per-round CPU-time ratios (process
CPU time of all threads: less disturbed by other jobs on a shared machine).

    python benchmarks/sampler_overhead.py [--rounds 15] [--size 256] [--spp 64]
"""

from __future__ import annotations

import argparse
import statistics
import time

import drjit as dr
import mitsuba as mi

import mcrt  # noqa: F401  (registers the plugins)

#: (ours, Mitsuba's equivalent)
PAIRS = (
    ({"type": "jittered"}, {"type": "stratified", "jitter": True}),
    ({"type": "uniform_grid"}, {"type": "stratified", "jitter": False}),
    ({"type": "poisson_disk"}, {"type": "independent"}),
    ({"type": "sobol"}, {"type": "independent"}),
    ({"type": "zsobol"}, {"type": "independent"}),
)


def cornell(sampler: dict, size: int, spp: int) -> mi.Scene:
    scene = mi.cornell_box()
    scene["sensor"]["film"]["width"] = size
    scene["sensor"]["film"]["height"] = size
    scene["sensor"]["sampler"] = {**sampler, "sample_count": spp}
    if sampler["type"] == "zsobol":  # plain Mitsuba: the film width is the scene's to give
        scene["sensor"]["sampler"]["width"] = size
    scene["integrator"] = {"type": "path", "max_depth": 8}
    return mi.load_dict(scene)


def timed_render(scene: mi.Scene, spp: int, seed: int) -> tuple[float, float]:
    """(wall seconds, process CPU seconds over all threads) of one render."""
    dr.sync_thread()
    start, cpu = time.perf_counter(), time.process_time()
    image = mi.render(scene, spp=spp, seed=seed)
    dr.eval(image)
    dr.sync_thread()
    return time.perf_counter() - start, time.process_time() - cpu


def label(sampler: dict) -> str:
    extra = "".join(f" {k}={v}" for k, v in sampler.items() if k != "type")
    return sampler["type"] + extra


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=64)
    args = parser.parse_args()

    print(f"Cornell box {args.size}x{args.size}, path (max_depth 8), {args.spp} spp, "
          f"{args.rounds} interleaved rounds after warm-up, Dr.Jit threads: "
          f"{dr.thread_count()}")
    print(f"{'ours':24s} {'mitsuba':32s} {'ours [s]':>9s} {'theirs [s]':>10s} {'ratio':>7s} "
          f"{'IQR':>13s} {'CPU ratio':>9s}")
    for ours, theirs in PAIRS:
        scenes = (cornell(ours, args.size, args.spp), cornell(theirs, args.size, args.spp))
        for scene in scenes:  # warm-up: compile and cache kernels
            timed_render(scene, args.spp, seed=0)
        times: tuple[list[tuple[float, float]], ...] = ([], [])
        for r in range(args.rounds):
            order = (0, 1) if r % 2 == 0 else (1, 0)  # alternate who goes first
            for i in order:
                times[i].append(timed_render(scenes[i], args.spp, seed=r + 1))
        wall = [a[0] / b[0] for a, b in zip(*times)]
        cpu = [a[1] / b[1] for a, b in zip(*times)]
        q1, _, q3 = statistics.quantiles(wall, n=4)
        print(f"{label(ours):24s} {label(theirs):32s} "
              f"{statistics.median(t[0] for t in times[0]):9.3f} "
              f"{statistics.median(t[0] for t in times[1]):10.3f} {statistics.median(wall):7.3f} "
              f"{q1:6.3f}-{q3:6.3f} {statistics.median(cpu):9.3f}")

if __name__ == "__main__":
    main()
