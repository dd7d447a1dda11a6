"""Reproduce the bias of Mitsuba's ``path`` on cut-outs, with plain Mitsuba (no ``import mcrt``).

A diffuse plane (reflectance 0.5) wrapped in a ``mask`` BSDF of opacity ``o``, lit by
a point light of intensity 1 straight above it at distance 1 and seen from above by
an orthographic camera over a 0.2 x 0.2 patch (black behind). A fraction ``o`` of
the surface is there, so its radiance is ``o * (0.5 / pi) * cos / d^2``; over the
patch the falloff makes the mean 0.99 of the centre's (computed below by the same
integral). Prints, per opacity, the image mean of Mitsuba's ``direct``, ``path`` and
``prb`` and their ratios to that value. See docs/mask-path-bias.md.

    .venv/bin/python scripts/mask_path_bias.py          # ~10 s on 2 cores
"""

from __future__ import annotations

import argparse

import numpy as np


def scene(mi, integrator: str, opacity: float, res: int):
    to_world = (mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0])
                @ mi.ScalarTransform4f().scale([0.1, 0.1, 1]))
    spec = {"type": integrator} if integrator == "direct" else {"type": integrator, "max_depth": 4}
    return mi.load_dict({
        "type": "scene", "integrator": spec,
        "sensor": {"type": "orthographic", "to_world": to_world,
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}}},
        "light": {"type": "point", "position": [0, 0, 1],
                  "intensity": {"type": "rgb", "value": 1.0}},
        "plane": {"type": "rectangle",
                  "bsdf": {"type": "mask", "opacity": {"type": "rgb", "value": opacity},
                           "bsdf": {"type": "diffuse",
                                    "reflectance": {"type": "rgb", "value": 0.5}}}}})


def analytic(opacity: float, n: int = 512) -> float:
    """Mean of ``o (0.5 / pi) cos / d^2`` over the patch ``[-0.1, 0.1]^2`` at
    height 1 below the light (``cos / d^2 = (1 + r^2)^(-3/2)``), by the midpoint rule."""
    x = (np.arange(n) + 0.5) / n * 0.2 - 0.1
    r2 = x[:, None] ** 2 + x[None, :] ** 2
    return float(opacity * 0.5 / np.pi * np.mean((1.0 + r2) ** -1.5))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=16)
    args = ap.parse_args()
    import mitsuba as mi

    mi.set_variant(args.variant)
    print(f"mitsuba {mi.__version__}  variant {args.variant}  {args.res}x{args.res}  "
          f"{args.spp} spp; ratios to the analytic mean")
    print("opacity   analytic    direct      path       prb   direct/a  path/a  prb/a")
    for opacity in (0.25, 0.5, 0.75, 1.0):
        truth = analytic(opacity)
        means = [float(np.mean(np.asarray(mi.render(scene(mi, name, opacity, args.res),
                                                    spp=args.spp))[..., 0]))
                 for name in ("direct", "path", "prb")]
        ratios = "  ".join(f"{m / truth:6.3f}" for m in means)
        print(f"{opacity:7.2f}  {truth:9.5f}  " + "  ".join(f"{m:8.5f}" for m in means)
              + f"    {ratios}")


if __name__ == "__main__":
    main()
