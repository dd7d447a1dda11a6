"""What scoring one study render costs, part by part, and what its speed-ups buy.

A study scores every seed's render against the reference where it was rendered
(``mcrt.analysis.study.seeds.score_seed``): the aliasing score (the error's
spectrum and 64 sign-flip null draws) and CIEDE2000. This times, interleaved
after a warm-up, on a 320x240 error image (the quick study's checkerboard):

* a stack of 8 images' ``rfft2`` by numpy and by scipy (the same bits);
* ``aliasing_score`` as it runs (null batches on two threads) and with one thread;
* CIEDE2000 with the reference's CIELAB computed each time and passed in.

and prints medians in ms and the ratios (median of per-round ratios, IQR).

    python benchmarks/scoring_cost.py [--rounds 15]
"""

from __future__ import annotations

import argparse
import statistics
import time
from concurrent.futures import ThreadPoolExecutor
from unittest import mock

import numpy as np
import scipy.fft

from mcrt.analysis import aliasing
from mcrt.analysis.metrics import delta_e_2000, srgb_to_lab
from mcrt.core.timing import quartiles


class _OneThread(ThreadPoolExecutor):
    def __init__(self, max_workers: int | None = None) -> None:
        super().__init__(max_workers=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    reference = rng.random((240, 320, 3))
    image = reference + 0.05 * rng.standard_normal(reference.shape)
    error = (image - reference).mean(axis=-1)
    stack = rng.standard_normal((8, 240, 320))
    lab = srgb_to_lab(reference)

    def one_thread() -> object:
        with mock.patch.object(aliasing, "ThreadPoolExecutor", _OneThread):
            return aliasing.aliasing_score(error, seed=1)

    cases = {
        "rfft2 of 8 images, numpy": lambda: np.fft.rfft2(stack),
        "rfft2 of 8 images, scipy": lambda: scipy.fft.rfft2(stack),
        "aliasing_score, one thread": one_thread,
        "aliasing_score, two threads": lambda: aliasing.aliasing_score(error, seed=1),
        "CIEDE2000, reference Lab each time": lambda: delta_e_2000(image, reference),
        "CIEDE2000, reference Lab passed in": lambda: delta_e_2000(image, reference,
                                                                    reference_lab=lab),
    }
    times: dict[str, list[float]] = {name: [] for name in cases}
    for r in range(args.rounds + 2):  # two warm-up rounds
        for name, call in cases.items():
            start = time.perf_counter()
            call()
            if r >= 2:
                times[name].append(time.perf_counter() - start)
    print(f"{args.rounds} interleaved rounds after 2 warm-ups; median ms")
    for name, values in times.items():
        print(f"  {name}: {1e3 * statistics.median(values):.2f}")
    names = list(cases)
    for slow, fast in zip(names[::2], names[1::2], strict=True):
        ratios = [b / a for a, b in zip(times[slow], times[fast], strict=True)]
        q1, q3 = quartiles(ratios)
        print(f"{fast} / {slow.split(', ')[-1]}: {statistics.median(ratios):.2f} "
              f"({q1:.2f}-{q3:.2f})")


if __name__ == "__main__":
    main()
