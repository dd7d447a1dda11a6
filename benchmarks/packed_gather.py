"""How a filtered film's per-pixel gather kernel costs with its samples stored
separately or interleaved (``mcrt.core.packed``).

The kernel of ``mcrt.core.reach.FilterReach`` without the filter: every pixel
of a W x W film sums, for each of its 5 x 5 neighbours and each of their
``spp`` samples of one pass, 5 stored values (R, G, B, x, y), in float64. The
values are laid out as

* ``separate``: 5 arrays, one gather instruction each;
* ``group of 5``: one interleaved array (5 is not a power of two: no packet loads);
* ``4 + 1``: what mcrt stores (``Packed``: packet loads of 4 values, then 1);
* ``8, 3 padded``: one packet of 8 (3 wasted floats a sample).

Each layout's kernel is compiled and run once, then ``--rounds`` rounds time
each (the timing protocol's shuffled rounds, ``mcrt.core.timing``, with
``dr.sync_thread``); printed: the median ms and the ratio
to ``separate``.

A second table times mcrt's own kernel (``FilterReach.sums`` with Mitsuba's
Gaussian filter and a film's four sums, added into the film as the film adds
them) by the block of targets one lane gathers for (``--blocks``), and checks
that every block gives the bits of 1 x 1.

    python benchmarks/packed_gather.py [--res 256] [--spp 16] [--rounds 7]
                                       [--blocks 1x1 2x1 2x2 4x1 3x2]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Callable
from typing import Any

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")

from mcrt.core.packed import Packed  # noqa: E402  (needs the variant)
from mcrt.core.reach import BLOCK, FilterReach  # noqa: E402
from mcrt.core.timing import run_interleaved  # noqa: E402

OFFSETS = [(dx, dy) for dy in range(-2, 3) for dx in range(-2, 3)]


def layouts(columns: list[Any]) -> dict[str, Any]:
    """Layout name -> a function (lane, active) -> the 5 values."""
    lanes = dr.width(columns[0])
    five = dr.ravel(mi.ArrayXf(columns))
    eight = dr.ravel(mi.ArrayXf(columns + [columns[0]] * 3))
    packed = Packed.of(columns)
    dr.eval(five, eight, packed.arrays)
    assert dr.width(five) == 5 * lanes

    def separate(lane, active):
        return [dr.gather(mi.Float, c, lane, active) for c in columns]

    def group_of_5(lane, active):
        row = dr.gather(mi.ArrayXf, five, lane, active, shape=(5, dr.width(lane)))
        return [row[i] for i in range(5)]

    def padded_8(lane, active):
        row = dr.gather(mi.ArrayXf, eight, lane, active, shape=(8, dr.width(lane)))
        return [row[i] for i in range(5)]

    return {"separate": separate, "group of 5": group_of_5, "4 + 1 (mcrt)": packed.gather,
            "8, 3 padded": padded_8}


def kernel(read, width: int, spp: int) -> list[Any]:
    t = dr.arange(mi.UInt32, width * width)
    ty = t // width
    tx = t - ty * width
    sources = []
    for dx, dy in OFFSETS:
        gx, gy = mi.Int32(tx) - dx, mi.Int32(ty) - dy
        inside = (gx >= 0) & (gx < width) & (gy >= 0) & (gy < width)
        sources.append((inside, mi.UInt32(dr.select(inside, gy * width + gx, 0)) * spp))

    def body(k, *totals):
        out = list(totals)
        for inside, base in sources:
            r, g, b, x, y = read(base + k, inside)
            w = x * y  # stands in for the filter weight
            for c, v in enumerate((r * w, g * w, b * w, w)):
                out[c] = out[c] + mi.Float64(v)
        return (k + 1, *out)

    zeros = [dr.zeros(mi.Float64, width * width) for _ in range(4)]
    state = dr.while_loop((mi.UInt32(0), *zeros), lambda k, *s: k < spp, body)
    return list(state[1:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--blocks", nargs="+", default=["1x1", "2x1", "2x2", "4x1", "3x2"])
    args = parser.parse_args()
    lanes = args.res * args.res * args.spp
    rng = mi.PCG32(lanes)
    columns = [rng.next_float32() for _ in range(5)]
    reads = layouts(columns)
    for read in reads.values():  # compile
        dr.eval(kernel(read, args.res, args.spp))
    def case(read: Any) -> Callable[[], None]:
        return lambda: dr.eval(kernel(read, args.res, args.spp))

    samples = run_interleaved([case(read) for read in reads.values()], args.rounds, warmup=0,
                              sync=dr.sync_thread)  # the timing protocol (compiled above)
    times = {name: [s.wall for s in series] for name, series in zip(reads, samples, strict=True)}
    base = statistics.median(times["separate"])
    print(f"\nGather kernel, {args.res}^2 pixels x {args.spp} samples x 25 neighbours, "
          f"median of {args.rounds} rounds:\n")
    print("| layout | ms | ratio to separate |")
    print("|---|---:|---:|")
    for name, series in times.items():
        median = statistics.median(series)
        print(f"| {name} | {1000 * median:.1f} | {median / base:.2f} |")
    blocks(columns, args)
    return 0


def film_sums(columns: list[Any], res: int, spp: int, block: tuple[int, int]) -> list[Any]:
    """A pass of the Gaussian film's sums (weight, R, G, B) over a res^2 film."""
    packed = Packed.of(columns)
    reach = FilterReach(mi.load_dict({"type": "gaussian"}), (res, res), (0, 0), (res, res),
                        (0, 0), block=block)
    slots = reach.sums(packed, spp, 4,
                       lambda w, stored: [mi.Float64(w), *(mi.Float64(v * w) for v in stored)])
    sums = [dr.zeros(mi.Float64, res * res) for _ in range(4)]
    for slot in slots:
        for total, value in zip(sums, slot.values, strict=True):
            dr.scatter_add(total, value, slot.index, slot.valid, mode=dr.ReduceMode.NoConflicts)
    dr.eval(sums)
    return sums


def blocks(columns: list[Any], args: argparse.Namespace) -> None:
    """Time FilterReach by block shape (positions: each lane's own pixel)."""
    lane = dr.arange(mi.UInt32, args.res * args.res * args.spp) // args.spp
    columns = columns[:3] + [mi.Float(lane % args.res) + columns[3],
                             mi.Float(lane // args.res) + columns[4]]
    shapes = [tuple(int(v) for v in b.split("x")) for b in args.blocks]
    first = [dr.ravel(s).numpy() for s in film_sums(columns, args.res, args.spp, (1, 1))]
    same = {}
    for shape in shapes:  # compile, and compare the bits
        got = [dr.ravel(s).numpy() for s in film_sums(columns, args.res, args.spp, shape)]
        same[shape] = all((a == b).all() for a, b in zip(got, first, strict=True))
    def sums(shape: tuple[int, ...]) -> Callable[[], None]:
        return lambda: film_sums(columns, args.res, args.spp, shape)

    samples = run_interleaved([sums(shape) for shape in shapes], args.rounds, warmup=0,
                              sync=dr.sync_thread)
    times = {shape: [s.wall for s in series] for shape, series in zip(shapes, samples, strict=True)}
    base = statistics.median(times[shapes[0]])
    print(f"\nFilterReach (Gaussian film, 4 sums), {args.res}^2 pixels x {args.spp} samples, "
          f"by targets per lane, median of {args.rounds} rounds (mcrt: {BLOCK[0]}x{BLOCK[1]}):\n")
    print(f"| block | ms | ratio to {args.blocks[0]} | bits of 1x1 |")
    print("|---|---:|---:|---|")
    for shape, series in times.items():
        median = statistics.median(series)
        print(f"| {shape[0]}x{shape[1]} | {1000 * median:.1f} | {median / base:.2f} | "
              f"{'same' if same[shape] else 'DIFFERENT'} |")


if __name__ == "__main__":
    sys.exit(main())
