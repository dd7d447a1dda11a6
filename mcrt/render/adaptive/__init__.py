"""Adaptive, variance-driven sampling with multi-level reconstruction.

The lecture's recipe, made precise:

1. **Passes.** Pass 0 gives every pixel ``min_spp`` samples. After each pass
   every pixel's error is tested (below). A pixel that fails, and every
   neighbour within ``dilation`` pixels of it (against false negatives: a
   feature that all of a pixel's samples missed is usually hit by a
   neighbour's), is *active* in the next pass. All active pixels get the same
   batch of new samples, and the batch grows from pass to pass so that a pixel
   active in every pass multiplies its count by about ``growth`` per pass (16,
   32, 48, 73, 98, 162, 226, 347, 468, 724, ... with ``jittered`` and the
   default 1.5: smaller steps overshoot the needed count less, larger ones
   need fewer passes). A neighbour is thus refined at
   the failing pixel's rate, not by a token sample or two, and a missed sliver
   of a small bright light is found as fast as its neighbour converges. A pass
   traces only the active pixels' samples, as one compacted wavefront (lanes
   built from the active pixel ids; a second batch size only where a pixel's
   ``max_spp`` budget is nearly spent), so it costs time in proportion to its
   samples, not to the image size. A pixel whose remaining budget cannot fit
   the smallest batch is done, and no longer keeps its neighbours active; the
   loop stops when no pixel is active.

2. **Error criterion.** With ``Y`` the pixel's mean luminance (linear sRGB
   weights), ``se_Y`` its standard error, ``z`` the two-sided normal quantile of
   ``confidence`` (1.96 at 0.95) and ``Ybar`` the image's mean luminance
   (each pixel clipped at the 99th percentile, so that a small bright light
   does not set the level), a pixel stays active while::

       z * se_Y  >  threshold * max(Y, dark_floor * Ybar)

   i.e. until, at the stated confidence, its relative error is below
   ``threshold``; ``dark_floor`` turns the test into an absolute one for pixels
   darker than ``dark_floor * Ybar``, so black pixels stop too. ``se_Y`` is
   bounded by ``sum_c w_c se_c`` over the channels' standard errors
   ``se_c = sqrt(var_c / n)`` (equal for grey pixels, never smaller), where
   ``var_c`` is the i.i.d. sample variance: for stratified samplers it
   overestimates the true error, so the test is conservative. A pixel with
   fewer than two finite samples has an unknown error and stays active until
   its budget is spent.

3. **Samples across passes: independent stratified batches of growing size.**
   In every pass an active pixel receives one *complete* pattern of ``m``
   samples of the scene's sampler, where ``m`` comes from a ladder
   ``min_spp * 2^i`` rounded down to counts the sampler supports (e.g. squares
   for ``jittered``: 16, 25, 64, 121, 256, ...). Every batch is stratified on its own, and
   since batches grow geometrically, most of a converged pixel's samples come
   from its largest, best-stratified batches. (A prefix of one big pattern is
   not an option: our samplers permute strata, so the first ``k`` of ``N``
   samples are not stratified.)
   No sample repeats: with mcrt's counter-based samplers, pass ``k`` draws
   epoch ``k`` of the pixel's sequence (sample indices ``k*m .. k*m+m-1`` at
   sample count ``m``), and every epoch is a fresh, independently permuted and
   jittered pattern. Mitsuba's samplers cannot address a pixel's sequence, so
   each (pass, batch size, chunk) wavefront is seeded with its own hashed seed
   and ``set_samples_per_wavefront(m)``: each pixel's ``m`` lanes still form one
   stratified pattern (``stratified``, ``multijitter``, ``ldsampler``, ...), but
   batches are decorrelated only by distinct seeds, not by construction.
   Pass 0 equals a fixed render with ``min_spp`` samples and the same seed.

4. **Multi-level reconstruction.** Samples are binned into ``s x s`` uniform
   sub-pixels (by their position inside the pixel); each non-empty sub-pixel is
   the mean of its samples; the sub-pixels are then filtered into pixels with
   the film's reconstruction filter evaluated at the sub-pixel centres (for
   ``box``: the plain average of the pixel's non-empty sub-pixels). Empty
   sub-pixels are left out and the filter weights renormalised over the
   non-empty ones. A pixel whose samples crowd into one small region is thus
   not biased toward that region (the lecture's 80%-black example,
   :func:`reconstruct_samples`).

Modules: :mod:`.settings` (the parameters, declared once), :mod:`.criterion`
(the error test), :mod:`.ladder` (batch sizes), :mod:`.reconstruct` (multi-level
reconstruction), :mod:`.sums` (per-pixel moments and sub-pixel sums),
:mod:`.engine` (the render loop, checkpoints), :mod:`.wavefront` (one
pass's compacted wavefront, traced), :mod:`.frozen` (the same wavefront
recorded once per batch size with Dr.Jit's frozen functions and replayed
without tracing: the same bits), :mod:`.result` (what a render returns). The
``adaptive`` integrator plugin is :mod:`mcrt.render.adaptive_integrator`; the
command line's options are in :mod:`mcrt.cli._adaptive_args`, the sample-count
heat map in :mod:`mcrt.io.heatmap`.

Per-pixel moments are float64, continued sample by sample with Welford's
update across passes, and each pixel's sub-pixel sums are formed in sample order
(:mod:`.sums`: one kernel per wavefront, no merge formula). Samples that are
NaN or infinite are left out of the moments and sub-pixels, counted per pixel,
and still count toward the pixel's budget (a pixel producing only NaN stops at
``max_spp``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .reconstruct import bin_samples, reconstruct, reconstruct_samples, subpixel_filter
from .settings import PARAMETERS, PARAMETERS_BY_NAME, AdaptiveSettings, Param

if TYPE_CHECKING:  # imported on first use (below): `mcrt render` without --adaptive skips them
    from .criterion import (
        IMAGE_MEAN_QUANTILE,
        LUMINANCE,
        dilate,
        error_ratio,
        image_mean_luminance,
        luminance_error,
    )
    from .engine import check_integrator, render_adaptive
    from .ladder import batch_ladder, budget_batches, pass_batch_size
    from .result import AdaptiveRender, PassRecord, pass_time_fit

#: Name -> submodule, for the names imported when first used.
_LAZY = {
    **dict.fromkeys(["IMAGE_MEAN_QUANTILE", "LUMINANCE", "dilate", "error_ratio",
                     "image_mean_luminance", "luminance_error"], "criterion"),
    **dict.fromkeys(["check_integrator", "render_adaptive"], "engine"),
    **dict.fromkeys(["batch_ladder", "budget_batches", "pass_batch_size"], "ladder"),
    **dict.fromkeys(["AdaptiveRender", "PassRecord", "pass_time_fit"], "result"),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module = importlib.import_module(f"{__name__}.{_LAZY[name]}")
    for other, home in _LAZY.items():  # bind the module's names once
        if home == _LAZY[name]:
            globals()[other] = getattr(module, other)
    return globals()[name]


__all__ = [
    "IMAGE_MEAN_QUANTILE",
    "LUMINANCE",
    "PARAMETERS",
    "PARAMETERS_BY_NAME",
    "AdaptiveRender",
    "AdaptiveSettings",
    "Param",
    "PassRecord",
    "batch_ladder",
    "bin_samples",
    "budget_batches",
    "check_integrator",
    "dilate",
    "error_ratio",
    "image_mean_luminance",
    "luminance_error",
    "pass_batch_size",
    "pass_time_fit",
    "reconstruct",
    "reconstruct_samples",
    "render_adaptive",
    "subpixel_filter",
]
