"""How often does a study flag an unbiased sampler as biased? And does it find a real bias?

Runs ``--studies`` small null studies of samplers that are unbiased by
construction, each with its own seeds and its own reference seed, and counts
the studies in which any cell is flagged ``biased`` (Holm's correction over the
study's cells at a family-wise 5%: about 1 study in 20 by chance at most, fewer
when the interval is conservative). Then runs configs/bias.toml, where Mitsuba's
``ldsampler`` is biased, and prints what it flags.

    python benchmarks/bias_false_alarms.py              # 20 studies, ~2-4 min on 2 cores
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UNBIASED = "independent,jittered,sobol,zsobol,multijitter,stratified"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--studies", type=int, default=20)
    p.add_argument("--samplers", default=UNBIASED)
    p.add_argument("--scenes", default="cornell_box:32,checkerboard:0",
                   help="scene:res pairs (res 0: the scene's own size)")
    p.add_argument("--spp", default="4,16")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--biased-config", default=str(ROOT / "configs" / "bias.toml"))
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        os.environ["MCRT_CACHE_DIR"] = cache
        import mcrt  # noqa: F401  (the variant, the plugins)
        from mcrt.analysis.study import load_config, parse_config, run_study
        from mcrt.analysis.study.conclude import bias_lines

        logging.getLogger("mcrt").setLevel(logging.WARNING)
        spp = [int(s) for s in args.spp.split(",")]
        scenes = []
        for item in args.scenes.split(","):
            name, res = item.split(":")
            scene = {"path": str(ROOT / "scenes" / f"{name}.xml")}
            if int(res):
                scene["params"] = {"res": int(res)}
            scenes.append(scene)
        flagged, cells = 0, 0
        for study in range(args.studies):
            config = parse_config({
                "name": f"null{study}", "spp": spp, "time_rounds": args.seeds,
                "seeds": [1000 * study + i for i in range(args.seeds)],
                "samplers": args.samplers.split(","), "scenes": scenes,
                "reference": {"spp": 16 * max(spp), "seed": 7919 * (study + 1)}})
            result = run_study(config)
            cells += len(result.cells)
            lines = bias_lines(result.cells)
            flagged += bool(lines)
            zmax = max(abs(c["bias_z"]) for c in result.cells)
            print(f"null study {study + 1:2d}: {len(result.cells)} cells, largest |z| "
                  f"{zmax:.2f}, {'FLAGGED: ' + '; '.join(lines) if lines else 'no flag'}",
                  flush=True)
        print(f"\nfalse alarms: {flagged} of {args.studies} null studies ({cells} cells in "
              f"all; samplers {args.samplers}); goal: at most 1")
        biased = run_study(load_config(args.biased_config))
        lines = bias_lines(biased.cells)
        print(f"\n{Path(args.biased_config).name}: {len(lines)} sampler(s) flagged")
        for line in lines:
            print(f"  {line}")


if __name__ == "__main__":
    main()
