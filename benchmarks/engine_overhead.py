"""The pass engine alone against ``mi.render``, in one process.

``mcrt.core.render.render_film`` and ``mi.render`` of the same scene (the Cornell
box), sampler and spp, each warmed up once, then ``--rounds`` interleaved runs;
wall time with ``dr.sync_thread()`` and the image copied to numpy in both. Prints
the median times and the ratio of medians (engine / mi.render), and, as a floor
for any design that splits a render into passes, ``mi.render`` itself called
once per pass of the engine's pass shape (same number of samples). This separates
the engine's cost from the command line's fixed costs (imports, plan, outputs),
which ``benchmarks/render_overhead.py`` measures end to end.

    python benchmarks/engine_overhead.py [--res 256 1024] [--spp 16] [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.core.engine import pass_shape  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402

CORNELL = Path(__file__).resolve().parents[1] / "scenes" / "cornell_box.xml"


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    dr.sync_thread()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--samplers", nargs="+", default=["jittered", "independent"])
    args = parser.parse_args()
    print("| film | sampler | engine [s] | mi.render [s] | ratio | mi.render in the engine's "
          "passes [s] | ratio to mi.render |\n|---|---|---|---|---|---|---|")
    for res in args.res:
        for name in args.samplers:
            scene = mi.load_file(str(CORNELL), res=str(res), sampler=name)

            def ours() -> None:
                render_film(scene, make_sampler(name, args.spp), seed=0)

            def theirs() -> None:
                np.array(mi.render(scene, spp=args.spp))

            shape = pass_shape(res * res, args.spp)

            def split() -> None:  # Mitsuba itself, one call per pass of the engine's shape
                for index in range(shape.passes):
                    np.array(mi.render(scene, spp=shape.group, seed=index))

            for fn in (ours, theirs, split):
                fn()
            a, b, c = [], [], []
            for _ in range(args.rounds):
                a.append(timed(ours))
                b.append(timed(theirs))
                c.append(timed(split))
            ma, mb, mc = (statistics.median(x) for x in (a, b, c))
            print(f"| {res}^2 | {name} | {ma:.3f} | {mb:.3f} | {ma / mb:.3f} | {mc:.3f} "
                  f"({shape.passes} x {shape.group} spp) | {mc / mb:.3f} |", flush=True)


if __name__ == "__main__":
    main()
