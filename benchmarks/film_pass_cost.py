"""A film render's fixed cost per pass: passes traced against passes replayed.

The same render (the Cornell box with a box filter, ``--res`` pixels square,
``--spp`` samples per pixel, one seed per call) split into 2, 4, 8, ... ``--spp``
passes: the samples stay the same, so the slope of the time against the number
of passes (:func:`mcrt.core.timing.fit_cost`) is what one more pass costs on
its own. Each render has a progress bar (off screen), as ``mcrt render`` has, so
its passes are replayed one at a time (:mod:`mcrt.core.pass_replay`) unless
``MCRT_REPLAY=0``; both sides run in this process, interleaved by the timing
protocol (:func:`mcrt.core.timing.run_interleaved`, one warm-up each). Goal:
<= 1 ms per pass. ``--motion``: scenes/effects/motion.xml instead, one motion
sub-frame per pass (the ball and the cube move before each pass).

    python benchmarks/film_pass_cost.py [--res 64] [--spp 64] [--rounds 9] 2>/dev/null
                                        [--samplers sobol independent] [--motion]
"""

from __future__ import annotations

import argparse
import os
import statistics
from pathlib import Path

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.core import pass_replay, replay  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.core.timing import fit_cost, run_interleaved  # noqa: E402
from mcrt.render.plan import plan_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
MOTION = ROOT / "scenes" / "effects" / "motion.xml"
GOAL = 1e-3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--samplers", nargs="+", default=["sobol", "independent"])
    parser.add_argument("--motion", action="store_true",
                        help="scenes/effects/motion.xml, a motion sub-frame per pass")
    args = parser.parse_args()
    planned = (plan_scene(MOTION, params={"width": str(args.res), "height": str(args.res)})
               if args.motion else None)
    if planned is not None:
        scene = planned.scene
    else:
        text = CORNELL.read_text().replace('<rfilter type="gaussian"/>', '<rfilter type="box"/>')
        scene = mi.load_string(text, res=str(args.res), spp=str(args.spp))
    counts = [p for p in (2, 4, 8, 16, 32, 64, 128) if p <= args.spp and args.spp % p == 0]
    seeds = iter(range(1 << 30))

    def case(name: str, passes: int, on: bool):
        def run() -> None:
            os.environ[replay.ENV] = "1" if on else "0"
            sampler, seed, hook = make_sampler(name, args.spp), next(seeds), None
            if planned is not None:  # one sub-frame per pass
                _, hook = planned.schedule(sampler, args.spp, seed, subframes=passes)
            render_film(scene, sampler, seed=seed, passes=passes, progress=True, on_pass=hook)
        return run

    what = "motion.xml (a sub-frame per pass)" if args.motion else "Cornell box"
    print(f"{what} {args.res}^2, box filter, {args.spp} spp in {counts} passes; "
          f"{args.rounds} rounds, medians", flush=True)
    print("\n| sampler | traced: ms per pass (+-SE) | replayed: ms per pass (+-SE) | "
          "replayed / traced, whole render at the most passes | goal <= 1 ms |")
    print("|---|---|---|---|---|")
    for name in args.samplers:
        cases = [case(name, p, on) for on in (False, True) for p in counts]
        samples = run_interleaved(cases, args.rounds, warmup=1, sync=dr.sync_thread)
        medians = [statistics.median(s.wall for s in runs) for runs in samples]
        traced = fit_cost(counts, medians[:len(counts)])
        replayed = fit_cost(counts, medians[len(counts):])
        ratio = medians[-1] / medians[len(counts) - 1]
        print(f"| {name} | {traced.per_unit * 1e3:.2f} (+-{traced.per_unit_se * 1e3:.2f}) | "
              f"{replayed.per_unit * 1e3:.2f} (+-{replayed.per_unit_se * 1e3:.2f}) | "
              f"{ratio:.2f} | {'PASS' if replayed.per_unit <= GOAL else 'FAIL'} |", flush=True)
    print(f"\nrecordings: {pass_replay.RECORDINGS.count()} (one per pass shape and sampler)")


if __name__ == "__main__":
    main()
