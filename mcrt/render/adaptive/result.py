"""What an adaptive render returns: its passes and the developed per-pixel arrays."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from ...core.job import Checkpoint  # (at run time: Dr.Jit reads the fields' types)
from ...core.render import linear_srgb
from ...core.stats import PixelStats
from .settings import AdaptiveSettings


@dataclass
class PassRecord:
    """What one pass did."""

    index: int
    #: Pixels traced in this pass.
    active_pixels: int
    #: Samples traced in this pass (lanes).
    samples: int
    #: Distinct batch sizes (one compacted wavefront each, or more if chunked).
    batch_sizes: tuple[int, ...]
    #: Wall time of the pass: lanes, trace, moments, bookkeeping (synchronised).
    seconds: float
    #: Pixels whose error test passed after this pass (before dilation).
    converged_pixels: int
    #: NaN/Inf samples met in this pass.
    nonfinite: int


@dataclass
class AdaptiveRender:
    """Result of :func:`~mcrt.render.adaptive.render_adaptive`.

    Per-pixel arrays cover the film's crop window (the sampled border, if any,
    is cut off); ``stats`` are the box-binned sample moments (R, G, B) in
    float64.
    """

    image: np.ndarray  # (H, W, C) float32, the film's channels (R G B, Y or X Y Z; [A])
    channels: list[str]
    stats: PixelStats
    #: Samples traced per pixel, NaN/Inf included, (H, W) int64.
    spp: np.ndarray
    passes: list[PassRecord]
    #: Wall time of the passes and of developing the image (a film render's
    #: includes its film's development too), a resumed render's earlier runs included
    #: (the passes they kept: a pass an interruption dropped is not counted).
    seconds: float
    settings: AdaptiveSettings
    sampler: str
    #: Batch sizes the sampler was used with (the ladder).
    batch_ladder: tuple[int, ...]
    #: The error test's bound on the standard error of each pixel's luminance
    #: (:func:`~mcrt.render.adaptive.luminance_error`), (H, W).
    luminance_stderr: np.ndarray
    #: Pixels that pass the error test at the end (the others ran out of
    #: budget, or were only refined as neighbours), (H, W) bool.
    converged: np.ndarray
    #: Samples traced, NaN/Inf included: the passes' samples, a sampled border's
    #: pixels included (which ``spp`` leaves out, as the image does).
    traced_samples: int
    #: NaN/Inf samples traced (and left out), a sampled border's included, as
    #: the passes count them; the ``nonfinite`` layer covers the image only.
    traced_nonfinite: int
    #: Makes the checkpoint of the finished render (on demand; given to renders
    #: that save checkpoints).
    state: Callable[[], Checkpoint] | None = field(default=None, repr=False, compare=False)

    @property
    def checkpoint(self) -> Checkpoint | None:
        """The finished render's sums and loop state, to write its outputs later
        (built when asked for: a render that writes its files never pays for a
        copy of its sums)."""
        return self.state() if self.state is not None else None

    @property
    def samples(self) -> int:
        """Samples traced (:attr:`traced_samples`): ``spp.sum()`` plus those of a
        sampled border, as a film render's count them."""
        return self.traced_samples

    @property
    def rgb(self) -> np.ndarray:
        """The image as linear sRGB (H, W, 3), whatever the film's pixel format."""
        return linear_srgb(self.image, self.channels)

    def film_channels(self) -> dict[str, np.ndarray]:
        """The film's channels under Mitsuba's labels (``R G B [A]``, ``Y [A]``,
        ``X Y Z [A]``), (H, W) each, for ``write_exr(channels=...)``."""
        return {name: self.image[..., c] for c, name in enumerate(self.channels)}

    @property
    def variance(self) -> np.ndarray:
        """Per-pixel sample variance of R, G, B (float64)."""
        return self.stats.variance

    @property
    def standard_error(self) -> np.ndarray:
        """Per-pixel i.i.d. standard error of the R, G, B means (float64)."""
        return self.stats.standard_error

    @property
    def nonfinite(self) -> np.ndarray:
        """NaN/Inf samples per image pixel (a sampled border's are left out, as
        from ``spp``; :attr:`nonfinite_samples` counts them)."""
        return self.stats.nonfinite

    @property
    def nonfinite_samples(self) -> int:
        """NaN/Inf samples traced (:attr:`traced_nonfinite`): ``nonfinite.sum()``
        plus those of a sampled border, as a film render's count them."""
        return self.traced_nonfinite

    def layers(self) -> dict[str, np.ndarray]:
        """Layers for :func:`mcrt.io.write_exr` besides :meth:`film_channels` (it
        stores them as float32 and says where a finite value overflows it)."""
        return {"variance": self.variance, "stderr": self.standard_error,
                "stderr_y": self.luminance_stderr, "spp": self.spp, "nonfinite": self.nonfinite}

    def summary(self) -> dict:
        """Scalars for metadata and reports."""
        return {"adaptive": 1, "passes": len(self.passes), "samples": self.samples,
                "mean_spp": round(int(self.spp.sum()) / self.spp.size, 3),
                "min_spp_used": int(self.spp.min()), "max_spp_used": int(self.spp.max()),
                "nonfinite_samples": self.nonfinite_samples,
                "render_seconds": round(self.seconds, 6),
                "batch_ladder": " ".join(map(str, self.batch_ladder)),
                **{f"adaptive_{k}": v for k, v in asdict(self.settings).items()}}


def pass_time_fit(passes: list[PassRecord]) -> dict[str, float]:
    """Least-squares line ``seconds = intercept + slope * samples`` over passes,
    with R^2 (the check that a pass costs time in proportion to its samples):
    :func:`mcrt.core.timing.fit_cost`, the fixed and per-unit cost of the timing
    protocol."""
    from ...core.timing import fit_cost

    fit = fit_cost([p.samples for p in passes], [p.seconds for p in passes])
    if not np.isfinite(fit.per_unit):  # fewer than two distinct pass sizes
        mean = float(np.mean([p.seconds for p in passes])) if passes else 0.0
        return {"intercept": mean, "slope": 0.0, "r2": 0.0, "passes": float(len(passes))}
    return {"intercept": fit.fixed, "slope": fit.per_unit, "r2": fit.r2,
            "passes": float(len(passes))}


__all__ = ["AdaptiveRender", "PassRecord", "pass_time_fit"]
