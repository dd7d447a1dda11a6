"""``mcrt demo``: render the shipped scenes with every sampler and compare them."""

from __future__ import annotations

import argparse
import csv
import logging
from collections.abc import Callable
from pathlib import Path

from ..analysis.metrics import rel_mse
from ..core.atomic import atomic_path
from ..core.provenance import (
    COMMAND,
    absolute,
    command_text,
    csv_values,
    png_text,
    scene_facts,
    software,
)
from ..core.render import FilmRender, render_film
from ..core.sampling import check_sampler_name, make_sampler
from ..core.timing import run_interleaved, summarise
from ..errors import McrtError
from ..io import write_contact_sheet, write_exr, write_png
from ..render.plan import plan_scene
from . import SUMMARIES, _common
from ._common import ensure_writable_dir, examples, positive_int

log = logging.getLogger("mcrt.demo")

#: Samplers compared by default: ours, then Mitsuba's closest equivalents.
DEMO_SAMPLERS = ("uniform_grid", "jittered", "poisson_disk", "independent", "stratified")

#: The shipped scenes the demo renders.
DEMO_SCENES = ("cornell_box.xml", "checkerboard.xml")


def default_scene_dir() -> Path:
    """``scenes/`` of the source checkout this package runs from."""
    return Path(__file__).resolve().parents[2] / "scenes"


def add_parser(commands) -> None:
    p = commands.add_parser(
        "demo", help=SUMMARIES["demo"],
        description="Renders each shipped scene with each sampler at the scene's default "
                    "sample count, and a high-spp jittered reference; writes EXR/PNG images, a "
                    "contact sheet per scene and results.csv with relMSE and time. Times follow "
                    "mcrt's timing protocol: each sampler first renders once untimed (kernel "
                    "compilation), then the samplers render in interleaved rounds, shuffled "
                    "per round; a time is the median of its rounds.",
        epilog=examples("mcrt demo", "mcrt demo --samplers jittered,sobol -o out/demo_sobol"))
    p.add_argument("-o", "--output", default="out/demo", metavar="DIR",
                   help="output directory (default: out/demo)")
    p.add_argument("--samplers", default=",".join(DEMO_SAMPLERS), metavar="A,B,...",
                   help="comma-separated samplers (default: %(default)s)")
    p.add_argument("--scenes", type=Path, default=None, metavar="DIR",
                   help="directory holding the shipped scenes (default: the checkout's scenes/)")
    p.add_argument("--reference-factor", type=positive_int, default=16, metavar="K",
                   help="reference spp = K x the scene's spp (default: 16)")
    p.add_argument("--rounds", type=positive_int, default=3, metavar="R",
                   help="timed renders per sampler, interleaved (default: 3)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import drjit as dr

    names = [name.strip() for name in args.samplers.split(",") if name.strip()]
    samplers = [check_sampler_name(name) for name in names]
    if not samplers:
        raise McrtError("--samplers: give at least one sampler")
    scene_dir = args.scenes or default_scene_dir()
    paths = [scene_dir / name for name in DEMO_SCENES]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise McrtError(f"shipped scene(s) not found: {', '.join(missing)} (use --scenes DIR)")
    with _common.removed_if_refused(Path(args.output)):  # a refused demo leaves no folder
        out = ensure_writable_dir(Path(args.output))
        # All loading errors first. The shipped demo scenes are static: no sub-frames.
        scenes = {path.stem: plan_scene(path).scene for path in paths}
        pixels = sum(int(s.sensors()[0].film().size()[0]) * int(s.sensors()[0].film().size()[1])
                     for s in scenes.values())
        # Per scene: the reference and each sampler's EXR (RGB) and PNG, and the contact sheet.
        _common.require_space(out, _common.PLOTS_BYTES + pixels * (len(samplers) + 1)
                              * (_common.image_bytes(1, 3) + 2 * 4), "the images")

    _common.note_first_run()
    record = _common.recorded(args, "--samplers", ",".join(samplers), "--scenes",
                              absolute(scene_dir), "--reference-factor", args.reference_factor,
                              "--rounds", args.rounds)
    rows = []
    for stem, scene in scenes.items():
        spp = scene.sensors()[0].sampler().sample_count()
        ref_spp = spp * args.reference_factor
        print(f"[{stem}] reference: jittered, {ref_spp} spp ...", flush=True)
        reference = render_film(scene, make_sampler("jittered", ref_spp), seed=0,
                                progress=not args.quiet)
        write_exr(out / f"{stem}_reference.exr", {"rgb": reference.image},
                  {**_header(paths, stem, "jittered", ref_spp, 0), "spp": reference.spp,
                   "role": "reference"})
        sheet = []
        results: dict[str, FilmRender] = {}

        def case(name: str, scene=scene, results=results, spp=spp) -> Callable[[], None]:
            def render() -> None:  # seed 1 every round: the same image, timed R times
                results[name] = render_film(scene, make_sampler(name, spp), seed=1,
                                            progress=False)
            return render

        # The timing protocol (mcrt.core.timing): an untimed warm-up per sampler, then
        # interleaved rounds; every round renders the same image.
        samples = run_interleaved([case(name) for name in samplers], args.rounds,
                                  sync=dr.sync_thread)
        for name, timing in zip(samplers, samples, strict=True):
            result, summary = results[name], summarise(timing)
            error = rel_mse(result.rgb, reference.rgb)
            stem_out = out / f"{stem}_{name}"
            header = _header(paths, stem, name, spp, 1)
            write_exr(stem_out.with_suffix(".exr"), {"rgb": result.image},
                      {**header, "spp": result.spp})
            write_png(stem_out.with_suffix(".png"), result.rgb, text=png_text(header))
            rows.append({"scene": stem, "sampler": name, "spp": result.spp,
                         "seconds": round(summary.median, 4),
                         "seconds_spread": round(summary.spread, 4), "rounds": summary.n,
                         "rel_mse": f"{error:.4e}"})
            sheet.append((f"{name} ({result.spp} spp)\nrelMSE {error:.2e}, "
                          f"{summary.median:.2f} s", result.rgb))
            doubt = f"  ({'; '.join(summary.problems())})" if summary.problems() else ""
            print(f"[{stem}] {name:13s} spp {result.spp:5d}  time {summary.median:6.2f} s "
                  f"+- {summary.spread:.2f}  relMSE {error:.3e}{doubt}", flush=True)
        sheet.append((f"reference ({reference.spp} spp)", reference.rgb))
        write_contact_sheet(out / f"{stem}_comparison.png", sheet, columns=3,
                            text=png_text(record))

    made = csv_values(record)  # how the file was made: on every row
    with atomic_path(out / "results.csv") as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=[*rows[0], *made])
        writer.writeheader()
        writer.writerows({**row, **made} for row in rows)
    print(f"times: median of {args.rounds} interleaved rounds +- robust spread, after an untimed "
          f"warm-up render per sampler; wrote "
          f"images, {', '.join(f'{s}_comparison.png' for s in scenes)} and results.csv to {out}")
    return 0


def _header(paths: list[Path], stem: str, sampler: str, spp: int, seed: int) -> dict:
    """A demo image's header: what ``mcrt render`` records, with the command that
    renders the same pixels (:mod:`mcrt.core.provenance`)."""
    path = next(p for p in paths if p.stem == stem)
    return {**software(), "mcrt_kind": "render", "scene": str(path), **scene_facts(path, {}),
            "sampler": sampler, "spp_requested": spp, "seed": seed,
            COMMAND: command_text("render", absolute(path), "--sampler", sampler, "--spp", spp,
                                  "--seed", seed)}
