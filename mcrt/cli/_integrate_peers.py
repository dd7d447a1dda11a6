"""``mcrt integrate utk`` and ``mcrt integrate funcsamp2d``: the peers' benchmarks.

Definitions and published figures: :mod:`mcrt.analysis.peers`. Each sampler's
figures are printed next to the published row of the same construction
(``independent`` = UTK's white noise / funcsamp2D's random; ``jittered`` and
Mitsuba's ``stratified`` = UTK's stratified; ``sobol`` = funcsamp2D's Owen-
scrambled Sobol'), with ``z = (ours - published) / (se sqrt 2)``: the published
figure is assumed to carry the same standard error as ours (same design).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from ..analysis import peers
from ..core.atomic import atomic_path
from ..core.jsonfile import write_json
from ..core.provenance import csv_values
from ..core.sampling import mitsuba_message, quiet_sampler_warnings
from ..errors import McrtError
from ..samplers.points import point_sets

SUITES = ("utk", "funcsamp2d")
DEFAULT_SAMPLERS = ("independent", "jittered", "sobol", "zsobol", "poisson_disk")


def _points(sampler: str, trials: int, n: int, seed: int, params: dict) -> np.ndarray:
    """``trials`` point sets of ``n`` points (``params``: the user's ``-P``)."""
    own = {"width": trials} if sampler == "zsobol" else {}
    with quiet_sampler_warnings():
        return point_sets(sampler, trials, n, seed=seed, **own, **params)


def _counts(published: tuple[int, ...], args: argparse.Namespace) -> list[int]:
    counts = [n for n in published if args.min_n <= n <= args.max_n]
    if not counts:
        raise McrtError(f"{args.integrand}: no published sample count ({published}) lies in "
                        f"[--min-n, --max-n] = [{args.min_n}, {args.max_n}]")
    return counts


def _z(ours: float, se: float, published: float | None) -> str:
    if published is None or se <= 0:
        return ""
    return f"{(ours - published) / (se * math.sqrt(2.0)):+6.1f}"


def run_utk(args: argparse.Namespace, samplers: list[str], out: Path) -> list[dict]:
    counts = _counts(peers.UTK_COUNTS, args)
    trials = args.trials or peers.UTK_POINT_SETS
    families = {name: make(args.integrands, seed=args.seed)
                for name, make in peers.UTK_FAMILIES.items()}
    print(f"UTK integration test (utk-team/utk): MSE over {args.integrands} random integrands "
          f"x {trials} point sets per N (published: 4096 x 16); +-: standard error; z: "
          "(ours - published) / (se sqrt 2); [E white]: the exact expected white-noise "
          "figure on this database (mean Var[f] / N)")
    pub: float | None
    print(f"{'family':9s} {'sampler':13s} {'N':>5s} {'MSE':>10s} {'+-se':>6s} "
          f"{'published':>10s} {'row':12s} {'ratio':>6s} {'z':>6s}")
    for row_name, table in peers.UTK_PUBLISHED.items():
        for key in families:
            for n in counts:
                print(f"{key:9s} {'[UTK]':13s} {n:5d} {table[key][n]:10.3e} {'':6s} "
                      f"{'':10s} {row_name:12s}")
    for family_name, family in families.items():
        for n in counts:
            expected = family.white_noise_mse(n)
            white = peers.UTK_PUBLISHED["white noise"][family_name][n]
            print(f"{family_name:9s} {'[E white]':13s} {n:5d} {expected:10.3e} {'exact':>6s} "
                  f"{white:10.3e} {'white noise':12s} {expected / white:6.2f}")
    rows = []
    for name in samplers:
        for index, n in enumerate(counts):
            try:
                pts = _points(name, trials, n, (args.seed + index) % (1 << 32), args.params)
            except Exception as error:  # the sampler refuses this count
                print(f"{'':9s} {name:13s} {n:5d}  skipped: {mitsuba_message(error)}")
                continue
            for family_name, family in families.items():
                fig = peers.utk_mse(family.estimates(pts), family.exact)
                row = peers.UTK_ROW_OF.get(name)
                pub = peers.UTK_PUBLISHED[row][family_name].get(n) if row else None
                ratio = f"{fig.mse / pub:6.2f}" if pub else ""
                print(f"{family_name:9s} {name:13s} {pts.shape[1]:5d} {fig.mse:10.3e} "
                      f"{100 * fig.rel_se:5.1f}% {pub or math.nan:10.3e} {row or '-':12s} "
                      f"{ratio:>6s} {_z(fig.mse, fig.stderr, pub):>6s}")
                rows.append({"suite": "utk", "family": family_name, "sampler": name,
                             "n": pts.shape[1], "point_sets": fig.point_sets,
                             "integrands": fig.integrands, "mse": fig.mse,
                             "stderr": fig.stderr, "published": pub, "published_row": row})
    return rows


def run_funcsamp(args: argparse.Namespace, samplers: list[str], out: Path) -> list[dict]:
    counts = _counts(peers.FUNCSAMP_COUNTS, args)
    trials = args.trials or peers.FUNCSAMP_SEQUENCES
    print(f"funcsamp2D (perchristensen/funcsamp2D): mean |error| over {trials} sequences "
          "(published: 100); columns N = " + ", ".join(map(str, counts)))
    print("published quarterdisk curves (errors_quarterdisk_<set>.data):")
    for name, values in peers.FUNCSAMP_PUBLISHED.items():
        cells = " ".join(f"{v:9.2e}" for n, v in zip(peers.FUNCSAMP_COUNTS, values, strict=True)
                         if n in counts)
        print(f"  {name:18s} {cells}")
    errors: dict[str, dict[int, dict[str, float]]] = {}
    for name in samplers:
        errors[name] = {}
        for index, n in enumerate(counts):
            try:
                pts = _points(name, trials, n, (args.seed + index) % (1 << 32), args.params)
            except Exception as error:
                print(f"  {name}: N = {n} skipped: {mitsuba_message(error)}")
                continue
            errors[name][n] = peers.funcsamp_errors(pts)
    rows: list[dict] = []
    print(f"{'function':16s} {'sampler':13s} " + " ".join(f"{n:>9d}" for n in counts)
          + "  slope  published (row)")
    for function in peers.FUNCSAMP:
        for name in samplers:
            curve = [errors[name].get(n, {}).get(function, math.nan) for n in counts]
            ok = [(n, v) for n, v in zip(counts, curve, strict=True) if v == v and v > 0]
            slope = (np.polyfit(np.log([n for n, _ in ok]), np.log([v for _, v in ok]), 1)[0]
                     if len(ok) >= 2 else math.nan)
            pub = ""
            if function == "quarterdisk" and name in peers.FUNCSAMP_ROW_OF:
                src = peers.FUNCSAMP_ROW_OF[name]
                pub = " ".join(f"{v:.2e}" for n, v in zip(peers.FUNCSAMP_COUNTS,
                                                          peers.FUNCSAMP_PUBLISHED[src],
                                                          strict=True)
                               if n in counts) + f" ({src})"
            print(f"{function:16s} {name:13s} " + " ".join(f"{v:9.2e}" for v in curve)
                  + f"  {slope:+5.2f}  {pub}")
            rows.extend({"suite": "funcsamp2d", "family": function, "sampler": name, "n": n,
                         "point_sets": trials, "mean_abs_error": v}
                        for n, v in zip(counts, curve, strict=True))
    print("slope: of ln mean|error| against ln N (the RMSE rate; MSE slope = 2x)")
    return rows


def run(args: argparse.Namespace, samplers: list[str], out: Path, record: dict[str, str]) -> int:
    if args.integrand == "utk":
        rows = run_utk(args, samplers, out)
    else:
        rows = run_funcsamp(args, samplers, out)
    stem = out / f"integrate_{args.integrand}"
    fields = sorted({key for row in rows for key in row})
    made = csv_values(record)  # how the file was made: on every row
    with atomic_path(stem.with_suffix(".csv")) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=[*(fields or ["suite"]), *made])
        writer.writeheader()
        writer.writerows({**row, **made} for row in rows)
    write_json(stem.with_suffix(".json"), {"suite": args.integrand, "seed": args.seed,
                                           "rows": rows, **record})
    print(f"wrote {stem.name}.csv and .json to {out}")
    return 0
