"""``mcrt render``: render a scene with any sampler, write EXR + PNG."""

from __future__ import annotations

import argparse
import logging

from .. import __version__
from ..io import write_exr, write_png
from ..render import adaptive
from ..render.passes import render_film
from ..render.plan import parse_effect_overrides, plan_scene
from ..render.scene import check_sampler_name, make_sampler, parse_defines, sampler_name
from ..samplers import ALL_SAMPLERS
from ._common import check_output_files, non_negative_int, output_stem, positive_int
from .plan_cmd import add_effect_argument

log = logging.getLogger("mcrt.render")


def add_parser(commands) -> None:
    p = commands.add_parser(
        "render", help="render a scene with a chosen sampler",
        description="Render SCENE.xml and write OUT.exr (float32) and OUT.png (sRGB preview; "
                    "linear values above 1 are clipped).")
    p.add_argument("scene", metavar="SCENE.xml", help="Mitsuba 3 XML scene")
    p.add_argument("--sampler", metavar="NAME",
                   help=f"sampler plugin (default: the scene's); one of {', '.join(ALL_SAMPLERS)}")
    p.add_argument("--spp", type=positive_int, metavar="N",
                   help="samples per pixel (default: the scene's)")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument("-D", dest="defines", action="append", metavar="KEY=VALUE",
                   help="set a scene parameter ($KEY in the XML); repeatable")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="output path without extension (default: <scene>_<sampler>)")
    add_effect_argument(p)  # the render follows the scene's plan (see `mcrt plan`)
    adaptive.add_cli_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    # Everything a user can get wrong is checked before rendering starts.
    if args.sampler is not None:
        check_sampler_name(args.sampler)
    params = parse_defines(args.defines)
    planned = plan_scene(args.scene, params, parse_effect_overrides(args.effect))
    scene = planned.scene
    scene_sampler = scene.sensors()[0].sampler()
    name = args.sampler or sampler_name(scene_sampler)
    spp = args.spp or scene_sampler.sample_count()
    sampler = make_sampler(name, spp, args.seed) if args.sampler else scene_sampler
    stem = output_stem(args.output, f"{_scene_stem(args.scene)}_{name}")
    adaptive_settings = adaptive.cli_settings(args, scene, planned.plan)
    if adaptive_settings is not None:
        metadata = {"mcrt_version": __version__, "scene": str(args.scene), "seed": args.seed,
                    "defines": " ".join(f"{k}={v}" for k, v in params.items())}
        return adaptive.run_cli_render(args, scene, sampler, name, adaptive_settings, stem,
                                       metadata)
    exr_path, png_path = stem.with_suffix(".exr"), stem.with_suffix(".png")
    check_output_files(exr_path, png_path)

    passes, on_pass = planned.schedule(sampler, spp, args.seed)  # motion sub-frames
    log.info("plan: %s", ", ".join(planned.plan.effects_on))
    result = render_film(scene, sampler, spp=spp, seed=args.seed, progress=not args.quiet,
                         passes=passes, on_pass=on_pass)
    if result.spp != spp:
        log.info("%s uses %d samples per pixel (requested %d)", name, result.spp, spp)
    metadata = {"mcrt_version": __version__, "scene": str(args.scene), "sampler": name,
                "spp": result.spp, "seed": args.seed, "passes": result.passes,
                "render_seconds": round(result.seconds, 6),
                "defines": " ".join(f"{k}={v}" for k, v in params.items()),
                "effects": ",".join(planned.plan.effects_on), "plan": planned.plan.to_json()}
    write_exr(exr_path, {"rgb": result.image}, metadata)
    write_png(png_path, result.rgb)
    height, width = result.image.shape[:2]
    print(f"sampler {name}  spp {result.spp}  {width}x{height}  passes {result.passes}  "
          f"time {result.seconds:.2f} s  {result.samples_per_second / 1e6:.2f} M samples/s")
    print(f"wrote {exr_path} and {png_path}")
    return 0


def _scene_stem(path: str) -> str:
    from pathlib import Path

    return Path(path).stem
