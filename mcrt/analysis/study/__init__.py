"""Studies: what accuracy costs in time, for scenes x samplers x sample counts x seeds.

A study is described by a TOML file (see ``configs/quick.toml``)::

    name = "quick"                      # optional, default: the file's stem
    description = "..."                 # optional
    spp = [4, 16, 64]                   # sample counts (>= 2 distinct)
    seeds = 3                           # K seeds 0..K-1, or a list [0, 7, 9] (>= 2)
    image_spp = 16                      # optional: spp of the report's images
    time_rounds = 5                     # optional: timed renders per cell (>= seeds)
    baseline = "independent"            # optional: the sampler ratios compare with
    aliasing_draws = 32                 # optional: sign-flip draws of the aliasing null
    samplers = ["uniform_grid", "jittered",
                {name = "jittered", label = "jitter0.5", params = {jitter = 0.5}}]
    filters = ["box", "gaussian"]       # optional axis: each scene once per film filter
                                        # (cells' scene "<name>~<filter>", filter-aware
                                        # references; see configs/filters.toml)
    plugins = ["my_sampler.py"]         # optional: files registering samplers (relative
                                        # to the TOML file; see mcrt.plugins), loaded
                                        # before the samplers are checked

    [reference]                         # high-spp image every render is compared with
    spp = 4096
    sampler = "independent"             # optional (default); its standard error is exact
    seed = 0                            # optional
    spp_per_pass = 256                  # optional

    [[scenes]]
    path = "../scenes/checkerboard.xml" # relative to the TOML file
    name = "checkerboard"               # optional, default: the file's stem
    params = {width = 160, height = 120}  # optional $parameters of the scene

:func:`load_config` checks *everything* (keys, numbers, sampler names and
parameters, scene files, films) before any rendering and reports the first
problem as a one-line :class:`~mcrt.errors.McrtError`.

:func:`run_study` renders every scene's cells in groups, one per sample count
(every sampler at that spp), by the timing protocol of :mod:`mcrt.core.timing`:
each cell's untimed warm-up (kernels compile and are cached), then
``time_rounds`` rounds that render every cell of the group once in a shuffled
order; the first rounds render the seeds (scored against the reference), the
rest are timing-only. A render's time is the wall time of
:func:`mcrt.core.render.render_film` (tracing all passes, accumulating and
developing the film, synchronised with ``dr.sync_thread()``; scene loading,
sampler construction, copying the image to numpy and the metrics are *not*
included), with its process CPU time and the other processes runnable at its
start. Per cell it records the median time with a 95% interval, and over the K
seeds the mean and spread of: MSE and relMSE against the reference, the MSE in
excess of the reference's own noise (:func:`~mcrt.analysis.metrics.mse_excess`),
CIEDE2000, the aliasing score of the error; and from the K images together the
mean per-pixel variance of the pixel estimate (Welford over seeds: the real
variance of the estimator, stratification included), the MSE of the
seed-averaged image (``mse = mse_of_mean + (K - 1) / K * variance`` exactly) and
its bias with a 95% interval. NaN/Inf pixels are counted (``nonfinite``),
logged, left out of the per-pixel moments and count as zero error in the
metrics. Cells whose MSE is below :data:`RESOLVED_FACTOR` x the reference's
noise floor are flagged and left out of fits. Per (scene, sampler) it fits the
log-log slope of the excess MSE against spp and against seconds and the cost
per render as fixed + per sample, and computes the efficiency
``1 / (excess MSE x seconds)`` of every cell with a 95% interval; across cells
(:mod:`.conclude`) each efficiency as a ratio to the baseline sampler's at the
same spp (times paired by round), the Holm-corrected bias flags and whether the
timing held.

Interruption and resume: with a :class:`StudyState` (``mcrt compare`` keeps one
in ``<report dir>/.mcrt-resume/``) every finished cell is saved atomically as
soon as it is done, keyed by :func:`study_key` (the configuration's content,
the scenes' content and the software versions). A Ctrl-C raises
:class:`~mcrt.core.job.Interrupted` (mcrt's one interruption, a
``KeyboardInterrupt``) carrying the partial :class:`StudyResult` of the
finished cells as ``partial``; the next run with the same key
takes the saved cells instead of rendering them again (a group's cells finish
together: the renders of an interrupted group are rendered again).

The package, one concern a module:

* :mod:`.config` - the configuration's schema, parsing and checks;
* :mod:`.fields` - the fields of a cell and of a fit, declared once (the JSON
  keys, the CSV columns and the report's definitions and tables derive from it);
* :mod:`.summary` - a cell's summary over seeds, its images, the log-log fits;
* :mod:`.conclude` - what holds across cells: ratios to the baseline, bias flags,
  the timing verdict, and those in words;
* :mod:`.store` - the resume state;
* :mod:`.runner` - :func:`run_study` and its result.
"""

from __future__ import annotations

from .checks import check_config
from .config import (
    MAX_NAME_BYTES,
    MIN_REFERENCE_FACTOR,
    STUDY_NULL_DRAWS,
    WARMUP_SEED,
    ConfigError,
    ReferenceSpec,
    SamplerSpec,
    SceneSpec,
    StudyConfig,
    cell_keys,
    load_config,
    parse_config,
)
from .fields import CELL_FIELDS, FIT_FIELDS, RESOLVED_FACTOR, Cell, Column, Field
from .runner import ReferenceInfo, StudyResult, environment, run_study
from .store import STATE_DIR, STATE_FORMAT, StudyState, reference_fingerprint, study_key
from .summary import (
    CellImages,
    CellRenders,
    CellScores,
    ReferenceImage,
    cell_images,
    cell_renders,
    fit_sampler,
    summarise_cell,
)

__all__ = ["CELL_FIELDS", "FIT_FIELDS", "MAX_NAME_BYTES", "MIN_REFERENCE_FACTOR",
           "RESOLVED_FACTOR", "STATE_DIR", "STATE_FORMAT", "STUDY_NULL_DRAWS", "WARMUP_SEED",
           "Cell", "CellImages", "CellRenders", "CellScores", "Column", "ConfigError", "Field",
           "ReferenceImage", "ReferenceInfo", "ReferenceSpec", "SamplerSpec", "SceneSpec",
           "StudyConfig",
           "StudyResult", "StudyState", "cell_images", "cell_keys", "cell_renders",
           "check_config", "environment", "fit_sampler", "load_config", "parse_config",
           "reference_fingerprint", "run_study", "study_key", "summarise_cell"]
