"""Executors run a job's tasks; :func:`~mcrt.core.job.run_job` folds the results.

An executor has one method, ``map(fn, tasks, start)``, yielding
``(index, fn(index))`` for every task index from ``start`` to ``tasks - 1``, in
any order.
Tasks are deterministic, so which executor ran them never changes a result.
:class:`InProcess` runs them here, one after the other; a distributed
executor only has to provide the same method.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol, TypeVar

R = TypeVar("R")


class Executor(Protocol):
    def map(self, fn: Callable[[int], R], tasks: int,
            start: int = 0) -> Iterator[tuple[int, R]]: ...


class InProcess:
    """Run tasks in this process, in order (the default)."""

    def map(self, fn: Callable[[int], R], tasks: int,
            start: int = 0) -> Iterator[tuple[int, R]]:
        for index in range(start, tasks):
            yield index, fn(index)
