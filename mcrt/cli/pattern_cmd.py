"""``mcrt pattern``: analyse the point sets a sampler gives the pixels of a render."""

from __future__ import annotations

import argparse
import csv
import logging
import math
from pathlib import Path

import numpy as np

from ..analysis import patterns
from ..core.atomic import atomic_path
from ..core.jsonfile import write_json
from ..core.provenance import csv_values, png_text
from ..core.sampling import check_sampler_name, make_sampler, quiet_sampler_warnings
from ..errors import McrtError
from ..samplers.base import is_mcrt_sampler
from ..samplers.points import MAX_BUILTIN_PIXEL, point_sets
from ..samplers.poisson_tables import MAX_POINTS
from . import SUMMARIES, _common
from ._common import (
    ensure_writable_dir,
    examples,
    non_negative_int,
    positive_int,
    sampler_choices,
)

log = logging.getLogger("mcrt.pattern")

#: Largest sample count analysed (the O(N^2) discrepancy and the O(N^2) spectrum
#: lattice make larger sets impractical; it is also poisson_disk's table limit).
MAX_PATTERN_SPP = MAX_POINTS

#: Work budgets (see patterns.spectrum_work / discrepancy_work): about 3 s for
#: the spectrum and 5 s for both discrepancies on a quiet 2-core machine.
#: Beyond them fewer pixels are used, with a note.
SPECTRUM_BUDGET = 1 << 31
DISCREPANCY_BUDGET = 1 << 29

#: Largest N for which the point plot draws poisson_disk's disks.
MAX_DISKS_DRAWN = 2048

#: Samplers whose 2D points fill a k x k grid of strata (drawn in the point plot).
GRID_SAMPLERS = ("uniform_grid", "jittered", "stratified", "multijitter", "orthogonal")


def add_parser(commands) -> None:
    p = commands.add_parser(
        "pattern", help=SUMMARIES["pattern"],
        description="Draws the points NAME gives the first K pixels of a render (film "
                    "dimension by default, through the same calls Mitsuba makes) and measures "
                    "them: averaged power spectrum P(k) (white noise = 1), radially averaged "
                    "spectrum with frequencies in units of 1 / mean spacing (f = |k| / sqrt(N)), "
                    "anisotropy in dB, L2-star and centered discrepancy, and rho = d_min / d_hex. "
                    "Writes points.png, spectrum.png, radial.png, overview.png, radial.csv and "
                    "summary.json to DIR and prints the summary.",
        epilog=examples("mcrt pattern poisson_disk --spp 256",
                        "mcrt pattern jittered --param jitter=0.5 -o out/pattern_half_jitter",
                        "mcrt pattern sobol --spp 64 --dimension 2"))
    p.add_argument("sampler", metavar="NAME", help=f"sampler: one of {sampler_choices()}")
    p.add_argument("--spp", type=positive_int, default=256, metavar="N",
                   help="samples per pixel (default 256; samplers may round it)")
    p.add_argument("--pixels", type=positive_int, default=256, metavar="K",
                   help="pixels (point sets) to average over (default 256)")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument("--dimension", type=non_negative_int, default=0, metavar="D",
                   help="sampler dimension (call index) to analyse; 0 = film position (default)")
    p.add_argument("--kmax", type=positive_int, default=None, metavar="K",
                   help="largest integer frequency of the spectrum (default ceil(2 sqrt(N)))")
    p.add_argument("-P", "--param", action="append", metavar="KEY=VALUE",
                   help="sampler parameter, e.g. --param jitter=0.5; repeatable")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default out/pattern_<NAME>)")
    p.set_defaults(run=run)


def grid_resolution(sampler: str, n: int) -> int | None:
    """Strata per axis to draw for grid samplers (None for the others): those of
    :data:`GRID_SAMPLERS` and any registered sampler that claims k x k strata."""
    from ..samplers import registry

    k = math.isqrt(n)
    grid = sampler in GRID_SAMPLERS or (sampler in registry.names() and
                                        "stratified" in registry.info(sampler).claims)
    return k if grid and k * k == n and k > 1 else None


def run(args: argparse.Namespace) -> int:
    name = check_sampler_name(args.sampler)
    params = _common.parse_sampler_params(args.param, "--param")
    if args.spp > MAX_PATTERN_SPP:
        raise McrtError(f"--spp: at most {MAX_PATTERN_SPP} samples per pixel, got {args.spp}")
    with quiet_sampler_warnings():
        sampler = make_sampler(name, args.spp, **params)  # checks the parameters
    if not is_mcrt_sampler(sampler) and args.pixels > MAX_BUILTIN_PIXEL:  # seeded per wavefront
        raise McrtError(f"--pixels: at most {MAX_BUILTIN_PIXEL} for Mitsuba's samplers "
                        f"(and users' samplers that are not McrtSamplers)")
    n = sampler.sample_count()
    if n > MAX_PATTERN_SPP:
        raise McrtError(f"{name} rounds {args.spp} samples up to {n}, above {MAX_PATTERN_SPP}")
    if n != args.spp:
        log.info("%s uses %d samples per pixel (requested %d)", name, n, args.spp)
    kmax = args.kmax or patterns.default_kmax(n)
    if kmax > 4096:
        raise McrtError(f"--kmax: at most 4096, got {kmax}")
    target = Path(args.output or f"out/pattern_{name}")
    with _common.removed_if_refused(target):  # a refused command leaves no folder
        out = ensure_writable_dir(target)
        _common.require_space(out, _common.PLOTS_BYTES, "the plots")

    per_set = patterns.spectrum_work(1, n, kmax)
    spectrum_sets = max(1, min(args.pixels, SPECTRUM_BUDGET // per_set))
    discrepancy_sets = max(1, min(args.pixels, DISCREPANCY_BUDGET // max(n * n, 1)))
    if spectrum_sets < args.pixels:
        log.info("spectrum averaged over %d of %d pixels (work budget)", spectrum_sets, args.pixels)
    if discrepancy_sets < args.pixels:
        log.info("discrepancy computed on %d of %d pixels (work budget)", discrepancy_sets,
                 args.pixels)

    with quiet_sampler_warnings():
        points = point_sets(sampler, args.pixels, n, dimension=args.dimension, seed=args.seed)
    report = patterns.analyse_points(points, kmax=kmax, spectrum_sets=spectrum_sets,
                                     discrepancy_sets=discrepancy_sets)
    summary = {"sampler": name, "params": params, "spp_requested": args.spp,
               "seed": args.seed, "dimension": args.dimension, **report.summary(),
               **_common.recorded(args, name, "--spp", args.spp, "--pixels", args.pixels,
                                  "--seed", args.seed, "--dimension", args.dimension,
                                  *(["--kmax", args.kmax] if args.kmax else []),
                                  *_common.param_words("--param", args.param))}
    _write_outputs(out, name, points, report, summary, args)
    _print_summary(summary, out)
    return 0


def _title(name: str, params: dict, n: int) -> str:
    extra = "".join(f", {k}={v}" for k, v in params.items())
    return f"{name}{extra}, N = {n}"


def _write_outputs(out: Path, name: str, points: np.ndarray, report: patterns.PatternReport,
                   summary: dict, args: argparse.Namespace) -> None:
    from ..analysis import plots

    n = report.n_points
    title = _title(name, summary["params"], n)
    grid = grid_resolution(name, n)
    radius = None
    if name == "poisson_disk" and 1 < n <= MAX_DISKS_DRAWN:
        radius = 0.5 * float(report.rho[0]) * patterns.d_hex(n)

    def points_axes(ax):
        plots.plot_point_set(ax, points[0], grid=grid, radius=radius,
                             title=f"{title}\npixel 0, rho = {report.rho[0]:.3f}")

    fig = plots.new_figure(4.2, 4.2)
    points_axes(fig.add_subplot())
    text = png_text(summary)
    plots.save_figure(fig, out / "points.png", text=text)

    spectrum_title = f"power spectrum ({report.spectrum_sets} pixels)"
    fig = plots.new_figure(5.0, 4.2)
    plots.plot_spectrum(fig.add_subplot(), report.spectrum, n, title=f"{title}\n{spectrum_title}")
    plots.save_figure(fig, out / "spectrum.png", text=text)

    fig = plots.new_figure(5.0, 5.0)
    ax_p, ax_a = fig.subplots(2, 1, sharex=True)
    plots.plot_radial_power(ax_p, report.radial, title=f"{title}\nradially averaged power")
    plots.plot_anisotropy(ax_a, report.radial)
    plots.save_figure(fig, out / "radial.png", text=text)

    fig = plots.new_figure(15.0, 3.8)
    axes = fig.subplots(1, 4)
    points_axes(axes[0])
    plots.plot_spectrum(axes[1], report.spectrum, n, title=spectrum_title, colorbar=False)
    plots.plot_radial_power(axes[2], report.radial, title="radially averaged power")
    plots.plot_anisotropy(axes[3], report.radial, title="anisotropy")
    plots.save_figure(fig, out / "overview.png", text=text)

    r = report.radial
    made = csv_values(summary)  # how the file was made: on every row
    with atomic_path(out / "radial.csv") as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["radius", "frequency", "power", "anisotropy_db", "count", *made])
        writer.writerows([int(k), f"{f:.6g}", f"{p:.6g}", f"{a:.6g}", int(c), *made.values()]
                         for k, f, p, a, c in zip(r.radius, r.frequency, r.power,
                                                  r.anisotropy_db, r.count, strict=True))
    write_json(out / "summary.json", summary)


def _print_summary(s: dict, out: Path) -> None:
    extra = "".join(f" {k}={v}" for k, v in s["params"].items())
    print(f"pattern {s['sampler']}{extra}: N = {s['n_points']} points, {s['sets']} pixels, "
          f"dimension {s['dimension']}, seed {s['seed']}")
    print(f"  rho = d_min / d_hex       mean {s['rho_mean']:.4f}   min {s['rho_min']:.4f}")
    print(f"  L2-star discrepancy       mean {s['l2_star_mean']:.4e} +- {s['l2_star_std']:.1e} "
          f"(sd, {s['discrepancy_sets']} pixels)")
    print(f"  centered L2 discrepancy   mean {s['centered_mean']:.4e}")
    print(f"  low-frequency power       {s['low_frequency_power']:.4f}  "
          f"(mean P(k) for 0 < f < 0.5; white noise 1)")
    print(f"  radial peak               P = {s['peak_power']:.3f} at f = {s['peak_frequency']:.3f}")
    print(f"  anisotropy, 0.5 <= f <= 2 {s['anisotropy_db']:.1f} dB  "
          f"(white-noise floor {s['anisotropy_floor_db']:.1f} dB, "
          f"{s['spectrum_sets']} periodograms)")
    print(f"wrote points.png, spectrum.png, radial.png, overview.png, radial.csv, summary.json "
          f"to {out}")
