"""Adaptive sampling vs fixed spp on scenes/edges.xml: relMSE at equal time, time at
equal relMSE, and pass time vs active samples.

Protocol
--------
* Reference: two independent `jittered` references of ``--reference-spp`` each
  (``mcrt.analysis.reference.get_reference``, cached), averaged. Their
  difference gives an unbiased per-pixel estimate of the averaged reference's
  own noise, ``(A - B)^2 / 4``, which is subtracted from every squared error
  (relMSE uses eps = 0.01 as in ``mcrt.analysis.metrics.rel_mse``). The table
  also prints the reference's noise floor.
* Fixed spp: ``render_film`` (= ``mi.render``: the scene's box film) with each
  sampler in ``--fixed-samplers`` at each count in ``--fixed-spp``.
* Adaptive: ``render_adaptive`` with each sampler in ``--adaptive-samplers`` at
  each threshold in ``--thresholds`` (other settings: defaults or flags).
* Every configuration is rendered once untimed (kernel compilation), then
  ``--repeats`` times with different seeds, configurations interleaved round by
  round; time = median wall time (``dr.sync_thread()`` around), relMSE = mean.
* Equal time: for each adaptive point, the best fixed sampler's relMSE at the
  same time, by log-log interpolation of its (time, relMSE) curve. Equal
  relMSE: the least time any fixed sampler needs for the adaptive relMSE (same
  interpolation). Points outside a fixed curve's measured range are
  extrapolated from its end segment and flagged with "~". Both with wall time
  and with process CPU time (all threads), which other jobs on a shared machine
  disturb less.
* Pass time: all passes of the timed adaptive renders, least-squares line
  ``seconds = a + b * samples`` with R^2.

Timings are only meaningful on a quiet machine.

    python benchmarks/adaptive_efficiency.py [--width 256 --height 192] [--repeats 3]
        [--quick] [--docs docs] [--json out.json]

Another scene: ``--scene scenes/cornell_box.xml --param res=128`` (its own
parameters, repeatable; ``--width``/``--height`` are edges.xml's).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import mcrt  # noqa: F401  (registers the plugins)
from mcrt.analysis.reference import get_reference
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from mcrt.core.timing import round_orders
from mcrt.render.adaptive import AdaptiveSettings, pass_time_fit, render_adaptive
from mcrt.render.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "edges.xml"
EPSILON = 1e-2


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=Path, default=SCENE,
                   help="the scene (default scenes/edges.xml)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="a scene parameter (repeatable); with none, edges.xml's width and height")
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=192)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--reference-spp", type=int, default=4096,
                   help="spp of each of the two references (default 4096)")
    p.add_argument("--fixed-samplers", default="jittered,stratified,independent")
    p.add_argument("--fixed-spp", default="16,64,256,1024,2304")
    p.add_argument("--adaptive-samplers", default="jittered,independent")
    p.add_argument("--thresholds", default="0.1,0.05,0.035,0.025,0.018")
    p.add_argument("--max-spp", type=int, default=4096)
    p.add_argument("--dark-floor", type=float, default=AdaptiveSettings.dark_floor)
    p.add_argument("--dilation", type=int, default=AdaptiveSettings.dilation)
    p.add_argument("--growth", type=float, default=AdaptiveSettings.growth)
    p.add_argument("--variant", action="append", default=[], metavar="LABEL:KEY=V,...",
                   help="an extra adaptive series with the first adaptive sampler and these "
                        "settings, e.g. 'tuned:dark_floor=0.5,growth=1.5' (repeatable)")
    p.add_argument("--quick", action="store_true",
                   help="128x96, 1 repeat, fewer points: checks that the script works")
    p.add_argument("--docs", type=Path, default=None,
                   help="write adaptive_heatmap.png and adaptive_efficiency.png here")
    p.add_argument("--json", type=Path, default=None, help="write all measurements here")
    args = p.parse_args(argv)
    if args.quick:
        args.width, args.height, args.repeats = 128, 96, 1
        args.reference_spp = min(args.reference_spp, 1024)
        args.fixed_spp = "16,64,256,1024"
        args.thresholds = "0.1,0.05,0.025"
    return args


class Metric:
    """relMSE against the averaged reference, its own noise subtracted."""

    def __init__(self, a: np.ndarray, b: np.ndarray) -> None:
        self.reference = 0.5 * (a + b)
        self.noise = 0.25 * (a - b) ** 2
        self.weight = 1.0 / (self.reference ** 2 + EPSILON)

    def __call__(self, image: np.ndarray) -> float:
        error = (np.asarray(image, dtype=np.float64) - self.reference) ** 2 - self.noise
        return float(np.mean(error * self.weight))

    @property
    def floor(self) -> float:
        return float(np.mean(self.noise * self.weight))


def run_fixed(scene, name: str, spp: int, seed: int):
    sampler = make_sampler(name, spp)
    cpu = time.process_time()
    result = render_film(scene, sampler, seed=seed)
    return result.rgb, result.seconds, time.process_time() - cpu, result.spp, None


def run_adaptive(scene, name: str, settings: AdaptiveSettings, seed: int):
    sampler = make_sampler(name, settings.min_spp)
    cpu = time.process_time()
    result = render_adaptive(scene, sampler, settings, seed=seed)
    return (result.rgb, result.seconds, time.process_time() - cpu,
            result.samples / result.spp.size, result)


def interpolate(xs, ys, x) -> tuple[float, bool]:
    """y at x on the log-log polyline through (xs, ys) (xs increasing); flag if
    extrapolated from the end segments."""
    lx, ly = np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float))
    t = math.log(x)
    if lx[0] <= t <= lx[-1]:
        return float(np.exp(np.interp(t, lx, ly))), False
    i = (0, 1) if t < lx[0] else (-2, -1)
    slope = (ly[i[1]] - ly[i[0]]) / (lx[i[1]] - lx[i[0]])
    return float(np.exp(ly[i[0]] + slope * (t - lx[i[0]]))), True


def main(argv=None) -> int:
    args = parse_args(argv)
    params = (dict(item.split("=", 1) for item in args.param) if args.param
              else {"width": str(args.width), "height": str(args.height)})
    fixed_samplers = [s for s in args.fixed_samplers.split(",") if s]
    fixed_spp = [int(s) for s in args.fixed_spp.split(",") if s]
    adaptive_samplers = [s for s in args.adaptive_samplers.split(",") if s]
    # Adaptive series: (label, sampler, settings overrides).
    series = [(name, name, {}) for name in adaptive_samplers]
    for spec in args.variant:
        label, _, items = spec.partition(":")
        overrides = {}
        for item in filter(None, items.split(",")):
            key, _, value = item.partition("=")
            kind = type(getattr(AdaptiveSettings, key))
            overrides[key] = kind(value)
        series.append((f"{adaptive_samplers[0]} {label}", adaptive_samplers[0], overrides))
    labels = [label for label, _, _ in series]
    thresholds = [float(t) for t in args.thresholds.split(",") if t]

    print(f"# {args.scene.name} {params}", flush=True)
    start = time.perf_counter()
    refs = [get_reference(args.scene, params, spp=args.reference_spp, sampler="jittered",
                          seed=seed, progress=True) for seed in (101, 202)]
    metric = Metric(refs[0].mean, refs[1].mean)
    pixels = int(np.prod(refs[0].mean.shape[:2]))
    print(f"reference: 2 x {args.reference_spp} spp jittered "
          f"({'cached' if all(r.cached for r in refs) else 'rendered'}, "
          f"{time.perf_counter() - start:.0f} s); its own relMSE (noise floor, subtracted): "
          f"{metric.floor:.2e}", flush=True)

    scene = load_scene(args.scene, params)
    configs = []
    for name in fixed_samplers:
        for spp in fixed_spp:
            configs.append(("fixed", name, spp))
    for label, _, _ in series:
        for threshold in thresholds:
            configs.append(("adaptive", label, threshold))

    def settings_for(label: str, threshold: float) -> tuple[str, AdaptiveSettings]:
        _, sampler, overrides = next(x for x in series if x[0] == label)
        base = {"threshold": threshold, "max_spp": args.max_spp, "dark_floor": args.dark_floor,
                "dilation": args.dilation, "growth": args.growth}
        return sampler, AdaptiveSettings(**{**base, **overrides})

    def render(config, seed):
        kind, name, value = config
        if kind == "fixed":
            return run_fixed(scene, name, value, seed)
        return run_adaptive(scene, *settings_for(name, value), seed)

    for config in configs:  # warm-up: compile every kernel once
        render(config, seed=9999)
    records = {config: {"seconds": [], "cpu": [], "relmse": [], "spp": [], "passes": []}
               for config in configs}
    last_adaptive = {}
    for r, shuffled in enumerate(round_orders(len(configs), args.repeats)):  # the protocol's
        for config in (configs[i] for i in shuffled):
            image, seconds, cpu, spp, result = render(config, seed=r + 1)
            rec = records[config]
            rec["seconds"].append(seconds)
            rec["cpu"].append(cpu)
            rec["relmse"].append(metric(image))
            rec["spp"].append(float(spp))
            if result is not None:
                rec["passes"].extend((p.samples, p.seconds) for p in result.passes)
                last_adaptive[config] = result
        print(f"round {r + 1}/{args.repeats} done ({time.perf_counter() - start:.0f} s)",
              flush=True)

    summary = {c: {"seconds": statistics.median(v["seconds"]),
                   "cpu": statistics.median(v["cpu"]),
                   "relmse": float(np.mean(v["relmse"])),
                   "spp": float(np.mean(v["spp"]))} for c, v in records.items()}

    print("\n## Fixed spp\n")
    print("| sampler | spp | wall [s] | CPU [s] | relMSE |")
    print("|---|---:|---:|---:|---:|")
    curves = {"wall": {}, "cpu": {}}
    for name in fixed_samplers:
        points = [summary[("fixed", name, s)] for s in fixed_spp]
        for clock, key in (("wall", "seconds"), ("cpu", "cpu")):
            curves[clock][name] = sorted((p[key], p["relmse"]) for p in points)
        for p in points:
            print(f"| {name} | {p['spp']:.0f} | {p['seconds']:.2f} | {p['cpu']:.2f} | "
                  f"{p['relmse']:.3e} |")

    def compare(clock: str, t: float, e: float) -> dict:
        """Best fixed relMSE at time t, and least fixed time to relMSE e."""
        at_time, to_error = [], []
        for fixed, points in curves[clock].items():
            ts, es = [p[0] for p in points], [p[1] for p in points]
            value, extra = interpolate(ts, es, t)
            at_time.append((value, extra, fixed))
            order = np.argsort(es)  # relMSE increasing
            tt, extra2 = interpolate([es[i] for i in order], [ts[i] for i in order], e)
            to_error.append((tt, extra2, fixed))
        (fe, fe_x, fe_s), (ft, ft_x, ft_s) = min(at_time), min(to_error)
        return {"fixed_relmse": fe, "fixed_relmse_sampler": fe_s, "fixed_relmse_extrapolated": fe_x,
                "ratio_relmse": e / fe, "fixed_time": ft, "fixed_time_sampler": ft_s,
                "fixed_time_extrapolated": ft_x, "ratio_time": t / ft}

    print("\n## Adaptive vs the best fixed sampler\n")
    print("| sampler | threshold | mean spp | passes | wall [s] | CPU [s] | relMSE | "
          "relMSE / best fixed at equal time (wall, CPU) | time / best fixed time to equal "
          "relMSE (wall, CPU) |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---|")
    rows = []
    for name in labels:
        for threshold in thresholds:
            s = summary[("adaptive", name, threshold)]
            row = {"sampler": name, "threshold": threshold, "spp": s["spp"],
                   "seconds": s["seconds"], "cpu": s["cpu"], "relmse": s["relmse"],
                   "passes": len(last_adaptive[("adaptive", name, threshold)].passes),
                   "wall": compare("wall", s["seconds"], s["relmse"]),
                   "cpu_clock": compare("cpu", s["cpu"], s["relmse"])}
            rows.append(row)
            w, c = row["wall"], row["cpu_clock"]

            def mark(x: bool) -> str:
                return "~" if x else ""
            print(f"| {name} | {threshold:g} | {s['spp']:.0f} | {row['passes']} | "
                  f"{s['seconds']:.2f} | {s['cpu']:.2f} | {s['relmse']:.3e} | "
                  f"{mark(w['fixed_relmse_extrapolated'])}{w['ratio_relmse']:.2f} "
                  f"({w['fixed_relmse_sampler']}), "
                  f"{mark(c['fixed_relmse_extrapolated'])}{c['ratio_relmse']:.2f} "
                  f"({c['fixed_relmse_sampler']}) | "
                  f"{mark(w['fixed_time_extrapolated'])}{w['ratio_time']:.2f} "
                  f"({w['fixed_time_sampler']}), "
                  f"{mark(c['fixed_time_extrapolated'])}{c['ratio_time']:.2f} "
                  f"({c['fixed_time_sampler']}) |")

    all_passes = [p for c in configs if c[0] == "adaptive" for p in records[c]["passes"]]

    class _P:  # minimal PassRecord stand-in for pass_time_fit
        def __init__(self, samples, seconds):
            self.samples, self.seconds = samples, seconds

    fit = pass_time_fit([_P(n, t) for n, t in all_passes])
    print(f"\n## Pass time vs samples\n\n{len(all_passes)} passes: seconds = "
          f"{fit['intercept'] * 1e3:.1f} ms + {fit['slope'] * 1e9:.1f} ns x samples, "
          f"R^2 = {fit['r2']:.3f}")
    fixed_rate = [summary[("fixed", n, max(fixed_spp))]["seconds"]
                  / (summary[("fixed", n, max(fixed_spp))]["spp"] * pixels)
                  for n in fixed_samplers]
    print(f"(fixed-spp renders at {max(fixed_spp)} spp: "
          f"{statistics.median(fixed_rate) * 1e9:.1f} ns per sample)")
    print(f"\ntotal benchmark time {time.perf_counter() - start:.0f} s")

    if args.docs is not None:
        write_figures(args.docs, curves["wall"], rows, last_adaptive, all_passes, fit,
                      thresholds, labels)
    if args.json is not None:
        args.json.write_text(json.dumps({
            "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
            "reference_floor": metric.floor,
            "fixed": {f"{k[1]}@{k[2]}": v for k, v in summary.items() if k[0] == "fixed"},
            "adaptive": rows, "pass_fit": fit, "passes": all_passes}, indent=1))
    return 0


def write_figures(directory: Path, curves, rows, last_adaptive, passes, fit, thresholds,
                  adaptive_samplers) -> None:
    """docs/adaptive_heatmap.png (image + spp heat map) and adaptive_efficiency.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from mcrt.io import encode_srgb

    directory.mkdir(parents=True, exist_ok=True)
    sampler = adaptive_samplers[0]  # the first series (default settings)
    threshold = thresholds[len(thresholds) // 2]
    result = last_adaptive[("adaptive", sampler, threshold)]
    s = result.settings
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 3.9), constrained_layout=True)
    axes[0].imshow(encode_srgb(result.rgb))
    axes[0].set_title(f"adaptive ({sampler}, threshold {threshold:g}): "
                      f"{result.samples / result.spp.size:.0f} spp on average")
    image = axes[1].imshow(result.spp, cmap="inferno",
                           norm=LogNorm(vmin=s.min_spp, vmax=s.max_spp))
    axes[1].set_title(f"samples per pixel ({result.spp.min()}..{result.spp.max()}, "
                      f"{len(result.passes)} passes)")
    fig.colorbar(image, ax=axes[1], label="spp (log scale)")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.savefig(directory / "adaptive_heatmap.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for name, points in curves.items():
        axes[0].loglog([p[0] for p in points], [p[1] for p in points], "o--",
                       label=f"fixed {name}")
    for name in adaptive_samplers:
        pts = sorted((r["seconds"], r["relmse"]) for r in rows if r["sampler"] == name)
        axes[0].loglog([p[0] for p in pts], [p[1] for p in pts], "s-", lw=2,
                       label=f"adaptive {name}")
    axes[0].set_xlabel("wall time [s]")
    axes[0].set_ylabel("relMSE")
    axes[0].set_title("error vs time")
    axes[0].legend(fontsize=8)
    axes[0].grid(True, which="both", alpha=0.3)
    x = np.array([p[0] for p in passes], float)
    y = np.array([p[1] for p in passes], float)
    axes[1].plot(x / 1e6, y, ".", alpha=0.5, label="passes")
    xs = np.linspace(0, x.max(), 50)
    axes[1].plot(xs / 1e6, fit["intercept"] + fit["slope"] * xs, "-",
                 label=f"{fit['intercept'] * 1e3:.0f} ms + {fit['slope'] * 1e9:.0f} ns/sample, "
                       f"R$^2$={fit['r2']:.3f}")
    axes[1].set_xlabel("samples traced in the pass [millions]")
    axes[1].set_ylabel("pass time [s]")
    axes[1].set_title("pass time vs active samples")
    axes[1].legend(fontsize=8)
    axes[1].grid(True, alpha=0.3)
    fig.savefig(directory / "adaptive_efficiency.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
