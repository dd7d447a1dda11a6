"""Why Mitsuba's `multijitter` beats `sobol` on the Cornell box at 256 spp: edges.

Two measurements, side by side in one run:

1. **The Cornell box** (128x128, as in the study), per-pixel variance across seeds
   (no reference needed: the samplers are unbiased, so MSE = variance), at
   ``max_depth`` 1 (only the light seen directly: the film position is the only
   dimension, and the light's rim the only error), 2 (direct light) and 8 (the study's
   path tracer). Printed: mean over pixels and channels, and the ratio to
   ``multijitter``'s.
2. **Straight edges in one pixel**: UTK's random Heaviside integrands (an edge of
   random direction through a uniform point, exact areas; ``mcrt.analysis.peers``) and,
   for contrast, its random Gaussians, integrated by ``P`` independent point sets
   (pixels) of each sampler's film dimension, and by a *reference* Owen scrambling of
   the same Sobol' (0,2)-sequence computed here in numpy (every node of the scrambling
   tree flips with its own independent coin, by a 64-bit hash: nested uniform
   scrambling with no hash shortcuts), and by Matousek's random linear scrambling of it;
   and by the same reference Owen scrambling of a *different* (0,m,2)-net, Hammersley's
   ``(i / N, radical inverse of i)``. If ``sobol`` matched those references but not
   ``multijitter``, the gap is the scrambled net's, not mcrt's implementation; if the
   Hammersley column matched too, it is every scrambled (0,m,2)-net's (Owen's variance
   formula: a scrambled net's variance depends on the net only through how many pairs of
   its points share each elementary interval, and the (0,m,2) property fixes those counts;
   docs/samplers.md).

    python benchmarks/edge_variance.py [--seeds 12] [--sets 1024]     # ~2.5 min
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.analysis.peers import gaussian_family, heaviside_family  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.samplers.points import point_sets  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLERS = ("sobol", "zsobol", "multijitter", "ldsampler")
M64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def cornell(seeds: int, spp: int) -> None:
    print(f"Cornell box 128x128, {spp} spp: per-pixel variance across {seeds} seeds "
          f"(mean over pixels and channels; ratio to multijitter)\n")
    print("| max_depth | " + " | ".join(f"`{s}`" for s in SAMPLERS) + " |")
    print("|---:|" + "---:|" * len(SAMPLERS))
    for depth in (1, 2, 8):
        scene = mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res=128,
                             max_depth=depth)
        var = {}
        for name in SAMPLERS:
            params = {"width": 128} if name == "zsobol" else {}
            images = np.stack([render_film(scene, make_sampler(name, spp, **params),
                                           seed=seed).rgb for seed in range(seeds)])
            var[name] = float(images.astype(np.float64).var(axis=0, ddof=1).mean())
        print(f"| {depth} | " + " | ".join(
            f"{var[s]:.3e} ({var[s] / var['multijitter']:.2f})" for s in SAMPLERS) + " |",
            flush=True)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    x = (x + np.uint64(0x9E3779B97F4A7C15)) & M64
    x = ((x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & M64
    x = ((x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & M64
    return x ^ (x >> np.uint64(31))


def _sobol_fractions(n: int) -> list[np.ndarray]:
    """The first ``n`` points of Sobol' dimensions 0 and 1 as 32-bit fractions (bit 31 is
    the first binary digit), straight from their direction numbers: ``v_k = 2^-k`` (van der
    Corput) and ``m_k = 2 m_{k-1} xor m_{k-1}``, ``m_1 = 1`` (Joe & Kuo's dimension 2), with
    no shortcut shared with ``mcrt/samplers/_sobol.py``."""
    index = np.arange(n, dtype=np.uint64)
    coords = []
    for dim in (0, 1):
        value, v = np.zeros(n, dtype=np.uint64), 1 << 31
        for bit in range(32):
            value ^= np.where((index >> np.uint64(bit)) & np.uint64(1) != 0, np.uint64(v),
                              np.uint64(0))
            v = v >> 1 if dim == 0 else v ^ (v >> 1)
        coords.append(value)
    return coords


def _owen(value: np.ndarray, seed: np.ndarray, digits: int = 24) -> np.ndarray:
    """Nested uniform scrambling of 32-bit fractions: digit ``k`` flips by a coin of
    (seed, k, digits 1..k-1), independent for every node of the tree."""
    out = np.zeros_like(value)
    for k in range(digits):
        shift = np.uint64(31 - k)
        prefix = value >> (shift + np.uint64(1)) if k else np.zeros_like(value)
        coin = _splitmix64(prefix ^ (np.uint64(k) << np.uint64(40)) ^ seed) >> np.uint64(63)
        out |= (((value >> shift) & np.uint64(1)) ^ coin) << shift
    return out


def _linear(value: np.ndarray, rng: np.random.Generator, digits: int = 24) -> np.ndarray:
    """Matousek's random linear scrambling: the first ``digits`` digits times a random
    lower-triangular unit-diagonal matrix over GF(2), plus a random digital shift, one
    matrix and shift per row (point set)."""
    sets, n = value.shape
    bits = np.stack([(value >> np.uint64(31 - k)) & np.uint64(1) for k in range(digits)],
                    axis=1).astype(np.int64)                                  # (sets, digits, n)
    matrix = np.tril(rng.integers(0, 2, (sets, digits, digits)), -1) + np.eye(digits, dtype=int)
    shift = rng.integers(0, 2, (sets, digits, 1))
    scrambled = (np.einsum("sij,sjn->sin", matrix, bits) + shift) % 2
    out = np.zeros_like(value)
    for k in range(digits):
        out |= scrambled[:, k].astype(np.uint64) << np.uint64(31 - k)
    return out


def _hammersley_fractions(n: int) -> list[np.ndarray]:
    """Hammersley's ``n = 2^m`` points ``(i / n, radical inverse of i)`` as 32-bit fractions:
    a (0,m,2)-net with other generator matrices (reversal, identity) than Sobol's."""
    if n & (n - 1):
        raise ValueError(f"the Hammersley net needs a power of two, got {n}")
    index = np.arange(n, dtype=np.uint64)
    return [index << np.uint64(32 - (n.bit_length() - 1)), _sobol_fractions(n)[0]]


def reference_points(n: int, sets: int, net: str, scrambling: str,
                     seed: int = 1) -> np.ndarray:
    """``sets`` independently scrambled copies (``scrambling``: ``"owen"`` or ``"linear"``)
    of the first ``n`` points of ``net`` (``"sobol"``: the (0,2)-sequence; ``"hammersley"``),
    shape ``(sets, n, 2)``."""
    rng = np.random.default_rng(seed)
    coords = []
    for value in _hammersley_fractions(n) if net == "hammersley" else _sobol_fractions(n):
        rows = np.broadcast_to(value, (sets, n)).copy()
        if scrambling == "owen":
            keys = rng.integers(0, 2**63, size=(sets, 1), dtype=np.int64).astype(np.uint64)
            coords.append(_owen(rows, keys))
        else:
            coords.append(_linear(rows, rng))
    return np.stack([(c >> np.uint64(8)).astype(np.float64) / 2**24 for c in coords], -1)


#: The reference point sets computed here, by column label: (net, scrambling).
REFERENCES = {"reference Owen": ("sobol", "owen"), "reference linear": ("sobol", "linear"),
              "Owen-scrambled Hammersley": ("hammersley", "owen")}


def edges(sets: int, counts: tuple[int, ...]) -> None:
    families = {"Heaviside": heaviside_family(1024), "Gaussian": gaussian_family(256)}
    names = (*SAMPLERS, *REFERENCES)
    print(f"\nOne pixel's film dimension, {sets} point sets x UTK's random integrands "
          f"(1024 Heaviside edges, 256 Gaussians): MSE (ratio to multijitter)\n")
    print("| integrands | N | " + " | ".join(f"`{s}`" if s in SAMPLERS else s
                                           for s in names) + " |")
    print("|---|---:|" + "---:|" * len(names))
    for label, family in families.items():
        for n in counts:
            mse = {}
            for name in names:
                if name in REFERENCES:
                    points = reference_points(n, sets, *REFERENCES[name])
                else:
                    params = {"width": 64} if name == "zsobol" else {}
                    points = point_sets(name, range(sets), n, **params)
                mse[name] = float(np.mean((family.estimates(points) - family.exact) ** 2))
            print(f"| {label} | {n} | " + " | ".join(
                f"{mse[s]:.3e} ({mse[s] / mse['multijitter']:.2f})" for s in names) + " |",
                flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--sets", type=int, default=1024)
    args = parser.parse_args()
    cornell(args.seeds, args.spp)
    edges(args.sets, (64, 256))


if __name__ == "__main__":
    main()
