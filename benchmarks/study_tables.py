"""BENCHMARKS.md's study tables from a study's ``results.json``, every figure with its 95% interval.

Per scene: one row per sampler with the slopes of log MSE against log spp and
against log seconds, the cost per render split into a fixed part and a part per
sample, and the MSE and the median time per render at the largest spp; then the
efficiency of every sampler as a ratio to the study's baseline at every sample
count; then, per cell with spp >= ``--min-spp``, the best of ``--ours`` against the
best of ``--theirs`` (Mitsuba's built-ins), as an efficiency ratio with its interval
(the two MSEs over seeds and the time ratio paired by round, as the study computes
its ratios: mcrt.analysis.convergence.efficiency_ratio). Biased cells are listed.

    mcrt compare configs/full.toml -o out/compare/full
    python benchmarks/study_tables.py out/compare/full/results.json
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path

MITSUBA = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")


def _g(v: float | None, spec: str = ".2f") -> str:
    return format(v, spec) if v is not None and math.isfinite(v) else "-"


def _iv(v: float | None, low: float | None, high: float | None, spec: str = ".2f") -> str:
    return f"{_g(v, spec)} [{_g(low, spec)}, {_g(high, spec)}]" if v is not None else "-"


def main() -> None:
    from mcrt.analysis.convergence import efficiency_ratio, excess_mse, paired_time_ratio

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", type=Path)
    p.add_argument("--ours", default="sobol,zsobol")
    p.add_argument("--theirs", default=",".join(MITSUBA))
    p.add_argument("--min-spp", type=int, default=16)
    args = p.parse_args()
    data = json.loads(args.results.read_text())
    baseline = data["study"]["baseline"]
    cells: dict[str, dict[str, dict[int, dict]]] = defaultdict(lambda: defaultdict(dict))
    for c in data["cells"]:
        cells[c["scene"]][c["sampler"]][c["spp_requested"]] = c
    fits = {(f["scene"], f["sampler"]): f for f in data["fits"]}
    ours, theirs = args.ours.split(","), args.theirs.split(",")
    for scene, samplers in cells.items():
        counts = sorted(next(iter(samplers.values())))
        top = counts[-1]
        print(f"\n{scene}:\n")
        print(f"| sampler | slope vs spp [95%] | slope vs time [95%] | fixed ms | ns/sample "
              f"| MSE @{top} | ms/render @{top} [95%] |")
        print("|---|---|---|---:|---:|---:|---|")
        for name, by_spp in samplers.items():
            f, last = fits[(scene, name)], by_spp[top]
            spp_note = f" ({last['spp']})" if last["spp"] != top else ""
            print(f"| `{name}` | {_iv(f['slope_spp'], f['slope_spp_low'], f['slope_spp_high'])} "
                  f"| {_iv(f['slope_seconds'], f['slope_seconds_low'], f['slope_seconds_high'])} "
                  f"| {_g(1e3 * f['fixed_seconds'] if f['fixed_seconds'] else None, '.1f')} "
                  f"| {_g(1e9 * f['seconds_per_sample'] if f['seconds_per_sample'] else None, '.0f')} "  # noqa: E501
                  f"| {last['mse']:.2e}{spp_note} "
                  f"| {_iv(1e3 * last['seconds'], 1e3 * last['seconds_low'], 1e3 * last['seconds_high'], '.0f')} |")  # noqa: E501
        print(f"\nEfficiency as a ratio to `{baseline}`'s at the same spp [95%]:\n")
        print("| sampler | " + " | ".join(f"@{n}" for n in counts) + " |")
        print("|---|" + "---|" * len(counts))
        for name, by_spp in samplers.items():
            print(f"| `{name}` | " + " | ".join(
                _iv(by_spp[n]["efficiency_ratio"], by_spp[n]["efficiency_ratio_low"],
                    by_spp[n]["efficiency_ratio_high"]) for n in counts) + " |")
        _print_split(samplers, baseline, args.min_spp)
        biased = [f"`{c['sampler']}` @{c['spp']} ({c['bias']:+.1e}, t = {c['bias_z']:+.1f})"
                  for by_spp in samplers.values() for c in by_spp.values() if c["biased"]]
        print(f"\nBiased cells (Holm, 5% family-wise): {', '.join(biased) or 'none'}")
        mine_names = [s for s in ours if s in samplers]
        other_names = [s for s in theirs if s in samplers]
        if not (mine_names and other_names):
            continue
        print(f"\n| spp | best of {', '.join(ours)} | best of Mitsuba's | efficiency ratio [95%] |")
        print("|---:|---|---|---|")
        for n in counts:
            if n < args.min_spp:
                continue
            efficiency = {s: samplers[s][n]["efficiency"] or 0.0 for s in mine_names + other_names}
            mine = max(mine_names, key=efficiency.__getitem__)
            other = max(other_names, key=efficiency.__getitem__)
            a, b = samplers[mine][n], samplers[other][n]
            ratio = efficiency_ratio(
                excess_mse([r["mse"] for r in a["per_seed"]], a["mse_floor"]),
                excess_mse([r["mse"] for r in b["per_seed"]], b["mse_floor"]),
                paired_time_ratio(a["times"], b["times"]))
            low, high = ratio.interval()
            print(f"| {n} | `{mine}` | `{other}` | {_iv(ratio.value, low, high)} |")


def _print_split(samplers: dict[str, dict[int, dict]], baseline: str, min_spp: int) -> None:
    """Where the ratios' intervals come from: the half-width of the time part (the
    paired time ratio) and of the error part (the two excess MSEs) at spp >= min_spp."""
    from mcrt.analysis.convergence import LogEstimate, excess_mse, paired_time_ratio

    if baseline not in samplers:
        return
    time_part, error_part, total = [], [], []
    for name, by_spp in samplers.items():
        for n, c in by_spp.items():
            if name == baseline or n < min_spp or c["efficiency_ratio"] is None:
                continue
            b = samplers[baseline][n]
            t = paired_time_ratio(c["times"], b["times"])
            low, high = t.interval()
            time_part.append(max(t.value / low, high / t.value) - 1)
            ea = excess_mse([r["mse"] for r in c["per_seed"]], c["mse_floor"])
            eb = excess_mse([r["mse"] for r in b["per_seed"]], b["mse_floor"])
            low, high = LogEstimate(1.0, math.hypot(ea.se_log, eb.se_log), ea.df).interval()
            error_part.append(high - 1)
            total.append(max(c["efficiency_ratio"] / c["efficiency_ratio_low"],
                             c["efficiency_ratio_high"] / c["efficiency_ratio"]) - 1)
    if not total:
        return

    def spread(values: list[float]) -> str:
        values = sorted(values)
        return f"median +-{100 * values[len(values) // 2]:.1f}%, max +-{100 * values[-1]:.1f}%"

    print(f"\nHalf-widths of the ratios' 95% intervals at spp >= {min_spp}: {spread(total)} "
          f"({sum(v <= 0.10 for v in total)} of {len(total)} within +-10%); the time part "
          f"alone {spread(time_part)}, the error part alone {spread(error_part)}")


if __name__ == "__main__":
    main()
