"""``mcrt plan``: print the render plan of a scene (which effects, how they are sampled)."""

from __future__ import annotations

import argparse
import json

from ..core.sampling import check_sampler_name, make_sampler
from ..render.plan import EFFECTS, parse_effect_overrides, plan_scene
from ..render.scene import parse_defines
from . import SUMMARIES
from ._common import examples, non_negative_int, positive_int, sampler_choices


def add_effect_argument(parser: argparse.ArgumentParser) -> None:
    """``--effect NAME=on|off[,...]`` (repeatable), shared by ``plan`` and ``render``."""
    parser.add_argument(
        "--effect", action="append", metavar="NAME=on|off[,...]",
        help=f"switch an effect off or force it on ({', '.join(EFFECTS)}); e.g. "
             f"--effect dof=off,motion=on; repeatable")


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = commands.add_parser(
        "plan", help=SUMMARIES["plan"],
        description="Analyse SCENE.xml (camera aperture, emitters, BSDF roughness, moving "
                    "shapes, indirect light) and print the render plan that mcrt render follows: "
                    "effects on/off and why, integrator and depth, camera, shutter and "
                    "sub-frames, and the sample dimensions of each camera path.",
        epilog=examples("mcrt plan scenes/effects/dof.xml",
                        "mcrt plan scenes/cornell_box.xml --effect indirect=off --json"))
    p.add_argument("scene", metavar="SCENE.xml", help="Mitsuba 3 XML scene")
    add_effect_argument(p)
    p.add_argument("--sampler", metavar="NAME",
                   help=f"sampler (default: the scene's); one of {sampler_choices()}")
    p.add_argument("--spp", type=positive_int, metavar="N",
                   help="samples per pixel (default: the scene's); sets the sub-frame count")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                   help="seed of the sub-frame times (default 0)")
    p.add_argument("-D", dest="defines", action="append", metavar="KEY=VALUE",
                   help="set a scene parameter ($KEY in the XML); repeatable")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.sampler is not None:
        check_sampler_name(args.sampler)
    overrides = parse_effect_overrides(args.effect)
    planned = plan_scene(args.scene, parse_defines(args.defines), overrides)
    scene_sampler = planned.scene.sensors()[0].sampler()
    spp = args.spp or scene_sampler.sample_count()
    sampler = make_sampler(args.sampler, spp) if args.sampler else scene_sampler
    planned.schedule(sampler, spp, args.seed)
    if args.json:
        print(json.dumps(planned.plan.to_dict(), indent=2))
    else:
        print(planned.plan.describe())
    return 0
