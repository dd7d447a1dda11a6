"""What do mcrt's Python/Dr.Jit samplers cost inside Mitsuba, against Mitsuba's C++ ones?

Renders the Cornell box (256x256, path tracer, 64 spp) with each mcrt plugin
and with its Mitsuba equivalent, through ``mi.render`` (so Mitsuba drives the
sampler exactly as in any user scene). Timed by mcrt's protocol
(:func:`mcrt.core.timing.run_interleaved`: a warm-up that compiles and caches
every kernel, then rounds in a shuffled order, each render between
``dr.sync_thread()`` barriers); the script prints per-pair medians, the median
of the per-round wall-time ratios (ours / Mitsuba's) with their interquartile
range and 95% interval (:func:`mcrt.analysis.convergence.paired_time_ratio`),
and the median of the per-round CPU-time ratios (process CPU time of all
threads: less disturbed by other jobs on a shared machine).

    python benchmarks/sampler_overhead.py [--rounds 15] [--size 256] [--spp 64]
"""

from __future__ import annotations

import argparse
import itertools
import statistics
from collections.abc import Callable, Iterator

import drjit as dr
import mitsuba as mi

import mcrt  # noqa: F401  (registers the plugins)
from mcrt.analysis.convergence import paired_time_ratio
from mcrt.core.timing import run_interleaved

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


def renderer(scene: mi.Scene, spp: int, seeds: Iterator[int]) -> Callable[[], None]:
    """One render of ``scene`` with the next seed (the protocol times the call)."""
    def render() -> None:
        dr.eval(mi.render(scene, spp=spp, seed=next(seeds)))
    return render


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
          f"{'IQR':>13s} {'95% interval':>13s} {'CPU ratio':>9s}")
    for ours, theirs in PAIRS:
        scenes = (cornell(ours, args.size, args.spp), cornell(theirs, args.size, args.spp))
        seeds = itertools.count(1)
        samples = run_interleaved([renderer(scene, args.spp, seeds) for scene in scenes],
                                  args.rounds, warmup=1, sync=dr.sync_thread)
        walls = [[s.wall for s in case] for case in samples]
        wall = [a / b for a, b in zip(*walls)]
        cpu = [a.cpu / b.cpu for a, b in zip(*samples)]
        q1, _, q3 = statistics.quantiles(wall, n=4)
        low, high = paired_time_ratio(*walls).interval()
        print(f"{label(ours):24s} {label(theirs):32s} {statistics.median(walls[0]):9.3f} "
              f"{statistics.median(walls[1]):10.3f} {statistics.median(wall):7.3f} "
              f"{q1:6.3f}-{q3:6.3f} {low:6.3f}-{high:6.3f} {statistics.median(cpu):9.3f}")


if __name__ == "__main__":
    main()
