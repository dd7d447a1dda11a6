"""Is `zsobol`'s error blue over the screen? Two measures, against `sobol` and `independent`.

1. **A smooth per-pixel integrand** (the same Gaussian bump in every pixel of a 64x64
   grid, 4 points per pixel from ``point_sets`` of dimensions 0, 1 and 3): the low-band
   ratio (mcrt's aliasing measure, power at |f| < 0.25 against white noise) of the
   per-pixel error, and the variance of a 2x2 quad's summed error against four
   independent pixels' (1 for white noise, ~0 for perfectly anti-correlated pixels).
2. **The Cornell box** (``direct``, 64x64, box filter): the low-band ratio of the
   luminance error against a 4096-spp ``jittered`` reference, mean over seeds, at 4 and
   16 spp; also with the error clipped at its 90th percentile, and with the light hidden
   and sampled only by emitter sampling (no bright visible rim).
3. **The light's rim rows** on that Cornell box, where neighbouring pixels integrate
   the same sliver of the light: does a quad's pair of pixels in such a row cancel,
   against the least a pair stratified together could reach (8x the seeds)?
4. **Random straight edges** (film points, 64x64 pixels, a random edge per 2x2 quad, 8x
   the seeds): the variance of a quad's summed error against its four pixels', when the
   four pixels see the *same* edge (the best case for screen-space cancellation) and when
   one edge *crosses* the quad (what an image's edges do), next to the least a quad whose
   4N points form one net can reach on the same edge, ``4 V(4N) / V(N)`` with ``V`` the
   variance of ``sobol``'s N-point estimate (1/2 when ``V`` falls as ``N^-1.5``).

    python benchmarks/zsobol_blue_noise.py [--seeds 8]     # ~1 min
"""

from __future__ import annotations

import argparse

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.analysis.aliasing import low_band_ratio  # noqa: E402
from mcrt.core.colour import LUMINANCE_WEIGHTS  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.samplers.points import point_sets  # noqa: E402

WIDTH = 64
SAMPLERS = (("zsobol", {"width": WIDTH}), ("sobol", {}), ("independent", {}))
LUMINANCE = np.array(LUMINANCE_WEIGHTS)


def bump(points: np.ndarray) -> np.ndarray:
    return np.exp(-((points[..., 0] - 0.3) ** 2 + (points[..., 1] - 0.6) ** 2) / (2 * 0.2 ** 2))


def smooth_integrand() -> None:
    exact = bump(np.random.default_rng(0).random((4_000_000, 2))).mean()
    print("| sampler | dimension | low-band ratio | 2x2 quad variance / 4 pixels' |")
    print("|---|---:|---:|---:|")
    for name, params in SAMPLERS:
        for dimension in (0, 1, 3):
            points = point_sets(name, range(WIDTH * WIDTH), 4, dimension=dimension, **params)
            error = (bump(points.astype(np.float64)).mean(axis=1) - exact).reshape(WIDTH, WIDTH)
            quad = error.reshape(WIDTH // 2, 2, WIDTH // 2, 2).sum(axis=(1, 3))
            print(f"| {name} | {dimension} | {low_band_ratio(error):.3f} | "
                  f"{quad.var() / (4 * error.var()):.3f} |", flush=True)


#: The Cornell box's integrators: the issue's case (the light seen directly), and the light
#: hidden with emitter sampling only (no visible rim; shadows and smooth shading left).
CORNELL_CASES = (("direct", {"type": "direct"}),
                 ("direct, light hidden, emitter samples only",
                  {"type": "direct", "hide_emitters": True, "bsdf_samples": 0}))


def cornell(seeds: int) -> None:
    """Low-band ratio of the luminance error, also with the error clipped at the 90th
    percentile of its magnitude over all seeds (where the few heavy pixels stop
    dominating), and the share of the error energy held by the worst 5% of pixels."""
    print("\n| integrator | spp | sampler | low-band ratio (mean +- se over seeds) "
          "| clipped at p90 | worst 5% of pixels' share of the error energy | MSE |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for label, integrator in CORNELL_CASES:
        desc = mi.cornell_box()
        desc["sensor"]["film"].update(width=WIDTH, height=WIDTH, rfilter={"type": "box"})
        desc["integrator"] = integrator
        scene = mi.load_dict(desc)
        reference = render_film(scene, make_sampler("jittered", 4096), seed=12345).rgb @ LUMINANCE
        for spp in (4, 16):
            for name, params in SAMPLERS:
                errors = np.stack([
                    render_film(scene, make_sampler(name, spp, **params), seed=seed).rgb
                    @ LUMINANCE - reference for seed in range(seeds)])
                ratios = [low_band_ratio(e) for e in errors]
                clip = float(np.quantile(np.abs(errors), 0.9))
                clipped = [low_band_ratio(np.clip(e, -clip, clip)) for e in errors]
                energy = np.sort((errors ** 2).mean(axis=0).ravel())[::-1]
                worst = energy[:len(energy) // 20].sum() / energy.sum()
                print(f"| {label} | {spp} | {name} | {np.mean(ratios):.3f} +- "
                      f"{np.std(ratios) / np.sqrt(seeds):.3f} | {np.mean(clipped):.3f} | "
                      f"{worst:.2f} | {np.mean(errors ** 2):.3e} |", flush=True)


def _frac_var(t: float) -> float:
    """q (1 - q) for q the fractional part of t: the Bernoulli variance of the one
    stratum an edge cuts, with the edge t strata from the pixel's side."""
    q = t % 1.0
    return q * (1.0 - q)


def rim_rows(seeds: int) -> None:
    """The light's horizontal rims on the ``direct`` Cornell box: rows of pixels that
    see the same sliver of the light (alike integrands, the case screen-space
    anti-correlation is for). Per rim row: the light's coverage of its inner pixels
    (over the light's full value, both less the surface beside the light), and the
    variance of the summed error of the two pixels of a 2x2 quad's row against two
    independent pixels' (1: no cancellation), measured over ``seeds`` renders and,
    for comparison, the least it
    could be: two pixels whose 2N points are stratified together across them, for an
    edge at that coverage. Then each sampler's share of the error energy in these
    rows (the rest: the slanted sides and corners, whose neighbours are unlike)."""
    desc = mi.cornell_box()
    desc["sensor"]["film"].update(width=WIDTH, height=WIDTH, rfilter={"type": "box"})
    desc["integrator"] = {"type": "direct"}
    scene = mi.load_dict(desc)
    reference = render_film(scene, make_sampler("jittered", 4096), seed=12345).rgb @ LUMINANCE
    full = float(reference.max())
    columns = np.nonzero((reference >= 0.5 * full).any(axis=0))[0][1:-1]  # inner columns
    partial = (reference[:, columns] > 0.02 * full) & (reference[:, columns] < 0.995 * full)
    rows = [int(r) for r in np.nonzero(partial.all(axis=1))[0]]
    pairs = [c for c in columns if c % 2 == 0 and c + 1 in columns]
    print("\n| spp | sampler | rim row | coverage | quad-row pair variance / two pixels' "
          "| least for a pair stratified together | rim rows' share of the error energy |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for spp in (4, 16):
        for name, params in SAMPLERS:
            errors = np.stack([
                render_film(scene, make_sampler(name, spp, **params), seed=seed).rgb
                @ LUMINANCE - reference for seed in range(seeds)])
            energy = (errors ** 2).mean(axis=0)
            share = energy[np.ix_(rows, columns)].sum() / energy.sum()
            for r in rows:
                a, b = errors[:, r, pairs], errors[:, r, [c + 1 for c in pairs]]
                ratio = np.mean((a + b).var(axis=0) / (a.var(axis=0) + b.var(axis=0)))
                outside = np.minimum(reference[r - 1, columns], reference[r + 1, columns])
                cover = float(np.median((reference[r, columns] - outside) / (full - outside)))
                least = _frac_var(2 * spp * cover) / (2 * _frac_var(spp * cover))
                print(f"| {spp} | {name} | {r} | {cover:.3f} | {ratio:.2f} | {least:.2f} | "
                      f"{share:.2f} |", flush=True)


def _edge_estimates(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Per pixel, the mean over its points of the indicator ``normal . x < offset``
    (``points``: pixels x N x 2; ``normal``, ``offset``: per pixel)."""
    return ((points @ normal[..., None])[..., 0] < offset[:, None]).mean(axis=1)


def random_edges(seeds: int) -> None:
    """Quad-sum variance over pixel variances on random straight edges (no reference
    needed: variances over seeds). Edge: a uniform direction through a uniform point of
    the pixel (``same``: one edge in every pixel's own coordinates) or of the 2x2 quad
    (``crossing``: one edge in the quad's coordinates)."""
    rng = np.random.default_rng(7)
    quads = (WIDTH // 2) ** 2
    angle = rng.uniform(0.0, 2.0 * np.pi, quads)
    normal_q = np.stack([np.cos(angle), np.sin(angle)], -1)
    through = rng.random((quads, 2))
    y, x = np.divmod(np.arange(WIDTH * WIDTH), WIDTH)
    quad = (y // 2) * (WIDTH // 2) + x // 2
    corner = np.stack([x % 2, y % 2], -1).astype(np.float64)
    normal = normal_q[quad]
    same = (normal * through[quad]).sum(-1)
    crossing = (normal * (2.0 * through[quad] - corner)).sum(-1)

    def ratio(estimates: np.ndarray) -> float:  # seeds x pixels
        sums = np.zeros((estimates.shape[0], quads))
        np.add.at(sums.T, quad, estimates.T)
        return float(sums.var(axis=0, ddof=1).sum() / estimates.var(axis=0, ddof=1).sum())

    print("\n| spp | sampler | same edge in the quad's 4 pixels | one edge crossing the quad "
          "| least for a quad whose 4N points are one net (same edge) |")
    print("|---:|---|---:|---:|---:|")
    for spp in (4, 16):
        variance = {}
        for n in (spp, 4 * spp):  # V(N) and V(4N) of sobol on the "same" edges
            est = np.stack([_edge_estimates(point_sets("sobol", range(WIDTH * WIDTH), n,
                                                       seed=seed).astype(np.float64),
                                            normal, same) for seed in range(seeds)])
            variance[n] = est.var(axis=0, ddof=1).sum()
        least = 4.0 * variance[4 * spp] / variance[spp]
        for name, params in SAMPLERS:
            sets = [point_sets(name, range(WIDTH * WIDTH), spp, seed=seed,
                               **params).astype(np.float64) for seed in range(seeds)]
            alike = np.stack([_edge_estimates(p, normal, same) for p in sets])
            across = np.stack([_edge_estimates(p, normal, crossing) for p in sets])
            print(f"| {spp} | {name} | {ratio(alike):.2f} | {ratio(across):.2f} | "
                  f"{least:.2f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args()
    smooth_integrand()
    cornell(args.seeds)
    rim_rows(8 * args.seeds)
    random_edges(8 * args.seeds)


if __name__ == "__main__":
    main()
