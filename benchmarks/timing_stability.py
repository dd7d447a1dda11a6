"""Does a study's time half hold? The same small study twice: quiet, then with busy
processes on every core for the middle part of the run.

The study times its renders by mcrt's protocol (:mod:`mcrt.core.timing`:
warm-ups, every sampler of a sample count interleaved in shuffled rounds, medians,
paired ratios). The check: each sampler's efficiency ratio to the baseline at
spp >= ``--min-spp`` agrees between the two runs (their difference within the
two 95% intervals combined, and within 10%), or, where it does not, the loaded
run's report names that cell (or the baseline's) as disturbed. For contrast it
prints how far the *absolute* efficiencies (not paired) moved between the runs,
and the quiet run's interval half-widths.

    python benchmarks/timing_stability.py                 # ~1 min on 2 cores
    python benchmarks/timing_stability.py --busy 0        # both runs quiet (noise floor)
    python benchmarks/timing_stability.py --scene scenes/checkerboard.xml \
        --params "{ width = 320, height = 240 }"        # direct light: MSE tight over seeds

The reference is shared through a private cache (rendered once, by the first run).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CONFIG = """
name = "timing-stability"
spp = {spp}
seeds = {seeds}
time_rounds = {rounds}
samplers = {samplers}
baseline = "{baseline}"
[reference]
spp = {ref_spp}
[[scenes]]
path = "{scene}"
params = {params}
"""


def busy_for(seconds: float, count: int) -> None:
    """``count`` processes spinning for ``seconds`` (then killed)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    time.sleep(seconds)
    for p in procs:
        p.kill()
        p.wait()


def usable_cores() -> int:
    """The cores this process may run on (its affinity: ``taskset``, a cpuset), as
    :func:`mcrt.core.machine.machine` counts them; else every core."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def run(config: Path, out: Path, env: dict[str, str], busy: int, busy_start: float,
        busy_seconds: float) -> tuple[dict, float]:
    """One study; with ``busy`` > 0, that many spinning processes from
    ``busy_start`` seconds after its start, for ``busy_seconds``."""
    start = time.perf_counter()
    load = None
    if busy:
        load = threading.Timer(busy_start, busy_for, (busy_seconds, busy))
        load.start()
    done = subprocess.run([sys.executable, "-m", "mcrt", "-q", "compare", str(config),
                           "-o", str(out)], env=env, capture_output=True, text=True)
    if load is not None:
        load.join()
    if done.returncode != 0:
        sys.exit(f"study failed:\n{done.stderr[-3000:]}")
    seconds = time.perf_counter() - start
    return json.loads((out / "results.json").read_text()), seconds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=str(ROOT / "scenes" / "cornell_box.xml"))
    p.add_argument("--params", default="{ res = 64 }",
                   help="the scene's parameters, a TOML inline table (default: %(default)s)")
    p.add_argument("--samplers", default="independent,jittered,sobol,multijitter")
    p.add_argument("--baseline", default="independent")
    p.add_argument("--spp", default="4,16,64,256")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--min-spp", type=int, default=16)
    p.add_argument("--busy", type=int, default=usable_cores(),
                   help="spinning processes during the loaded run (default: one per core "
                        "this process may run on, %(default)s here)")
    args = p.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        config = root / "study.toml"
        spp = [int(s) for s in args.spp.split(",")]
        config.write_text(CONFIG.format(
            spp=spp, seeds=args.seeds, rounds=args.rounds, baseline=args.baseline,
            samplers=json.dumps(args.samplers.split(",")), ref_spp=16 * max(spp),
            scene=Path(args.scene).resolve(), params=args.params))
        env = {**os.environ, "MCRT_CACHE_DIR": str(root / "cache")}
        # Untimed first run: the reference and the kernel cache, so both timed runs are warm.
        run(config, root / "warm", env, 0, 0, 0)
        quiet, quiet_s = run(config, root / "quiet", env, 0, 0, 0)
        loaded, loaded_s = run(config, root / "loaded", env, args.busy, 0.25 * quiet_s,
                               0.5 * quiet_s)
    report(args, quiet, loaded, quiet_s, loaded_s)


def _cells(data: dict) -> dict[tuple[str, int], dict]:
    return {(c["sampler"], c["spp_requested"]): c for c in data["cells"]}


def report(args: argparse.Namespace, quiet: dict, loaded: dict, quiet_s: float,
           loaded_s: float) -> None:
    a, b = _cells(quiet), _cells(loaded)
    print(f"study: {args.samplers} on {Path(args.scene).name} {args.params}, spp "
          f"{args.spp}, {args.seeds} seeds, {args.rounds} rounds; quiet run {quiet_s:.0f} s, "
          f"loaded run {loaded_s:.0f} s ({args.busy} busy processes for the middle half)")
    disturbed = loaded["time_protocol"]["disturbed"]
    print(f"loaded run's report says timing was disturbed: {disturbed} "
          f"({len(loaded['time_protocol']['doubtful_cells'])} cells named); quiet run: "
          f"{quiet['time_protocol']['disturbed']}")
    print()
    named = {(d["sampler"], d["spp"]) for d in loaded["time_protocol"]["doubtful_cells"]}
    print("| sampler | spp | ratio quiet [95%] | ratio loaded [95%] | change | agree | "
          "named in loaded report | quiet half-width | absolute efficiency change |")
    print("|---|---:|---|---|---:|---|---|---:|---:|")
    worst, held, widest = 0.0, True, 0.0
    for key in sorted(a, key=lambda k: (k[1], k[0])):
        sampler, spp = key
        if sampler == args.baseline or spp < args.min_spp or key not in b:
            continue
        ca, cb = a[key], b[key]
        ra, rb = ca["efficiency_ratio"], cb["efficiency_ratio"]
        if ra is None or rb is None:
            continue
        change = rb / ra - 1
        # agree: the two ratios' difference is within their combined 95% uncertainty
        # (log half-widths added in quadrature) and within 10%
        wa = math.log(ca["efficiency_ratio_high"] / ra)
        wb = math.log(cb["efficiency_ratio_high"] / rb)
        inside = abs(math.log(rb / ra)) <= math.hypot(wa, wb) and abs(change) <= 0.10
        flagged = (sampler, cb["spp"]) in named or (args.baseline, cb["spp"]) in named
        half = max(ra / ca["efficiency_ratio_low"] - 1, ca["efficiency_ratio_high"] / ra - 1)
        absolute = cb["efficiency"] / ca["efficiency"] - 1
        worst = max(worst, abs(change))
        widest = max(widest, half)
        held &= inside or flagged
        print(f"| {sampler} | {ca['spp']} | {_iv(ca)} | {_iv(cb)} | {100 * change:+.1f}% | "
              f"{'yes' if inside else 'no'} | {'yes' if flagged else 'no'} | "
              f"{100 * half:.1f}% | {100 * absolute:+.1f}% |")
    print()
    print(f"largest change of a ratio: {100 * worst:.1f}%; widest quiet half-width "
          f"{100 * widest:.1f}%; goal (every ratio agrees within the intervals and 10%, or "
          f"its cell or the baseline's is named in the loaded report): "
          f"{'met' if held else 'NOT met'}")


def _f(v: float | None) -> str:
    return f"{v:.3f}" if v is not None and math.isfinite(v) else "-"


def _iv(c: dict) -> str:
    return (f"{_f(c['efficiency_ratio'])} [{_f(c['efficiency_ratio_low'])}, "
            f"{_f(c['efficiency_ratio_high'])}]")


if __name__ == "__main__":
    main()
