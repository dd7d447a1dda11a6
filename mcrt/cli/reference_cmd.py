"""``mcrt reference``: a cached, resumable high-spp reference with per-pixel statistics."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..analysis.reference import (
    DEFAULT_REFERENCE_SPP,
    get_reference,
    reference_layers,
    reference_metadata,
)
from ..core.atomic import remedy
from ..core.executor import cluster_address
from ..core.job import Interrupted
from ..core.provenance import located
from ..core.sampling import check_sampler_name
from ..errors import McrtError
from ..io import write_exr
from ..render.scene import check_scene_file, parse_defines
from . import SUMMARIES, _common
from ._common import (
    check_output_files,
    examples,
    non_negative_int,
    note_first_run,
    output_stem,
    positive_int,
    sampler_choices,
)


def add_parser(commands) -> None:
    p = commands.add_parser(
        "reference", help=SUMMARIES["reference"],
        description="Render a reference of SCENE.xml in passes of independent seeds, merging "
                    "exact float64 per-pixel statistics, and write OUT.exr: the mean as its R, G, "
                    "B channels and layers variance (per sample), stderr (of the mean), count "
                    "(samples per pixel) and nonfinite (if any). Results are cached by scene "
                    "content and parameters ($MCRT_CACHE_DIR, else $XDG_CACHE_HOME/mcrt, else "
                    "~/.cache/mcrt); an interrupted reference resumes from its last pass.",
        epilog=examples("mcrt reference scenes/cornell_box.xml --spp 4096",
                        "mcrt reference scenes/checkerboard.xml --sampler jittered -o out/refs/",
                        "mcrt reference scenes/edges.xml --sampler pointset -P filename=sets.npy",
                        "mcrt reference scenes/cornell_box.xml --spp 65536 --cluster local"))
    p.add_argument("scene", metavar="SCENE.xml", help="Mitsuba 3 XML scene")
    p.add_argument("--spp", type=positive_int, default=DEFAULT_REFERENCE_SPP, metavar="N",
                   help=f"total samples per pixel (default {DEFAULT_REFERENCE_SPP})")
    p.add_argument("--sampler", default="independent", metavar="NAME",
                   help=f"sampler plugin (default independent); one of {sampler_choices()}")
    p.add_argument("-P", "--sampler-param", dest="sampler_params", action="append",
                   metavar="KEY=VALUE",
                   help="a parameter of the --sampler plugin (e.g. -P filename=sets.npy for "
                        "pointset); repeatable")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                   help="seed; pass i uses a seed hashed from (S, i) (default 0)")
    p.add_argument("--spp-per-pass", type=positive_int, metavar="N",
                   help="samples per pixel of one pass (default 256, fewer for large images)")
    p.add_argument("-D", dest="defines", action="append", metavar="KEY=VALUE",
                   help="set a scene parameter ($KEY in the XML); repeatable")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="output EXR path, or a directory to write into "
                        "(default: out/<scene>_reference.exr)")
    p.add_argument("--no-cache", action="store_true",
                   help="neither read nor write the cache (no resume)")
    _common.add_cluster_argument(p)
    p.set_defaults(run=run)


def _output_path(out: str | None, scene: str) -> Path:
    """``-o OUT`` as an EXR path (the same rules as ``mcrt render``'s ``-o``)."""
    stem = output_stem(out, f"{Path(scene).stem}_reference")
    return stem.with_name(stem.name + ".exr")


def run(args: argparse.Namespace) -> int:
    # Everything a user can get wrong is checked before rendering starts
    # (get_reference loads the scene and plans the passes before its first pass).
    check_sampler_name(args.sampler)
    sampler_params = _common.parse_sampler_params(args.sampler_params)
    params = located(args.scene, parse_defines(args.defines))  # -D files by absolute path
    check_scene_file(args.scene)
    out = _output_path(args.output, args.scene)
    # Refused (a check, too little room) or failed before writing: no empty folder is left.
    with _common.removed_if_refused(out.parent):
        check_output_files(out)
        note_first_run()
        try:
            with _common.cluster_executor(cluster_address(args.cluster)) as executor:
                ref = get_reference(args.scene, params, spp=args.spp, sampler=args.sampler,
                                    seed=args.seed, spp_per_pass=args.spp_per_pass,
                                    progress=not args.quiet, cache=not args.no_cache,
                                    before_work=lambda w, h: _before_work(out, w * h),
                                    executor=executor, sampler_params=sampler_params)
        except Interrupted as stop:
            return _interrupted(stop, args, params, out)
    try:
        write_exr(out, reference_layers(ref), reference_metadata(ref, args.scene, params))
    except (McrtError, OSError) as error:
        raise McrtError(f"{error}; {_kept(ref)}: {remedy(error)} and run the same command "
                        f"again to write it without rendering") from None

    height, width = ref.mean.shape[:2]
    if ref.cached:
        print(f"found in cache (key {ref.key}): nothing rendered")
    elif ref.resumed_passes:
        print(f"resumed after pass {ref.resumed_passes} of {ref.passes}")
    spp_text = f"spp {ref.spp}" + (f" (requested {args.spp})" if ref.spp != args.spp else "")
    nonfinite = int(ref.stats.nonfinite.sum())
    print(f"reference {width}x{height}  sampler {ref.sampler}  {spp_text}  passes {ref.passes} "
          f"({ref.plan.describe() if ref.plan else ''})  samples {ref.drawn_samples}"
          + (f" ({nonfinite} non-finite, excluded)" if nonfinite else ""))
    # Wall time (all sessions of a resumed reference); on a cluster the passes'
    # own times, added up over the workers, are said apart and named as such.
    summed = (f"  (passes' summed time on the workers {ref.pass_seconds:.2f} s)"
              if ref.pass_seconds > 0 and cluster_address(args.cluster) else "")
    print(f"render {_common.speed(ref.seconds, ref.samples_per_second)}{summed}  "
          f"{_stderr_summary(ref.standard_error)}")
    print(f"wrote {out}")
    return 0


def _stderr_summary(stderr: np.ndarray) -> str:
    """``mean stderr X  max stderr Y`` over the pixels whose error is known (NaN:
    fewer than two finite samples), and how many are not."""
    known = stderr[np.isfinite(stderr)]
    if known.size == 0:
        return "stderr unknown (no pixel has two finite samples)"
    unknown = int(np.count_nonzero(~np.isfinite(stderr).all(axis=-1)))
    return (f"mean stderr {float(np.mean(known)):.3g}  max stderr {float(np.max(known)):.3g}"
            + (f"  ({unknown} pixels with fewer than two finite samples: stderr NaN)"
               if unknown else ""))


def _interrupted(stop: Interrupted, args: argparse.Namespace, params: dict[str, str],
                 out: Path) -> int:
    """Ctrl-C / SIGTERM: the finished passes written as a partial reference."""
    part = stop.partial
    meta = {**reference_metadata(part, args.scene, params), "partial": 1,
            "passes_done": stop.done, "spp": int(part.stats.count.max())}
    write_exr(out, reference_layers(part), meta)
    print(f"interrupted after {stop.done} of {part.passes} passes: wrote the partial "
          f"reference ({int(part.stats.count.max())} of {part.spp} spp) to {out}")
    if not args.no_cache:
        print("run the same command again to resume")
    return 130


def _kept(ref) -> str:
    """Where the finished reference is kept when its EXR cannot be written (with
    ``--no-cache`` it is saved to the cache now, so the work is not lost)."""
    from ..analysis.reference_cache import cache_paths, save_state

    finished = cache_paths(ref.key)[0]
    if not finished.is_file():
        try:
            save_state(finished, ref.key, ref.stats, ref.passes, ref.passes, ref.seconds,
                       complete=True)
        except (McrtError, OSError):
            return "the finished reference could not be kept"
    return f"the finished reference is kept in {finished}"


def _before_work(out: Path, pixels: int) -> None:
    """Checks once the image size is known: room for the EXR (11 float32 layers)."""
    _common.require_space(out.parent, _common.image_bytes(pixels, 11) + (1 << 20))
