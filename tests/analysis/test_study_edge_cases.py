"""Studies of unusual but valid inputs: what a cell's figures say about them."""

from __future__ import annotations

import math

import numpy as np

from mcrt.analysis.study import CellScores, ReferenceImage, SamplerSpec, summarise_cell
from mcrt.core.stats import PixelStats


def _cell(ref_var: np.ndarray, bias: float = 0.0):
    rng = np.random.default_rng(3)
    ref = rng.random((16, 16, 3))
    renders = [ref + bias + rng.normal(0.0, 0.05, ref.shape) for _ in range(3)]
    per_seed = [{"seed": s, "spp": 4, "seconds": 1e-3, "nonfinite": 0,
                 "mse": float(np.mean((r - ref) ** 2)), "mean_error": float(np.mean(r - ref)),
                 "rel_mse": 0.1, "delta_e": 1.0,
                 "aliasing": {"ratio": 1.0, "ratio_z": 0.1, "peak": 2.0, "peak_z": -0.2}}
                for s, r in enumerate(renders)]
    known = ref_var[np.isfinite(ref_var)]
    floor = float(np.mean(known)) if known.size else 0.0
    return summarise_cell(CellScores("scene", SamplerSpec("jittered", "jittered", {}), 4,
                                     per_seed, PixelStats.from_images(renders)),
                          ReferenceImage(ref, ref_var, floor))


def test_a_reference_pixel_without_a_standard_error_leaves_the_bias_measurable():
    """A reference pixel with fewer than two finite samples (scenes/hard/degenerate.xml's
    emitter of infinite radiance) has an unknown (NaN) standard error; the bias's
    reference term takes the known pixels' mean there, as the noise floor does,
    instead of turning every cell's bias interval and t statistic NaN (the bias flag
    then could never fire on such a scene)."""
    var = np.full((16, 16, 3), 1e-6)
    known = _cell(var, bias=0.01)
    var[2, 5] = np.nan
    cell = _cell(var, bias=0.01)
    for key in ("bias_z", "bias_low", "bias_high"):
        assert math.isfinite(cell[key]), key
        assert math.isclose(cell[key], known[key], rel_tol=1e-12), key
    assert cell["bias_z"] > 5  # a 0.01 bias against 0.05 noise over 768 values
    # No known pixel at all: the reference adds nothing it can state.
    assert math.isfinite(_cell(np.full((16, 16, 3), np.nan))["bias_z"])


def test_a_fits_points_count_the_seeds_it_used():
    """A seed whose MSE is at or below the reference's noise floor has no logarithm
    of its excess, and the log-log fit leaves it out: ``points`` says how many
    values the fit used (it said every seed's, 4 where 3 were used), and the slope
    is the fit through the others (checked against numpy's polyfit of them)."""
    from mcrt.analysis.study import fit_sampler

    floor = 1e-4
    cells = []
    for spp, mses in ((4, [4e-3, 5e-3]), (16, [1e-3, 0.5e-4])):  # 0.5e-4 < the floor
        per_seed = [{"mse": m} for m in mses]
        cells.append({"scene": "s", "sampler": "j", "resolved": True, "spp": spp,
                      "seconds": 0.01 * spp, "mse_floor": floor, "per_seed": per_seed,
                      "efficiency": 1.0, "times": [0.01 * spp]})
    fit = fit_sampler("s", "j", cells)
    assert fit["points"] == 3
    x = np.log10([4, 4, 16])
    y = np.log10(np.array([4e-3, 5e-3, 1e-3]) - floor)
    assert math.isclose(fit["slope_spp"], np.polyfit(x, y, 1)[0], rel_tol=1e-9)


def test_a_per_sample_cost_lost_in_the_scatter_is_shown_as_a_bound():
    """A tiny film's renders take the fixed cost and noise: the least-squares
    per-sample cost came out negative (-186 ns per sample, +- 480, on an 8 x 4
    sky) and the study's tables printed it as a cost. Now a cost whose 95%
    interval reaches 0 shows only its upper bound, a resolved one its value."""
    from mcrt.analysis.study.conclude import cost_text
    from mcrt.core.timing import fit_cost

    samples = [32 * spp for spp in (4, 16) for _ in range(5)]
    seconds = [1.2e-3, 1.0e-3, 1.4e-3, 1.1e-3, 1.3e-3, 1.3e-3, 1.1e-3, 1.0e-3, 1.2e-3, 1.25e-3]
    fit = fit_cost(samples, seconds)
    assert fit.per_unit < 0 < fit.per_unit + 1.96 * fit.per_unit_se  # noise, not a cost
    text = cost_text(fit.per_unit, fit.per_unit_se, 1e9)
    # (to the decimal of the standard error's first digit: 231 ns, 0.09 ms; a bound up)
    assert text == f"<{math.ceil(1e9 * (fit.per_unit + 1.96 * fit.per_unit_se)):d}"
    assert cost_text(fit.fixed, fit.fixed_se, 1e3) == f"{1e3 * fit.fixed:.2f}"  # resolved
    assert cost_text(2e-9, 1e-10, 1e9) == "2.0"
    assert cost_text(-1e-9, 1e-10, 1e9) == "-"  # negative and resolved: no cost at all
    assert cost_text(-1e-9, math.nan, 1e9) == "-" and cost_text(1e-9, math.nan, 1e9) == "1.00"
    assert cost_text(math.nan, math.nan, 1e9) == "-"


def test_a_cost_is_printed_to_the_precision_of_its_standard_error():
    """Measured: 8 quiet runs of one study printed the checkerboard's cost per sample
    as 21.70, 20.40, 30.50, 34.70 ... ns (se 2-7 ns): two decimals of a figure whose
    first digit was uncertain. A cost now keeps the decimals of its standard error's
    first significant digit."""
    from mcrt.analysis.study.conclude import cost_text

    assert cost_text(21.7e-9, 3.4e-9, 1e9) == "22"
    assert cost_text(272.2e-9, 3.3e-9, 1e9) == "272"
    assert cost_text(43.13e-9, 0.14e-9, 1e9) == "43.1"
    assert cost_text(1.474e-3, 0.06e-3, 1e3) == "1.47"
    assert cost_text(0.5e-9, 1e-9, 1e9) == "<3"  # its 95% interval reaches 0: a bound, up
    assert cost_text(2e-9, float("nan"), 1e9) == "2.00"  # no se: the given spec


def test_an_efficiency_ratio_is_printed_to_the_digits_its_interval_supports():
    """The console printed ``11.49 [2.76, 47.91]``: four digits of a ratio whose
    interval spans a factor of 17. Ratios now keep 3 significant digits at most,
    2 when the interval spans more than a factor of 1.2 (+-10%), alike on the console, in the
    sentences and in the report's tables (results.json keeps the full values)."""
    from mcrt.analysis.report_tables import CELL_COLUMNS, _ratio_cell, _show
    from mcrt.analysis.study.conclude import ratio_sentence, ratio_text

    assert ratio_text(11.49, 2.76, 47.91) == "11 [2.8, 48]"
    assert ratio_text(0.9871, 0.9623, 1.0134) == "0.987 [0.962, 1.01]"
    assert ratio_text(2.5641, 2.1739, 2.9412) == "2.6 [2.2, 2.9]"
    assert ratio_text(1.1934, 1.1187, 1.2781) == "1.19 [1.12, 1.28]"  # within a factor 1.2
    assert ratio_text(1234.5, 700.0, 2100.0) == "1200 [700, 2100]"  # plain decimals
    assert ratio_text(9.996, 9.99, 10.01) == "10.0 [9.99, 10.0]"
    assert ratio_text(math.nan, math.nan, math.nan) == "-"
    cell = {"sampler": "stratified", "spp": 16, "resolved": True, "efficiency_ratio": 2.5641,
            "efficiency_ratio_low": 2.1739, "efficiency_ratio_high": 2.9412}
    assert ratio_sentence(cell, "independent") == (
        "stratified needs 0.39x [0.34, 0.46] of independent's time for the same error at "
        "16 spp")
    wide = {**cell, "efficiency_ratio": 11.49, "efficiency_ratio_low": 2.76,
            "efficiency_ratio_high": 47.91}
    assert ratio_sentence(wide, "independent").startswith(
        "stratified needs 0.087x [0.021, 0.36] of independent's time")
    assert _ratio_cell(wide) == "11 [2.8, 48]"
    field = next(f for f in CELL_COLUMNS if f.name == "efficiency_ratio")
    assert _show(field, wide) == "11 [2.8, 48]"


def test_no_slope_against_time_where_the_times_do_not_tell_the_sample_counts_apart():
    """A render whose fixed cost dwarfs its sampling takes about as long at 4 as at
    64 spp: the slope of the error against such times was noise over noise (-40 to
    -182 on a thin-lens crop). Where the time intervals of the fewest- and the
    most-sample cells overlap the slope against time is NaN; the slope against spp
    stays; separated times give both."""
    from mcrt.analysis.study import fit_sampler

    def cells(times: list[tuple[float, float, float]]) -> list[dict]:
        return [{"scene": "s", "sampler": "j", "resolved": True, "spp": spp, "seconds": t,
                 "seconds_low": low, "seconds_high": high, "mse_floor": 0.0,
                 "per_seed": [{"mse": 1.0 / spp}, {"mse": 1.1 / spp}], "efficiency": 1.0,
                 "times": [t]}
                for spp, (low, t, high) in zip((4, 16, 64), times, strict=True)]

    flat = fit_sampler("s", "j", cells([(9e-3, 10e-3, 11e-3), (9.5e-3, 10.2e-3, 11e-3),
                                        (10e-3, 10.5e-3, 11.5e-3)]))
    assert math.isnan(flat["slope_seconds"]) and math.isnan(flat["slope_seconds_low"])
    assert math.isclose(flat["slope_spp"], -1.0, rel_tol=1e-9)
    apart = fit_sampler("s", "j", cells([(9e-3, 10e-3, 11e-3), (35e-3, 40e-3, 45e-3),
                                         (150e-3, 160e-3, 170e-3)]))
    assert math.isclose(apart["slope_seconds"], -1.0, rel_tol=1e-9)
