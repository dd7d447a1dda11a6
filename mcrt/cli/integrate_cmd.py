"""``mcrt integrate``: the lecture's Monte-Carlo integration bench, per sampler."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from ..analysis import integrands
from ..analysis.integrands import Integrand, integrand_names, make_integrand
from ..analysis.integrate import (
    DEFAULT_TRIALS,
    POINT_BUDGET,
    run_convergence,
    time_samplers,
)
from ..analysis.metrics import RESOLVED_FACTOR
from ..core.atomic import atomic_path
from ..core.jsonfile import write_json
from ..core.progress import Progress
from ..core.provenance import csv_values, png_text
from ..core.sampling import check_sampler_name
from ..errors import McrtError
from . import SUMMARIES, _common, _integrate_peers
from ._common import ensure_writable_dir, examples, non_negative_int, positive_int

DEFAULT_SAMPLERS = ("independent", "jittered", "poisson_disk")

#: Published MSE rates, for the printed comparison (None: no single rate).
EXPECTED_SLOPES = {
    "independent": {"pi": -1.0, "disk": -1.0, "gaussian": -1.0},
    "jittered": {"pi": -1.5, "disk": -1.5, "gaussian": -2.0},
    "stratified": {"pi": -1.5, "disk": -1.5, "gaussian": -2.0},
}

#: Largest trial count accepted (Mitsuba's samplers need pixel indices < 2^16).
MAX_TRIALS = 1 << 16


def add_parser(commands) -> None:
    p = commands.add_parser(
        "integrate", help=SUMMARIES["integrate"],
        description="Estimates an integral over the unit square with N samples of one pixel, "
                    "for N = MIN, 4 MIN, ..., <= MAX; many pixels are independent trials, "
                    "giving the MSE and its uncertainty. Prints a table and the fitted slope "
                    "of MSE against N per sampler, and writes integrate_<INTEGRAND>.png/.csv/"
                    ".json to DIR. pi: 4 x quarter-disc indicator (estimates pi); disk: "
                    "indicator of a disc (an edge); gaussian: a smooth bump. The peers' "
                    "benchmarks: utk (UTK's random Heaviside and Gaussian integrands, MSE at "
                    "N = 16/256/4096 next to UTK's published table) and funcsamp2d "
                    "(Christensen's 18 test functions, mean |error| at N = 16..1024). Your own: "
                    "a name a --plugin file registers (mcrt.register_integrand), or "
                    "FILE.py:FUNCTION for a function f(x, y) of numpy arrays in FILE.py; "
                    "without --exact its exact value is estimated (docs/integrate.md).",
        epilog=examples("mcrt integrate disk",
                        "mcrt integrate gaussian --sampler jittered,sobol --max-n 16384",
                        "mcrt integrate utk", "mcrt integrate funcsamp2d",
                        "mcrt integrate mine --plugin my_integrands.py",
                        "mcrt integrate my_integrands.py:corner --exact 0.5"))
    choices = (*integrand_names(), *_integrate_peers.SUITES)
    p.add_argument("integrand", metavar="INTEGRAND",
                   help=f"one of {', '.join(choices)}, one a --plugin registers, or "
                        f"FILE.py:FUNCTION")
    p.add_argument("--sampler", default=None, metavar="NAME[,NAME...]",
                   help=f"comma-separated samplers (default {','.join(DEFAULT_SAMPLERS)}; utk / "
                        f"funcsamp2d: {','.join(_integrate_peers.DEFAULT_SAMPLERS)})")
    p.add_argument("-P", "--param", action="append", metavar="KEY=VALUE",
                   help="a parameter of every --sampler, e.g. -P jitter=0.5 or, for your own "
                        "point sets, --sampler pointset -P filename=sets.npy; repeatable")
    p.add_argument("--min-n", type=positive_int, default=16, metavar="N",
                   help="smallest sample count (default 16)")
    p.add_argument("--max-n", type=positive_int, default=65536, metavar="N",
                   help="largest sample count (default 65536)")
    p.add_argument("--trials", type=positive_int, default=None, metavar="P",
                   help=f"pixels (independent trials) per N (default {DEFAULT_TRIALS}); fewer "
                        "at large N, see --budget; utk / funcsamp2d: point sets per N (default "
                        "16 / 100, as published)")
    p.add_argument("--integrands", type=positive_int, default=4096, metavar="M",
                   help="utk: random integrands per family (default 4096, as published)")
    p.add_argument("--budget", type=positive_int, default=POINT_BUDGET, metavar="POINTS",
                   help=f"at most this many points per N and sampler (default {POINT_BUDGET}; "
                        "trials = min(P, POINTS / N), at least 16)")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument("--exact", type=float, default=None, metavar="VALUE",
                   help="the exact integral of a FILE.py:FUNCTION integrand (default: "
                        "estimated, and its error subtracted from each MSE)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default out/integrate_<INTEGRAND>)")
    p.set_defaults(run=run)


def sample_counts(min_n: int, max_n: int) -> list[int]:
    """``min_n * 4^i`` up to ``max_n``."""
    counts, n = [], min_n
    while n <= max_n:
        counts.append(n)
        n *= 4
    return counts


def run(args: argparse.Namespace) -> int:

    peer = args.integrand in _integrate_peers.SUITES
    args.params = _common.parse_sampler_params(args.param, "--param")
    if args.sampler is None:
        args.sampler = ",".join(_integrate_peers.DEFAULT_SAMPLERS if peer else DEFAULT_SAMPLERS)
    samplers = [check_sampler_name(s.strip()) for s in args.sampler.split(",") if s.strip()]
    if not samplers:
        raise McrtError("--sampler: give at least one sampler")
    if len(set(samplers)) != len(samplers):
        raise McrtError("--sampler: a sampler is listed twice")
    if args.min_n > args.max_n:
        raise McrtError(f"--min-n ({args.min_n}) is larger than --max-n ({args.max_n})")
    if args.max_n > 1 << 20:
        raise McrtError(f"--max-n: at most {1 << 20}, got {args.max_n}")
    if args.trials is not None and (args.trials < 2 or args.trials > MAX_TRIALS):
        raise McrtError(f"--trials: between 2 and {MAX_TRIALS}, got {args.trials}")
    if args.integrands > 1 << 16:
        raise McrtError(f"--integrands: at most {1 << 16}, got {args.integrands}")
    counts = sample_counts(args.min_n, args.max_n)
    if args.params:
        for name in samplers:
            _check_params(name, counts, args.params)
    if peer and args.exact is not None:
        raise McrtError(f"--exact: only for a FILE.py:FUNCTION integrand, not {args.integrand}")
    if peer and args.integrand in integrand_names():
        raise McrtError(f"integrand name {args.integrand!r} is the peers' benchmark's: "
                        f"register yours under another name")
    integrand, word = (None, args.integrand) if peer else _integrand(args)
    target = Path(args.output or f"out/integrate_{integrand.name if integrand else word}")
    with _common.removed_if_refused(target):  # a refused command leaves no folder
        out = ensure_writable_dir(target)
        _common.require_space(out, _common.PLOTS_BYTES, "the plots")
    record = _common.recorded(args, word, "--sampler", ",".join(samplers),
                              *(["--exact", args.exact] if args.exact is not None else []),
                              *_common.param_words("-P", args.param),
                              "--min-n", args.min_n, "--max-n", args.max_n,
                              *(["--trials", args.trials] if args.trials is not None else []),
                              "--integrands", args.integrands, "--budget", args.budget,
                              "--seed", args.seed)
    if integrand is None:
        return _integrate_peers.run(args, samplers, out, record)
    if args.trials is None:
        args.trials = DEFAULT_TRIALS

    bar = Progress(len(counts) * len(samplers), not args.quiet, unit="N", desc="integrate")
    results = {}
    with bar:
        for name in samplers:
            bar.postfix(name)
            results[name] = run_convergence(
                name, [integrand], counts, max_trials=args.trials, budget=args.budget,
                seed=args.seed, timed=False, progress=bar.update, **args.params)[integrand.name]
        bar.postfix("timing (interleaved rounds)")
        time_samplers(results.values(), rounds=3, seed=args.seed, **args.params)

    _print_table(integrand, results)
    _write_outputs(out, args, integrand, results, record)
    return 0


def _integrand(args: argparse.Namespace) -> tuple[Integrand, str]:
    """The integrand ``args.integrand`` names and its word in the recorded command:
    a registered name, or ``FILE.py:FUNCTION`` (the file run as a plugin, by
    :mod:`mcrt.plugins`; recorded by its absolute path)."""
    spec = args.integrand
    path, colon, function = spec.rpartition(":")
    if not (colon and path.endswith(".py")):
        if spec not in integrand_names():
            raise McrtError(f"unknown integrand {spec!r}; choose one of: "
                            f"{', '.join((*integrand_names(), *_integrate_peers.SUITES))}, "
                            f"or FILE.py:FUNCTION")
        if args.exact is not None:
            raise McrtError("--exact: only for a FILE.py:FUNCTION integrand (a registered one "
                            "states its own)")
        return integrands.integrand(spec), spec
    from .. import plugins

    module = plugins.load_plugin(path, quiet=True)
    found = getattr(module, function, None)
    if found is None:
        defined = [k for k, v in vars(module).items() if not k.startswith("_") and (
            isinstance(v, Integrand) or getattr(v, "__module__", "") == module.__name__)]
        raise McrtError(f"{path}: defines no {function!r} (it defines: "
                        f"{', '.join(defined) or 'nothing callable'})")
    if isinstance(found, Integrand) and args.exact is not None:
        raise McrtError(f"--exact: {function} is an Integrand, which states its exact value")
    made = integrands.integrand(found) if isinstance(found, Integrand) else \
        make_integrand(found, args.exact, name=function)
    return made, f"{Path(path).expanduser().resolve()}:{function}"


def _check_params(sampler: str, counts: list[int], params: dict) -> None:
    """Refuse ``-P`` parameters that ``sampler`` cannot be made with at any count
    (a count it cannot make is skipped later, with the reason, as without ``-P``)."""
    from ..core.sampling import make_sampler, quiet_sampler_warnings

    first: McrtError | None = None
    for n in counts:
        try:
            with quiet_sampler_warnings():
                make_sampler(sampler, n, **params)
            return
        except McrtError as error:
            first = first or error
    raise McrtError(f"-P: {first}")


def _interval_text(low: float, high: float, spec: str) -> str:
    """``[low, high]``; ``exact`` for a zero-width interval (a deterministic estimator)."""
    return "exact" if low == high else f"[{low:{spec}}, {high:{spec}}]"


def _print_table(integrand: Integrand, results) -> None:
    exact = f"exact {integrand.exact:.12g}"
    if integrand.exact_method:
        exact = (f"exact value {integrand.exact:.12g} +- {integrand.exact_error:.2g}, "
                 f"{integrand.exact_method}")
    print(f"integrand {integrand.name}: {integrand.description}; {exact}")
    if integrand.floor > 0:
        print(f"the estimated exact value's squared error, the floor {integrand.floor:.3g}, "
              f"adds to every MSE: it is subtracted before the slope fit, and an MSE below "
              f"{RESOLVED_FACTOR:g} x floor is beyond what the estimate resolves (marked "
              f"'unresolved', left out of the fit)")
    print("estimate and |error|: pixel 0 (one run of the estimator); RMSE over all trials "
          "with its 95% interval (chi-square on min(2 / se_log^2, trials) degrees of freedom)")
    header = (f"{'sampler':13s} {'N':>6s} {'trials':>6s} {'estimate':>12s} {'|error|':>10s} "
              f"{'RMSE':>10s} {'RMSE 95% interval':>20s} {'time ms':>8s} {'ns/sample':>9s}")
    print(header)
    for name, conv in results.items():
        for p in conv.points:
            err = abs(float(p.estimates[0]) - p.exact)
            low, high = p.summary.interval()
            print(f"{name:13s} {p.n:6d} {p.trials:6d} {float(p.estimates[0]):12.8f} {err:10.3e} "
                  f"{p.summary.rmse:10.3e} "
                  f"{_interval_text(math.sqrt(low), math.sqrt(high), '.2e'):>20s} "
                  f"{1e3 * p.seconds:8.2f} {p.ns_per_sample:9.2f}"
                  f"{'' if p.resolved else '  unresolved'}")
        for n, reason in conv.skipped:
            print(f"{name:13s} {n:6d}  skipped: {reason}")
    print("fitted slope of ln MSE against ln N (weighted least squares; the RMSE slope is half "
          "of it) with its 95% interval: normal, or Student t on points - 2 degrees of freedom "
          "and widened by sqrt(chi2/dof) when the MSE scatters about a power law more than its "
          "own errors allow (chi2/dof > 1)")
    for name, conv in results.items():
        fit = conv.fit()
        unresolved = sum(not p.resolved for p in conv.points)
        left_out = f"  ({unresolved} unresolved N left out)" if unresolved else ""
        if fit.points < 2:
            print(f"  {name:13s} MSE slope n/a (fewer than two sample counts){left_out}")
            continue
        expected = EXPECTED_SLOPES.get(name, {}).get(integrand.name)
        note = f"  published rate {expected:g}" if expected is not None else ""
        if conv.deterministic:
            note += ("  (deterministic: every trial gives the same estimate; the interval is "
                     "the scatter about the line)")
            chi2 = ""
        else:
            chi2 = f"  chi2/dof {fit.chi2_dof:5.1f}" if fit.chi2_dof == fit.chi2_dof else ""
        low, high = fit.interval()
        print(f"  {name:13s} MSE slope {fit.slope:+.3f} {_interval_text(low, high, '+.3f')}"
              f"{chi2}{note}{left_out}")


def _write_outputs(out: Path, args, integrand, results, record: dict[str, str]) -> None:
    import numpy as np

    from ..analysis import plots

    stem = out / f"integrate_{integrand.name}"
    rows = []
    for name, conv in results.items():
        for p in conv.points:
            rows.append({"sampler": name, "n_requested": p.n_requested, "n": p.n,
                         "trials": p.trials, "estimate_pixel0": float(p.estimates[0]),
                         "mean_estimate": float(p.estimates.mean()), "exact": p.exact,
                         "exact_error": p.exact_error,
                         "mse": p.summary.mse, "mse_low": p.summary.interval()[0],
                         "mse_high": p.summary.interval()[1], "mse_floor": p.floor,
                         "mse_excess": p.mse_excess, "resolved": p.resolved,
                         "rmse": p.summary.rmse,
                         "se_log_mse": p.summary.se_log, "bias": p.summary.bias,
                         "seconds": p.seconds, "ns_per_sample": p.ns_per_sample})
    made = csv_values(record)  # how the file was made: on every row
    with atomic_path(stem.with_suffix(".csv")) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=[*(rows[0] if rows else ["sampler"]), *made])
        writer.writeheader()
        writer.writerows({**row, **made} for row in rows)
    slopes = {}
    for name, conv in results.items():
        fit = conv.fit()
        low, high = fit.interval()
        slopes[name] = {"slope": fit.slope, "slope_low": low, "slope_high": high,
                        "stderr": fit.stderr,
                        "stderr_scaled": fit.stderr_scaled, "points": fit.points,
                        "chi2_dof": fit.chi2_dof, "deterministic": conv.deterministic,
                        "unresolved": [p.n for p in conv.points if not p.resolved],
                        "skipped": [{"n": n, "reason": r} for n, r in conv.skipped]}
    summary = {"integrand": integrand.name, "description": integrand.description,
               "exact": integrand.exact, "exact_error": integrand.exact_error,
               "exact_method": integrand.exact_method or "known", "seed": args.seed,
               "budget": args.budget, "max_trials": args.trials, "slopes": slopes, **record}
    write_json(stem.with_suffix(".json"), summary)

    fig = plots.new_figure(6.0, 4.5)
    series = [(f"{name} ({conv.fit().slope:+.2f})", np.array([p.n for p in conv.points]),
               np.array([p.summary.mse for p in conv.points]),
               *np.array([p.summary.interval() for p in conv.points]).T)
              for name, conv in results.items() if conv.points]
    plots.plot_convergence(fig.add_subplot(), series,
                           title=f"MSE of the {integrand.name} estimate (slope in legend)")
    plots.save_figure(fig, stem.with_suffix(".png"), text=png_text(record))
    print(f"wrote {stem.name}.png, .csv and .json to {out}")
