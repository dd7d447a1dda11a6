"""Where an adaptive render's per-pass fixed cost goes, on scenes/edges.xml.

Renders ``scenes/edges.xml`` adaptively (``sobol``, default settings) ``--renders``
times after a warm-up and reports, per render:

* wall time, passes, and the fit ``seconds = a + b x samples`` over the passes
  (``a`` is the fixed cost a machine with faster kernels would not shrink);
* with ``--commit-timing``, the time of ``PixelSums.commit`` (the update of the
  sums at the end of each pass), timed with ``dr.sync_thread()`` around it
  (which keeps its kernel from running on while the host goes on, as it does in
  a render: off by default);
* from Dr.Jit's kernel history: the kernels' execution time, and the ``Memcpy``
  kernels per pass (whole-array copies, e.g. a scatter into an array that a
  pending gather still reads);
* where the passes' time goes, by kernel clocks: kernels as wide as the pass's
  samples (the trace), kernels a thread per active pixel - the reduction (few
  inputs, a sum per sub-pixel value out) and the commit (those sums in, a
  scatter into the grid) -, other kernels, and the rest (no kernel running: the
  host), each as a share of the passes' time and with its own fit against the
  samples.

The fit's intercept moves +-1-2 ms between runs of 4 renders here (it prints
with its standard error), as kernel times do on a shared machine. Steadier: the
time per pass in which no kernel ran (the passes' seconds less the kernels' own
clocks, per render: Python, numpy, tracing, launches), median over renders.

``--replay both`` renders each seed traced (``MCRT_REPLAY=0``: every wavefront
traced) and replayed (:mod:`mcrt.render.adaptive.frozen`), interleaved, in
alternating order, and fits each side on its own; ``on`` / ``off``: one side only
(``on``, the default, is what a render does).

    python benchmarks/adaptive_pass_cost.py [--renders 6] [--replay on|off|both]
        [--commit-timing] [--max-spp 4096]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")

from mcrt.core import replay  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.core.timing import fit_cost  # noqa: E402
from mcrt.render.adaptive import AdaptiveSettings, pass_time_fit, render_adaptive  # noqa: E402
from mcrt.render.adaptive.sums import PixelSums  # noqa: E402
from mcrt.render.scene import load_scene  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "edges.xml"
#: Untimed renders first: one traces each batch size, the next records it; a
#: seed may reach a batch size another did not.
WARM_UP_SEEDS = (1001, 1001, 1002, 1002)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--renders", type=int, default=6)
    parser.add_argument("--replay", choices=["on", "off", "both"], default="on",
                        help="replayed wavefronts, traced ones (MCRT_REPLAY=0), or both "
                             "interleaved (default: on)")
    parser.add_argument("--max-spp", type=int, default=AdaptiveSettings.max_spp,
                        help="per-pixel budget (benchmarks/adaptive_efficiency.py uses 4096)")
    parser.add_argument("--commit-timing", action="store_true",
                        help="time PixelSums.commit (synchronised: slows the passes)")
    args = parser.parse_args()
    sides = ["off", "on"] if args.replay == "both" else [args.replay]
    scene = load_scene(SCENE, {})
    settings = AdaptiveSettings(max_spp=args.max_spp)
    commit_seconds: list[float] = []
    commit = PixelSums.commit

    def timed_commit(self, pending) -> None:
        dr.sync_thread()
        start = time.perf_counter()
        commit(self, pending)
        dr.sync_thread()
        commit_seconds.append(time.perf_counter() - start)

    if args.commit_timing:
        PixelSums.commit = timed_commit  # type: ignore[method-assign]
    # Warm-ups (the replayed side records its wavefronts), with the kernel history
    # on as in the timed renders: a frozen function records again when Dr.Jit's
    # flags change, which made the first timed render trace every batch size
    # (~2 ms more a pass in it, 0.3-0.5 ms on the fit's intercept).
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    for side in sides:
        os.environ[replay.ENV] = "1" if side == "on" else "0"
        for seed in WARM_UP_SEEDS:  # (other seeds refine with other batch sizes)
            render_adaptive(scene, make_sampler("sobol", settings.min_spp), settings,
                            seed=seed)
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    rows: dict[str, list] = {side: [] for side in sides}
    for seed in range(1, args.renders + 1):
        for side in sides if seed % 2 else sides[::-1]:
            os.environ[replay.ENV] = "1" if side == "on" else "0"
            rows[side].append(_render(scene, settings, seed, commit_seconds))
    print(f"scenes/edges.xml, sobol, default settings but max_spp {args.max_spp}, "
          f"{args.renders} renders after a warm-up, Dr.Jit threads: {dr.thread_count()}")
    for side in sides:
        _report(f"wavefronts replayed ({replay.ENV}=1)" if side == "on"
                else f"wavefronts traced ({replay.ENV}=0)", rows[side])


def _render(scene, settings, seed: int, commit_seconds: list[float]) -> tuple:
    """One timed render: (wall, passes, kernel seconds, commit seconds, Memcpy kernels,
    result); each pass record gets ``kernels``: its kernel seconds by kind."""
    commit_seconds.clear()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # start empty
    history: list[dict] = []

    def on_pass(record) -> None:  # the pass's kernels (its commit ran before its end)
        kernels = dr.kernel_history()
        history.extend(kernels)
        record.kernels = _kinds(kernels, record.active_pixels)

    dr.sync_thread()
    start = time.perf_counter()
    result = render_adaptive(scene, make_sampler("sobol", settings.min_spp), settings,
                             seed=seed, on_pass=on_pass)
    dr.sync_thread()
    wall = time.perf_counter() - start
    history.extend(dr.kernel_history())
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernels = sum(k.get("execution_time", 0.0) for k in history) / 1e3
    copies = sum(k["type"] == dr.KernelType.Memcpy for k in history)
    commit = sum(commit_seconds) if commit_seconds else None  # (None: not timed)
    return wall, len(result.passes), kernels, commit, copies, result


#: What a pass's kernels are (``_kinds``).
KINDS = ("the trace (a lane per sample)", "the reduction (a thread per pixel)",
         "the commit (a thread per pixel)", "other kernels")


def _kinds(kernels: list[dict], pixels: int) -> tuple[float, ...]:
    """Seconds of a pass's kernels by kind: wider than its active pixels (the
    trace); a thread per pixel at most, with more outputs than inputs (the
    reduction: a sum per sub-pixel value out) or not (the commit: those sums in,
    scattered); and the rest (memsets, one-element kernels)."""
    out = [0.0] * len(KINDS)
    for k in kernels:
        size, seconds = int(k.get("size", 0)), k.get("execution_time", 0.0) / 1e3
        if k["type"] != dr.KernelType.JIT or size <= 1:
            out[3] += seconds
        elif size > pixels:
            out[0] += seconds
        else:
            out[1 if k["output_count"] > k["input_count"] else 2] += seconds
    return tuple(out)


def _breakdown(passes: list) -> None:
    """Each kind's share of the passes' time and its own line against samples."""
    total = sum(p.seconds for p in passes)
    samples = [p.samples for p in passes]
    parts = [[p.kernels[i] for p in passes] for i in range(len(KINDS))]
    parts.append([p.seconds - sum(p.kernels) for p in passes])
    for label, seconds in zip((*KINDS, "no kernel running (host)"), parts, strict=True):
        fit = fit_cost(samples, seconds)
        print(f"  {label}: {100 * sum(seconds) / total:.1f}% of the passes' time, "
              f"{1e3 * fit.fixed:.2f} ms + {1e9 * fit.per_unit:.1f} ns x samples")


def _report(title: str, rows: list) -> None:
    passes = [p for *_, r in rows for p in r.passes]
    fit = pass_time_fit(passes)
    se = fit_cost([p.samples for p in passes], [p.seconds for p in passes]).fixed_se
    print(f"\n{title}:\n")
    print("| render | wall [s] | passes | kernel execution [s] | commit [ms] | Memcpy per pass |")
    print("|---:|---:|---:|---:|---:|---:|")
    for i, (wall, count, kernels, commit_s, copies, _) in enumerate(rows):
        shown = "-" if commit_s is None else f"{1e3 * commit_s:.1f}"
        print(f"| {i + 1} | {wall:.3f} | {count} | {kernels:.3f} | {shown} | "
              f"{copies / count:.1f} |")
    idle = [(sum(p.seconds for p in r.passes) - kernels) / count
            for _, count, kernels, _, _, r in rows]
    print(f"time per pass without a kernel running: median {1e3 * statistics.median(idle):.2f}"
          f" ms (renders: {', '.join(f'{1e3 * x:.2f}' for x in idle)})")
    commits = [r[3] for r in rows if r[3] is not None]
    print(f"median: wall {statistics.median(r[0] for r in rows):.3f} s" + (
        f", commit {1e3 * statistics.median(commits):.1f} ms per render" if commits else ""))
    print(f"pass time over {fit['passes']:.0f} passes: {1e3 * fit['intercept']:.1f} "
          f"+- {1e3 * se:.1f} ms + {1e9 * fit['slope']:.1f} ns x samples (R^2 {fit['r2']:.3f})")
    print("where it goes (kernel clocks, all passes):")
    _breakdown(passes)


if __name__ == "__main__":
    main()
