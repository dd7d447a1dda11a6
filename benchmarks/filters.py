"""Reconstruction filters: blur, ringing, residual aliasing and noise at fixed sampling.

Protocol
--------
* Filters: Mitsuba's box, tent, gaussian, mitchell, catmullrom, lanczos, each
  with its default parameters, swapped into the scene's film
  (:data:`mcrt.render.scene.RFILTER_PARAM`, what ``filters = [...]`` does in a
  ``mcrt compare`` study: see ``configs/filters.toml``).
* Fixed sampling: ``jittered``, ``--spp`` samples per pixel, ``--seeds`` seeds.
* Slanted edge (``scenes/filters/slanted_edge.xml``, 128^2, levels 0.2 | 0.8,
  5 degrees), measured by :mod:`mcrt.analysis.edge`: the seed-averaged image's
  rows give the edge (50% crossings, a fitted line); every pixel's signed
  distance to it, binned at 1/16 pixel, gives the edge profile. *Blur*: its 10-90%
  rise distance in pixels. *Ringing*: the largest over- and undershoot beyond
  the two levels, in % of the step (negative lobes ring; box/tent/gaussian
  cannot).
* Checkerboard (``scenes/checkerboard.xml``, 160 x 120): the error against a
  reference of the *same filter* (``--reference-spp``, jittered), luminance.
  *Aliasing*: :func:`mcrt.analysis.aliasing.aliasing_score` of the first seed's
  error (ratio z, peak z, verdict), and the RMSE.
* Residual aliasing with regular sampling: the same checkerboard with the
  ``uniform_grid`` sampler (deterministic: all its error is moire the filter
  let through), against the same reference: RMSE and aliasing score.
* *Noise*: the variance of the pixel estimate across seeds (Welford, per
  pixel, luminance), mean over the checkerboard's pixels and over the slanted
  edge's pixels within 2 px of the edge (elsewhere the edge has none).

    python benchmarks/filters.py [--spp 16] [--seeds 8] [--figure docs/filters.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mcrt  # noqa: E402,F401  (variant, plugins)
from mcrt.analysis.aliasing import aliasing_score  # noqa: E402
from mcrt.analysis.edge import edge_metrics  # noqa: E402
from mcrt.analysis.filter_noise import filter_correlation  # noqa: E402
from mcrt.analysis.metrics import luminance  # noqa: E402
from mcrt.analysis.study.config import FILTERS  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.render.scene import RFILTER_PARAM, load_scene  # noqa: E402

EDGE = ROOT / "scenes" / "filters" / "slanted_edge.xml"
CHECKER = ROOT / "scenes" / "checkerboard.xml"
LOW, HIGH = 0.2, 0.8  # the slanted edge's two radiances


def renders(path: Path, rfilter: str, spp: int, seeds: range, sampler: str = "jittered",
            **params) -> list[np.ndarray]:
    scene = load_scene(path, {RFILTER_PARAM: rfilter, "spp": str(spp), "sampler": sampler,
                              **{k: str(v) for k, v in params.items()}})
    return [luminance(render_film(scene, seed=s).rgb.astype(np.float64)) for s in seeds]


def checker_metrics(images: list[np.ndarray], reference: np.ndarray, rfilter: str) -> dict:
    error = images[0] - reference
    score = aliasing_score(error, correlation=filter_correlation(rfilter))  # filter-aware null
    rmse = float(np.mean([np.sqrt(np.mean((im - reference) ** 2)) for im in images]))
    var = np.var(images, axis=0, ddof=1)
    return {"rmse": rmse, "ratio_z": score.ratio_z, "peak_z": score.peak_z,
            "verdict": score.verdict, "noise": float(var.mean()), "error": error}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--reference-spp", type=int, default=1024)
    p.add_argument("--figure", type=Path, help="write the figure (edge profiles, crops)")
    args = p.parse_args()
    seeds = range(args.seeds)
    rows = ["| filter | edge 10-90% [px] | overshoot [%] | undershoot [%] | noise (edge band) "
            "| noise (checker) | checker RMSE | ratio z | peak z | verdict "
            "| grid: checker RMSE | grid: ratio z | grid: peak z | grid: verdict |",
            "|---" * 14 + "|"]
    results = {}
    for f in FILTERS:
        edge = edge_metrics(renders(EDGE, f, args.spp, seeds), LOW, HIGH)
        params = {"width": 160, "height": 120}
        ref = renders(CHECKER, f, args.reference_spp, range(4242, 4243), **params)[0]
        check = checker_metrics(renders(CHECKER, f, args.spp, seeds, **params), ref, f)
        grid = checker_metrics(renders(CHECKER, f, args.spp, range(2), "uniform_grid",
                                       **params), ref, f)
        results[f] = (edge, check, grid)
        rows.append(f"| {f} | {edge.width:.2f} | {edge.overshoot:.1f} | {edge.undershoot:.1f} | "
                    f"{edge.noise:.2e} | {check['noise']:.2e} | "
                    f"{check['rmse']:.4f} | {check['ratio_z']:.1f} | {check['peak_z']:.1f} | "
                    f"{check['verdict']} | {grid['rmse']:.4f} | {grid['ratio_z']:.1f} | "
                    f"{grid['peak_z']:.1f} | {grid['verdict']} |")
        print(rows[-1], flush=True)
    print("\n" + "\n".join(rows))
    if args.figure is not None:
        plot(results, args.figure)
        print(f"wrote {args.figure}")
    return 0


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for f, (edge, _, _) in results.items():
        axes[0].plot(edge.x, edge.esf, label=f, lw=1.2)
    axes[0].set(xlim=(-3, 3), xlabel="distance to the edge [px]", ylabel="normalised level",
                title="slanted edge: edge profile (blur, ringing)")
    axes[0].axhline(0, color="k", lw=0.5)
    axes[0].axhline(1, color="k", lw=0.5)
    axes[0].legend(fontsize=8)
    names = list(results)
    width = [results[f][0].width for f in names]
    ring = [results[f][0].overshoot + results[f][0].undershoot for f in names]
    axes[1].scatter(width, ring)
    for f, wv, rv in zip(names, width, ring, strict=True):
        axes[1].annotate(f, (wv, rv), fontsize=8)
    axes[1].set(xlabel="edge 10-90% width [px] (blur)", ylabel="over + undershoot [%]",
                title="blur vs ringing")
    noise = [results[f][1]["noise"] for f in names]
    alias = [results[f][2]["rmse"] for f in names]
    axes[2].scatter(noise, alias)
    for f, nv, av in zip(names, noise, alias, strict=True):
        axes[2].annotate(f, (nv, av), fontsize=8)
    axes[2].set(xscale="log", xlabel="variance of the pixel estimate (checkerboard, jittered)",
                ylabel="checkerboard RMSE, uniform grid (moire left)",
                title="noise vs residual aliasing")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
