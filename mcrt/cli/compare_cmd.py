"""``mcrt compare``: run a study (scenes x samplers x spp x seeds) and write its report."""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from ..analysis.report import report_files, write_report
from ..analysis.study import load_config, run_study
from ._common import check_output_files, ensure_writable_dir

log = logging.getLogger("mcrt.compare")


def add_parser(commands) -> None:
    p = commands.add_parser(
        "compare", help="run a sampling study and write an HTML/CSV/JSON report",
        description="Run the study described by CONFIG.toml (scenes x samplers x sample counts "
                    "x seeds, see configs/quick.toml): time every render after a warm-up, "
                    "measure MSE, relMSE, variance, bias, CIEDE2000 and aliasing against a "
                    "high-spp reference, fit error-vs-spp and error-vs-time slopes, and write "
                    "report.html, results.csv, results.json and PNG plots into DIR.")
    p.add_argument("config", metavar="CONFIG.toml", help="study configuration (TOML)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="report directory (default: out/compare/<study name>)")
    p.add_argument("--check", action="store_true",
                   help="only validate the configuration (load scenes, make samplers) and exit")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)  # every input error surfaces here, before rendering
    if args.check:
        print(f"{args.config}: OK ({len(config.scenes)} scenes, {len(config.samplers)} samplers, "
              f"{len(config.spp)} sample counts, {len(config.seeds)} seeds: "
              f"{config.renders} renders)")
        return 0
    out = Path(args.output) if args.output else Path("out") / "compare" / config.name
    ensure_writable_dir(out)
    check_output_files(*report_files(out, [s.name for s in config.scenes]).values())

    result = run_study(config, progress=not args.quiet)
    files = write_report(result, out)

    for scene in config.scenes:
        print(f"{scene.name}: log-log slope of MSE vs spp and vs time; best efficiency "
              f"1/(MSE x s)")
        print(f"  {'sampler':14s} {'spp':>7s} {'time':>7s}  {'efficiency':>10s}")
        for sampler in config.samplers:
            fit = result.fit(scene.name, sampler.label)
            print(f"  {sampler.label:14s} {_num(fit['slope_spp'], '+.2f'):>7s} "
                  f"{_num(fit['slope_seconds'], '+.2f'):>7s}  "
                  f"{_num(fit['efficiency_max'], '.3g'):>10s}")
    print(f"study took {result.seconds:.1f} s; wrote {files['report']} "
          f"(and results.csv, results.json, plots in {out})")
    return 0


def _num(value: float, spec: str) -> str:
    return format(value, spec) if math.isfinite(value) else "-"
