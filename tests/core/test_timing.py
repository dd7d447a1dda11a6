"""The timing protocol (mcrt.core.timing): interleaved rounds, robust summaries,
the fixed/per-unit cost fit and the load probe, against numpy/scipy and real
processes."""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy import stats

from mcrt.core.timing import (
    OUTLIER_Z,
    SPREAD_LIMIT,
    Sample,
    fit_cost,
    others_running,
    quartiles,
    round_orders,
    run_interleaved,
    summarise,
)


def test_rounds_are_seeded_permutations_that_spread_every_case_over_every_position():
    orders = round_orders(5, 4000, seed=3)
    assert orders == round_orders(5, 4000, seed=3) and orders != round_orders(5, 4000, seed=4)
    assert all(sorted(o) == list(range(5)) for o in orders)
    # Position counts: 4000 rounds put each case at each position 800 times on
    # average (binomial sd sqrt(4000 * 0.2 * 0.8) = 25.3); a fixed round-robin
    # order would put it there 0 or 4000 times. 6 sd: no flake, no vacuous pass.
    counts = np.zeros((5, 5))
    for order in orders:
        for position, case in enumerate(order):
            counts[case, position] += 1
    assert np.all(np.abs(counts - 800) < 6 * 25.3), counts


def test_run_interleaved_warms_up_every_case_then_follows_the_rounds():
    calls: list[int] = []
    cases = [lambda i=i: calls.append(i) for i in range(3)]
    samples = run_interleaved(cases, rounds=4, warmup=1, seed=7)
    assert calls[:3] == [0, 1, 2]  # the warm-up, untimed
    assert calls[3:] == [i for order in round_orders(3, 4, seed=7) for i in order]
    assert [len(s) for s in samples] == [4, 4, 4]
    assert all(s.wall >= 0 and s.cpu >= 0 for case in samples for s in case)


def test_a_busy_case_costs_its_time_in_wall_and_cpu_clocks():
    def spin() -> None:  # 20 ms of this thread's CPU, however busy the machine is
        end = time.thread_time() + 0.02
        while time.thread_time() < end:
            pass

    def sleep() -> None:
        time.sleep(0.02)

    busy, idle = run_interleaved([spin, sleep], rounds=3, warmup=0)
    # Both take >= 20 ms of wall time; only the spinning one burns CPU time.
    assert all(s.wall >= 0.0199 for s in busy + idle)
    assert min(s.cpu for s in busy) >= 0.0199 and max(s.cpu for s in idle) < 0.005


def test_summary_is_the_median_with_a_robust_spread_and_flags_outliers():
    wall = [1.00, 1.02, 0.98, 1.01, 0.99, 1.60]
    summary = summarise([Sample(w, w / 2, 0) for w in wall])
    a = np.array(wall)
    assert summary.median == pytest.approx(np.median(a))
    mad = stats.median_abs_deviation(a, scale="normal")  # 1.4826 x MAD
    assert summary.spread == pytest.approx(mad, rel=1e-3)
    assert summary.outliers == 1  # only 1.60 is beyond OUTLIER_Z robust sd
    assert abs(1.60 - summary.median) > OUTLIER_Z * summary.spread
    assert summary.cpu_median == pytest.approx(np.median(a / 2))
    # one outlier in six: the median absorbs it, the case stays stable
    assert not summary.unstable and summary.stable and summary.problems() == []
    two = summarise([Sample(w, w) for w in (1.0, 1.01, 0.99, 1.0, 1.7, 1.9)])
    assert two.outliers == 2 and not two.stable
    assert two.problems() == ["2 outliers of 6 runs"]
    # 1-2% from a very tight median is many robust sd but immaterial: no outlier
    tight = summarise([Sample(w, w) for w in (63.17, 62.01, 62.53, 62.44, 62.56)])
    assert tight.outliers == 0 and tight.stable


def test_a_wide_spread_or_a_loaded_machine_is_named():
    wide = summarise([Sample(w, w) for w in (1.0, 1.3, 0.7, 1.25, 0.8)])
    assert wide.relative_spread > SPREAD_LIMIT and wide.unstable and not wide.stable
    assert "spread" in wide.problems()[0]
    loaded = summarise([Sample(1.0, 1.0, others) for others in (2, 1, 0, 3, 1)])
    assert loaded.is_loaded and not loaded.stable
    assert loaded.problems() == ["other processes running at 4 of 5 runs"]
    unknown = summarise([Sample(1.0, 1.0, None) for _ in range(3)])  # not Linux
    assert not unknown.is_loaded


def test_cost_fit_matches_scipy_linregress():
    rng = np.random.default_rng(5)
    units = np.repeat([1e4, 4e4, 1.6e5, 6.4e5], 5)
    seconds = 0.008 + 90e-9 * units + rng.normal(0, 0.001, units.size)
    fit = fit_cost(units, seconds)
    ref = stats.linregress(units, seconds)
    assert fit.per_unit == pytest.approx(ref.slope) and fit.fixed == pytest.approx(ref.intercept)
    assert fit.per_unit_se == pytest.approx(ref.stderr)
    assert fit.fixed_se == pytest.approx(ref.intercept_stderr)
    assert fit.r2 == pytest.approx(ref.rvalue ** 2)
    # The known truth lies within 4 standard errors (t(18): p < 0.001).
    assert abs(fit.fixed - 0.008) < 4 * fit.fixed_se
    assert abs(fit.per_unit - 90e-9) < 4 * fit.per_unit_se
    assert math.isnan(fit_cost([1.0, 1.0], [2.0, 3.0]).per_unit)  # one size: no slope


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_load_probe_sees_a_busy_process_and_not_our_own_threads():
    assert isinstance(others_running(), int)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        seen = []
        for _ in range(20):
            seen.append(others_running())
            time.sleep(0.01)
    finally:
        busy.kill()
        busy.wait()
    # The spinning process is runnable whenever it is sampled (on 2 cores it
    # may wait for the CPU, which still counts as runnable).
    assert sum(1 for s in seen if s and s >= 1) >= 18, seen


def test_quartiles_of_the_benchmarks_ratios():
    """The benchmarks' IQR: the exclusive-method quartiles (1..7: 2 and 6), and one
    round's value as its own (a --rounds 1 smoke run died in statistics.quantiles)."""
    assert quartiles([7.0, 1.0, 5.0, 3.0, 2.0, 6.0, 4.0]) == (2.0, 6.0)
    assert quartiles([0.8]) == (0.8, 0.8)


def test_runs_without_a_time_are_left_out_of_every_field_and_named():
    """A timed run of zero, negative or NaN wall time is no time at all. With no
    usable run the summary said "spread nan% of the median"; with some, it left
    them out of the median but not of the CPU median (NaN from one NaN CPU time)
    or of the loaded count ("other processes running at 8 of 2 runs"). Now they
    are left out of every field, counted and named; one round has no spread
    (NaN, unknown) and is not called unstable; no round has no quartiles."""
    none = summarise([Sample(0.0, 0.0), Sample(math.nan, math.nan), Sample(-1.0, 0.0)])
    assert none.n == 0 and none.dropped == 3 and not none.stable
    assert none.problems() == ["no usable time (of 3 runs, none took a positive, finite time)"]
    assert "nan" not in " ".join(none.problems())
    mixed = summarise([Sample(1.0, math.nan, 1), Sample(1.0, 0.5, 1)]
                      + [Sample(0.0, 0.0, 1)] * 6)
    assert (mixed.n, mixed.dropped, mixed.loaded, mixed.median) == (2, 6, 2, 1.0)
    assert mixed.cpu_median == 0.5
    assert mixed.problems() == ["6 runs without a positive, finite time left out",
                                "other processes running at 2 of 2 runs"]
    one = summarise([Sample(2.0, 2.0, 0)])
    assert one.n == 1 and math.isnan(one.spread) and not one.unstable and one.problems() == []
    assert all(math.isnan(q) for q in quartiles([]))
