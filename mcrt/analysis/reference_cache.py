"""A reference's cache files: its running state, saved after every merged pass.

``<cache>/reference/<key>.partial.npz`` while it renders, ``<key>.npz`` once
finished (the one :class:`~mcrt.core.state_file.Checkpoint` format: key and checksum).
:func:`load_state` uses a file only if it is an intact state of that key, in the
expected role, with every pixel holding exactly the samples of its passes;
anything else is set aside with a note and recomputed.

``<key>.lock`` while a process looks the reference up and renders it
(:func:`reference_lock`): a second process that wants the same reference at the
same time waits, with a note, and then finds it finished in the cache instead of
rendering it too (or resumes it, if the first was killed).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import numpy as np

from ..cache import cache_dir
from ..core.file_lock import waiting_lock
from ..core.filtered import SUMS, FilteredStats
from ..core.render import StatsRender
from ..core.state_file import Checkpoint, Saving, set_aside
from ..core.stats import PixelStats
from .pass_plan import PassPlan

#: Version of the cache files' layout and of the rendering recipe; bump it when
#: either changes so that stale references are never reused.
CACHE_FORMAT = 1

#: Cache subdirectory.
CACHE_NAME = "reference"

#: Bytes per pixel of a saved reference state (count, mean, M2, nonfinite).
STATE_BYTES_PER_PIXEL = 8 + 24 + 24 + 8


def cache_paths(key: str) -> tuple[Path, Path]:
    """``(finished, partial)`` cache files of ``key``."""
    directory = cache_dir(CACHE_NAME)
    return directory / f"{key}.npz", directory / f"{key}.partial.npz"


def reference_lock(key: str) -> contextlib.AbstractContextManager[None]:
    """Held while this process looks up and renders the reference of ``key``
    (around :func:`load_state` and the passes): another process that wants the
    same reference waits until this one is done, then reads the cache. The
    kernel drops the lock of a process that ends, killed or not."""
    return waiting_lock(cache_dir(CACHE_NAME) / f"{key}.lock",
                        "another mcrt ({holder}) is rendering the same reference: waiting for "
                        "it, then taking its result from the cache (or going on from its "
                        "saved passes if it stopped)")


def save_state(path: Path, key: str, stats: PixelStats | FilteredStats, passes_done: int,
               passes: int, seconds: float, complete: bool) -> None:
    """Write a reference's running state to ``path`` (a :class:`Checkpoint`)."""
    if isinstance(stats, FilteredStats):
        arrays = stats.arrays()
    else:
        arrays = {"count": np.asarray(stats.count, np.int64),
                  "mean": np.asarray(stats.mean, np.float64),
                  "m2": np.asarray(stats.m2, np.float64),
                  "nonfinite": np.asarray(stats.nonfinite, np.int64)}
    Checkpoint({"complete": bool(complete), "passes_done": int(passes_done),
                "passes": int(passes), "seconds": float(seconds)}, arrays).save(path, key)


def load_state(path: Path, key: str, plan: PassPlan, shape: tuple[int, int],
               complete: bool, filtered: bool = False
               ) -> tuple[PixelStats | FilteredStats, int, float] | None:
    """Read a state written by :func:`save_state`; ``(stats, passes_done, seconds)``
    if it is an intact state of ``key`` in the expected role, else None.

    Besides the checkpoint's own checks (key, checksum), checked: the role
    (``complete`` and passes done, so a partial state is never returned as
    finished), array shapes and dtypes, and that every pixel holds exactly the
    samples of the passes done.
    """
    found = Checkpoint.load(path, key)
    if found is None:
        return None
    meta, arrays = found.meta, found.arrays
    if meta.get("complete") is not complete:
        return None  # an intact state in the other role (partial vs finished)
    done: Any = meta.get("passes_done")
    h, w = shape
    expected = {"count": ((h, w), np.int64), "nonfinite": ((h, w), np.int64),
                "mean": ((h, w, 3), np.float64), "m2": ((h, w, 3), np.float64)}
    if filtered:
        expected = {"count": ((h, w), np.int64), "nonfinite": ((h, w), np.int64),
                    **{f"sum_{k}": ((h, w, c), np.float64) for k, c in SUMS}}
    ok = (meta.get("passes") == plan.passes and isinstance(done, int)
          and (done == plan.passes if complete else 0 < done < plan.passes)
          and all(name in arrays and arrays[name].shape == shape_
                  and arrays[name].dtype == dtype for name, (shape_, dtype) in expected.items()))
    if ok:
        moments = ["sum_w", "sum_w2"] if filtered else ["m2"]
        ok = bool(np.all(arrays["count"] + arrays["nonfinite"] == plan.spp_before(done))
                  and all(np.all(arrays[m] >= 0) for m in moments)
                  and all(np.isfinite(arrays[m]).all() for m in expected))
    if not ok:
        set_aside(path, "not a consistent state of this reference")
        return None
    stats: PixelStats | FilteredStats
    if filtered:
        stats = FilteredStats.from_arrays(arrays)
    else:
        stats = PixelStats(**{name: arrays[name] for name in expected})
    return stats, done, float(meta.get("seconds", 0.0))


class StateSaver:
    """Saves a reference's state after every merged pass (partial, then finished),
    under the one failure policy (:class:`~mcrt.core.state_file.Saving`: a failed
    write is noted once and turns saving off, the reference goes on)."""

    def __init__(self, key: str, plan: PassPlan, finished: Path, partial: Path,
                 enabled: bool) -> None:
        self.key, self.plan, self.finished, self.partial = key, plan, finished, partial
        self.saving = Saving("the reference cache", "the reference goes on without it",
                             on=enabled)

    def save(self, count: int, merged: StatsRender, seconds: float) -> None:
        """Save the first ``count`` passes, ``merged``, made in ``seconds`` of wall
        time (all sessions)."""
        last = count == self.plan.passes

        def write() -> None:
            save_state(self.finished if last else self.partial, self.key, merged.stats, count,
                       self.plan.passes, seconds, complete=last)
            if last:
                with contextlib.suppress(OSError):
                    self.partial.unlink()

        self.saving(write)
