"""Multisampling vs supersampling at equal N: edge error, texture aliasing, shading cost.

Protocol
--------
* Scenes: ``scenes/multisample/`` (assets written by its ``make_assets.py`` if missing).
  ``polygons.xml``: flat-coloured (emissive) facets, deterministic image (all
  error is edge error), at two shading costs: ``$shading`` = 1 and 16 light
  samples per shading point (shadow rays that add exactly zero: a black BSDF).
  ``checker.xml``: Mitsuba's ``checkerboard``, 0.85-pixel checks.
  ``bitmap.xml``: a generated zone plate (1.5 cycles per pixel at the frame's edge).
* Supersampling (SS): the scene's ``direct`` integrator, ``jittered`` sampler, box
  filter, N samples per pixel. Multisampling (MS): the same scene with its
  integrator nested in ``multisample`` (``mcrt render --multisample``; default
  ``centre`` representative, groups by primitive), same sampler, seeds and N.
* Error: RMSE of the luminance against a reference (SS at ``--reference-spp``,
  jittered, box; for the prefiltered textures the reference is that of the
  *unfiltered* texture: the ideal image is the box-filtered texture), mean over
  ``--seeds`` seeds. Aliasing: :func:`mcrt.analysis.aliasing.aliasing_score` of
  the first seed's error image (z of the low-band ratio and peak-to-median
  against the sign-flip null; verdict ``aliased`` when either z > 5).
* Shading evaluations per pixel: SS shades every sample (N); MS, what the
  ``multisample`` integrator counted (representatives), per pixel.
* Time: ``render_film`` wall time (passes, synchronised), best of ``--repeats``
  after one untimed warm-up render (kernel compilation). Timings are only
  meaningful on a quiet machine.

    python benchmarks/multisample.py [--quick] [--figure docs/multisampling.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mitsuba as mi
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mcrt  # noqa: E402,F401  (variant, plugins)
from mcrt.analysis.aliasing import aliasing_score  # noqa: E402
from mcrt.analysis.metrics import luminance  # noqa: E402
from mcrt.core.render import render_film  # noqa: E402
from mcrt.render.multisample import wrap_integrator  # noqa: E402
from mcrt.render.scene import read_scene  # noqa: E402

SCENES = ROOT / "scenes" / "multisample"


def ensure_assets() -> None:
    needed = [SCENES / "meshes" / "facets.ply", SCENES / "textures" / "zoneplate.png",
              SCENES / "textures" / "zoneplate_prefiltered.png",
              SCENES / "textures" / "checker_prefiltered.png"]
    if not all(p.exists() for p in needed):
        sys.path.insert(0, str(SCENES))
        import make_assets  # type: ignore[import-not-found]

        make_assets.main()


def load(name: str, multisample: bool, **params) -> mi.Scene:
    desc = read_scene(SCENES / name, {k: str(v) for k, v in params.items()})
    if multisample:
        wrap_integrator(desc, "multisample")
    return desc.instantiate()


def render(scene: mi.Scene, seed: int) -> tuple[np.ndarray, float]:
    result = render_film(scene, seed=seed)
    return luminance(result.rgb.astype(np.float64)), result.seconds


def timed(scene: mi.Scene, repeats: int) -> float:
    render(scene, 1000)  # warm-up: kernel compilation
    return min(render(scene, 1001 + r)[1] for r in range(repeats))


def measure(name: str, multisample: bool, spp: int, reference: np.ndarray, seeds: int,
            repeats: int, **params) -> dict:
    scene = load(name, multisample, spp=spp, **params)
    errors, first = [], None
    for seed in range(seeds):
        image, _ = render(scene, seed)
        errors.append(float(np.sqrt(np.mean((image - reference) ** 2))))
        if first is None:
            first = image - reference
    pixels = int(np.prod(reference.shape))
    counts = getattr(scene.integrator(), "counts", None)
    # shading evaluations per pixel, counted before the timed renders
    evals = counts.evaluations / (pixels * seeds) if counts is not None else float(spp)
    seconds = timed(scene, repeats)
    score = aliasing_score(first)
    return {"rmse": float(np.mean(errors)), "evals": evals,
            "seconds": seconds, "ratio_z": score.ratio_z, "peak_z": score.peak_z,
            "verdict": score.verdict, "image": reference + first}


def reference_image(name: str, spp: int, **params) -> np.ndarray:
    image, _ = render(load(name, False, spp=spp, **params), 4242)
    return image


def edge_table(args) -> list[str]:
    ref = reference_image("polygons.xml", args.reference_spp)
    rows = ["| shading | N | SS RMSE | MS RMSE | SS shading / px | MS shading / px "
            "| MS / SS shading | SS time [s] | MS time [s] | MS / SS time |", "|---" * 10 + "|"]
    for shading in args.shading:
        for n in args.spp:
            ss = measure("polygons.xml", False, n, ref, args.seeds, args.repeats, shading=shading)
            ms = measure("polygons.xml", True, n, ref, args.seeds, args.repeats, shading=shading)
            rows.append(f"| {shading} | {n} | {ss['rmse']:.5f} | {ms['rmse']:.5f} | "
                        f"{ss['evals']:.2f} | {ms['evals']:.3f} | "
                        f"{ms['evals'] / ss['evals']:.3f} | {ss['seconds']:.3f} | "
                        f"{ms['seconds']:.3f} | {ms['seconds'] / ss['seconds']:.2f} |")
            print(rows[-1], flush=True)
    return rows


TEXTURE_CASES = [
    # label, scene, multisample, params, reference params
    ("checker, SS", "checker.xml", False, {}, ("checker.xml", {})),
    ("checker, MS", "checker.xml", True, {}, ("checker.xml", {})),
    ("checker, MS + prefiltered bitmap", "bitmap.xml", True,
     {"texture": "textures/checker_prefiltered.png"}, ("checker.xml", {})),
    ("zone plate, SS", "bitmap.xml", False, {}, ("bitmap.xml", {})),
    ("zone plate, MS (bilinear lookup)", "bitmap.xml", True, {}, ("bitmap.xml", {})),
    ("zone plate, MS (nearest lookup)", "bitmap.xml", True, {"filter_type": "nearest"},
     ("bitmap.xml", {})),
    ("zone plate, MS + prefiltered bitmap", "bitmap.xml", True,
     {"texture": "textures/zoneplate_prefiltered.png"}, ("bitmap.xml", {})),
    ("zone plate, SS + prefiltered bitmap", "bitmap.xml", False,
     {"texture": "textures/zoneplate_prefiltered.png"}, ("bitmap.xml", {})),
]


def texture_table(args, images: dict) -> list[str]:
    refs: dict[str, np.ndarray] = {}
    rows = ["| case | N | RMSE | aliasing ratio z | peak z | verdict | shading / px "
            "| time [s] |", "|---" * 8 + "|"]
    n = args.texture_spp
    for label, scene, multisample, params, (ref_scene, ref_params) in TEXTURE_CASES:
        if ref_scene not in refs:
            refs[ref_scene] = reference_image(ref_scene, args.reference_spp, **ref_params)
        r = measure(scene, multisample, n, refs[ref_scene], args.seeds, args.repeats, **params)
        images[label] = r["image"]
        rows.append(f"| {label} | {n} | {r['rmse']:.4f} | {r['ratio_z']:.1f} | "
                    f"{r['peak_z']:.1f} | {r['verdict']} | {r['evals']:.2f} | "
                    f"{r['seconds']:.3f} |")
        print(rows[-1], flush=True)
    for name, ref in refs.items():
        images[f"reference ({name}, {args.reference_spp} spp)"] = ref
    return rows


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", type=int, nargs="+", default=[4, 16, 64])
    p.add_argument("--shading", type=int, nargs="+", default=[1, 16],
                   help="light samples per shading point in polygons.xml (its $shading)")
    p.add_argument("--texture-spp", type=int, default=16)
    p.add_argument("--reference-spp", type=int, default=1024)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="small reference, 1 seed, 1 repeat")
    p.add_argument("--figure", type=Path, help="write a contact sheet of the texture cases")
    args = p.parse_args()
    if args.quick:
        args.reference_spp, args.seeds, args.repeats = 256, 1, 1
    ensure_assets()
    print("## edges: scenes/multisample/polygons.xml")
    edges = edge_table(args)
    print("\n## textures")
    images: dict[str, np.ndarray] = {}
    textures = texture_table(args, images)
    print("\n" + "\n".join(edges) + "\n\n" + "\n".join(textures))
    if args.figure is not None:
        from mcrt.io.png import write_contact_sheet

        sheet = [(label.replace(", ", "\n"), np.repeat(img[..., None], 3, axis=-1))
                 for label, img in images.items()]
        write_contact_sheet(args.figure, sheet, columns=4, zoom=2)
        print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
