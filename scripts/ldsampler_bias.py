"""Reproduce the bias of Mitsuba's ``ldsampler`` with plain Mitsuba (no ``import mcrt``).

Renders scenes/glossy_bias.xml with each sampler for a few seeds, renders a high-spp
reference with the ``independent`` sampler (unbiased by construction) as several
independent passes, and prints per sampler the mean over pixels and channels of
(mean over seeds - reference), its standard error, z = bias / se and a verdict
(biased when |z| > --threshold, default 4). See docs/ldsampler-bias.md.

    .venv/bin/python scripts/ldsampler_bias.py                  # ~1 min on 2 cores
    .venv/bin/python scripts/ldsampler_bias.py --samplers independent,ldsampler \\
        --spp 64 -D rfilter=box -D max_depth=2

The standard error counts the covariances between neighbouring pixels and between
channels (a gaussian filter splats every sample into 5 x 5 pixels, and R, G, B of one
pixel move together): Var(mean) = sum over pixel pairs up to --cov-radius apart and
channel pairs of their covariance across renders / renders / (pixels x channels)^2, for
the seeds and for the reference's passes. The naive per-pixel SE (per-pixel variances
only) is printed as ``se_naive``; on this scene it is ~3x too small, so |z| computed
from it overstates every deviation, including the independent sampler's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "glossy_bias.xml"
DEFAULT_SAMPLERS = "independent,ldsampler,multijitter,stratified,orthogonal"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=SCENE, help="scene XML (default: %(default)s)")
    ap.add_argument("--samplers", default=DEFAULT_SAMPLERS,
                    help="comma-separated Mitsuba sampler plugins (default: %(default)s)")
    ap.add_argument("--spp", type=int, default=256,
                    help="samples per pixel of each seed's render (default: %(default)s)")
    ap.add_argument("--seeds", type=int, default=8,
                    help="renders per sampler, seeds 0..N-1 (default: %(default)s)")
    ap.add_argument("--ref-spp", type=int, default=8192,
                    help="reference samples per pixel, sampler independent (default: %(default)s)")
    ap.add_argument("--ref-pass-spp", type=int, default=1024,
                    help="spp of each independent reference pass (default: %(default)s)")
    ap.add_argument("--res", type=int, default=96, help="image width and height (default: 96)")
    ap.add_argument("-D", dest="params", action="append", default=[], metavar="KEY=VALUE",
                    help="extra scene parameter, e.g. -D rfilter=box -D max_depth=2")
    ap.add_argument("--threshold", type=float, default=4.0,
                    help="|z| above which a sampler is called biased (default: %(default)s)")
    ap.add_argument("--cov-radius", type=int, default=4,
                    help="largest pixel offset whose covariance enters the SE (default: 4, "
                         "twice the gaussian filter's radius)")
    ap.add_argument("--variant", default="llvm_ad_rgb",
                    help="Mitsuba variant (default: %(default)s)")
    args = ap.parse_args(argv)
    if args.seeds < 2 or args.spp < 1 or args.res < 1 or args.ref_pass_spp < 1:
        ap.error("need --seeds >= 2 and positive --spp, --res, --ref-pass-spp")
    if args.ref_spp < 2 * args.ref_pass_spp:
        ap.error("--ref-spp must be at least 2 x --ref-pass-spp (the SE needs two passes)")
    for kv in args.params:
        if "=" not in kv:
            ap.error(f"-D expects KEY=VALUE, got {kv!r}")
    return args


def se_of_mean(images: np.ndarray, radius: int) -> float:
    """Standard error of the grand mean of ``images.mean(0)`` (images: renders x H x W x C),
    counting covariances between pixels up to ``radius`` apart and between channels."""
    n, h, w, c = images.shape
    x = images - images.mean(0)
    total = 0.0
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            a = x[:, max(0, dy):h + min(0, dy), max(0, dx):w + min(0, dx)]
            b = x[:, max(0, -dy):h + min(0, -dy), max(0, -dx):w + min(0, -dx)]
            total += float(np.einsum("shwc,shwd->", a, b)) / (n - 1)
    return float(np.sqrt(max(total, 0.0) / n)) / (h * w * c)


def se_naive(images: np.ndarray) -> float:
    """The same SE from per-pixel, per-channel variances only (pixels assumed independent)."""
    n = images.shape[0]
    return float(np.sqrt(images.var(0, ddof=1).sum() / n)) / images[0].size


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import mitsuba as mi

    mi.set_variant(args.variant)
    mi.set_log_level(mi.LogLevel.Error)  # orthogonal/ldsampler warn when they round the spp
    params = dict(kv.split("=", 1) for kv in args.params)
    params["res"] = str(args.res)

    def render(sampler: str, spp: int, seed: int) -> tuple[np.ndarray, int]:
        scene = mi.load_file(str(args.scene), sampler=sampler, spp=str(spp), **params)
        effective = scene.sensors()[0].sampler().sample_count()
        image = mi.render(scene, seed=seed)
        return np.array(image, dtype=np.float64), effective

    print(f"scene {args.scene.name}  params {params}  mitsuba {mi.__version__}  "
          f"variant {args.variant}")
    t0 = time.perf_counter()
    n_pass = args.ref_spp // args.ref_pass_spp
    ref_passes = np.stack([render("independent", args.ref_pass_spp, 1_000_003 + k)[0]
                           for k in range(n_pass)])
    reference = ref_passes.mean(0)
    se_ref = se_of_mean(ref_passes, args.cov_radius)
    se_ref_naive = se_naive(ref_passes)
    print(f"reference: independent, {n_pass} x {args.ref_pass_spp} spp, "
          f"mean {reference.mean():.5f}, se {se_ref:.2e} ({time.perf_counter() - t0:.1f} s)")
    print(f"{args.seeds} seeds x {args.spp} spp per sampler; bias = mean over pixels and channels "
          f"of (mean over seeds - reference)")
    print(f"{'sampler':<12} {'spp':>5} {'bias':>11} {'rel':>8} {'se':>9} {'z':>8} "
          f"{'z_naive':>8}  verdict")
    independent_flagged = False
    for name in [s.strip() for s in args.samplers.split(",") if s.strip()]:
        t = time.perf_counter()
        rendered = [render(name, args.spp, seed) for seed in range(args.seeds)]
        images = np.stack([img for img, _ in rendered])
        spp_eff = rendered[0][1]
        bias = float((images.mean(0) - reference).mean())
        se = float(np.hypot(se_of_mean(images, args.cov_radius), se_ref))
        se_n = float(np.hypot(se_naive(images), se_ref_naive))
        z = bias / se
        biased = abs(z) > args.threshold
        independent_flagged |= biased and name == "independent"
        verdict = (f"BIASED (|z| > {args.threshold:g})" if biased
                   else f"unbiased (|z| <= {args.threshold:g})")
        print(f"{name:<12} {spp_eff:>5} {bias:>+11.3e} {bias / reference.mean():>+8.2%} "
              f"{se:>9.2e} {z:>+8.1f} {bias / se_n:>+8.1f}  {verdict}  "
              f"({time.perf_counter() - t:.1f} s)")
    print(f"total {time.perf_counter() - t0:.1f} s")
    if independent_flagged:
        print("note: the independent sampler came out biased: the reference or the SE is off",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
