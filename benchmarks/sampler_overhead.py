"""What do mcrt's Python/Dr.Jit samplers cost inside Mitsuba, against Mitsuba's C++ ones?

Renders the Cornell box (256x256, path tracer, 64 spp) with each mcrt plugin
and with its Mitsuba equivalent, through ``mi.render`` (so Mitsuba drives the
sampler exactly as in any user scene). Runs are interleaved (ours, theirs,
ours, ...) after a warm-up that compiles and caches every kernel, each timed
with ``dr.sync_thread()`` around it; the script prints per-pair medians and the
median of the per-round time ratios (ours / Mitsuba's).

    python benchmarks/sampler_overhead.py [--rounds 9] [--size 256] [--spp 64]
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
)


def cornell(sampler: dict, size: int, spp: int) -> mi.Scene:
    scene = mi.cornell_box()
    scene["sensor"]["film"]["width"] = size
    scene["sensor"]["film"]["height"] = size
    scene["sensor"]["sampler"] = {**sampler, "sample_count": spp}
    scene["integrator"] = {"type": "path", "max_depth": 8}
    return mi.load_dict(scene)


def timed_render(scene: mi.Scene, spp: int, seed: int) -> float:
    dr.sync_thread()
    start = time.perf_counter()
    image = mi.render(scene, spp=spp, seed=seed)
    dr.eval(image)
    dr.sync_thread()
    return time.perf_counter() - start


def label(sampler: dict) -> str:
    extra = "".join(f" {k}={v}" for k, v in sampler.items() if k != "type")
    return sampler["type"] + extra


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=64)
    args = parser.parse_args()

    print(f"Cornell box {args.size}x{args.size}, path (max_depth 8), {args.spp} spp, "
          f"{args.rounds} interleaved rounds after warm-up, Dr.Jit threads: "
          f"{dr.thread_count()}")
    print(f"{'ours':24s} {'mitsuba':32s} {'ours [s]':>9s} {'theirs [s]':>10s} {'ratio':>7s}")
    for ours, theirs in PAIRS:
        scenes = (cornell(ours, args.size, args.spp), cornell(theirs, args.size, args.spp))
        for scene in scenes:  # warm-up: compile and cache kernels
            timed_render(scene, args.spp, seed=0)
        times: tuple[list[float], list[float]] = ([], [])
        for r in range(args.rounds):
            order = (0, 1) if r % 2 == 0 else (1, 0)  # alternate who goes first
            for i in order:
                times[i].append(timed_render(scenes[i], args.spp, seed=r + 1))
        ratios = [a / b for a, b in zip(*times)]
        print(f"{label(ours):24s} {label(theirs):32s} {statistics.median(times[0]):9.3f} "
              f"{statistics.median(times[1]):10.3f} {statistics.median(ratios):7.3f}")


if __name__ == "__main__":
    main()
