"""Executors run a job's tasks; :func:`~mcrt.core.job.run_job` folds the results.

An executor has one method, ``map(fn, tasks, start)``, yielding
``(index, fn(tasks[index]))`` for every index from ``start`` on, in any order.
Tasks are deterministic, so which executor ran them never changes a result.
:class:`InProcess` runs them here, one after the other; a distributed
executor only has to provide the same method.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class Executor(Protocol):
    def map(self, fn: Callable[[T], R], tasks: Sequence[T],
            start: int = 0) -> Iterator[tuple[int, R]]: ...


class InProcess:
    """Run tasks in this process, in order (the default)."""

    def map(self, fn: Callable[[T], R], tasks: Sequence[T],
            start: int = 0) -> Iterator[tuple[int, R]]:
        for index in range(start, len(tasks)):
            yield index, fn(tasks[index])
