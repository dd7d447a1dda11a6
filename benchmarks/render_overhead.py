"""What does ``mcrt render`` cost end to end, against a plain Mitsuba script doing the same render?

Each measurement is a whole process, from its start to its exit after the
image files are written:

* **mcrt**: ``mcrt -q render cornell_box.xml -D res=N --spp S --sampler X -o OUT``
  (EXR with mcrt's layers and metadata, and the sRGB PNG preview);
* **plain**: ``python plain.py``, a script that does ``mi.load_file`` +
  ``mi.render`` and writes the image as a float32 EXR with OpenEXR (it imports
  mcrt only to register the sampler when X is one of mcrt's plugins).

Cases: resolutions ``--res`` (default 256 and 1024) x the Cornell box with its
box filter and a copy with a Gaussian filter (written to a temporary directory)
x samplers ``jittered`` (mcrt's) and ``independent`` (Mitsuba's). Every process
runs once as a warm-up (Dr.Jit's kernel cache, the page cache, the Poisson
tables), then ``--rounds`` timed rounds run the pair in an order shuffled per
round (``mcrt.core.timing.round_orders``, the timing protocol's). Peak RSS comes
from ``wait4`` (``ru_maxrss`` of exactly that child), as does its CPU time (user
+ system, all threads: less disturbed by other jobs on a shared machine than wall
time).

The package is byte-compiled first (``compileall``, as ``scripts/setup.sh`` does), so
neither side compiles Python sources at start-up, whatever ``PYTHONDONTWRITEBYTECODE`` says.

Start-up: ``python -c "import mcrt"`` and ``mcrt --help`` against
``python -c "import mitsuba; mitsuba.set_variant('llvm_ad_rgb')"``, interleaved.

Prints one markdown table: medians, the median of the per-round ratios
(mcrt / plain) with their interquartile range, the goal and PASS/FAIL per row;
then an A/A control per resolution (the plain script against itself, box
filter, ``independent``, the same rounds): on a shared machine one process
varies by 10-15% from run to run, and the control shows how far a median
ratio of that many rounds moves with nothing changed.
Goals: time <= 1.05x, peak RSS <= 1.5x, start-up <= +0.3 s.

    python benchmarks/render_overhead.py [--rounds 9] [--res 256 1024] [--spp 16]
    python benchmarks/render_overhead.py --quick     # smoke run: tiny images, 1 round
"""

from __future__ import annotations

import argparse
import compileall
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from mcrt.core.timing import round_orders

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
BOX_FILTER = '<rfilter type="box"/>'

#: Goals (mcrt against plain).
TIME_GOAL = 1.05      # ratio of wall times
RSS_GOAL = 1.5        # ratio of peak resident set sizes
STARTUP_GOAL = 0.3    # seconds more than `import mitsuba` + set_variant

MCRT_PLUGINS = ("uniform_grid", "jittered", "poisson_disk")

PLAIN_SCRIPT = f'''\
"""Plain Mitsuba: load the scene, render it, write a float32 EXR."""
import sys

import mitsuba as mi
import numpy as np
import OpenEXR

scene_path, res, spp, sampler, out = sys.argv[1:6]
mi.set_variant("llvm_ad_rgb")
if sampler in {MCRT_PLUGINS!r}:
    import mcrt  # noqa: F401  (registers the sampler plugin)
scene = mi.load_file(scene_path, res=res, spp=spp, sampler=sampler)
image = np.asarray(mi.render(scene, spp=int(spp), seed=0), dtype=np.float32)
channels = {{c: np.ascontiguousarray(image[:, :, i]) for i, c in enumerate("RGB")}}
header = {{"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}}
OpenEXR.File(header, channels).write(out)
'''


@dataclass
class Run:
    """One finished child process."""

    wall: float   # seconds from spawn to exit
    cpu: float    # user + system seconds, all threads
    rss: float    # peak resident set size, MiB


@dataclass
class Series:
    runs: list[Run] = field(default_factory=list)

    def median(self, attr: str) -> float:
        return statistics.median(getattr(r, attr) for r in self.runs)


def run_process(argv: list[str], cwd: Path, log: Path) -> Run:
    """Run ``argv`` to completion; stdout and stderr go to ``log``."""
    with open(log, "wb") as out:
        start = time.perf_counter()
        proc = subprocess.Popen(argv, cwd=cwd, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        tail = log.read_text(errors="replace").strip().splitlines()[-15:]
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(argv)}\n" + "\n".join(tail))
    return Run(wall=wall, cpu=usage.ru_utime + usage.ru_stime, rss=usage.ru_maxrss / 1024.0)


def mcrt_command() -> list[str]:
    """The console script next to this interpreter, else ``python -m mcrt``."""
    script = Path(sys.executable).with_name("mcrt")
    return [str(script)] if script.exists() else [sys.executable, "-m", "mcrt"]


@dataclass
class Case:
    res: int
    filter: str
    sampler: str
    scene: Path

    @property
    def name(self) -> str:
        return f"{self.res}^2 {self.filter} {self.sampler}"


def commands(case: Case, spp: int, work: Path, plain: Path) -> dict[str, list[str]]:
    stem = work / f"{case.res}_{case.filter}_{case.sampler}"
    return {
        "mcrt": [*mcrt_command(), "-q", "render", str(case.scene), "-D", f"res={case.res}",
                 "--spp", str(spp), "--sampler", case.sampler, "-o", f"{stem}_mcrt"],
        "plain": [sys.executable, str(plain), str(case.scene), str(case.res), str(spp),
                  case.sampler, f"{stem}_plain.exr"],
    }


def check_outputs(case: Case, work: Path) -> str:
    """Both processes wrote an image of the same mean (a sanity check, not a test)."""
    from mcrt.io import read_exr  # only here: keeps this process small while it measures

    stem = work / f"{case.res}_{case.filter}_{case.sampler}"
    ours = read_exr(f"{stem}_mcrt.exr")[0]["rgb"]
    theirs = read_exr(f"{stem}_plain.exr")[0]["rgb"]
    if ours.shape != theirs.shape:
        return f"shapes differ: {ours.shape} vs {theirs.shape}"
    a, b = float(ours.mean()), float(theirs.mean())
    return "" if abs(a - b) <= 0.05 * max(abs(b), 1e-6) else f"means differ: {a:.4g} vs {b:.4g}"


def quartiles(values: list[float]) -> tuple[float, float]:
    if len(values) < 2:
        return values[0], values[0]
    q1, _, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, q3


def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def measure_renders(cases: list[Case], spp: int, rounds: int, work: Path, plain: Path,
                    ) -> list[tuple[Case, Series, Series, str]]:
    results = []
    for case in cases:
        cmds = commands(case, spp, work, plain)
        print(f"  {case.name}: warm-up", file=sys.stderr, flush=True)
        for who, argv in cmds.items():
            run_process(argv, work, work / f"{who}.log")
        problem = check_outputs(case, work)
        series = {who: Series() for who in cmds}
        whos = ("mcrt", "plain")
        for order in round_orders(2, rounds):  # the timing protocol's shuffled rounds
            for who in (whos[i] for i in order):
                series[who].runs.append(run_process(cmds[who], work, work / f"{who}.log"))
        print(f"  {case.name}: mcrt {series['mcrt'].median('wall'):.2f} s, "
              f"plain {series['plain'].median('wall'):.2f} s", file=sys.stderr, flush=True)
        results.append((case, series["mcrt"], series["plain"], problem))
    return results


def measure_control(case: Case, spp: int, rounds: int, work: Path, plain: Path
                    ) -> tuple[Series, Series]:
    """The A/A control: the plain script against itself, in the same interleaved
    rounds; the spread of its ratios is the noise the mcrt rows are read against."""
    argv = commands(case, spp, work, plain)["plain"]
    print(f"  {case.name}: A/A control", file=sys.stderr, flush=True)
    run_process(argv, work, work / "control.log")
    first, second = Series(), Series()
    for order in round_orders(2, rounds):
        for series in ((first, second)[i] for i in order):
            series.runs.append(run_process(argv, work, work / "control.log"))
    return first, second


def measure_startup(rounds: int, work: Path) -> dict[str, list[float]]:
    py = sys.executable
    argvs = {
        "mitsuba": [py, "-c", "import mitsuba; mitsuba.set_variant('llvm_ad_rgb')"],
        "import mcrt": [py, "-c", "import mcrt"],
        "mcrt --help": [*mcrt_command(), "--help"],
    }
    for argv in argvs.values():  # warm-up (page cache, .pyc files)
        run_process(argv, work, work / "startup.log")
    times: dict[str, list[float]] = {name: [] for name in argvs}
    names = list(argvs)
    for order in round_orders(len(names), rounds):
        for name in (names[i] for i in order):
            times[name].append(run_process(argvs[name], work, work / "startup.log").wall)
    return times


def ratio_row(label: str, unit: str, ours: list[float], theirs: list[float], goal: float,
              fmt: str = "{:.2f}") -> str:
    ratios = [a / b for a, b in zip(ours, theirs, strict=True)]
    ratio = statistics.median(ratios)
    q1, q3 = quartiles(ratios)
    return (f"| {label} | {fmt.format(statistics.median(ours))} {unit} "
            f"| {fmt.format(statistics.median(theirs))} {unit} "
            f"| {ratio:.3f} ({q1:.3f}-{q3:.3f}) | <= {goal:g}x | {verdict(ratio <= goal)} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9, help="timed rounds (default 9)")
    parser.add_argument("--res", type=int, nargs="+", default=[256, 1024],
                        help="image resolutions (default 256 1024)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: --res 32 --spp 4 --rounds 1 (unless given)")
    args = parser.parse_args()
    if args.quick:
        given = set(sys.argv[1:])
        args.res = args.res if "--res" in given else [32]
        args.spp = args.spp if "--spp" in given else 4
        args.rounds = args.rounds if "--rounds" in given else 1
    if args.rounds < 1 or args.spp < 1 or min(args.res) < 1:
        parser.error("--rounds, --spp and --res must be positive")

    # Measure mcrt as scripts/setup.sh leaves it: byte-compiled (site-packages come
    # compiled by pip). Where PYTHONDONTWRITEBYTECODE is set, stale or missing .pyc files
    # would otherwise make every mcrt process compile its modules again (~0.13 s).
    compileall.compile_dir(ROOT / "mcrt", quiet=1)
    with tempfile.TemporaryDirectory(prefix="mcrt_overhead_") as tmp:
        work = Path(tmp)
        plain = work / "plain.py"
        plain.write_text(PLAIN_SCRIPT)
        gaussian = work / "cornell_box_gaussian.xml"
        text = CORNELL.read_text()
        if text.count(BOX_FILTER) != 1:
            raise SystemExit(f"{CORNELL}: expected one {BOX_FILTER} to replace")
        gaussian.write_text(text.replace(BOX_FILTER, '<rfilter type="gaussian"/>'))
        scenes = {"box": CORNELL, "gaussian": gaussian}
        cases = [Case(res, name, sampler, path) for res in args.res
                 for name, path in scenes.items() for sampler in ("jittered", "independent")]

        print(f"measuring {len(cases)} cases x {args.rounds} rounds ...", file=sys.stderr)
        renders = measure_renders(cases, args.spp, args.rounds, work, plain)
        controls = [(case, *measure_control(case, args.spp, args.rounds, work, plain))
                    for case in cases if case.filter == "box" and case.sampler == "independent"]
        startup = measure_startup(max(args.rounds, 5), work)

    print(f"\n`mcrt render` against a plain Mitsuba script: Cornell box, path tracer, "
          f"{args.spp} spp, {args.rounds} interleaved rounds after a warm-up; "
          f"{os.cpu_count()} CPUs, Python {sys.version.split()[0]}.\n")
    print("| measurement | mcrt | plain | ratio mcrt/plain (IQR) | goal | |")
    print("|---|---:|---:|---:|---|---|")
    problems = []
    for case, ours, theirs, problem in renders:
        print(ratio_row(f"{case.name}: time", "s", [r.wall for r in ours.runs],
                        [r.wall for r in theirs.runs], TIME_GOAL))
        print(ratio_row(f"{case.name}: peak RSS", "MiB", [r.rss for r in ours.runs],
                        [r.rss for r in theirs.runs], RSS_GOAL, fmt="{:.0f}"))
        if problem:
            problems.append(f"{case.name}: {problem}")

    print("\n| A/A control: the plain script against itself | ratio (IQR) |")
    print("|---|---:|")
    for case, first, second in controls:
        ratios = [a.wall / b.wall for a, b in zip(first.runs, second.runs, strict=True)]
        q1, q3 = quartiles(ratios)
        print(f"| {case.name}: time | {statistics.median(ratios):.3f} ({q1:.3f}-{q3:.3f}) |")

    base = startup["mitsuba"]
    print("\n| start-up | median | `import mitsuba` + set_variant | difference (IQR) | goal | |")
    print("|---|---:|---:|---:|---|---|")
    for name in ("import mcrt", "mcrt --help"):
        diffs = [a - b for a, b in zip(startup[name], base, strict=True)]
        diff = statistics.median(diffs)
        q1, q3 = quartiles(diffs)
        print(f"| `{name}` | {statistics.median(startup[name]):.3f} s "
              f"| {statistics.median(base):.3f} s | {diff:+.3f} s ({q1:+.3f} to {q3:+.3f}) "
              f"| <= +{STARTUP_GOAL:g} s | {verdict(diff <= STARTUP_GOAL)} |")

    print("\nCPU time (user + system, all threads; median ratio mcrt/plain): " + ", ".join(
        f"{case.name} "
        f"{statistics.median(a.cpu / b.cpu for a, b in zip(o.runs, t.runs, strict=True)):.3f}"
        for case, o, t, _ in renders))
    for problem in problems:
        print(f"warning: outputs differ, {problem}")
    return 0


if __name__ == "__main__":
    if not hasattr(os, "wait4"):
        raise SystemExit("needs os.wait4 (Linux, macOS)")
    sys.exit(main())
