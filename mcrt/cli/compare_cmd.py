"""``mcrt compare``: run a study (scenes x samplers x spp x seeds) and write its report.

Every finished cell is saved in ``DIR/.mcrt-resume/`` as it completes. Ctrl-C
writes the report of the finished cells, marked partial, and exits with status
130; running the same command again resumes: saved cells are not rendered
again (see :class:`mcrt.analysis.study.store.StudyState`).
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from ..analysis.report import report_files, write_report
from ..analysis.study import (
    STATE_DIR,
    StudyResult,
    StudyState,
    load_config,
    run_study,
)
from ..analysis.study.conclude import (
    bias_lines,
    cost_df,
    cost_text,
    cpus_line,
    interval_text,
    ratio_sentence,
    ratio_text,
    timing_lines,
)
from ..core.atomic import remedy
from ..core.executor import cluster_address
from ..core.job import Interrupted
from ..errors import McrtError
from . import SUMMARIES, _common
from ._common import check_output_files, ensure_writable_dir, examples
from .reproduce_study import CARRIERS_TEXT

log = logging.getLogger("mcrt.compare")

#: Libraries a study loads after its first render (CIEDE2000 from colour, which
#: loads scipy and its OpenBLAS; the report's plots, images and FLIP maps):
#: imported before any render (see :func:`mcrt.cli._common.import_up_front`).
STUDY_MODULES = ("colour", "colour.difference", "matplotlib.figure",
                 "matplotlib.backends.backend_agg", "PIL.Image", "PIL.ImageDraw",
                 "PIL.ImageFont", "OpenEXR", "flip_evaluator")

#: Address space :data:`STUDY_MODULES` take with one OpenBLAS thread (measured:
#: 186 MiB after Mitsuba, 218 before numpy's OpenBLAS has its buffer), with room to spare.
STUDY_MODULE_BYTES = 288 << 20


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = commands.add_parser(
        "compare", help=SUMMARIES["compare"],
        description="Run the study described by CONFIG.toml (scenes x samplers x sample counts "
                    "x seeds, see configs/quick.toml): time every render after a warm-up, "
                    "measure MSE, relMSE, variance, bias, CIEDE2000 and aliasing against a "
                    "high-spp reference, fit error-vs-spp and error-vs-time slopes, and write "
                    "report.html, results.csv, results.json and PNG plots into DIR. Finished "
                    f"cells are saved in DIR/{STATE_DIR}: after Ctrl-C (which writes a partial "
                    "report) the same command resumes where it stopped.",
        epilog=examples("mcrt compare configs/quick.toml",
                        "mcrt compare configs/quick.toml --check",
                        "mcrt compare configs/full.toml -o out/full -q",
                        "mcrt compare configs/full.toml --cluster local:2",
                        "mcrt compare --from out/compare/quick/results.csv",
                        "mcrt compare --from out/compare/quick/results.json -o again"))
    p.add_argument("config", metavar="CONFIG.toml", nargs="?",
                   help="study configuration (TOML)")
    p.add_argument("--from", dest="from_file", metavar=CARRIERS_TEXT,
                   help="run again the study whose results file this is (the command it "
                        "records) into -o DIR (default: its folder + _again, beside it), and "
                        "say whether every cell's numbers are the same bit for bit in the new "
                        "file of that kind, times aside (exit status 1 if not)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="report directory (default: out/compare/<study name>)")
    p.add_argument("--check", action="store_true",
                   help="only validate the configuration (load scenes, make samplers) and exit")
    p.add_argument("--restart", action="store_true",
                   help=f"ignore the cells saved in DIR/{STATE_DIR} and measure every cell again")
    p.add_argument("--retime", action="store_true",
                   help=f"time the cells saved in DIR/{STATE_DIR} again (interleaved rounds of "
                        "timing-only renders) and rewrite the report; their errors are kept, "
                        "e.g. after the report said that timing was disturbed")
    _common.add_cluster_argument(p)
    p.set_defaults(run=run)


def resume_command(args: argparse.Namespace, out: Path) -> str:
    """The command line that resumes this study: with its variant (whose key the
    saved state carries; without it the state would belong to another study) and
    the plugins the command line or ``$MCRT_PLUGINS`` loaded (the configuration's
    own ``plugins`` load with it)."""
    import mitsuba as mi

    from ..plugins import command_words

    quiet = ["-q"] if getattr(args, "quiet", False) else []
    variant = mi.variant() or "llvm_ad_rgb"
    given = ["--variant", variant] if getattr(args, "variant", None) or \
        variant != "llvm_ad_rgb" else []
    given += command_words(getattr(args, "plugin_files", None) or [])
    return shlex.join(["mcrt", *quiet, *given, "compare", str(args.config), "-o", str(out)])


def _study_command(args: argparse.Namespace) -> str:
    """``mcrt --variant V [--plugin FILE]... compare CONFIG``, the configuration
    and plugin files by absolute path: what results.json records, to run the
    study again from any folder (into its default output, or ``-o`` added)."""
    from ..core.provenance import COMMAND

    return _common.recorded(args, str(Path(args.config).resolve()))[COMMAND]


def run(args: argparse.Namespace) -> int:
    if args.from_file is not None:
        from .reproduce_study import run_from

        return run_from(args)
    if args.config is None:
        raise McrtError(f"give the study's configuration (CONFIG.toml), or --from "
                        f"{CARRIERS_TEXT}")
    config = load_config(args.config)  # every input error surfaces here, before rendering
    if args.check:
        print(f"{args.config}: OK ({len(config.scenes)} scenes, {len(config.samplers)} samplers, "
              f"{len(config.spp)} sample counts, {len(config.seeds)} seeds, {config.rounds} "
              f"timed rounds: {config.renders} renders)")
        return 0
    out = Path(args.output) if args.output else Path("out") / "compare" / config.name
    with _common.removed_if_refused(out):  # a refused study leaves no empty folder
        if args.retime and args.restart:
            raise McrtError("--retime times the saved cells again; --restart discards them: "
                            "use one of the two")
        ensure_writable_dir(out)
        check_output_files(*report_files(out, [s.name for s in config.scenes]).values())
        for state_dir in sorted(out.glob(f"{STATE_DIR}*")):  # the saved state, and set aside
            _common.check_state_directory(state_dir, "the study's saved state")
        _check_space(config, out)
        _common.import_up_front(STUDY_MODULES, STUDY_MODULE_BYTES,
                                "the study's metrics and report")
    _common.note_first_run()

    with StudyState.open(out, config, restart=args.restart) as state:  # the lock, released
        return _measure(args, config, state, out)


def _measure(args: argparse.Namespace, config, state: StudyState, out: Path) -> int:
    """Measure the study's cells (resuming ``state``), write the report, summarise."""
    if args.retime:
        if len(state.cells) < config.cells:
            raise McrtError(f"--retime needs every cell measured: {len(state.cells)} of "
                            f"{config.cells} are saved in {state.directory}; run the same "
                            f"command without --retime first")
        log.info("timing the %d saved cells again (their errors are kept)", len(state.cells))
    elif state.cells:
        log.info("resuming: %d of %d cells were measured by an earlier run (%s; --restart "
                 "measures them again)", len(state.cells), config.cells, state.directory)
    try:
        with _common.cluster_executor(cluster_address(args.cluster)) as executor:
            result = run_study(config, progress=not args.quiet, state=state, executor=executor,
                               retime=args.retime)
    except Interrupted as stop:
        return _write_partial(stop.partial, args, out)
    except McrtError as error:
        if state.cells and state.writable:
            raise McrtError(f"{error} ({len(state.cells)} finished cells are saved in "
                            f"{state.directory}; the same command resumes)") from None
        raise
    result.command = _study_command(args)
    try:
        files = write_report(result, out)
    except KeyboardInterrupt:  # every cell is measured and saved: only the report is missing
        print(f"mcrt: interrupted while writing the report; the {len(state.cells)} measured "
              f"cells are saved: to write it, run: {resume_command(args, out)}", file=sys.stderr)
        return 130
    except (McrtError, OSError) as error:
        kept = (f"; the {len(state.cells)} measured cells are kept in {state.directory}: "
                f"{remedy(error)} and run the same command again to write the report without "
                f"measuring again") if state.cells and state.writable else ""
        raise McrtError(f"{error}{kept}") from None

    _print_summary(result)
    for line in bias_lines(result.cells):
        print(f"bias: {line}")
    # The resume command's variant and plugins: the saved cells are the variant's own.
    retime = f"{resume_command(args, out)} --retime"
    for line in timing_lines(result.timing, retime):
        print(f"timing: {line}")
    pinned = cpus_line(result.environment)
    if pinned:
        print(f"timing: {pinned}")
    resumed = (f" ({result.resumed_cells} of {config.cells} cells from the saved state)"
               if result.resumed_cells else "")
    print(f"study took {result.seconds:.1f} s of wall time{resumed}, including kernel "
          f"compilation, warm-ups and references (the per-render times of the report exclude "
          f"them); wrote {files['report']} (and results.csv, results.json, plots in {out})")
    return 0


def _check_space(config, out: Path) -> None:
    """Room for the report (plots, tables, per-scene image sheets), the resume
    state's images (three float32 arrays per scene and sampler) and the
    references' cache files, before any cell is measured."""
    from ..analysis.reference_cache import STATE_BYTES_PER_PIXEL, cache_paths
    from ..core.atomic import check_free_space

    pixels = [config.film_pixels[spec.name] for spec in config.scenes]  # by load_config
    samplers = len(config.samplers)
    report = sum(p * (samplers * 3 * 4 * 2 + (samplers + 1) * 4 * 3) for p in pixels)
    # Per cell: the viewer's images in the resume state (7 float32 a pixel), as EXR (7)
    # and embedded in report.html (at most 10, base64).
    report += sum(p * samplers * len(config.spp) * 4 * (7 + 7 + 14) for p in pixels)
    _common.require_space(out, report + _common.PLOTS_BYTES, "the report and its resume state")
    cache = cache_paths("x")[0].parent
    check_free_space(cache, sum(3 * STATE_BYTES_PER_PIXEL * p for p in pixels),
                     "the reference cache files")


def _write_partial(result: StudyResult, args: argparse.Namespace, out: Path) -> int:
    """Ctrl-C: the report of the finished cells, marked partial; exit status 130.

    A second Ctrl-C while it is written leaves the previous files (atomic
    writes) and the saved state intact; the command line then reports a plain
    interruption.
    """
    command = resume_command(args, out)
    result.resume_command = command
    result.command = _study_command(args)
    done, total = len(result.cells), result.config.cells
    try:
        write_report(result, out)
        written = f"wrote a partial report ({done} of {total} cells) to {out}"
    except McrtError as error:
        written = f"could not write the partial report ({error})"
    print(f"mcrt: interrupted: {written}; to resume, run: {command}", file=sys.stderr)
    return 130


def _print_summary(result: StudyResult) -> None:
    """Per scene: slopes and cost per sampler, then efficiency ratios to the
    baseline at every spp (95% intervals), then the ratios at the largest spp
    in words."""
    config, baseline = result.config, result.config.baseline
    for scene in result.scenes:
        print(f"{scene}: log-log slopes of excess MSE vs spp and vs time [95%]; cost per "
              f"render = fixed + per sample (fit over the timed renders)")
        print(f"  {'sampler':14s} {'slope vs spp':>22s} {'slope vs time':>22s} "
              f"{'fixed ms':>9s} {'ns/sample':>9s}")
        for sampler in config.samplers:
            fit = result.fit(scene, sampler.label)
            spp_slope, time_slope = (
                interval_text(fit[f"slope_{k}"], fit[f"slope_{k}_low"], fit[f"slope_{k}_high"],
                              "+.2f") for k in ("spp", "seconds"))
            df = cost_df([c for c in result.cells
                          if c["scene"] == scene and c["sampler"] == sampler.label])
            fixed = cost_text(fit["fixed_seconds"], fit["fixed_seconds_se"], 1e3, df=df)
            per_sample = cost_text(fit["seconds_per_sample"], fit["seconds_per_sample_se"], 1e9,
                                   df=df)
            print(f"  {sampler.label:14s} {spp_slope:>22s} {time_slope:>22s} "
                  f"{fixed:>9s} {per_sample:>9s}")
        print(f"  efficiency = 1/(excess MSE x median render time), as a ratio to {baseline}'s "
              f"at the same spp [95%]:")
        cells = {(c["sampler"], c["spp_requested"]): c for c in result.cells
                 if c["scene"] == scene}
        rows = []
        for sampler in config.samplers:
            row = []
            for spp in config.spp:
                c = cells.get((sampler.label, spp))
                row.append("pending" if c is None else "unresolved" if not c["resolved"] else
                           ratio_text(c["efficiency_ratio"], c["efficiency_ratio_low"],
                                      c["efficiency_ratio_high"]))
            rows.append((sampler.label, row))
        width = max([20, *(len(r) + 1 for _, row in rows for r in row)])  # columns stay apart
        print(f"  {'sampler':14s} " + " ".join(f"{f'{spp} spp':>{width}s}" for spp in config.spp))
        for label, row in rows:
            print(f"  {label:14s} " + " ".join(f"{r:>{width}s}" for r in row))
        largest = max(spp for (_, spp) in cells) if cells else None
        for sampler in config.samplers:
            c = cells.get((sampler.label, largest)) if largest is not None else None
            sentence = ratio_sentence(c, baseline) if c is not None else ""
            if sentence:
                print(f"  {sentence}")

