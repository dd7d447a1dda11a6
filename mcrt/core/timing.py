"""The timing protocol: how every figure in seconds is taken, in one place.

Timing on a shared machine is noisy: another process, a frequency change or a
page-cache flush slows whatever runs at that moment. So every command that
reports seconds (``mcrt compare``, ``mcrt demo``, ``mcrt integrate``, the
benchmarks) times the same way, after pyperf and hyperfine:

1. **Warm-up.** Every case runs once untimed first, so kernels are compiled
   (or loaded from the cache) before any timed run.
2. **Interleaved repetitions.** The timed runs come in *rounds*; each round
   runs every case once, in an order shuffled afresh each round
   (:func:`round_orders`, seeded, so a rerun uses the same orders). A change of
   machine load then hits every case alike instead of landing on one of them,
   and runs of one round are close in time, so the ratio of two cases' times
   within a round (*paired*) cancels slow drifts.
3. **Both clocks.** Each timed run records wall time (``perf_counter``) and the
   process's CPU time (``process_time``: every thread of the process, so
   Dr.Jit's worker threads too), and how many threads of other processes were
   runnable at its start and at its end, the smaller of the two
   (``procs_running`` of ``/proc/stat`` less this process's runnable threads;
   None elsewhere).
4. **Robust summary** (:class:`TimingSummary`): the median; 1.4826 x the
   median absolute deviation as the spread; outliers (more than
   :data:`OUTLIER_Z` robust sd and :data:`OUTLIER_MIN` of the median from it);
   and a stability verdict: *unstable* when the relative spread
   exceeds :data:`SPREAD_LIMIT`, *loaded* when other processes were runnable at
   the start of more than :data:`LOADED_SHARE` of the runs, and doubtful too
   when more than a quarter of the runs are outliers (the median absorbs a few).
5. **Fixed and per-unit cost apart** (:func:`fit_cost`): ``t = fixed + per_unit
   x units`` by least squares over all timed runs of a case at several sizes
   (e.g. units = samples), with standard errors.

The statistics of intervals and tests live in :mod:`mcrt.analysis.significance`
(this module only measures and summarises).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

#: A case whose robust relative spread (1.4826 MAD / median) exceeds this is unstable.
SPREAD_LIMIT = 0.10
#: A timed run more than this many robust sd from the median is an outlier...
OUTLIER_Z = 3.5
#: ... and more than this fraction of the median away from it (closer is immaterial,
#: however tight the other runs are).
OUTLIER_MIN = 0.05
#: A case is loaded when other processes were runnable at more than this share of its runs.
LOADED_SHARE = 0.25


@dataclass(frozen=True)
class Sample:
    """One timed run: wall and process CPU seconds, and the threads of other processes
    runnable at both its start and its end (None where unknown)."""

    wall: float
    cpu: float
    others: int | None = None


def _own_running() -> int:
    """Threads of this process that are runnable now (state R in /proc/self/task):
    the caller, and Dr.Jit's workers while they spin down after a kernel."""
    count = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 1
    for task in tasks:
        try:
            with open(f"/proc/self/task/{task}/stat", "rb") as f:
                state = f.read().rsplit(b")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        count += state == b"R"
    return max(count, 1)


def _others_once() -> int | None:
    own = _own_running()
    try:
        with open("/proc/stat", "rb") as f:
            for line in f:
                if line.startswith(b"procs_running"):
                    total = int(line.split()[1])
                    return max(0, total - max(own, _own_running()))
    except (OSError, ValueError, IndexError):
        pass
    return None


def others_running() -> int | None:
    """Threads of other processes runnable now: ``procs_running`` of
    ``/proc/stat`` (every runnable thread of the machine) less this process's
    runnable threads, the smaller of two reads half a millisecond apart (Dr.Jit's
    workers spin for a moment after a kernel, and a single read catches them
    or a passing kernel thread; a competing process is runnable in both); None
    where the kernel does not say (not Linux)."""
    first = _others_once()
    if not first:
        return first
    time.sleep(0.0005)
    second = _others_once()
    return first if second is None else min(first, second)


def timed(fn: Callable[[], T], sync: Callable[[], None] | None = None) -> tuple[T, Sample]:
    """Run ``fn()`` once and time it; ``sync`` (e.g. ``dr.sync_thread``) is called
    before the clocks stop so that queued device work is counted."""
    before = others_running()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    out = fn()
    if sync is not None:
        sync()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    after = others_running()
    # A process that competed for the run is runnable at both ends; a thread that is
    # runnable for an instant (a kernel worker, ours spinning down) rarely is.
    others = None if before is None or after is None else min(before, after)
    return out, Sample(wall, cpu, others)


def round_orders(cases: int, rounds: int, seed: int = 0) -> list[list[int]]:
    """The order of ``cases`` in each of ``rounds`` rounds: a permutation drawn
    afresh per round from a generator seeded by ``seed`` (the same orders on
    every run with that seed)."""
    rng = np.random.default_rng([0x71AE, seed])
    return [[int(i) for i in rng.permutation(cases)] for _ in range(rounds)]


def run_interleaved(cases: Sequence[Callable[[], Any]], rounds: int, warmup: int = 1,
                    seed: int = 0, sync: Callable[[], None] | None = None
                    ) -> list[list[Sample]]:
    """The protocol for callables in this process: ``warmup`` untimed calls of
    each case, then ``rounds`` rounds in shuffled order; the samples per case,
    in round order. Renders in the warm-up are recorded for replay at once
    (:func:`mcrt.core.replay.warming_up`), so no timed call records."""
    from .replay import warming_up  # (replay imports the engine: not at module load)

    with warming_up():
        for _ in range(warmup):
            for case in cases:
                case()
                if sync is not None:
                    sync()
    samples: list[list[Sample]] = [[] for _ in cases]
    for order in round_orders(len(cases), rounds, seed):
        for i in order:
            samples[i].append(timed(cases[i], sync)[1])
    return samples


@dataclass(frozen=True)
class TimingSummary:
    """What a case's timed runs say (wall time unless noted); see the module doc."""

    n: int
    median: float
    spread: float                 # 1.4826 x MAD (s)
    minimum: float
    cpu_median: float
    outliers: int
    loaded: int                   # runs that started with other processes runnable
    unstable: bool = field(default=False)
    dropped: int = 0              # runs left out: wall time zero, negative or not finite

    @property
    def relative_spread(self) -> float:
        return self.spread / self.median if self.median > 0 else math.nan

    @property
    def is_loaded(self) -> bool:
        return self.n > 0 and self.loaded > LOADED_SHARE * self.n

    @property
    def has_outliers(self) -> bool:
        """More than a quarter of the runs are outliers (the median absorbs fewer)."""
        return 4 * self.outliers > self.n

    @property
    def stable(self) -> bool:
        """Neither unstable, nor loaded, nor with many outliers, nor with runs
        left out (what :meth:`problems` names)."""
        return not (self.unstable or self.is_loaded or self.has_outliers or self.dropped)

    def problems(self) -> list[str]:
        """What makes this case's timing doubtful, in words (empty: nothing)."""
        if self.n == 0:
            return [f"no usable time (of {self.dropped} runs, none took a positive, finite "
                    f"time)"]
        out = []
        if self.dropped:
            out.append(f"{self.dropped} runs without a positive, finite time left out")
        if self.unstable:
            out.append(f"spread {100 * self.relative_spread:.0f}% of the median")
        if self.has_outliers:
            out.append(f"{self.outliers} outliers of {self.n} runs")
        if self.is_loaded:
            out.append(f"other processes running at {self.loaded} of {self.n} runs")
        return out


def summarise(samples: Sequence[Sample]) -> TimingSummary:
    """The robust summary of a case's timed runs (NaN fields when there are none).

    A run whose wall time is not positive and finite is no time at all: it is
    left out of every field (the CPU median and the loaded count too, which
    otherwise spoke of more runs than ``n``) and counted in ``dropped``. The CPU
    median is over the kept runs' finite CPU times (NaN if none)."""
    kept = [s for s in samples if math.isfinite(s.wall) and s.wall > 0]
    dropped = len(samples) - len(kept)
    samples = kept
    wall = np.array([s.wall for s in samples], dtype=np.float64)
    n = int(wall.size)
    if n == 0:
        nan = math.nan
        return TimingSummary(0, nan, nan, nan, nan, 0, 0, unstable=True, dropped=dropped)
    median = float(np.median(wall))
    spread = float(1.4826 * np.median(np.abs(wall - median))) if n > 1 else math.nan
    outliers = int(np.count_nonzero(np.abs(wall - median)
                                    > max(OUTLIER_Z * spread, OUTLIER_MIN * median))) \
        if n > 2 else 0
    cpu_times = [s.cpu for s in samples if math.isfinite(s.cpu)]
    cpu = float(np.median(cpu_times)) if cpu_times else math.nan
    loaded = sum(1 for s in samples if s.others)
    unstable = bool(n > 1 and spread / median > SPREAD_LIMIT)
    return TimingSummary(n, median, spread, float(wall.min()), cpu, outliers, loaded,
                         unstable=unstable, dropped=dropped)


@dataclass(frozen=True)
class CostFit:
    """``seconds = fixed + per_unit x units`` by least squares, with standard errors."""

    fixed: float
    per_unit: float
    fixed_se: float
    per_unit_se: float
    n: int
    r2: float


def quartiles(values: Sequence[float]) -> tuple[float, float]:
    """First and third quartiles (``statistics.quantiles``, exclusive method) of
    the benchmarks' per-round ratios; a single value is its own (one round: a
    smoke run)."""
    import statistics

    if not values:  # no round: no quartile (not an IndexError)
        return math.nan, math.nan
    if len(values) < 2:
        return values[0], values[0]
    q1, _, q3 = statistics.quantiles(values, n=4)
    return q1, q3


def fit_cost(units: Sequence[float], seconds: Sequence[float]) -> CostFit:
    """The fixed and per-unit cost of a case timed at several sizes (``units``:
    samples, passes, ...); NaN with fewer than two distinct sizes. Standard
    errors are the usual OLS ones (residual variance on n - 2 degrees of freedom;
    NaN with two points)."""
    x = np.asarray(units, dtype=np.float64)
    y = np.asarray(seconds, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = int(x.size)
    nan = math.nan
    if n < 2 or np.ptp(x) == 0:
        return CostFit(float(y.mean()) if n else nan, nan, nan, nan, n, nan)
    xm, ym = float(x.mean()), float(y.mean())
    sxx = float(((x - xm) ** 2).sum())
    slope = float(((x - xm) * (y - ym)).sum() / sxx)
    fixed = ym - slope * xm
    residual = y - (fixed + slope * x)
    total = float(((y - ym) ** 2).sum())
    r2 = 1.0 - float((residual ** 2).sum()) / total if total > 0 else 1.0
    if n > 2:
        s2 = float((residual ** 2).sum()) / (n - 2)
        slope_se = math.sqrt(s2 / sxx)
        fixed_se = math.sqrt(s2 * (1.0 / n + xm * xm / sxx))
    else:
        slope_se = fixed_se = nan
    return CostFit(fixed, slope, fixed_se, slope_se, n, r2)


__all__ = ["LOADED_SHARE", "OUTLIER_MIN", "OUTLIER_Z", "SPREAD_LIMIT", "CostFit", "Sample",
           "TimingSummary", "fit_cost", "others_running", "quartiles", "round_orders",
           "run_interleaved", "summarise", "timed"]
