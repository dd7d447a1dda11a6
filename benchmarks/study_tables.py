"""BENCHMARKS.md's study tables from a study's ``results.json``, and issue 13's efficiency check.

Per scene: one row per sampler with the slopes of log MSE against log spp and
against log seconds (with their standard errors), the efficiency ``1 / (MSE x
seconds)`` at every sample count, and the MSE and seconds per render at the
largest. Then, per cell with spp >= ``--min-spp``, the best of ``--ours`` against
the best of ``--theirs`` (Mitsuba's built-ins), as a ratio of efficiencies.

    mcrt compare configs/full.toml -o out/compare/full
    python benchmarks/study_tables.py out/compare/full/results.json
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

MITSUBA = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", type=Path)
    p.add_argument("--ours", default="sobol,zsobol")
    p.add_argument("--theirs", default=",".join(MITSUBA))
    p.add_argument("--min-spp", type=int, default=16)
    args = p.parse_args()
    data = json.loads(args.results.read_text())
    cells: dict[str, dict[str, dict[int, dict]]] = defaultdict(lambda: defaultdict(dict))
    for c in data["cells"]:
        cells[c["scene"]][c["sampler"]][c["spp_requested"]] = c
    fits = {(f["scene"], f["sampler"]): f for f in data["fits"]}
    ours, theirs = args.ours.split(","), args.theirs.split(",")
    for scene, samplers in cells.items():
        counts = sorted(next(iter(samplers.values())))
        print(f"\n{scene}:\n")
        print("| sampler | slope vs spp | slope vs time | "
              + " | ".join(f"efficiency @{n}" for n in counts)
              + f" | MSE @{counts[-1]} | s/render @{counts[-1]} |")
        print("|---|---|---|" + "---|" * len(counts) + "---|---|")
        for name, by_spp in samplers.items():
            f = fits[(scene, name)]
            last = by_spp[counts[-1]]
            spp_note = f" ({last['spp']})" if last["spp"] != counts[-1] else ""
            print(f"| `{name}` | {f['slope_spp']:.2f} +- {f['slope_spp_se']:.2f} "
                  f"| {f['slope_seconds']:.2f} +- {f['slope_seconds_se']:.2f} | "
                  + " | ".join(f"{by_spp[n]['efficiency']:.1e}" for n in counts)
                  + f" | {last['mse']:.2e}{spp_note} | {last['seconds']:.3f} +- "
                  f"{last['seconds_sd']:.3f} |")
        print(f"\n| spp | best of {', '.join(ours)} | efficiency | best of Mitsuba's "
              f"| efficiency | ratio |")
        print("|---:|---|---:|---|---:|---:|")
        for n in counts:
            if n < args.min_spp:
                continue
            def efficiency(name: str, n: int = n) -> float:
                return samplers[name][n]["efficiency"]

            mine = max((s for s in ours if s in samplers), key=efficiency)
            other = max((s for s in theirs if s in samplers), key=efficiency)
            a, b = samplers[mine][n]["efficiency"], samplers[other][n]["efficiency"]
            print(f"| {n} | `{mine}` | {a:.2e} | `{other}` | {b:.2e} | {a / b:.2f} |")


if __name__ == "__main__":
    main()
