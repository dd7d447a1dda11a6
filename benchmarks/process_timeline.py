"""Where a whole ``mcrt render`` process spends its time, stage by stage, next to
the plain Mitsuba script of ``render_overhead.py``.

Each round runs both processes (order shuffled per round: mcrt.core.timing). A
process notes the wall clock when its script starts, after its imports, after loading (plain) or
planning (mcrt) the scene, before and after rendering, and after writing its
files; the parent notes spawn and exit. Printed: the median milliseconds of
each stage over the rounds:

* **interpreter start**: spawn to the script's first line;
* **imports**: Mitsuba, numpy, OpenEXR and ``set_variant`` (plain); the ``mcrt``
  command's modules (mcrt, which activates the variant);
* **scene**: ``mi.load_file`` (plain); parsing the command line and planning
  the scene (mcrt), then the checks before rendering (mcrt's ``checks``);
* **render**, **write** (plain: the EXR; mcrt: EXR and PNG preview) and
  **exit** (the last file written to the process's end).

The mcrt process is the console script's ``main()`` with three of
``mcrt.cli.render_cmd``'s functions wrapped to note the time (nothing else
changes: the command's modules are imported as the console script imports them,
with the cyclic collector held back and then frozen). Box filter, ``--sampler``
as given.

    python benchmarks/process_timeline.py [--rounds 7] [--res 256] [--spp 16] [--sampler S]
"""

from __future__ import annotations

import sys
import time  # the children import nothing else before their first mark
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
STAGES = ("start", "imports", "scene", "checks", "render", "write", "exit")


def _hand_over(marks: dict[str, float]) -> None:
    sys.stderr.write(f"MARKS {marks!r}\n")
    sys.stderr.flush()


def plain_child(scene: str, res: int, spp: int, sampler: str, out: str) -> None:
    marks = {"start": time.time()}
    import mitsuba as mi
    import numpy as np
    import OpenEXR

    mi.set_variant("llvm_ad_rgb")
    if sampler in ("uniform_grid", "jittered", "poisson_disk", "sobol", "zsobol"):
        import mcrt  # noqa: F401  (registers the sampler plugin)
    marks["imports"] = time.time()
    loaded = mi.load_file(scene, res=res, spp=spp, sampler=sampler)
    marks["scene"] = marks["checks"] = time.time()
    image = np.asarray(mi.render(loaded, spp=spp, seed=0), dtype=np.float32)
    marks["render"] = time.time()
    channels = {c: np.ascontiguousarray(image[:, :, i]) for i, c in enumerate("RGB")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(out)
    marks["write"] = time.time()
    _hand_over(marks)


def mcrt_child(scene: str, res: int, spp: int, sampler: str, out: str) -> None:
    marks = {"start": time.time()}
    from mcrt._gc import collection_held_back
    from mcrt.cli import main

    with collection_held_back(freeze=True):  # as the console script imports its command
        import mcrt.cli.render_cmd as command

    marks["imports"] = time.time()

    def noting(name: str, after: str, before: str | None = None):
        wrapped = getattr(command, name)

        def call(*args, **kwargs):
            if before:
                marks[before] = time.time()
            result = wrapped(*args, **kwargs)
            marks[after] = time.time()
            if after == "write":  # the last mark: hand them over before the process ends
                _hand_over(marks)
            return result
        setattr(command, name, call)

    noting("plan_scene", "scene")
    noting("render_film", "render", before="checks")
    noting("_write", "write")
    sys.argv = ["mcrt", "-q", "render", scene, "-D", f"res={res}", "--spp", str(spp),
                "--sampler", sampler, "-o", out]
    sys.exit(main())


def run_child(kind: str, args, out: Path) -> dict[str, float]:
    import ast
    import subprocess

    argv = [sys.executable, __file__, "--child", kind, str(args.res), str(args.spp),
            args.sampler, str(out)]
    spawned = time.time()
    done = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT)
    ended = time.time()
    if done.returncode != 0:
        raise SystemExit(f"{kind} failed:\n{done.stderr[-2000:]}")
    line = [x for x in done.stderr.splitlines() if x.startswith("MARKS ")][-1]
    marks = ast.literal_eval(line[len("MARKS "):])
    points = [spawned] + [marks[s] for s in STAGES[:-1]] + [ended]
    return {stage: 1000.0 * (b - a)
            for stage, a, b in zip(STAGES, points[:-1], points[1:], strict=True)}


def main() -> int:
    if sys.argv[1:2] == ["--child"]:  # KIND RES SPP SAMPLER OUT
        kind, res, spp, sampler, out = sys.argv[2:7]
        child = plain_child if kind == "plain" else mcrt_child
        child(str(CORNELL), int(res), int(spp), sampler, out)
        return 0
    import argparse
    import statistics
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--sampler", default="independent")
    args = parser.parse_args()

    rows: dict[str, list[dict[str, float]]] = {"plain": [], "mcrt": []}
    with tempfile.TemporaryDirectory(prefix="mcrt_timeline_") as tmp:
        outs = {"plain": Path(tmp) / "plain.exr", "mcrt": Path(tmp) / "mcrt"}
        for kind in rows:  # warm-up: kernel cache, page cache
            run_child(kind, args, outs[kind])
        from mcrt.core.timing import round_orders  # the driver only: children import nothing

        kinds = ("mcrt", "plain")
        for order in round_orders(2, args.rounds):  # the timing protocol's shuffled rounds
            for kind in (kinds[i] for i in order):
                rows[kind].append(run_child(kind, args, outs[kind]))
    print(f"\nOne {args.res}^2 render ({args.sampler}, {args.spp} spp, box filter) as a whole "
          f"process, median ms of {args.rounds} interleaved rounds:\n")
    print("| stage | plain | mcrt |")
    print("|---|---:|---:|")
    labels = {"start": "interpreter start", "imports": "imports (and `set_variant`)",
              "scene": "load / plan the scene", "checks": "checks before rendering",
              "render": "render", "write": "write the files", "exit": "exit"}
    for stage in STAGES:
        cells = [statistics.median(r[stage] for r in rows[k]) for k in ("plain", "mcrt")]
        print(f"| {labels[stage]} | {cells[0]:.0f} | {cells[1]:.0f} |")
    totals = [statistics.median(sum(r.values()) for r in rows[k]) for k in ("plain", "mcrt")]
    print(f"| total | {totals[0]:.0f} | {totals[1]:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
