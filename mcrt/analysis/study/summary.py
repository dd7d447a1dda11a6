"""What a study makes of its renders: a cell's summary over seeds, its images, the fits.

A cell is a :class:`~.fields.Cell`, the fields declared in
:data:`~.fields.CELL_FIELDS` (built by :func:`summarise_cell`), a fit a dict of
:data:`~.fields.FIT_FIELDS` (:func:`fit_sampler`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.stats import PixelStats
from ...core.timing import Sample, fit_cost, summarise
from ..aliasing import UNMEASURED, Z_THRESHOLD
from ..convergence import NONE, efficiency_estimate, excess_mse, fit_loglog, typical_time
from ..metrics import bias, error_map, mse, variance_map
from ..significance import t_quantile
from .config import SamplerSpec
from .fields import FIT_FIELDS, RESOLVED_FACTOR, Cell, cell_record, record


@dataclass
class CellImages:
    """Images of one (scene, sampler) at the report's spp (seed = first seed)."""

    render: np.ndarray           # (H, W, 3) linear
    error: np.ndarray            # (H, W) luminance error vs the reference
    std: np.ndarray              # (H, W) per-pixel sd of the estimate across seeds


@dataclass
class CellRenders:
    """Images of one (scene, sampler, spp) cell, for the report's viewer and EXR files."""

    mean: np.ndarray             # (H, W, 3) float32 mean over seeds (NaN/Inf samples left out)
    first: np.ndarray            # (H, W, 3) float32 render of the first seed, as rendered
    variance: np.ndarray         # (H, W) float32 per-pixel variance across seeds (channel mean)


def cell_renders(renders: list[np.ndarray], stats: PixelStats) -> CellRenders:
    """A cell's images for the viewer: mean and variance over seeds, the first seed."""
    return CellRenders(mean=np.asarray(stats.mean, dtype=np.float32),
                       first=np.asarray(renders[0], dtype=np.float32),
                       variance=variance_map(stats.variance).astype(np.float32))


def _mean_sd(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


def _mean(per_seed: list[dict[str, Any]], key: str) -> float:
    """Mean over seeds of the aliasing measure ``key``."""
    return float(np.mean([r["aliasing"][key] for r in per_seed]))


def _verdict(ratio_z: float, peak_z: float) -> str:
    if np.isnan(ratio_z):  # the image is too small to measure
        return UNMEASURED
    if ratio_z > Z_THRESHOLD or peak_z > Z_THRESHOLD:
        return "aliased"
    return "blue" if ratio_z < -Z_THRESHOLD else "noise"


@dataclass(frozen=True)
class ReferenceImage:
    """A scene's reference as every render of the study is measured against it."""

    mean: np.ndarray             # (H, W, 3) float64
    var: np.ndarray              # its per-pixel variance (squared standard error)
    floor: float                 # mean of ``var``: what it adds to every MSE


@dataclass(frozen=True)
class CellScores:
    """What one (scene, sampler, spp) cell's renders gave: its scored seeds'
    records (:func:`~.seeds.score_seed`) and their renders' pixel moments."""

    scene: str
    sampler: SamplerSpec
    spp: int                         # requested
    per_seed: list[dict[str, Any]]
    stats: PixelStats
    #: the film filter of a ``filters`` study ("" otherwise)
    rfilter: str = ""
    #: what the film's filter multiplies the variance of a mean over pixels by
    #: (:func:`mcrt.analysis.filter_noise.variance_factor`; 1: box)
    variance_factor: float = 1.0
    #: every timed render of the cell in round order (None: the seeds' own renders)
    times: Sequence[Sample] | None = None


def summarise_cell(scores: CellScores, ref: ReferenceImage) -> Cell:
    """The cell of ``scores`` against its scene's reference ``ref``. The
    study-wide fields (ratios to the baseline, the bias flag, the verdict) are
    filled by :func:`~.conclude.conclude`."""
    per_seed, stats, times = scores.per_seed, scores.stats, scores.times
    floor, sampler = ref.floor, scores.sampler
    if times is None:
        times = [Sample(r["seconds"], r.get("cpu_seconds", math.nan)) for r in per_seed]
    mse_mean, mse_sd = _mean_sd([r["mse"] for r in per_seed])
    rel_mean, rel_sd = _mean_sd([r["rel_mse"] for r in per_seed])
    de_mean, de_sd = _mean_sd([r["delta_e"] for r in per_seed])
    excess = mse_mean - floor
    resolved = bool(mse_mean > RESOLVED_FACTOR * floor)
    b = _bias(per_seed, ref.mean, ref.var, scores.variance_factor)
    ratio_z, peak_z = _mean(per_seed, "ratio_z"), _mean(per_seed, "peak_z")
    nan = math.nan
    values = {
        "scene": scores.scene, "filter": scores.rfilter, "sampler": sampler.label,
        "plugin": sampler.name, "params": dict(sampler.params), "spp_requested": scores.spp,
        "spp": int(per_seed[0]["spp"]), "seeds": [r["seed"] for r in per_seed],
        "mse": mse_mean, "mse_sd": mse_sd, "mse_floor": floor, "mse_excess": excess,
        "mse_of_mean": mse(stats.mean, ref.mean),
        "resolved": resolved,
        "rel_mse": rel_mean, "rel_mse_sd": rel_sd,
        "efficiency_ratio": nan, "efficiency_ratio_low": nan, "efficiency_ratio_high": nan,
        "efficiency_samples": nan,
        "variance": float(variance_map(stats.variance).mean()),
        "bias": b.value, "bias_low": b.low, "bias_high": b.high, "bias_z": b.z,
        "bias_df": b.df,
        "biased": False, "verdict": "",
        "delta_e": de_mean, "delta_e_sd": de_sd,
        "aliasing_ratio": _mean(per_seed, "ratio"), "aliasing_ratio_z": ratio_z,
        "aliasing_peak": _mean(per_seed, "peak"), "aliasing_peak_z": peak_z,
        "aliasing": _verdict(ratio_z, peak_z),
        "nonfinite": int(sum(r["nonfinite"] for r in per_seed)),
        "per_seed": per_seed,
    }
    return cell_record({**values, **_time_fields(values, times)})


@dataclass(frozen=True)
class _Bias:
    value: float
    z: float
    df: float
    low: float
    high: float


def _bias(per_seed: list[dict[str, Any]], ref_mean: np.ndarray, ref_var: np.ndarray,
          variance_factor: float) -> _Bias:
    """The mean error of the seed-averaged image and its Student-t statistic.

    The seeds are the replications: their image means' spread gives the standard
    error, to which the reference's own noise adds (its image mean's variance from
    its per-pixel standard errors, the film filter's pixel correlation and a
    pixel's channels taken as correlated). The statistic is referred to Student's t
    on K - 1 degrees of freedom, the replications', whatever the share of the
    reference's term: that term is itself estimated from pixels, which heavy tails
    make too small, so it is credited with no degrees of freedom of its own (with
    infinite ones, 4 of 20 null studies flagged an unbiased sampler at 16 spp,
    where the reference's term dominates). A test on the replications holds up
    where pixel errors are heavy-tailed (a path tracer's fireflies at low spp make
    the per-pixel variances of a few seeds too small, and a test built on them
    flags unbiased samplers)."""
    from ..significance import t_quantile

    d = np.array([r["mean_error"] for r in per_seed], dtype=np.float64)
    k = d.size
    value = float(d.mean())
    v_seed = float(d.var(ddof=1)) / k if k > 1 else 0.0
    v_ref = bias(ref_mean, ref_mean, reference_variance=_known_variance(ref_var),
                 variance_factor=variance_factor, correlated_channels=True).standard_error ** 2
    se = math.sqrt(v_seed + v_ref)
    if se == 0:
        z = 0.0 if value == 0 else math.copysign(math.inf, value)
        return _Bias(value, z, math.inf, value, value)
    df = k - 1.0 if k > 1 else math.inf
    half = t_quantile(0.975, df) * se
    return _Bias(value, value / se, df, value - half, value + half)


def _known_variance(var: np.ndarray) -> np.ndarray:
    """``var`` with its unknown values (NaN: a reference pixel with fewer than two
    finite samples, e.g. one that sees an emitter of infinite radiance) replaced by
    the mean of the known ones, as the noise floor averages over the known pixels
    only; one such pixel made the reference's term, and so every cell's bias
    interval and ``bias_z``, NaN, and the bias flag could never fire."""
    var = np.asarray(var, dtype=np.float64)
    known = np.isfinite(var)
    if known.all():
        return var
    return np.where(known, var, float(var[known].mean()) if known.any() else 0.0)


def retime_cell(cell: Cell, times: Sequence[Sample]) -> Cell:
    """``cell`` with the times of other timed renders (``mcrt compare --retime``):
    its errors are kept, its time and efficiency fields made anew."""
    return cell_record({**cell, **_time_fields(cell, times)})


def _time_fields(cell: Mapping[str, Any], times: Sequence[Sample]) -> dict[str, Any]:
    """The time fields of a cell from its timed renders (:mod:`mcrt.core.timing`:
    median, robust spread, 95% interval, CPU time, what disturbed them) and its
    efficiency with a 95% interval (:func:`~mcrt.analysis.convergence.efficiency_estimate`)."""
    summary = summarise(times)
    wall = [t.wall for t in times]
    time = typical_time(wall)
    low, high = time.interval()
    eff = efficiency_estimate(excess_mse([r["mse"] for r in cell["per_seed"]],
                                         cell["mse_floor"]), time) \
        if cell["resolved"] else NONE
    eff_low, eff_high = eff.interval()
    return {"seconds": summary.median, "seconds_low": low, "seconds_high": high,
            "seconds_sd": summary.spread, "seconds_min": summary.minimum,
            "cpu_seconds": summary.cpu_median, "times": wall,
            "cpu_times": [t.cpu for t in times], "time_others": [t.others for t in times],
            "time_problems": "; ".join(summary.problems()),
            "efficiency": eff.value, "efficiency_low": eff_low, "efficiency_high": eff_high}


def cell_images(renders: list[np.ndarray], stats: PixelStats,
                ref_mean: np.ndarray) -> CellImages:
    """The report's images of a cell: its first seed's render, that render's
    luminance error (NaN/Inf pixels as the reference's) and the per-pixel sd."""
    first = np.where(np.isfinite(renders[0]), renders[0], ref_mean)
    return CellImages(render=renders[0].astype(np.float32),
                      error=error_map(first, ref_mean).astype(np.float32),
                      std=np.sqrt(variance_map(stats.variance)).astype(np.float32))


def fit_sampler(scene: str, sampler: str, cells: Sequence[Cell],
                pixels: int = 0) -> dict[str, Any]:
    """Log-log slopes of the excess MSE vs spp and vs seconds over the resolved
    cells' per-seed values (NaN unless at least two sample counts are resolved:
    the timing scatter of one cell's seeds is not a slope; a cell's x for the
    time slope is its median time), and the sampler's cost split into a fixed
    per-render part and a per-sample part (:func:`mcrt.core.timing.fit_cost`
    over every timed render of every cell; ``pixels``: the film's, 0 to skip)."""
    mine = [c for c in cells if c["scene"] == scene and c["sampler"] == sampler]
    used = [c for c in mine if c["resolved"]]
    x_spp: list[float] = []
    x_sec: list[float] = []
    y: list[float] = []
    for c in used:
        for r in c["per_seed"]:
            x_spp.append(c["spp"])
            x_sec.append(c["seconds"])
            y.append(r["mse"] - c["mse_floor"])
    # A seed whose excess is not positive has no logarithm: the fit leaves it out,
    # and ``points`` counts the values it uses.
    usable = sum(1 for v in y if math.isfinite(v) and v > 0)
    out: dict[str, Any] = {"scene": scene, "sampler": sampler, "points": usable,
                           "cells_used": len(used), "cells": len(mine)}
    sample_counts = len({c["spp"] for c in used})
    out.update(_slope("spp", x_spp, y, sample_counts))
    out.update(_slope("seconds", x_sec, y, sample_counts if _times_apart(used) else 0))
    effs = [c["efficiency"] for c in mine if math.isfinite(c["efficiency"])]
    out["efficiency_max"] = max(effs) if effs else float("nan")
    samples = [c["spp"] * pixels for c in mine for _ in c["times"]]
    cost = fit_cost(samples, [t for c in mine for t in c["times"]]) if pixels else fit_cost([], [])
    out.update({"fixed_seconds": cost.fixed, "fixed_seconds_se": cost.fixed_se,
                "seconds_per_sample": cost.per_unit,
                "seconds_per_sample_se": cost.per_unit_se})
    return record(FIT_FIELDS, out)


def _times_apart(used: Sequence[Cell]) -> bool:
    """Whether a slope against time has a run to fit: the time interval of the cell
    with the fewest samples lies below that of the cell with the most. Where they
    overlap (a fixed cost per render dwarfs the sampling: a thin-lens crop's
    renders took about as long at 4 as at 64 spp) the times do not tell the
    sample counts apart, and the fit came out at -40 to -182: noise over noise."""
    if len(used) < 2:
        return False
    fewest = min(used, key=lambda c: c["spp"])
    most = max(used, key=lambda c: c["spp"])
    return float(fewest.get("seconds_high", fewest["seconds"])) < \
        float(most.get("seconds_low", most["seconds"]))


def _slope(key: str, x: list[float], y: list[float], sample_counts: int) -> dict[str, float]:
    """The fit of log y against log x as ``slope_<key>`` etc.; NaN without a slope
    (fewer than two resolved sample counts: one cell's seed scatter is no slope)."""
    try:
        if sample_counts < 2:
            raise ValueError("fewer than two resolved sample counts")
        fit = fit_loglog(x, y)
    except ValueError:
        nan = float("nan")
        return {f"slope_{key}": nan, f"slope_{key}_se": nan, f"slope_{key}_low": nan,
                f"slope_{key}_high": nan, f"intercept_{key}": nan, f"r2_{key}": nan}
    half = t_quantile(0.975, fit.n - 2) * fit.slope_se if fit.n > 2 else float("nan")
    return {f"slope_{key}": fit.slope, f"slope_{key}_se": fit.slope_se,
            f"slope_{key}_low": fit.slope - half, f"slope_{key}_high": fit.slope + half,
            f"intercept_{key}": fit.intercept, f"r2_{key}": fit.r2}
