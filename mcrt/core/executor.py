"""Executors run a job's tasks; :func:`~mcrt.core.job.run_job` folds the results.

An executor has one method, ``map(fn, tasks, start, shared, name, groups)``,
yielding ``(index, fn(index, **shared))`` for every task index from ``start`` to
``tasks - 1``, in any order. Tasks are deterministic, so which executor ran
them never changes a result. ``groups(index)``, where given, names the tasks
that are best run by one process (they share a warm-up); an executor may
ignore it.

* :class:`InProcess` runs them here, one after the other (the default);
* :class:`~mcrt.core.cluster.DaskExecutor` runs them on a Dask cluster
  (``local``, ``local:N`` or a scheduler's address), chosen with
  :func:`executor_for` from the ``--cluster`` option or ``MCRT_CLUSTER``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any, Protocol, TypeVar

R = TypeVar("R")

#: Environment variable naming the cluster when ``--cluster`` is not given.
CLUSTER_ENV = "MCRT_CLUSTER"


class Executor(Protocol):
    def map(self, fn: Callable[..., R], tasks: int, start: int = 0,
            shared: dict[str, Any] | None = None, name: str = "",
            groups: Callable[[int], int] | None = None) -> Iterator[tuple[int, R]]: ...


class InProcess:
    """Run tasks in this process, in order (the default)."""

    def map(self, fn: Callable[..., R], tasks: int, start: int = 0,
            shared: dict[str, Any] | None = None, name: str = "",
            groups: Callable[[int], int] | None = None) -> Iterator[tuple[int, R]]:
        for index in range(start, tasks):
            yield index, fn(index, **(shared or {}))

    def close(self) -> None:
        pass


def cluster_status(executor: Any) -> str:
    """``", workers B/N busy"`` for a progress bar when tasks run on a cluster,
    else ``""``."""
    status = getattr(executor, "status", None)
    text = status() if callable(status) else ""
    return f", {text}" if text else ""


def task_memory(executor: Any) -> int | None:
    """The memory a task can plan to use where ``executor`` runs it, when that is not
    this process: the least over a cluster's workers, their Dask memory limits
    included (:mod:`mcrt.core.worker_memory`); None for this process."""
    measure = getattr(executor, "available_bytes", None)
    return measure() if callable(measure) else None


def cluster_address(option: str | None) -> str | None:
    """The cluster to use: the ``--cluster`` option, else ``$MCRT_CLUSTER``
    (empty or unset: none, in-process)."""
    address = option if option is not None else os.environ.get(CLUSTER_ENV, "")
    return address.strip() or None


def executor_for(address: str | None) -> Any:
    """:class:`InProcess` for no address (Dask is not even imported), else a
    :class:`~mcrt.core.cluster.DaskExecutor` connected to ``address``."""
    if address is None:
        return InProcess()
    from .cluster import DaskExecutor

    if address.strip().startswith("local"):  # its processes are this command's children
        from .local_workers import start_resource_tracker

        start_resource_tracker()
    return DaskExecutor.connect(address)
