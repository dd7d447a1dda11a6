"""What a study says about its timing, on synthetic timed renders of known
distribution: cells where other processes competed are named as disturbed, with
the advice to time again on a quiet machine; cells whose times varied with no
other process seen are named as unsteady, without that advice (a quiet machine
was what they had)."""

from __future__ import annotations

import numpy as np

from mcrt.analysis.study.conclude import timing_lines, timing_verdict
from mcrt.core.timing import Sample, summarise


def _cell(sampler: str, times: list[float], others: int) -> dict:
    samples = [Sample(t, 2 * t, others) for t in times]
    return {"scene": "checkerboard", "sampler": sampler, "spp": 16,
            "time_problems": "; ".join(summarise(samples).problems()),
            "time_others": [s.others for s in samples]}


def _bimodal(rng: np.random.Generator, n: int = 5) -> list[float]:
    """A 160x120 render on a quiet 2-core machine: 8 ms, or 20 ms in a slow round."""
    slow = rng.random(n) < 0.4
    slow[:2] = [False, True]  # both modes in every draw
    return list(np.where(slow, 0.020, 0.008) * np.exp(rng.normal(0, 0.02, n)))


def _steady(rng: np.random.Generator, n: int = 5) -> list[float]:
    return list(0.008 * np.exp(rng.normal(0, 0.01, n)))


def test_a_quiet_machine_s_unsteady_cells_are_not_called_disturbed_by_others():
    """Measured: on a quiet 2-core machine (no other process runnable at 99% of the
    renders) every one of 8 repeated studies named 7-11 of 24 cells, and told the
    user to time again on a quiet machine, as if load had disturbed them."""
    rng = np.random.default_rng(5)
    cells = [_cell("independent", _bimodal(rng), 0), _cell("jittered", _steady(rng), 0)]
    timing = timing_verdict(cells, {"machine": {"loadavg": [0.9], "cpus_usable": 2}})
    assert timing["disturbed"] and not timing["competed"]
    lines = timing_lines(timing, "mcrt compare study.toml -o out --retime")
    text = " ".join(lines)
    assert "unsteady in 1 cells" in text and "checkerboard/independent/16 spp" in text
    assert "disturbed" not in text and "quiet machine does not cure" in text
    assert "--retime" not in text and "time again on a quiet machine" not in text


def test_cells_where_other_processes_competed_are_disturbed_and_retimed():
    rng = np.random.default_rng(6)
    cells = [_cell("independent", list(np.array(_bimodal(rng)) * 2), 1),
             _cell("jittered", _bimodal(rng), 0), _cell("poisson_disk", _steady(rng), 0)]
    timing = timing_verdict(cells, {"machine": {"loadavg": [2.1], "cpus_usable": 2}})
    assert timing["disturbed"] and timing["competed"]
    assert [d["loaded"] for d in timing["doubtful_cells"]] == [True, False]
    text = " ".join(timing_lines(timing, "mcrt compare study.toml -o out --retime"))
    assert "disturbed by other processes in 1 cells: checkerboard/independent" in text
    assert "unsteady in 1 cells" in text and "checkerboard/jittered" in text
    assert text.endswith("mcrt compare study.toml -o out --retime")


def test_steady_quiet_timing_says_nothing_and_an_old_result_still_reads():
    rng = np.random.default_rng(7)
    cells = [_cell("independent", _steady(rng), 0), _cell("jittered", _steady(rng), 0)]
    assert timing_lines(timing_verdict(cells, {})) == []
    old = {"disturbed": True, "loaded_share": 0.9, "doubtful_cells": [
        {"scene": "s", "sampler": "a", "spp": 4, "problems": "other processes running at 5 "
                                                             "of 5 runs"}]}
    text = " ".join(timing_lines(old))
    assert "disturbed by other processes in 1 cells" in text
    assert "time again on a quiet machine" in text
