"""The fields of a study's results, declared once.

Every value a study records per (scene, sampler, spp) cell is one
:class:`Field` of :data:`CELL_FIELDS`, every value of a (scene, sampler) fit
one of :data:`FIT_FIELDS`. Everything else is derived from these tuples:

* the keys (and their order) of every cell and fit the study produces
  (:func:`record` builds them and refuses a key that is missing or not
  declared) and so of ``results.json`` and the resume state;
* the columns of ``results.csv`` (:data:`CSV_COLUMNS`), and those a run of the
  same study repeats (:data:`REPEATED_COLUMNS`: not timed);
* the report's definitions (:data:`DEFINITIONS`), its table of cells
  (:data:`CELL_COLUMNS`) and the slope columns of its summary table
  (:data:`FIT_COLUMNS`).

How a table column shows its value (the ``show`` of a :class:`Column`):
``text`` the value as text, ``count`` an integer, ``value`` a number,
``sd`` a number +- the field ``<name>_sd`` (``se``: ``<name>_se``),
``interval`` a number with ``[<name>_low, <name>_high]``, ``z`` a number
with ``(<name>_z)``, ``flag`` nothing when true, ``Column.false`` when false.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict, cast

import numpy as np

from ...core.provenance import CSV_COLUMNS as CSV_PROVENANCE
from ..aliasing import DEFAULT_CELLS, DEFAULT_CUTOFF, MIN_SIZE, UNMEASURED, Z_THRESHOLD
from ..metrics import REL_MSE_EPSILON, RESOLVED_FACTOR

Show = Literal["text", "count", "value", "sd", "se", "interval", "z", "flag"]


@dataclass(frozen=True)
class Column:
    """How a field appears as a column of one of the report's HTML tables."""

    heading: str                 # plain text (escaped by the report)
    show: Show = "value"         # see the module doc
    scale: float = 1.0           # display factor (seconds are shown in ms)
    false: str = ""              # what a ``flag`` column shows when the flag is false


@dataclass(frozen=True)
class Field:
    """One value of a cell (or fit) of a study, and where it appears."""

    name: str
    #: the report's definition of the value ("" = none of its own)
    definition: str = ""
    #: the term its definition is listed under (default: ``name``)
    term: str = ""
    #: a key of every cell in results.json (False: a results.csv column only)
    json: bool = True
    #: a column of results.csv
    csv: bool = True
    #: its column in the report's table, if any
    column: Column | None = None
    #: it depends on the renders' times (no two runs give the same value)
    timed: bool = False


CELL_FIELDS: tuple[Field, ...] = (
    Field("scene", column=Column("scene", "text")),
    Field("filter", "the film's reconstruction filter set by the study's filters axis (the "
                    "scene's name then ends in ~filter); empty: the scene's own filter",
          column=Column("filter", "text")),
    Field("sampler", column=Column("sampler", "text")),
    Field("plugin"),
    Field("params"),
    Field("spp_requested"),
    Field("spp", column=Column("spp", "count")),
    Field("seeds"),
    Field("seconds", "median wall time of one render over the cell's timed renders: the "
                     "seeds' renders and timing-only ones, every sampler of a sample count "
                     "interleaved in shuffled rounds after a warm-up (see time_protocol); "
                     "seconds_low/high: its 95% interval (Student t on the log, se = "
                     "sqrt(pi/2) sd(log t) / sqrt(n)), over this run's rounds: a slow "
                     "spell longer than them moves the whole cell, so another run may fall "
                     "outside it (docs/metrics.md); efficiency_ratio pairs renders and holds",
          column=Column("time (ms) [95%]", "interval", scale=1e3), timed=True),
    Field("seconds_low", timed=True),
    Field("seconds_high", timed=True),
    Field("seconds_sd", "robust spread of the timed renders: 1.4826 x their median absolute "
                        "deviation (s)", timed=True),
    Field("seconds_min", timed=True),
    Field("cpu_seconds", "median process CPU time of the timed renders (all threads; "
                         "above the wall time when rendering uses several cores)", timed=True),
    Field("times", "wall time of every timed render, in round order (s)", timed=True),
    Field("cpu_times", timed=True),
    Field("time_others", "other runnable processes when each timed render started "
                         "(procs_running of /proc/stat; empty where unknown)", timed=True),
    Field("time_problems", "what makes the cell's timing doubtful: a spread over 10% of the "
                           "median, outliers (> 3.5 robust sd) in over a quarter of its "
                           "renders, other processes running at over a quarter of them; "
                           "empty: none",
          column=Column("timing", "text"), timed=True),
    Field("mse", "mean over pixels and channels of (render - reference)^2, averaged over seeds",
          column=Column("MSE", "sd")),
    Field("mse_sd"),
    Field("mse_floor", "mean squared standard error of the reference: what its own noise adds "
                       "to every MSE"),
    Field("mse_excess", "mse - mse_floor: unbiased estimate of the MSE against the exact image "
                        "(render and reference independent); used for slopes and efficiency",
          column=Column("MSE \u2212 floor")),
    Field("mse_of_mean", "MSE of the seed-averaged image; mse = mse_of_mean + (K - 1) / K x "
                         "variance (K seeds) exactly, so the two split the error into "
                         "bias-like and noise parts"),
    Field("resolved", f"mse > {RESOLVED_FACTOR:g} x mse_floor; unresolved cells are left out "
                      "of fits and get no efficiency",
          column=Column("resolved", "flag", false="unresolved")),
    Field("rel_mse", f"mean (render - reference)^2 / (reference^2 + {REL_MSE_EPSILON:g})",
          column=Column("relMSE")),
    Field("rel_mse_sd"),
    Field("efficiency", "1 / (mse_excess x seconds), on the median wall time of a whole "
                        "render (fixed host cost included); efficiency_low/high: its 95% "
                        "interval (delta method on the log: the seeds' MSE spread and the "
                        "time's standard error, Student t at Welch-Satterthwaite degrees of "
                        "freedom)",
          column=Column("efficiency [95%]", "interval"), timed=True),
    Field("efficiency_low", timed=True),
    Field("efficiency_high", timed=True),
    Field("efficiency_ratio", "efficiency / the baseline sampler's at the same spp, with a "
                              "95% interval (the two MSEs' spreads and the paired time ratio "
                              "of renders timed in the same rounds); its inverse is the time "
                              "needed for the baseline's error relative to the baseline's; an "
                              "interval containing 1: no significant difference",
          column=Column("eff. ratio [95%]", "interval"), timed=True),
    Field("efficiency_ratio_low", timed=True),
    Field("efficiency_ratio_high", timed=True),
    Field("efficiency_samples", "1 / (mse_excess x seconds_per_sample x pixels x spp): the "
                                "efficiency on the per-sample cost alone (the sampler's fixed "
                                "per-render cost removed, see the fits)", timed=True),
    Field("variance", "mean over pixels and channels of the per-pixel variance of the pixel "
                      "estimate across seeds (Welford, float64; 0 for a deterministic sampler)",
          column=Column("variance")),
    Field("bias", "mean of (seed-averaged render - reference) over pixels and channels, with "
                  "a 95% Student-t interval: the seeds' image means are the replications "
                  "(K - 1 degrees of freedom), the reference's noise added (its per-pixel "
                  "standard errors, the film filter's pixel correlation, channels as one)",
          column=Column("bias [95%]", "interval")),
    Field("bias_low"),
    Field("bias_high"),
    Field("bias_z", "bias / its standard error (a t statistic on bias_df degrees of freedom)"),
    Field("bias_df", "the degrees of freedom of that standard error: K - 1, the seeds' (the "
                     "reference's term, estimated from its pixels, is credited with none)"),
    Field("biased", "the bias is significant: its two-sided p-value (Student t from bias_z and "
                    "bias_df) is rejected by Holm's step-down correction at 0.05 over every "
                    "measured cell of the study"),
    Field("delta_e", "mean CIEDE2000 of the displayed images (linear sRGB clipped to [0, 1], "
                     "D65, Y_white = 1)",
          column=Column("\u0394E00")),
    Field("delta_e_sd"),
    Field("aliasing_ratio", f"share of luminance-error energy at |f| < {DEFAULT_CUTOFF} "
                            "cycles/pixel over that band's share of frequency bins (Hann "
                            "window, DC excluded): white noise ~1, moire >> 1, blue noise < 1",
          column=Column("alias ratio (z)", "z")),
    Field("aliasing_ratio_z"),  # defined with aliasing_peak_z
    Field("aliasing_peak", f"max / median of the error power averaged over {DEFAULT_CELLS}x"
                           f"{DEFAULT_CELLS} frequency cells: noise ~1, coherent patterns >> 1",
          column=Column("peak (z)", "z")),
    Field("aliasing_peak_z", "(value - null mean) / null sd, the null from random sign flips "
                             "of the per-pixel errors (independent pixel errors of the same "
                             "magnitudes)", term="aliasing_*_z"),
    Field("aliasing", f"'aliased' if either z (mean over seeds) > {Z_THRESHOLD:g}, 'blue' if "
                      f"the ratio's z < -{Z_THRESHOLD:g}, else 'noise'; '{UNMEASURED}' (and the "
                      f"four measures NaN) for an image under {MIN_SIZE} pixels on a side",
          column=Column("aliasing", "text")),
    Field("verdict", "the aliasing verdict, with 'biased' added for a biased cell",
          column=Column("verdict", "text")),
    Field("nonfinite"),
    Field("per_seed", csv=False),
    # The row's progress, written by the report for measured and pending cells alike.
    Field("status", json=False),
    Field("seeds_done", json=False),
    Field("seeds_total", json=False),
    # How the file was made, the same on every row (results.json's command):
    # :data:`mcrt.core.provenance.CSV_COLUMNS`.
    *(Field(name, json=False) for name in CSV_PROVENANCE),
)

FIT_FIELDS: tuple[Field, ...] = (
    Field("scene"),
    Field("sampler"),
    Field("points"),
    Field("cells_used"),
    Field("cells"),
    Field("slope_spp", "least-squares slope of log10(mse_excess) vs log10(spp) over the "
                       "resolved cells' per-seed values (a seed whose excess is not positive "
                       "has no logarithm and is left out: points counts the values used; "
                       "slope_*_se: its OLS standard error; slope_*_low/high: its 95% "
                       "interval, Student t on n - 2 degrees of freedom)",
          column=Column("slope vs spp [95%]", "interval")),
    Field("slope_spp_se"),
    Field("slope_spp_low"),
    Field("slope_spp_high"),
    Field("intercept_spp"),
    Field("r2_spp"),
    Field("slope_seconds", "the same against log10(seconds), each cell at its median time; "
                           "NaN where the time intervals of the cells with the fewest and "
                           "the most samples overlap (the times do not tell them apart)",
          column=Column("slope vs time [95%]", "interval")),
    Field("slope_seconds_se"),
    Field("slope_seconds_low"),
    Field("slope_seconds_high"),
    Field("intercept_seconds"),
    Field("r2_seconds"),
    Field("efficiency_max"),
    Field("fixed_seconds", "the sampler's fixed cost per render: the intercept of the "
                           "least-squares line seconds = fixed + seconds_per_sample x samples "
                           "over every timed render of its cells (samples = pixels x spp; "
                           "*_se: OLS standard errors)"),
    Field("fixed_seconds_se"),
    Field("seconds_per_sample", "the slope of that line: the cost of one more sample"),
    Field("seconds_per_sample_se"),
)


def json_keys(fields: Iterable[Field]) -> tuple[str, ...]:
    """The keys, in order, of a record of ``fields`` (a cell or a fit)."""
    return tuple(f.name for f in fields if f.json)


def plain(value: Any) -> Any:
    """JSON-ready copy keeping NaN/Inf (Python's json writes and reads them back)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, Path):
        return str(value)
    return value


def record(fields: tuple[Field, ...], values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` as a record of ``fields``: the declared keys in the declared
    order, as plain JSON-ready values (:func:`plain`).

    A declared key without a value, or a value of an undeclared key, is a
    programming error (the report would lose or invent a field): ValueError.
    """
    keys = json_keys(fields)
    missing = [k for k in keys if k not in values]
    extra = [k for k in values if k not in keys]
    if missing or extra:
        raise ValueError(f"record does not match its declared fields: missing {missing}, "
                         f"undeclared {extra}")
    return {k: plain(values[k]) for k in keys}


class Cell(TypedDict):
    """One (scene, sampler, spp) cell of a study as :func:`cell_record` makes it and
    results.json and the resume state hold it: the keys of :data:`CELL_FIELDS`
    that are in results.json, in their order (a test checks that the two agree).
    A seed's record in ``per_seed`` is :func:`~.seeds.score_seed`'s dict."""

    scene: str
    filter: str
    sampler: str
    plugin: str
    params: dict[str, Any]
    spp_requested: int
    spp: int
    seeds: list[int]
    seconds: float
    seconds_low: float
    seconds_high: float
    seconds_sd: float
    seconds_min: float
    cpu_seconds: float
    times: list[float]
    cpu_times: list[float]
    time_others: list[int | None]
    time_problems: str
    mse: float
    mse_sd: float
    mse_floor: float
    mse_excess: float
    mse_of_mean: float
    resolved: bool
    rel_mse: float
    rel_mse_sd: float
    efficiency: float
    efficiency_low: float
    efficiency_high: float
    efficiency_ratio: float
    efficiency_ratio_low: float
    efficiency_ratio_high: float
    efficiency_samples: float
    variance: float
    bias: float
    bias_low: float
    bias_high: float
    bias_z: float
    bias_df: float
    biased: bool
    delta_e: float
    delta_e_sd: float
    aliasing_ratio: float
    aliasing_ratio_z: float
    aliasing_peak: float
    aliasing_peak_z: float
    aliasing: str
    verdict: str
    nonfinite: int
    per_seed: list[dict[str, Any]]


def cell_record(values: Mapping[str, Any]) -> Cell:
    """``values`` as a :class:`Cell` (:func:`record` of :data:`CELL_FIELDS`)."""
    return cast(Cell, record(CELL_FIELDS, values))


#: Keys of every cell a study produces (results.json, the resume state).
CELL_KEYS = json_keys(CELL_FIELDS)
#: Keys of every (scene, sampler) fit.
FIT_KEYS = json_keys(FIT_FIELDS)
#: Columns of results.csv, in order.
CSV_COLUMNS = tuple(f.name for f in CELL_FIELDS if f.csv)
#: Columns of results.csv that a run of the same study writes again as they are:
#: neither timed nor how the file was made (``compare --from``).
REPEATED_COLUMNS = tuple(f.name for f in CELL_FIELDS
                         if f.csv and not f.timed and f.name not in CSV_PROVENANCE)
#: The report's definitions: term -> text, cells' then fits'.
DEFINITIONS = {f.term or f.name: f.definition for f in CELL_FIELDS + FIT_FIELDS if f.definition}
#: Columns of the report's table of cells.
CELL_COLUMNS = tuple(f for f in CELL_FIELDS if f.column is not None)
#: Columns of the report's summary table taken from the fits (slopes).
FIT_COLUMNS = tuple(f for f in FIT_FIELDS if f.column is not None)
