"""``mcrt render``: render a scene with any sampler, write EXR + PNG.

Interrupting a render (Ctrl-C) writes the passes finished so far as OUT.exr /
OUT.png, marked partial with their sample count, and keeps a checkpoint next to
them (``.OUT.exr.mcrt-resume.npz``); running the same command again resumes
from it. If the outputs cannot be written at the end (say, a full disk), the
finished render is kept the same way and the next run only writes it.
"""

from __future__ import annotations

import argparse
import functools
import logging
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import asdict, replace
from pathlib import Path

from ..core.atomic import check_free_space, remedy
from ..core.engine import reseeds_each_pass
from ..core.executor import cluster_address
from ..core.job import Checkpoint, Checkpointing, CheckpointStore, Interrupted
from ..core.provenance import located, png_text
from ..core.render import FilmRender, PassTasks, render_film
from ..core.render_job import checkpoint_paths, render_key, require_render_memory
from ..core.sampling import (
    base_seed,
    check_sampler_name,
    make_sampler,
    quiet_sampler_warnings,
    sampler_name,
)
from ..core.sampling import sampler_params as sampler_params_of
from ..core.trace import film_grid_size
from ..errors import McrtError
from ..io import write_exr, write_png
from ..io.parallel import write_all
from ..render import adaptive
from ..render.plan import parse_effect_overrides, plan_scene
from ..render.scene import parse_defines
from ..samplers import names
from ..samplers.base import is_mcrt_sampler
from . import SUMMARIES, _adaptive_args, _common
from ._common import (
    check_output_files,
    checkpoint_interval,
    examples,
    non_negative_int,
    note_first_run,
    output_stem,
    positive_int,
    sampler_choices,
)
from ._render_record import check_replaces_same, job_text, render_metadata
from .plan_cmd import add_effect_argument

log = logging.getLogger("mcrt.render")


def add_parser(commands) -> None:
    p = commands.add_parser(
        "render", help=SUMMARIES["render"],
        description="Render SCENE.xml and write OUT.exr (float32) and OUT.png (sRGB preview; "
                    "linear values above 1 are clipped). Ctrl-C writes the passes finished so "
                    "far (marked partial); the same command then resumes.",
        epilog=examples("mcrt render scenes/cornell_box.xml --sampler poisson_disk --spp 64",
                        "mcrt render scenes/cornell_box.xml -D res=128 -o out/renders/",
                        "mcrt render scenes/edges.xml --adaptive --threshold 0.05",
                        "mcrt render --from out/cornell_box_sobol.exr -o again"))
    p.add_argument("scene", metavar="SCENE.xml", nargs="?", help="Mitsuba 3 XML scene")
    p.add_argument("--from", dest="from_exr", metavar="FILE.exr",
                   help="render again what FILE.exr records (any EXR mcrt wrote: a render, "
                        "a reference, a study's image) with its settings alone, to -o OUT "
                        "(default: FILE_again.exr beside it), and say whether the pixels are "
                        "the same bit for bit (exit status 1 if not)")
    p.add_argument("--sampler", metavar="NAME",
                   help=f"sampler plugin (default: the scene's); one of {sampler_choices()}")
    p.add_argument("-P", "--sampler-param", dest="sampler_params", action="append",
                   metavar="KEY=VALUE",
                   help="a parameter of the --sampler plugin (e.g. -P jitter=0.5); repeatable")
    p.add_argument("--spp", type=positive_int, metavar="N",
                   help="samples per pixel (default: the scene's)")
    p.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument("-D", dest="defines", action="append", metavar="KEY=VALUE",
                   help="set a scene parameter ($KEY in the XML); repeatable")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="output path without extension, or a directory to write into "
                        "(default: out/<scene>_<sampler>)")
    _common.add_cluster_argument(p)
    add_effect_argument(p)  # the render follows the scene's plan (see `mcrt plan`)
    p.add_argument("--multisample", action="store_true",
                   help="multisampling: trace visibility at every sample but shade once per "
                        "surface per pixel (nests the scene's integrator in multisample; "
                        "see docs/multisampling.md)")
    _adaptive_args.add_cli_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.from_exr is not None:
        from .reproduce import run_from

        return run_from(args)
    if args.scene is None:
        raise McrtError("give the scene to render (SCENE.xml), or --from FILE.exr")
    # Everything a user can get wrong is checked before rendering starts.
    if args.sampler is not None:
        check_sampler_name(args.sampler)
    params = located(args.scene, parse_defines(args.defines))  # -D files by absolute path
    sampler_params = parse_sampler_params(args.sampler_params, args.sampler)
    overrides = parse_effect_overrides(args.effect)
    multisample = getattr(args, "multisample", False)
    if multisample and getattr(args, "adaptive", False):
        raise McrtError("--multisample and --adaptive cannot be combined (multisampling shares "
                        "shading among a pixel's samples of one whole-image pass)")
    planned = plan_scene(args.scene, params, overrides,
                         wrap="multisample" if multisample else None)
    if multisample:
        _note_shading_noise(planned.plan.effects_on, planned.scene.sensors()[0])
    scene = planned.scene
    scene_sampler = scene.sensors()[0].sampler()
    name = args.sampler or sampler_name(scene_sampler)
    spp = args.spp or scene_sampler.sample_count()
    adaptive_settings = _adaptive_args.cli_settings(args, scene, planned.plan)
    # An adaptive render sets its own batch counts, from min_spp up: its sampler is made
    # at min_spp (a point-set file may hold no larger sets), and a note on rounding --spp
    # (its budget) would be about a sample count it never uses.
    quiet = quiet_sampler_warnings() if adaptive_settings is not None else nullcontext()
    with quiet:
        sampler = make_sampler(name, spp if adaptive_settings is None else
                               adaptive_settings.min_spp, **sampler_params) \
            if args.sampler else scene_sampler
    if sampler is scene_sampler and adaptive_settings is None and spp != sampler.sample_count():
        sampler = sampler.clone()  # --spp: the scene's at that count (rounding noted below)
        with quiet_sampler_warnings():
            sampler.set_sample_count(spp)
    stem = output_stem(args.output, f"{Path(args.scene).stem}_{name}")
    exr_path, png_path = stem.with_suffix(".exr"), stem.with_suffix(".png")
    heat_path = stem.with_name(stem.name + "_spp.png")
    budget = adaptive_settings.max_spp if adaptive_settings is not None else spp
    with _common.removed_if_refused(exr_path.parent):  # a refused render leaves no folder
        check_output_files(exr_path, png_path, *([heat_path] if adaptive_settings else []))
        check_output_space(exr_path.parent, scene)
        width, height = (int(v) for v in film_grid_size(scene.sensors()[0].film()))
        require_render_memory(width, height, adaptive_settings.subpixels
                              if adaptive_settings is not None else None)
        cluster = _render_cluster(args, sampler, adaptive=adaptive_settings is not None)
        metadata = render_metadata(args, params, sampler, budget, scene, planned.plan,
                                   adaptive_settings)
        check_replaces_same(exr_path, metadata, named=bool(args.output))
    note_first_run()
    log.info("plan: %s", planned.plan.summary())
    if adaptive_settings is not None:
        metadata["plan"] = planned.plan.to_json()
        key = render_key(args.scene, params, overrides, name, 0, args.seed, None,
                         adaptive=asdict(adaptive_settings), sampler_params=sampler_params)
        return _run_adaptive(args, scene, sampler, name, adaptive_settings, metadata,
                             (exr_path, png_path, heat_path), key)

    passes, on_pass = planned.schedule(sampler, spp, args.seed)  # motion sub-frames
    metadata["plan"] = planned.plan.to_json()  # with the sub-frame times just chosen
    if sampler.sample_count() != spp:
        log.info("%s uses %d samples per pixel (requested %d)", name, sampler.sample_count(), spp)
    key = render_key(args.scene, params, overrides, name, sampler.sample_count(), args.seed,
                     passes, sampler_params=metadata["sampler_params"])
    store, state = _resumable(args, exr_path, key, spp, stem)
    if state is not None:
        log.info("resuming after pass %d of %d", state.meta["done"], state.meta["settings"][1])

    tasks = _pass_tasks(args, planned, params, overrides, name, sampler, spp) if cluster \
        else None
    try:
        with _common.cluster_executor(cluster) as executor:
            result = render_film(scene, sampler, seed=args.seed, progress=not args.quiet,
                                 passes=passes, on_pass=on_pass,
                                 checkpoints=_checkpointing(store, state),
                                 tasks=replace(tasks, executor=executor) if tasks else None)
    except Interrupted as stop:
        target = stop.state.meta["settings"][0] if stop.state is not None else spp

        def write_partial(partial: FilmRender) -> str:
            _write(exr_path, png_path, partial, {**metadata, "partial": 1, "spp_target": target})
            return f"{exr_path} and {png_path} ({partial.spp} spp)"

        return _interrupted(stop, store, write_partial, f"of {stop.total} passes")
    _write_or_keep(store, lambda: _write(exr_path, png_path, result, metadata),
                   lambda: result.checkpoint)
    height, width = result.image.shape[:2]
    print(f"sampler {name}  spp {result.spp}  {width}x{height}  passes {result.passes}  "
          f"{_common.speed(result.seconds, result.samples_per_second)}")
    if result.nonfinite_samples:
        print(_nonfinite_line(result.nonfinite_samples, result.image_nonfinite))
    import numpy as np  # (loaded by the render already)

    overflowed = int(np.count_nonzero(~np.isfinite(result.image).all(axis=-1)))
    if overflowed:  # non-finite samples are left out: these are finite ones that overflowed
        log.warning("%d pixels are infinite although their samples are finite: their "
                    "filtered mean, or the film's conversion of it to its pixel format, passed "
                    "float32's 3.4e38; scale the scene's radiance down", overflowed)
    _print_shading_counts(scene)
    print(f"wrote {exr_path} and {png_path}")
    return 0


def _render_cluster(args: argparse.Namespace, sampler, adaptive: bool) -> str | None:
    """The cluster a render's passes run on (``--cluster``, else ``$MCRT_CLUSTER``),
    or None. Its passes can be tasks only with samplers a worker can start at any
    pass (mcrt's, counter-based, and Mitsuba's ``independent``, seeded afresh by
    every pass; Mitsuba's stratified ones carry a random state from pass to pass)
    and without --adaptive: an error with --cluster, in-process (with a note)
    when the cluster only comes from the environment."""
    address = cluster_address(args.cluster)
    if address is None:
        return None
    why = ("--adaptive renders run in one process" if adaptive else
           None if is_mcrt_sampler(sampler) or reseeds_each_pass(sampler) else
           f"{sampler_name(sampler)} carries its random state from pass to pass, which a "
           f"worker cannot recreate; use one of mcrt's samplers "
           f"({', '.join(names('mcrt'))}) or independent")
    if why is None:
        return address
    if args.cluster is not None:
        raise McrtError(f"--cluster: {why}")
    log.info("rendering in this process, not on $MCRT_CLUSTER: %s", why)
    return None


def _pass_tasks(args: argparse.Namespace, planned, params: dict[str, str],
                overrides: dict[str, bool], name: str, sampler, spp: int) -> PassTasks:
    """The render's passes as tasks (``--cluster``; the executor is added later)."""
    from ..core.scene_files import SceneSource  # only a distributed render ships its scene
    from ..render.loaded import FilmPassTask, film_pass, remember_planned

    wrap = "multisample" if getattr(args, "multisample", False) else None
    source = SceneSource.of(args.scene, params)
    remember_planned(source, params, planned, overrides, wrap)  # for in-process tasks too
    task = FilmPassTask(tuple(sorted(params.items())), tuple(sorted(overrides.items())), wrap,
                        name, tuple(sorted(sampler_params_of(sampler).items())), spp,
                        args.seed, base_seed(sampler), scene_sampler=args.sampler is None)
    return PassTasks(functools.partial(film_pass, task), {"scene": source})


def _print_shading_counts(scene) -> None:
    """What a ``multisample`` integrator shaded (nothing for other integrators)."""
    counts = getattr(scene.integrator(), "counts", None)
    if counts is None or not counts.samples:
        return
    per_pass = sorted(set(counts.samples_per_pixel))
    print(f"multisample: {counts.evaluations} shading evaluations for {counts.samples} "
          f"samples ({counts.per_sample:.4f} per sample), visibility samples shared per pixel "
          f"and pass: {', '.join(map(str, per_pass))}")


def _interrupted(stop: Interrupted, store: CheckpointStore, write, what: str) -> int:
    """Ctrl-C / SIGTERM: write the finished work as a partial image (``write(partial)``
    returns a description of the files) and keep the checkpoint to resume from."""
    kept = store.save(stop.state) if stop.state is not None and stop.done else None
    if stop.partial is not None:
        files = write(stop.partial)
        print(f"interrupted after {stop.done} {what}: wrote the partial image to {files}")
    else:
        print("interrupted before the first pass finished: nothing written")
    if kept is not None:
        print(f"checkpoint {kept}: run the same command again to resume")
    return 130


def _resumable(args: argparse.Namespace, exr_path: Path, key: str, budget: int,
               stem: Path) -> tuple[CheckpointStore, Checkpoint | None]:
    """A render's checkpoint store next to its EXR, and the state to resume from (if any)."""
    paths = checkpoint_paths(exr_path, key)
    _common.check_state_files(paths, "the render's checkpoint")
    store = CheckpointStore(paths, key, job_text(args, budget, stem))
    return store, store.load()


def _checkpointing(store: CheckpointStore, state: Checkpoint | None) -> Checkpointing:
    return Checkpointing(state, store.save_periodic, checkpoint_interval())


def _write_or_keep(store: CheckpointStore, write: Callable[[], None],
                   finished: Callable[[], Checkpoint | None]) -> None:
    """Write a finished render's outputs, then drop its checkpoint. If writing fails
    (a full disk, a film mcrt misreads, ...), the render is kept (``finished()``, or
    the last checkpoint saved if it has none) and the error says how to write it
    without rendering again. ``finished`` is called only then: taken before writing,
    the copy of a 1024^2 film's float64 sums raised the peak memory by 32-64 MiB."""
    try:
        write()
    except Exception as error:
        state = finished()
        kept = store.save(state) if state is not None else store.saved
        where = (f"; the finished render is kept in {kept}: {remedy(error)} and run the same "
                 f"command again to write it without rendering") if kept else ""
        text = f"{error}" if isinstance(error, (McrtError, OSError)) \
            else f"cannot write the outputs: {error}"
        raise McrtError(text + where) from None
    store.discard()


def parse_sampler_params(items: list[str] | None, sampler: str | None) -> dict:
    """``-P key=value`` items to the ``--sampler`` plugin's parameters."""
    params = _common.parse_sampler_params(items)
    if params and sampler is None:
        raise McrtError("-P sets parameters of the sampler given with --sampler")
    return params


def _nonfinite_line(total: int, image_counts, layer: str = "") -> str:
    """The console line of a render's NaN/Inf samples: ``total`` counts every one
    traced (the EXR's ``nonfinite_samples``), ``image_counts`` those per image
    pixel (the ``nonfinite`` layer); a film with a sampled border traces the
    border's pixels too, and its share is named, so the numbers add up."""
    inside = int(image_counts.sum())
    pixels = int((image_counts > 0).sum())
    where = (f"{pixels} pixels affected" if inside == total else
             f"{inside} in {pixels} image pixels, {total - inside} in the film's sampled "
             f"border around the image")
    return f"non-finite samples: {total} (NaN/Inf, left out of the image; {where}{layer})"


def _write(exr_path: Path, png_path: Path, result: FilmRender, metadata: dict) -> None:
    """Write the EXR (no timings in it, so equal renders give equal files) and PNG."""
    meta = {**metadata, "spp": result.spp, "passes": result.passes,
            "nonfinite_samples": result.nonfinite_samples,
            "image_channels": " ".join(result.base_channels)}
    if result.aov_count:
        meta["aov_channels"] = " ".join(result.aovs)
    # The film's channels under Mitsuba's own labels: R G B [A], Y [A] or X Y Z [A]
    # unprefixed, then each AOV channel by its name (``nn.X``, ``_arg_0.R``, ...).
    channels = {name: result.image[..., c] for c, name in enumerate(result.channels)}
    layers = {}
    if result.nonfinite_samples:
        layers["nonfinite"] = result.image_nonfinite.astype("float32")  # the image's pixels
    write_all(lambda: write_exr(exr_path, layers, meta, channels=channels),
              lambda: write_png(png_path, result.rgb, text=png_text(metadata)))  # linear sRGB


def _run_adaptive(args, scene, sampler, name: str, settings, metadata: dict,
                  paths: tuple[Path, Path, Path], key: str) -> int:
    """``mcrt render --adaptive``: passes with active-pixel counts, EXR layers for
    RGB, variance, standard error and sample counts, and a PNG heat map of the
    sample counts. Ctrl-C and resume work as for fixed-spp renders."""
    from ..io.heatmap import write_heatmap

    exr_path, png_path, heat_path = paths
    store, state = _resumable(args, exr_path, key, settings.max_spp, exr_path.with_suffix(""))
    if state is not None:
        log.info("resuming after adaptive pass %d", state.meta["next_pass"])
    grid = film_grid_size(scene.sensors()[0].film())
    pixels = int(grid[0]) * int(grid[1])

    def report(record) -> None:
        if args.quiet:
            return
        sizes = "+".join(map(str, record.batch_sizes))
        print(f"pass {record.index:2d}  active {record.active_pixels:9,d} px "
              f"({100.0 * record.active_pixels / pixels:5.1f}%)  batch {sizes:>14s}  "
              f"samples {record.samples:11,d}  {record.seconds:6.2f} s  "
              f"converged {100.0 * record.converged_pixels / pixels:5.1f}%", flush=True)

    def write(result, extra: dict) -> None:
        meta = {**metadata, **result.summary(), "sampler": result.sampler,
                "image_channels": " ".join(result.channels), **extra}
        meta.pop("render_seconds", None)  # no timings: equal renders, equal files
        write_all(lambda: write_exr(exr_path, result.layers(), meta,
                                    channels=result.film_channels()),
                  lambda: write_png(png_path, result.rgb, text=png_text(metadata)),
                  lambda: write_heatmap(heat_path, result.spp, settings.min_spp,
                                        settings.max_spp, png_text=png_text(metadata)))

    try:
        result = adaptive.render_adaptive(scene, sampler, settings, seed=args.seed,
                                          on_pass=report,
                                          checkpoints=_checkpointing(store, state))
    except Interrupted as stop:
        def write_partial(partial) -> str:
            write(partial, {"partial": 1})
            return f"{exr_path}, {png_path} and {heat_path} ({partial.samples} samples)"

        return _interrupted(stop, store, write_partial, "adaptive passes")
    _write_or_keep(store, lambda: write(result, {}), lambda: result.checkpoint)
    height, width = result.image.shape[:2]
    spp = result.spp
    rate = result.samples / result.seconds if result.seconds > 0 else float("inf")
    print(f"sampler {name}  adaptive  spp mean {spp.mean():.1f} (min {spp.min()}, max "
          f"{spp.max()})  {width}x{height}  passes {len(result.passes)}  "
          f"{_common.speed(result.seconds, rate)}")
    if result.nonfinite_samples:
        print(_nonfinite_line(result.nonfinite_samples, result.nonfinite,
                              ", see layer 'nonfinite'"))
    exhausted = 1.0 - float(result.converged.mean())
    if exhausted > EXHAUSTED_SHARE:
        print(f"note: {100 * exhausted:.1f}% of pixels ran out of the budget of "
              f"{settings.max_spp} spp without meeting the threshold "
              f"{settings.threshold:g}: their error is the budget's, not the threshold's; "
              f"raise --max-spp (or the threshold) to let the adaptive sampler choose")
    print(f"wrote {exr_path}, {png_path} and {heat_path} (sample counts, log scale "
          f"{settings.min_spp}..{settings.max_spp})")
    return 0


#: Effects whose noise multisampling samples at its shading rate, not the pixel's samples.
SHADING_EFFECTS = ("soft_shadows", "glossy", "indirect")


def _note_shading_noise(effects_on: list[str], sensor) -> None:
    """Multisampling shades once per surface per pixel: stochastic shading (area
    lights, rough BSDFs, indirect light) then gets that one sample, not the N of
    supersampling. Say so, once, where a user would otherwise wonder at the noise
    (not on a sensor where every sample is shaded, a radiance meter's)."""
    from ..render.multisample_integrator import shares_shading

    noisy = [e for e in SHADING_EFFECTS if e in effects_on]
    if noisy and shares_shading(sensor):
        log.warning("--multisample shades each surface once per pixel: this scene's %s noise "
                    "is sampled at that rate, so the image is far noisier than supersampling "
                    "at the same spp; multisampling pays off for edges over cheap, noise-free "
                    "shading (docs/multisampling.md)", ", ".join(noisy))


#: Above this share of pixels that did not pass the error test, an adaptive render says
#: that the budget, not the threshold, decided the image.
EXHAUSTED_SHARE = 0.5


def check_output_space(directory: Path, scene) -> None:
    """Refuse to start when the output directory cannot hold the results.

    Needed: the float32 EXR (uncompressed upper bound), the PNG and, for a
    resumable render, a float64 checkpoint of the film.
    """
    film = scene.sensors()[0].film()
    width, height = (int(v) for v in film_grid_size(film))
    channels = 5
    check_free_space(directory, width * height * (channels * 4 + 4 + channels * 8) + (1 << 20),
                     largest=width * height * channels * 8)  # the checkpoint's float64 sums
