"""Batch sizes of the adaptive passes: the sampler's ladder, per-pass growth, budgets.

In every pass an active pixel receives one complete pattern of ``m`` samples,
``m`` from a ladder ``min_spp * 2^i`` rounded down to counts the sampler
supports (see :mod:`mcrt.render.adaptive`).
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ...core.sampling import quiet_sampler_warnings
from ...errors import McrtError
from .settings import AdaptiveSettings

#: The largest batch asked of a sampler. Mitsuba's sample counts are 32-bit, and some
#: samplers never return when asked for 2^31 or more (``ldsampler``'s rounding to a
#: power of 4, ``orthogonal``'s prime squares); a larger budget repeats the top batch.
MAX_BATCH = 2 ** 30


def _count_for(sampler: mi.Sampler, request: int) -> int | None:
    """Sample count the sampler uses for ``request`` (None if it refuses)."""
    try:
        sampler.set_sample_count(request)
    except Exception:  # noqa: BLE001 - a sampler refusing a count (too many points)
        return None
    return int(sampler.sample_count())


def batch_ladder(sampler: mi.Sampler, min_spp: int, max_spp: int) -> tuple[int, ...]:
    """Batch sizes ``min_spp * 2^i`` rounded down to counts the sampler supports.

    The first entry is the sampler's count for ``min_spp`` (rounded *up* if the
    sampler must, e.g. ``jittered`` 20 -> 25); all entries are <= ``max_spp``.
    """
    with quiet_sampler_warnings():
        first = _count_for(sampler, min_spp)
        if first is None:
            raise McrtError(f"adaptive: the sampler cannot draw min_spp = {min_spp} samples")
        if first > max_spp:
            raise McrtError(f"adaptive: the sampler rounds min_spp {min_spp} up to {first}, "
                            f"more than max_spp {max_spp}")
        ladder = [first]
        request = 2 * first
        while request <= min(max_spp, MAX_BATCH):
            count = _largest_within(sampler, ladder[-1], request)
            if count is not None:
                ladder.append(count)
            elif _count_for(sampler, request) is None:
                break  # the sampler refuses this count, and so every larger one
            request *= 2
        sampler.set_sample_count(first)
    return tuple(ladder)


def _largest_within(sampler: mi.Sampler, low: int, high: int) -> int | None:
    """The largest count the sampler uses in ``(low, high]`` (None: none).

    A sampler's count is non-decreasing in the request (it rounds up: squares,
    prime squares, powers of 4) and it refuses every request beyond its limit,
    so a bisection over requests finds the largest one it serves within ``high``:
    ~log2(high) calls, where a scan down from ``high`` took up to ``high - low``
    (hours for a budget of 2^30, weeks for 2^40)."""
    count = _count_for(sampler, high)
    if count is not None and low < count <= high:
        return count
    best, lo, hi = None, low + 1, high - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        count = _count_for(sampler, mid)
        if count is not None and count <= high:
            best = count if count > low else best
            lo = mid + 1
        else:
            hi = mid - 1
    return best


def pass_batch_size(leader: int, ladder: tuple[int, ...], settings: AdaptiveSettings) -> int:
    """Batch size of the next pass, given ``leader``, the sample count of a pixel
    that was active in every pass so far: the ladder size nearest (on a log
    scale) to ``(growth - 1) * leader``, so such a pixel's count grows by about
    ``growth`` per pass; at most what still fits ``max_spp``."""
    ladder_a = np.asarray(ladder, dtype=np.float64)
    target = max((settings.growth - 1.0) * leader, ladder_a[0])
    midpoints = np.sqrt(ladder_a[:-1] * ladder_a[1:])  # geometric midpoints
    index = int(np.searchsorted(midpoints, target, side="right"))
    fits = budget_batches(np.array([leader]), ladder, settings.max_spp)[0]
    return int(min(ladder[index], fits)) if fits else int(ladder[index])


def budget_batches(traced: np.ndarray, ladder: tuple[int, ...], max_spp: int) -> np.ndarray:
    """Largest ladder size that fits each pixel's remaining budget (0: none fits,
    the pixel is done)."""
    ladder_a = np.asarray(ladder, dtype=np.int64)
    index = np.searchsorted(ladder_a, max_spp - np.asarray(traced), side="right") - 1
    return np.where(index >= 0, ladder_a[np.maximum(index, 0)], 0)


__all__ = ["batch_ladder", "budget_batches", "pass_batch_size"]
