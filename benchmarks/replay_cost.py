"""Replayed (frozen) renders against traced ones and against a plain ``mi.render``.

Small renders of one scene with a new seed each time, as a study renders its
cells: ``mi.render`` (Mitsuba's own sampler and film), ``render_film`` with
``MCRT_REPLAY=0`` (traced every time) and ``render_film`` replayed
(:mod:`mcrt.core.replay`: traced once, then its kernels replayed), all with the
image copied to numpy and ``dr.sync_thread()``. mcrt's protocol
(:func:`mcrt.core.timing.run_interleaved`): three warm-up calls of each, then
``--rounds`` shuffled rounds; prints the medians and the medians of the
per-round ratios with their interquartile range. Goal: replayed <= 0.6x
``mi.render`` for the study-sized render (16x16, 4 spp).

``--study CONFIG`` also runs ``mcrt -q compare CONFIG`` as whole processes,
alternately with replay off and on (``--study-runs`` pairs, after one untimed
run that fills the kernel and reference caches), and checks that their
results.json agree in every field but the timings. With ``--baseline CHECKOUT``
(another checkout of mcrt, e.g. ``git worktree add /tmp/before REV``) the pairs
are this tree against that checkout's code (``PYTHONPATH``) instead: what a
change did to a whole study's wall time.

    python benchmarks/replay_cost.py                          # ~1 minute
    python benchmarks/replay_cost.py --study configs/quick.toml --study-runs 3
    python benchmarks/replay_cost.py --res --study configs/quick.toml --baseline /tmp/before
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.core import replay  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.core.timing import quartiles, run_interleaved  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
#: Fields of results.json that are timings (differ between any two runs).
TIMED = ("seconds", "efficiency", "time", "environment", "date", "cached")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, nargs="*", default=[16, 64],
                        help="film sizes of the render rows (none: only the study)")
    parser.add_argument("--spp", type=int, default=4)
    parser.add_argument("--samplers", nargs="+", default=["jittered", "sobol", "independent"])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--study", type=Path, help="a study configuration to time end to end")
    parser.add_argument("--study-runs", type=int, default=2)
    parser.add_argument("--baseline", type=Path,
                        help="with --study: time this tree against another checkout of mcrt")
    args = parser.parse_args()
    if args.res:
        print(f"{args.rounds} rounds after 3 warm-up calls; ratio: median of per-round ratios "
              f"(IQR)\n")
        print("| render | sampler | mi.render [ms] | traced [ms] | replayed [ms] | traced / "
              "mi.render | replayed / mi.render | replayed / traced |\n|---|---|---:|---:|---:|"
              "---|---|---|")
    for res in args.res:
        for name in args.samplers:
            row(res, args.spp, name, args.rounds)
    if args.study is not None:
        study(args.study, args.study_runs, args.baseline)


def row(res: int, spp: int, name: str, rounds: int) -> None:
    scene = mi.load_file(str(CORNELL), res=str(res), sampler=name, spp=str(spp))
    seeds = iter(range(1, 1 << 30))

    def plain() -> None:
        np.asarray(mi.render(scene, seed=next(seeds)))

    def ours(on: bool):
        def render() -> None:
            os.environ[replay.ENV] = "1" if on else "0"
            render_film(scene, make_sampler(name, spp), seed=next(seeds))
        return render

    samples = run_interleaved([plain, ours(False), ours(True)], rounds, warmup=3,
                              sync=dr.sync_thread)
    wall = [[s.wall for s in case] for case in samples]
    ms = [statistics.median(w) * 1e3 for w in wall]

    def ratio(a: int, b: int) -> str:
        r = [x / y for x, y in zip(wall[a], wall[b], strict=True)]
        q1, q3 = quartiles(r)
        return f"{statistics.median(r):.3f} ({q1:.3f}-{q3:.3f})"

    print(f"| {res}x{res}, {spp} spp | `{name}` | {ms[0]:.2f} | {ms[1]:.2f} | {ms[2]:.2f} | "
          f"{ratio(1, 0)} | {ratio(2, 0)} | {ratio(2, 1)} |", flush=True)


def _untimed(value):
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if not any(w in k for w in TIMED)}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def study(config: Path, runs: int, baseline: Path | None = None) -> None:
    """Whole ``mcrt compare`` processes, alternately: replay off ("0") and on ("1"),
    or the ``baseline`` checkout ("0") and this tree ("1")."""
    times: dict[str, list[float]] = {"0": [], "1": []}
    results: dict[str, object] = {}
    with tempfile.TemporaryDirectory() as tmp:
        def run(flag: str, index: int) -> float:
            out = Path(tmp) / f"{flag}-{index}"
            env = {**os.environ, replay.ENV: flag, "MCRT_CACHE_DIR": str(Path(tmp) / flag)}
            if baseline is not None:
                env[replay.ENV] = "1"
                if flag == "0":
                    env["PYTHONPATH"] = str(baseline.resolve())
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "mcrt", "-q", "compare", str(config), "-o",
                            str(out)], check=True, env=env, stdout=subprocess.DEVNULL)
            seconds = time.perf_counter() - start
            results.setdefault(flag, _untimed(json.loads((out / "results.json").read_text())))
            return seconds

        run("1", -1)  # kernels and references cached (each side its own cache)
        run("0", -1)
        for i in range(runs):
            for flag in ("0", "1") if i % 2 == 0 else ("1", "0"):
                times[flag].append(run(flag, i))
    off, on = statistics.median(times["0"]), statistics.median(times["1"])
    same = results["0"] == results["1"]
    names = (f"{baseline}", "this tree") if baseline is not None else ("replay off", "on")
    runs_text = " / ".join(", ".join(f"{t:.1f}" for t in times[f]) for f in ("0", "1"))
    print(f"\n`mcrt -q compare {config}` ({runs} alternated pairs after a warm-up run each): "
          f"{names[0]} {off:.1f} s, {names[1]} {on:.1f} s (runs {runs_text}): "
          f"**{on / off:.3f}x**; results.json equal but for timings: {same}")


if __name__ == "__main__":
    main()
