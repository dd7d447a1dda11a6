"""Where a whole study's wall time goes: kernels, scoring, the report, imports.

Runs ``mcrt -q compare CONFIG`` in this process (kernels and references cached
by an untimed first run, as ``replay_cost.py --study`` times it) under cProfile
with Dr.Jit's kernel history on, and prints the wall time, the time Dr.Jit's
kernels ran (their own clocks, summed over kernel launches) and the cumulative
time of the study's parts. The profiler adds some overhead to Python-heavy
parts (scoring, the report); kernel time is measured by Dr.Jit, not by it.

    python benchmarks/study_breakdown.py [configs/quick.toml] 2>/dev/null
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import pstats
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (label, function name as cProfile lists it (file suffix, name)), in the order printed.
PARTS = [
    ("renders (render_film)", ("mcrt/core/render.py", "render_film")),
    ("scoring (score_seed)", ("mcrt/analysis/study/seeds.py", "score_seed")),
    ("  aliasing score", ("mcrt/analysis/aliasing.py", "aliasing_score")),
    ("  CIEDE2000", ("mcrt/analysis/metrics.py", "delta_e_2000")),
    ("report (write_report)", ("mcrt/analysis/report.py", "write_report")),
    ("  figures (save_figure)", ("mcrt/analysis/plots.py", "save_figure")),
    ("  viewer data (FLIP, files)", ("mcrt/analysis/viewer/data.py", "write_viewer_data")),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", nargs="?", default=ROOT / "configs" / "quick.toml", type=Path,
                        help="a study configuration (default: the repository's configs/quick.toml)")
    args = parser.parse_args()
    import drjit as dr

    from mcrt.cli import main as mcrt_main

    with tempfile.TemporaryDirectory() as out:
        _run(mcrt_main, args.config, Path(out) / "warm")  # kernels and references cached
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # (emptied)
        profile = cProfile.Profile()
        start = time.perf_counter()
        profile.enable()
        _run(mcrt_main, args.config, Path(out) / "timed")
        profile.disable()
        wall = time.perf_counter() - start
        history = dr.kernel_history()
    kernels = sum(k.get("execution_time", 0.0) for k in history) / 1e3
    stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    print(f"mcrt -q compare {args.config}: {wall:.1f} s under the profiler")
    print(f"  Dr.Jit kernels ran {kernels:.1f} s ({len(history)} launches)")
    for label, (suffix, name) in PARTS:
        cumulative = sum(entry[3] for (path, _, func), entry in stats.items()
                         if func == name and path.endswith(suffix))
        print(f"  {label}: {cumulative:.1f} s")


def _run(mcrt_main, config: Path, out: Path) -> None:
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # (the study's own summary)
            code = mcrt_main(["-q", "compare", str(config), "-o", str(out)])
    except SystemExit as stop:
        code = stop.code
    if code not in (0, None):  # (mcrt's main returns its exit status; its error is printed)
        raise SystemExit(f"mcrt -q compare {config} failed (exit status {code})")


if __name__ == "__main__":
    main()
