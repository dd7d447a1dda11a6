"""Reference throughput: ``get_reference`` against one plain ``mi.render`` of the same samples.

Scene: ``scenes/cornell_box.xml`` (path tracer, max_depth 8, box filter) at
SIZE x SIZE. Both sides draw SPP samples per pixel with Mitsuba's
``independent`` sampler:

* ``mi.render``   ``mi.render(scene, spp=SPP)`` on a loaded scene (one pass, one
                  kernel, film accumulation in float32);
* ``reference``   ``get_reference(..., cache=False)``: scene load, pass plan,
                  cache key, then passes with exact float64 per-pixel moments
                  merged with Chan's formula;
* ``ref+cache``   the same with the cache on (a fresh, empty cache directory
                  each time), so the state checkpoint after every pass and the
                  final cache file are written.

Each round runs the three in a shuffled order (``mcrt.core.timing.round_orders``,
the timing protocol's) after a warm-up that compiles and caches every kernel;
every timing is wall time with ``dr.sync_thread()`` around it, and process CPU
time (all Dr.Jit threads) is recorded too, as it is less sensitive to other
programs running on the machine. The script prints medians
and the medians of the per-round ratios:

* ``end-to-end`` wall time of ``get_reference`` / (scene load + ``mi.render``);
* ``render-only`` ``Reference.seconds`` (the passes) / ``mi.render`` alone.

    python benchmarks/reference_throughput.py [--rounds 5] [--size 256] [--spp 256]
                                              [--spp-per-pass N]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

import mcrt  # noqa: F401  (variant + plugins)
from mcrt.analysis.reference import get_reference, plan_passes
from mcrt.core.timing import round_orders
from mcrt.render.scene import load_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "cornell_box.xml"


def clock() -> tuple[float, float]:
    dr.sync_thread()
    return time.perf_counter(), time.process_time()


def run_mi(params: dict[str, str], spp: int, seed: int) -> dict[str, float]:
    w0, c0 = clock()
    scene = load_scene(SCENE, {**params, "sampler": "independent"})
    w1, _ = clock()
    image = mi.render(scene, spp=spp, seed=seed)
    dr.eval(image)
    w2, c2 = clock()
    return {"wall": w2 - w0, "cpu": c2 - c0, "render": w2 - w1}


def run_reference(params: dict[str, str], spp: int, seed: int, per_pass: int | None,
                  cache: bool) -> dict[str, float]:
    directory = tempfile.mkdtemp(prefix="mcrt-bench-cache-") if cache else None
    old = os.environ.get("MCRT_CACHE_DIR")
    if directory:
        os.environ["MCRT_CACHE_DIR"] = directory
    try:
        w0, c0 = clock()
        ref = get_reference(SCENE, params, spp=spp, sampler="independent", seed=seed,
                            spp_per_pass=per_pass, cache=cache)
        w1, c1 = clock()
    finally:
        if directory:
            shutil.rmtree(directory, ignore_errors=True)
            if old is None:
                os.environ.pop("MCRT_CACHE_DIR", None)
            else:
                os.environ["MCRT_CACHE_DIR"] = old
    assert ref.drawn_samples == ref.stats.count.size * spp and not ref.cached
    return {"wall": w1 - w0, "cpu": c1 - c0, "render": ref.seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--spp-per-pass", type=int, default=None)
    args = parser.parse_args()
    params = {"res": str(args.size)}
    plan = plan_passes("independent", args.spp, args.size * args.size, args.spp_per_pass)
    samples = args.size * args.size * args.spp

    print(f"Cornell box {args.size}x{args.size}, path (max_depth 8), independent, {args.spp} spp "
          f"= {samples / 1e6:.1f} M samples; reference passes {plan.describe()}; "
          f"{args.rounds} rounds after warm-up; Dr.Jit threads {dr.thread_count()}")
    runs = {
        "mi.render": lambda seed: run_mi(params, args.spp, seed),
        "reference": lambda seed: run_reference(params, args.spp, seed, args.spp_per_pass, False),
        "ref+cache": lambda seed: run_reference(params, args.spp, seed, args.spp_per_pass, True),
    }
    names = list(runs)
    for name in names:  # warm-up: compile and cache every kernel
        runs[name](0)
    times: dict[str, list[dict[str, float]]] = {name: [] for name in names}
    for r, order in enumerate(round_orders(len(names), args.rounds)):  # the protocol's order
        for i in order:
            times[names[i]].append(runs[names[i]](r + 1))

    def med(name: str, field: str) -> float:
        return statistics.median(t[field] for t in times[name])

    def ratio(name: str, field: str) -> float:
        return statistics.median(a[field] / b[field]
                                 for a, b in zip(times[name], times["mi.render"], strict=True))

    print(f"{'':10s} {'wall [s]':>9s} {'render [s]':>10s} {'cpu [s]':>8s} {'M samples/s':>12s} "
          f"{'end-to-end':>11s} {'render-only':>12s} {'cpu ratio':>10s}")
    for name in names:
        line = (f"{name:10s} {med(name, 'wall'):9.3f} {med(name, 'render'):10.3f} "
                f"{med(name, 'cpu'):8.2f} {samples / med(name, 'render') / 1e6:12.2f}")
        if name != "mi.render":
            line += (f" {ratio(name, 'wall'):11.3f} {ratio(name, 'render'):12.3f} "
                     f"{ratio(name, 'cpu'):10.3f}")
        print(line)
    print("ratios: medians of per-round ratios to mi.render (goal <= 1.1)")


if __name__ == "__main__":
    main()
