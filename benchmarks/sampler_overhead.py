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

Users' point sets (the ``pointset`` plugin from files of 256 and 4096 sets,
and a generator registered with ``mcrt.register_sampler``) are timed against
``independent`` too; ``--only pointset`` times just those.

    python benchmarks/sampler_overhead.py [--rounds 15] [--size 256] [--spp 64] [--only NAME,...]
"""

from __future__ import annotations

import argparse
import atexit
import itertools
import shutil
import statistics
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import mcrt  # (registers the plugins)
from mcrt.analysis.convergence import paired_time_ratio
from mcrt.core.timing import quartiles, run_interleaved
from mcrt.samplers.point_sources import jittered_sets

#: (ours, Mitsuba's equivalent)
PAIRS = (
    ({"type": "jittered"}, {"type": "stratified", "jitter": True}),
    ({"type": "uniform_grid"}, {"type": "stratified", "jitter": False}),
    ({"type": "poisson_disk"}, {"type": "independent"}),
    ({"type": "sobol"}, {"type": "independent"}),
    ({"type": "zsobol"}, {"type": "independent"}),
)


def user_pairs(spp: int, folder: Path) -> list[tuple[dict, dict]]:
    """Users' point sets against ``independent``: files of 256 and 4096 jittered
    sets of ``spp`` points, and a generator of them (tabulated before timing)."""
    pairs = []
    for sets in (256, 4096):
        path = folder / f"jittered-{sets}.npy"
        np.save(path, jittered_sets(sets, spp, np.random.default_rng(sets)).astype(np.float32))
        pairs.append(({"type": "pointset", "filename": str(path)}, {"type": "independent"}))
    mcrt.register_sampler("bench_generator", points=jittered_sets, sets=4096)
    pairs.append(({"type": "bench_generator"}, {"type": "independent"}))
    return pairs


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
    extra = "".join(f" {k}={Path(v).name if k == 'filename' else v}"
                    for k, v in sampler.items() if k != "type")
    return sampler["type"] + extra


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--only", default="", help="comma-separated sampler types to time")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="mcrt-overhead-"))  # the point-set files
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    pairs = [*PAIRS, *user_pairs(args.spp, folder)]
    if args.only:
        pairs = [p for p in pairs if p[0]["type"] in args.only.split(",")]

    print(f"Cornell box {args.size}x{args.size}, path (max_depth 8), {args.spp} spp, "
          f"{args.rounds} interleaved rounds after warm-up, Dr.Jit threads: "
          f"{dr.thread_count()}")
    print(f"{'ours':32s} {'mitsuba':24s} {'ours [s]':>9s} {'theirs [s]':>10s} {'ratio':>7s} "
          f"{'IQR':>13s} {'95% interval':>13s} {'CPU ratio':>9s}")
    for ours, theirs in pairs:
        scenes = (cornell(ours, args.size, args.spp), cornell(theirs, args.size, args.spp))
        seeds = itertools.count(1)
        samples = run_interleaved([renderer(scene, args.spp, seeds) for scene in scenes],
                                  args.rounds, warmup=1, sync=dr.sync_thread)
        walls = [[s.wall for s in case] for case in samples]
        wall = [a / b for a, b in zip(*walls, strict=True)]
        cpu = [a.cpu / b.cpu for a, b in zip(*samples, strict=True)]
        q1, q3 = quartiles(wall)
        low, high = paired_time_ratio(*walls).interval()
        print(f"{label(ours):32s} {label(theirs):24s} {statistics.median(walls[0]):9.3f} "
              f"{statistics.median(walls[1]):10.3f} {statistics.median(wall):7.3f} "
              f"{q1:6.3f}-{q3:6.3f} {low:6.3f}-{high:6.3f} {statistics.median(cpu):9.3f}")


if __name__ == "__main__":
    main()
