"""The pass engine alone against ``mi.render``, in one process.

``mcrt.core.render.render_film`` and ``mi.render`` of the same scene (the Cornell
box with its box filter, and a copy with Mitsuba's default Gaussian filter),
sampler and spp, timed by mcrt's protocol (:func:`mcrt.core.timing.run_interleaved`:
each warmed up once, then ``--rounds`` rounds in a shuffled order); wall and CPU
time (all threads) with ``dr.sync_thread()`` and the image copied to numpy in
both. Prints the medians and the ratios of medians
(engine / mi.render), and, as a floor for any design that splits a render into
passes, ``mi.render`` itself called once per pass of the engine's pass shape
(same number of samples). This separates the engine's cost from the command
line's fixed costs (imports, plan, outputs), which
``benchmarks/render_overhead.py`` measures end to end.

    python benchmarks/engine_overhead.py [--res 256 1024] [--spp 16] [--rounds 5]
                                         [--filters box gaussian]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

import mcrt  # noqa: E402,F401  (registers the samplers)
from mcrt.core.render import render_film  # noqa: E402
from mcrt.core.sampling import make_sampler  # noqa: E402
from mcrt.core.timing import run_interleaved  # noqa: E402

CORNELL = Path(__file__).resolve().parents[1] / "scenes" / "cornell_box.xml"


BOX_FILTER = '<rfilter type="box"/>'


def scene_file(kind: str, folder: Path) -> Path:
    """The Cornell box with its box filter, or a copy with Mitsuba's default."""
    if kind == "box":
        return CORNELL
    text = CORNELL.read_text()
    if BOX_FILTER not in text:
        raise SystemExit(f"{CORNELL} no longer has {BOX_FILTER}: update this benchmark")
    copy = folder / "cornell_gaussian.xml"
    copy.write_text(text.replace(BOX_FILTER, ""))
    return copy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--samplers", nargs="+", default=["jittered", "independent"])
    parser.add_argument("--filters", nargs="+", choices=["box", "gaussian"],
                        default=["box", "gaussian"])
    args = parser.parse_args()
    print("| film | sampler | engine [s] | mi.render [s] | ratio (wall) | ratio (CPU) | "
          "mi.render in the engine's passes [s] | ratio to mi.render |\n"
          "|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for res in args.res:
            for kind in args.filters:
                for name in args.samplers:
                    row(scene_file(kind, Path(tmp)), kind, res, name, args.spp, args.rounds)


def row(path: Path, kind: str, res: int, name: str, spp: int, rounds: int) -> None:
    scene = mi.load_file(str(path), res=str(res), sampler=name)

    def ours() -> None:
        render_film(scene, make_sampler(name, spp), seed=0)

    def theirs() -> None:
        np.array(mi.render(scene, spp=spp))

    passes = render_film(scene, make_sampler(name, spp), seed=0).passes  # the engine's shape
    group = spp // passes

    def split() -> None:  # Mitsuba itself, one call per pass of the engine's shape
        for index in range(passes):
            np.array(mi.render(scene, spp=group, seed=mi.UInt32(index)))

    cases = (ours, theirs, split)
    samples = run_interleaved(cases, rounds, warmup=1, sync=dr.sync_thread)
    wall = {fn: statistics.median(t.wall for t in v) for fn, v in zip(cases, samples, strict=True)}
    cpu = {fn: statistics.median(t.cpu for t in v) for fn, v in zip(cases, samples, strict=True)}
    print(f"| {res}^2 {kind} | {name} | {wall[ours]:.3f} | {wall[theirs]:.3f} | "
          f"{wall[ours] / wall[theirs]:.3f} | {cpu[ours] / cpu[theirs]:.3f} | "
          f"{wall[split]:.3f} ({passes} x {group} spp) | {wall[split] / wall[theirs]:.3f} |",
          flush=True)


if __name__ == "__main__":
    main()
