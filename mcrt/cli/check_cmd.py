"""``mcrt check``: does a sampler keep the sampler contract, its claims and the statistics?"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.progress import Progress
from ..core.sampling import check_sampler_name
from . import SUMMARIES, _common
from ._common import ensure_writable_dir, examples, non_negative_int, positive_int, sampler_choices


def add_parser(commands) -> None:
    p = commands.add_parser(
        "check", help=SUMMARIES["check"],
        description="Runs the variance-comparison test suite on sampler NAME (mcrt's, "
                    "Mitsuba's or one a --plugin or register_sampler brings in), with fixed "
                    "seeds: the sampler contract (determinism, values in [0, 1), clone, fork, "
                    "seeding, pixels that share no values), the properties the sampler "
                    "claims (stratified, latin, net, min_distance, progressive, quadrature: "
                    "checked exactly on the points of "
                    "real pixels), unbiasedness on integrands with known values (t tests with "
                    "Holm's correction, also across two dimensions; a quadrature sampler's "
                    "film terms are reported, not tested), the MSE rate against N (no worse "
                    "than independent sampling), discrepancy and low-frequency power relative "
                    "to independent points. A sampler that serves only some sample counts (a "
                    "pointset file's set sizes) is checked at those. Prints a table; with -o, "
                    "writes report.html, results.json and figures to DIR. Exit status 0 when "
                    "every check holds, 1 when one fails.",
        epilog=examples("mcrt check jittered",
                        "mcrt check jittered -P jitter=0.5 -o out/check_jittered",
                        "mcrt check ldsampler --quick",
                        "mcrt check pointset -P filename=sets.npy --spp 64"))
    p.add_argument("sampler", metavar="NAME", help=f"sampler: one of {sampler_choices()}")
    p.add_argument("-P", "--param", action="append", metavar="KEY=VALUE",
                   help="sampler parameter, e.g. -P jitter=0.5; repeatable")
    p.add_argument("--quick", action="store_true",
                   help="the tests' budget: 16x fewer trials, counts up to 1024 (well under "
                        "a second; less power to find a bias)")
    p.add_argument("--spp", type=positive_int, metavar="N",
                   help="samples per pixel of the contract, unbiasedness, discrepancy and "
                        "spectrum checks (default: 16 for the first two, 256 for the others, "
                        "or the nearest count the sampler serves); the sampler must serve N")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                   help="seed of every check (default 0)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="write report.html, results.json and the figures to DIR")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..analysis.check import Subject, checks_for, run_checks
    from ..analysis.check_report import table_lines, verdict, write_report

    name = check_sampler_name(args.sampler)
    params = _common.parse_sampler_params(args.param, "--param")
    out = None
    if args.output:
        out = ensure_writable_dir(Path(args.output))
        _common.require_space(out, _common.PLOTS_BYTES, "the report")
    rows = len(checks_for(Subject(name, params)))
    with Progress(rows, not args.quiet, unit="check", desc=f"check {name}") as bar:
        def progress(row: str) -> None:
            bar.postfix(row)
            bar.update()
        results = run_checks(name, params, quick=args.quick, seed=args.seed, progress=progress,
                             spp=args.spp)
    extra = "".join(f" {k}={v}" for k, v in params.items())
    print(f"check {name}{extra}: seed {args.seed}{', quick' if args.quick else ''}"
          f"{f', --spp {args.spp}' if args.spp else ''}")
    print("\n".join(table_lines(results)))
    print(verdict(results))
    if out is not None:
        record = _common.recorded(args, name, *_common.param_words("-P", args.param),
                                  *(["--quick"] if args.quick else []),
                                  *(["--spp", args.spp] if args.spp else []), "--seed", args.seed)
        files = write_report(out, name, params, args.seed, args.quick, results, args.spp,
                             record)
        print(f"wrote {', '.join(files)} to {out}")
    return 1 if any(r.status == "FAIL" for r in results) else 0
