"""What running on Dask costs and gains: the same reference and study in this
process and on ``local:1`` / ``local:2`` clusters, side by side.

Modes (each timed after a warm-up run that compiles kernels and plans scenes):

* ``here:1`` / ``here:C``: in this process with 1 / C Dr.Jit threads (C = ``os.cpu_count()``);
* ``local:1`` / ``local:2``: a LocalCluster of 1 / 2 worker processes with cores / N
  Dr.Jit threads each: on 2 cores, one worker with 2 threads / two with 1 (cluster
  start-up is timed separately, not in the runs).

Rounds are interleaved (every mode once per round, shuffled: mcrt.core.timing), ratios
are medians. Prints:

* the **per-task overhead** of the cluster: ``(local:1 - here:C) / tasks`` (the
  same threads, the same tasks: what scheduling, transfers and the client's fold
  add per task), for the reference and the study, and as a share of a task;
* **throughput** (tasks/s, samples/s) and **speed-up** of ``local:2`` against
  ``here:C`` (goal: within 1.1x) and against ``here:1``;
* the study's times in each mode.

    python benchmarks/cluster_scaling.py [--rounds 3] [--res 128] [--spp 1024]
    python benchmarks/cluster_scaling.py --quick     # smoke run
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"

STUDY = """
name = "scaling"
spp = [4, 16, 64]
seeds = 4
image_spp = 16
samplers = ["independent", "jittered", "sobol"]

[reference]
spp = 256

[[scenes]]
path = "{scene}"
name = "cornell_box"
params = {{ res = {res} }}
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--res", type=int, default=128, help="reference film size")
    parser.add_argument("--spp", type=int, default=1024, help="reference samples per pixel")
    parser.add_argument("--spp-per-pass", type=int, default=64, help="samples per task")
    parser.add_argument("--study-res", type=int, default=128)
    parser.add_argument("--quick", action="store_true", help="tiny sizes, one round")
    args = parser.parse_args()
    if args.quick:
        args.rounds, args.res, args.spp, args.spp_per_pass, args.study_res = 1, 32, 64, 16, 32

    work = Path(tempfile.mkdtemp(prefix="mcrt_scaling_"))  # the study's config; the cache
    atexit.register(shutil.rmtree, work, ignore_errors=True)
    os.environ.setdefault("MCRT_CACHE_DIR", str(work / "cache"))  # (unless the user's is set)
    import drjit as dr

    import mcrt  # noqa: F401
    from mcrt.analysis.reference import get_reference
    from mcrt.analysis.study import load_config, run_study
    from mcrt.core.cluster import DaskExecutor
    from mcrt.core.timing import round_orders

    config_path = work / "scaling.toml"
    config_path.write_text(STUDY.format(scene=CORNELL, res=args.study_res))
    config = load_config(config_path)
    params = {"res": str(args.res)}
    tasks = args.spp // args.spp_per_pass

    start = time.perf_counter()
    clusters = {"local:1": DaskExecutor.connect("local:1"),
                "local:2": DaskExecutor.connect("local:2")}
    startup = (time.perf_counter() - start) / 2
    cores = os.cpu_count() or 1
    modes = {"here:1": (None, 1), f"here:{cores}": (None, cores),
             "local:1": (clusters["local:1"], cores), "local:2": (clusters["local:2"], cores)}
    here = f"here:{cores}"

    def reference(mode: str) -> float:
        executor, threads = modes[mode]
        dr.set_thread_count(threads)  # (cluster modes: this client's own threads)
        t = time.perf_counter()
        get_reference(CORNELL, params, spp=args.spp, spp_per_pass=args.spp_per_pass,
                      cache=False, executor=executor)
        return time.perf_counter() - t

    def study(mode: str) -> float:
        executor, threads = modes[mode]
        dr.set_thread_count(threads)  # (cluster modes: this client's own threads)
        t = time.perf_counter()
        run_study(config, executor=executor)
        return time.perf_counter() - t

    print(f"reference: {args.res}^2, {args.spp} spp in {tasks} tasks of {args.spp_per_pass} spp;"
          f" study: {config.cells} cells x {len(config.seeds)} seeds = "
          f"{config.cells * len(config.seeds)} tasks; cluster start-up {startup:.1f} s",
          flush=True)
    for mode in modes:  # warm-up: kernels, scenes, the study's reference (cached)
        reference(mode)
        study(mode)
    ref_times: dict[str, list[float]] = {m: [] for m in modes}
    study_times: dict[str, list[float]] = {m: [] for m in modes}
    for r, shuffled in enumerate(round_orders(len(modes), args.rounds)):  # the protocol's
        for mode in (list(modes)[i] for i in shuffled):
            ref_times[mode].append(reference(mode))
            study_times[mode].append(study(mode))
        print(f"  round {r + 1}: " + ", ".join(f"{m} {ref_times[m][-1]:.2f}/"
                                               f"{study_times[m][-1]:.2f} s" for m in modes),
              flush=True)
    for executor in clusters.values():
        executor.close()

    med = {m: statistics.median(v) for m, v in ref_times.items()}
    smed = {m: statistics.median(v) for m, v in study_times.items()}
    samples = args.res * args.res * args.spp
    study_tasks = config.cells * len(config.seeds)
    print("\n| mode | reference [s] | tasks/s | M samples/s | study [s] | study tasks/s |")
    print("|---|---:|---:|---:|---:|---:|")
    for m in modes:
        print(f"| {m} | {med[m]:.2f} | {tasks / med[m]:.1f} | {samples / med[m] / 1e6:.2f} | "
              f"{smed[m]:.2f} | {study_tasks / smed[m]:.1f} |")
    for name, times, count in (("reference", med, tasks), ("study", smed, study_tasks)):
        overhead = (times["local:1"] - times[here]) / count
        task = times[here] / count
        print(f"{name}: per-task overhead (local:1 - {here}) {overhead * 1e3:.1f} ms per task "
              f"= {100 * overhead / task:.1f}% of its {task:.2f} s tasks, "
              f"{100 * overhead:.1f}% of a 1 s task (goal <= 5%); local:2 / {here} "
              f"{times['local:2'] / times[here]:.3f} (goal <= 1.1); speed-up of local:2 over "
              f"here:1 {times['here:1'] / times['local:2']:.2f}x")

if __name__ == "__main__":
    main()
