"""What a study concludes across its cells: ratios to the baseline, bias flags, timing.

A cell's own fields come from its renders (:mod:`.summary`); these need the
other cells too, so they are derived whenever a result is made (a resumed or
retimed study derives them afresh):

* ``efficiency_ratio`` (and its 95% interval): a cell's efficiency over the
  baseline sampler's at the same scene and sample count
  (:func:`~mcrt.analysis.convergence.efficiency_ratio`, times paired round by
  round); ``efficiency_samples``: the efficiency on the sampler's per-sample
  cost (its fit's ``seconds_per_sample``);
* ``biased``: the cell's bias z is significant after Holm's correction over every
  measured cell of the study (:func:`mcrt.analysis.significance.holm`; family-wise
  false-alarm rate 5% under the null that every sampler is unbiased);
* ``verdict``: the aliasing verdict, plus "biased";
* :func:`timing_verdict`: whether the study's timing held (cells whose timing
  was unstable or loaded, the machine's load before and after).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from ...core.timing import LOADED_SHARE
from ..convergence import efficiency_ratio, excess_mse, paired_time_ratio
from ..significance import holm, t_quantile, two_sided_p
from .fields import Cell, cell_record

#: Family-wise false-alarm rate of the study's bias flags.
BIAS_ALPHA = 0.05


def conclude(cells: Sequence[Cell], fits: list[dict[str, Any]], baseline: str,
             pixels: dict[str, int]) -> list[Cell]:
    """The cells with their study-wide fields filled (new records, same order);
    ``pixels``: each scene's film pixels (for the per-sample efficiency)."""
    flags = holm([two_sided_p(c["bias_z"], c["bias_df"]) for c in cells], BIAS_ALPHA)
    base = {(c["scene"], c["spp_requested"]): c for c in cells if c["sampler"] == baseline}
    cost = {(f["scene"], f["sampler"]): f["seconds_per_sample"] for f in fits}
    out = []
    for cell, biased in zip(cells, flags, strict=True):
        values: dict[str, Any] = {**cell, "biased": bool(biased),
                                  "verdict": _verdict(cell, bool(biased))}
        values.update(_ratio(cell, base.get((cell["scene"], cell["spp_requested"]))))
        per_sample = cost.get((cell["scene"], cell["sampler"]), math.nan)
        product = cell["mse_excess"] * per_sample * pixels.get(cell["scene"], 0) * cell["spp"]
        values["efficiency_samples"] = (1.0 / product if cell["resolved"] and product > 0
                                        else math.nan)
        out.append(cell_record(values))
    return out


def _verdict(cell: Cell, biased: bool) -> str:
    return f"{cell['aliasing']}; biased" if biased else str(cell["aliasing"])


def _ratio(cell: Cell, base: Cell | None) -> dict[str, float]:
    nan = math.nan
    if base is None or not (cell["resolved"] and base["resolved"]):
        return {"efficiency_ratio": nan, "efficiency_ratio_low": nan,
                "efficiency_ratio_high": nan}
    if cell["sampler"] == base["sampler"]:
        return {"efficiency_ratio": 1.0, "efficiency_ratio_low": 1.0,
                "efficiency_ratio_high": 1.0}
    ratio = efficiency_ratio(
        excess_mse([r["mse"] for r in cell["per_seed"]], cell["mse_floor"]),
        excess_mse([r["mse"] for r in base["per_seed"]], base["mse_floor"]),
        paired_time_ratio(cell["times"], base["times"]))
    low, high = ratio.interval()
    return {"efficiency_ratio": ratio.value, "efficiency_ratio_low": low,
            "efficiency_ratio_high": high}


def timing_verdict(cells: Sequence[Cell], environment: dict[str, Any]) -> dict[str, Any]:
    """Whether the study's times can be trusted: the cells whose timing was
    doubtful (``time_problems``), the share of timed renders that started with
    other processes runnable, and the machine's load before and after.

    ``disturbed``: some cell's timing is doubtful, or the study's renders were
    loaded. ``competed``: other processes were seen competing (a cell loaded at
    over :data:`~mcrt.core.timing.LOADED_SHARE` of its renders, or the study's
    share above it); without it a doubtful cell's times varied on a quiet
    machine, which timing again on a quiet machine does not cure."""
    doubtful = [{"scene": c["scene"], "sampler": c["sampler"], "spp": c["spp"],
                 "problems": c["time_problems"], "loaded": _loaded(c["time_others"])}
                for c in cells if c["time_problems"]]
    others = [o for c in cells for o in c["time_others"] if o is not None]
    loaded = sum(1 for o in others if o) / len(others) if others else math.nan
    busy = bool(others) and loaded > LOADED_SHARE
    disturbed = bool(doubtful) or busy
    start = environment.get("machine", {})
    end = environment.get("machine_end", {})
    return {"protocol": "warm-up per cell, then interleaved rounds in a shuffled order per "
                        "round and sample count; median wall time; intervals by the delta "
                        "method (Student t)",
            "disturbed": disturbed, "competed": busy or any(d["loaded"] for d in doubtful),
            "doubtful_cells": doubtful, "loaded_share": loaded,
            "loadavg_start": start.get("loadavg"), "loadavg_end": end.get("loadavg"),
            "cpus_usable": start.get("cpus_usable"), "cpu_quota": start.get("cpu_quota")}


def _loaded(others: Sequence[int | None]) -> bool:
    """Other processes were runnable at over LOADED_SHARE of a cell's timed renders."""
    known = [o for o in others if o is not None]
    return bool(known) and sum(1 for o in known if o) > LOADED_SHARE * len(known)


# --------------------------------------------------------------------------- in words


def _g(value: float, spec: str = ".3g") -> str:
    return format(value, spec) if math.isfinite(value) else "-"


def interval_text(value: float, low: float, high: float, spec: str = ".3g") -> str:
    """``value [low, high]`` (``-`` for NaN)."""
    if not math.isfinite(value):
        return "-"
    return f"{_g(value, spec)} [{_g(low, spec)}, {_g(high, spec)}]"


#: An efficiency ratio is written to this many significant digits at most...
RATIO_DIGITS = 3
#: ... and one fewer when its 95% interval spans more than this factor (high / low): past
#: +-10% the third digit is noise (0.39 [0.34, 0.46], not 0.390 [0.340, 0.460]).
RATIO_WIDE = 1.2


def _sig(value: float, digits: int) -> str:
    """``value`` to ``digits`` significant digits in plain decimals (1200, 0.0046)."""
    if not math.isfinite(value):
        return "-"
    if value == 0:
        return "0"
    places = digits - 1 - math.floor(math.log10(abs(value)))
    rounded = round(value, places)
    if rounded and math.floor(math.log10(abs(rounded))) > math.floor(math.log10(abs(value))):
        places -= 1  # (9.996 -> 10.0 at 3 digits, not 10.00)
    return f"{round(value, places):.{max(0, places)}f}"


def ratio_parts(value: float, low: float, high: float) -> tuple[str, str, str]:
    """An efficiency ratio and its 95% interval, each to the significant digits the
    interval's width supports: :data:`RATIO_DIGITS` (``0.987 [0.962, 1.01]``), one
    fewer when the interval spans more than a factor :data:`RATIO_WIDE`
    (``2.6 [2.2, 2.9]``; ``11 [2.8, 48]``, once printed ``11.49 [2.76, 47.91]``:
    four digits of a figure known to a factor of 17). The console, the report and the sentences
    "needs 0.39x [0.34, 0.46]" all write ratios so; results.json keeps full values."""
    wide = not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high
                and high <= RATIO_WIDE * low)
    digits = RATIO_DIGITS - 1 if wide else RATIO_DIGITS
    return _sig(value, digits), _sig(low, digits), _sig(high, digits)


def ratio_text(value: float, low: float, high: float) -> str:
    """``value [low, high]`` of an efficiency ratio (:func:`ratio_parts`; ``-`` for NaN)."""
    if not math.isfinite(value):
        return "-"
    v, lo, hi = ratio_parts(value, low, high)
    return f"{v} [{lo}, {hi}]"


def cost_df(cells: Sequence[Cell]) -> float:
    """Degrees of freedom of the cost fit over ``cells`` (one sampler's cells of a
    scene, :func:`~.summary.fit_sampler`): its timed renders less 2, the residual
    variance's; ``inf`` when fewer than 3 are recorded (no standard error then)."""
    n = sum(1 for c in cells for t in c["times"] if math.isfinite(t))
    return float(n - 2) if n > 2 else math.inf


def cost_text(value: float, se: float, scale: float, spec: str = ".2f",
              df: float = math.inf) -> str:
    """A cost of the timing fit (:func:`mcrt.core.timing.fit_cost`: seconds per
    render or per sample) times ``scale``, in words: the value when its 95%
    interval ``value +- q se`` lies above 0; else only what the times bound it
    by, ``< value + q se`` (a cost is never negative, and a tiny film's
    per-sample cost is lost in the fixed cost's scatter: the fit gave -186 ns
    per sample +- 480); ``-`` when nothing bounds it. ``q``: Student's t on the
    fit's ``df`` (:func:`cost_df`: renders - 2; 6 renders, df 4: 2.78, where the
    normal 1.96 called a cost of 0 resolved 6% of the time, not 2.5%).

    Written to the decimal of the standard error's first significant digit (a
    bound rounded up), not more: 8 runs of one study on a quiet machine gave 20
    to 35 ns per sample, se 2-7, once printed as 21.70, 30.50, ...; ``spec``
    only where there is no standard error."""
    if not math.isfinite(value):
        return "-"
    if not math.isfinite(se):  # two sizes, no residual: the value, if it can be a cost
        return format(value * scale, spec) if value > 0 else "-"
    q = t_quantile(0.975, df)
    high = value + q * se
    places = max(0, -math.floor(math.log10(se * scale))) if se > 0 else None
    if value - q * se > 0:
        return format(value * scale, spec if places is None else f".{places}f")
    if high <= 0:
        return "-"
    if places is None:
        return f"<{format(high * scale, spec)}"
    return f"<{math.ceil(high * scale * 10 ** places) / 10 ** places:.{places}f}"


def bias_lines(cells: Sequence[Cell]) -> list[str]:
    """One line per (scene, sampler) with biased cells: where, how much, how sure."""
    measured = sum(1 for c in cells if math.isfinite(two_sided_p(c["bias_z"], c["bias_df"])))
    groups: dict[tuple[str, str], list[Cell]] = {}
    for c in cells:
        if c["biased"]:
            groups.setdefault((c["scene"], c["sampler"]), []).append(c)
    lines = []
    for (scene, sampler), found in groups.items():
        parts = ", ".join(f"{c['spp']} spp: {c['bias']:+.2e} (t = {c['bias_z']:+.1f})"
                          for c in found)
        lines.append(f"{sampler} is biased on {scene} at {parts}; Holm-corrected over "
                     f"{measured} cells at {BIAS_ALPHA:g}")
    return lines


def timing_lines(timing: dict[str, Any], retime: str = "") -> list[str]:
    """What disturbed the study's timing, naming the cells (empty: it held).

    Cells where other processes competed are *disturbed* (time again on a quiet
    machine); doubtful cells without them are *unsteady*: their renders' times
    varied by themselves (or by something too brief to be seen), so the advice is
    more rounds, not a quiet machine (on a quiet 2-core machine a 160x120 render
    took 8 or 20 ms from one round to the next)."""
    if not timing.get("disturbed"):
        return []
    lines = []
    doubtful = timing.get("doubtful_cells", [])
    # (a result written before "loaded" was recorded: its problems name the load)
    loaded = [d for d in doubtful
              if d.get("loaded", "other processes running" in d["problems"])]
    unsteady = [d for d in doubtful if d not in loaded]
    if loaded:
        lines.append(f"timing was disturbed by other processes in {len(loaded)} cells: "
                     f"{_cells_text(loaded)}")
    if unsteady:
        lines.append(f"timing was unsteady in {len(unsteady)} cells with no other process "
                     f"seen competing: {_cells_text(unsteady)}; their renders' times varied "
                     f"by themselves, which a quiet machine does not cure: more rounds "
                     f"(time_rounds) narrow their intervals")
    share = timing.get("loaded_share", math.nan)
    if isinstance(share, float) and math.isfinite(share) and share > LOADED_SHARE:
        lines.append(f"other processes were runnable at the start of {100 * share:.0f}% of "
                     f"the timed renders (load average {timing.get('loadavg_start')} -> "
                     f"{timing.get('loadavg_end')} on {timing.get('cpus_usable')} CPUs)")
    competed = timing.get("competed", bool(loaded) or (isinstance(share, float)
                                                        and share > LOADED_SHARE))
    advice = "ratios pair renders timed in the same round and are the figures to trust"
    if competed:
        advice += "; " + (f"to time again without measuring the errors again: {retime}"
                          if retime else "time again on a quiet machine (mcrt compare --retime)")
    lines.append(advice)
    return lines


def cpus_line(environment: dict[str, Any]) -> str:
    """The note that a study ran on fewer CPUs than its machine has (empty if
    not): ``environment["cpus"]`` is the machine's count; ``environment["machine"]``
    holds ``cpus_usable``, the CPUs this process could run on (its CPU affinity:
    taskset, a container's cpuset), and ``cpu_quota``, the CPUs its cgroup's CPU
    quota allows (``docker --cpus``; None or absent: no quota). The smaller of the
    two limits the study, and the note names it. Renders use every usable CPU, so
    a limited study's absolute times are slower than the machine's (one of two
    CPUs: ~70%), while the ratios pair renders taken under the same limit."""
    facts = environment.get("machine") or {}
    cpus = environment.get("cpus")
    if not isinstance(cpus, int) or cpus <= 0:
        return ""
    limits = {}
    usable = facts.get("cpus_usable")
    if isinstance(usable, int) and 0 < usable < cpus:
        limits["CPU affinity: taskset, a container's cpuset"] = float(usable)
    quota = facts.get("cpu_quota")
    if (isinstance(quota, (int, float)) and not isinstance(quota, bool)
            and math.isfinite(quota) and 0 < quota < cpus):
        limits["a cgroup CPU quota: docker --cpus, cpu.max"] = float(quota)
    if not limits:
        return ""
    limit = min(limits.values())
    why = "; ".join(k for k, v in limits.items() if v == limit)
    count = f"{limit:.3g}"
    return (f"only {count} of the machine's {cpus} CPUs were usable ({why}): the absolute "
            f"times hold for {count} CPU{'s' if limit != 1 else ''}, not for the whole "
            f"machine; ratios are unaffected")


def _cells_text(cells: Sequence[dict[str, Any]], shown: int = 8) -> str:
    text = "; ".join(f"{d['scene']}/{d['sampler']}/{d['spp']} spp ({d['problems']})"
                     for d in cells[:shown])
    return text + (f" and {len(cells) - shown} more" if len(cells) > shown else "")


def ratio_sentence(cell: Cell, baseline: str) -> str:
    """"X needs 0.62x [0.55, 0.70] of B's time for the same error at N spp"."""
    value = cell["efficiency_ratio"]
    low, high = cell["efficiency_ratio_low"], cell["efficiency_ratio_high"]
    if not math.isfinite(value) or cell["sampler"] == baseline:
        return ""
    times, lower, upper = ratio_parts(*(1 / v if v else math.inf for v in (value, high, low)))
    text = (f"{cell['sampler']} needs {times}x [{lower}, {upper}] of {baseline}'s time for "
            f"the same error at {cell['spp']} spp")
    if low <= 1.0 <= high:
        text += " (no significant difference)"
    return text
__all__ = ["BIAS_ALPHA", "RATIO_DIGITS", "RATIO_WIDE", "bias_lines", "conclude", "cost_df",
           "cost_text", "cpus_line", "interval_text", "ratio_parts", "ratio_sentence", "ratio_text",
           "timing_lines", "timing_verdict"]
