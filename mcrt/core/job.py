"""Jobs: deterministic lists of tasks with a content key, one interruption type.

* :func:`content_key` is the one identity function: the SHA-256 of everything a
  result's bits depend on (the scene's content, settings, variant, versions).
* A job's saved state (the one :class:`Checkpoint` format, where a render keeps
  it, when it is saved, the one policy for a failed save) lives in
  :mod:`mcrt.core.state_file`; its names are importable from here too.
* :class:`Interrupted` is the one exception a job raises on Ctrl-C (or
  SIGTERM/SIGHUP): it carries the partial result and where its checkpoint is.
* :func:`run_job` runs a job's tasks through an executor
  (:mod:`mcrt.core.executor`) and folds their results in task order, so the
  result does not depend on the order in which tasks finish.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

from .executor import Executor
from .state_file import Checkpoint, Checkpointing, CheckpointPacer, CheckpointStore

# --------------------------------------------------------------------------- keys


def content_key(payload: dict[str, Any]) -> str:
    """SHA-256 (32 hex digits) of ``payload`` with the variant and the versions
    of mcrt, Mitsuba and Dr.Jit added, as canonical JSON."""
    import drjit as dr
    import mitsuba as mi

    from .._version import __version__

    drjit_version = dr.__version__  # type: ignore[attr-defined]  # not in drjit's stubs
    full = {**payload, "variant": mi.variant(),
            "versions": [__version__, mi.__version__, drjit_version]}
    text = json.dumps(full, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


# --------------------------------------------------------------------------- interruptions


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM/SIGHUP) during a job: ``partial`` is the result of the
    work finished so far (None if nothing finished), ``done`` of ``total`` units,
    ``state`` the :class:`Checkpoint` to resume from, ``checkpoint`` where it was
    saved (None if not saved)."""

    def __init__(self, partial: Any, done: int, total: int, state: Checkpoint | None = None,
                 checkpoint: Path | None = None) -> None:
        super().__init__("interrupted")
        self.partial = partial
        self.done = done
        self.total = total
        self.state = state
        self.checkpoint = checkpoint


# --------------------------------------------------------------------------- jobs

R = TypeVar("R")
T = TypeVar("T")


@dataclass
class Job(Generic[R, T]):
    """``tasks`` deterministic tasks, numbered from 0: ``run(index, **shared)``
    is a pure function of the task's index, ``fold(total, result)`` combines
    results in task order into a total. ``key`` identifies the job
    (:func:`content_key`). ``shared`` holds inputs every task takes (a scene's
    files, say): an executor delivers each once per worker. A job that may run
    on a cluster has a picklable ``run`` (a module-level function or a
    ``functools.partial`` of one) and picklable ``shared`` values."""

    key: str
    tasks: int
    run: Callable[..., R]
    fold: Callable[[T | None, R], T]
    shared: dict[str, Any] = field(default_factory=dict)
    #: ``groups(index)``: tasks best run by one process (they share a warm-up).
    groups: Callable[[int], int] | None = None


def run_job(job: Job[R, T], executor: Executor | None = None, done: int = 0, total: T | None = None,
            on_fold: Callable[[int, T], None] | None = None) -> T | None:
    """Run ``job.tasks[done:]`` and fold their results, in task order, into
    ``total`` (the fold of the first ``done`` results). ``on_fold(count, total)``
    runs after each fold (to checkpoint and report progress).

    Ctrl-C raises :class:`Interrupted` with the fold so far as ``partial``.
    """
    from .executor import InProcess

    executor = executor or InProcess()
    pending: dict[int, R] = {}
    next_index = done
    try:
        for index, result in executor.map(job.run, job.tasks, start=done, shared=job.shared,
                                          name=job.key, groups=job.groups):
            pending[index] = result
            while next_index in pending:
                total = job.fold(total, pending.pop(next_index))
                next_index += 1
                if on_fold is not None:
                    on_fold(next_index, total)
    except KeyboardInterrupt as stop:
        if isinstance(stop, Interrupted):
            raise
        raise Interrupted(total, next_index, job.tasks) from None
    return total


__all__ = ["Checkpoint", "CheckpointPacer", "CheckpointStore", "Checkpointing", "Interrupted",
           "Job", "content_key", "run_job"]
