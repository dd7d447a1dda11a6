"""A Dask worker's memory limit, counted like ``ulimit -v`` and cgroup limits.

A worker with a memory limit (``dask worker --memory-limit``, ``LocalCluster(memory_limit=...)``,
dask-jobqueue's ``memory``; mcrt's ``local:N`` gives each worker 1/N of the machine's) is not
limited by the kernel: its nanny reads the process's resident memory every 100 ms and, above
the terminate fraction of the limit (``distributed.worker.memory.terminate``, 0.95), terminates
it and starts a new one. Nothing fails in the process first, so a pass sized to the host's
memory is killed in the middle, on every worker Dask tries it on. So:

* :func:`install` (run in each worker by :class:`~mcrt.core.cluster.WorkerSetup`) adds the
  limit to :func:`mcrt.core.memory.available_bytes`: the terminate fraction of the limit less
  the process's resident memory. Passes planned in a worker (a study's renders) fit under it,
  and one that cannot fit at all is a one-line error there, not a kill;
* :func:`workers_available`: the least of that over a cluster's workers, for the passes the
  client plans and the workers trace (a render's, a reference's);
* :func:`memory_kill`: whether a worker that died was the nanny's memory kill (the nanny logs
  a ``worker-restart-memory`` event at the scheduler), for the error of a task Dask gave up on.

No Dask import here: the worker and the client are given.
"""

from __future__ import annotations

import time
from typing import Any

from .memory import _mib, add_limit, available_bytes, resident_bytes

#: What the limit is called in messages (``... (under the Dask worker's memory limit)``).
LIMIT_NAME = "the Dask worker's memory limit"

#: The event a nanny logs at the scheduler when it restarts its worker for memory.
MEMORY_EVENT = "worker-restart-memory"

#: Seconds to wait for that event after Dask reported the worker's death (the nanny
#: sends it before terminating the worker, on another connection).
EVENT_WAIT = 1.0


def nanny_budget(worker: Any) -> int | None:
    """Resident bytes above which ``worker``'s nanny terminates it; None without a
    limit, without a nanny (a worker alone only pauses at its limit) or with the
    terminate fraction off."""
    import dask

    limit = getattr(getattr(worker, "memory_manager", None), "memory_limit", None)
    fraction = dask.config.get("distributed.worker.memory.terminate", False)
    if not limit or not fraction or getattr(worker, "nanny", None) is None:
        return None
    return int(limit * fraction)


def _left(budget: int) -> int | None:
    """Bytes the process may still add before its nanny terminates it. The buffers
    Dr.Jit keeps for reuse count as resident: when they make the budget look short
    (less than half left), they are returned and the memory read again."""
    resident = resident_bytes()
    if resident is None:
        return None
    if budget - resident < budget // 2:
        from .accumulators import release_cached_memory

        release_cached_memory()
        resident = resident_bytes() or resident
    return max(0, budget - resident)


def install(worker: Any) -> None:
    """Count ``worker``'s memory limit in this process's available memory."""
    budget = nanny_budget(worker)
    add_limit(LIMIT_NAME, (lambda: None) if budget is None else (lambda: _left(budget)))


def workers_available(client: Any) -> int | None:
    """The least memory a task can plan to use on any worker of ``client``'s
    cluster now (:func:`~mcrt.core.memory.available_bytes` there, their Dask limits
    included); None when no worker answers."""
    found = client.run(available_bytes, on_error="return")
    known = [value for value in found.values() if isinstance(value, int)]
    return min(known) if known else None


def memory_kill(client: Any, worker: Any) -> str | None:
    """How ``worker`` (a dead worker's ``WorkerState``, as ``KilledWorker`` carries
    it) died, if its nanny restarted it for memory: ``"restarted by its nanny at 588
    MiB, over 95% of its 600 MiB memory limit"``; None for any other death."""
    address, limit = getattr(worker, "address", None), getattr(worker, "memory_limit", None)
    pid = getattr(worker, "pid", None)  # (a later worker may reuse a fixed address)
    if address is None:
        return None
    import dask

    fraction = dask.config.get("distributed.worker.memory.terminate", 0.95)
    deadline = time.monotonic() + EVENT_WAIT
    while True:
        try:
            events = client.get_events(MEMORY_EVENT)
        except Exception:  # noqa: BLE001 - the cause is a detail: the error is raised anyway
            return None
        for _, event in reversed(events):
            if isinstance(event, dict) and event.get("worker") == address and \
                    (not pid or event.get("pid") in (None, pid)):
                rss = f" at {_mib(int(event['rss']))}" if "rss" in event else ""
                of = f" of its {_mib(limit)} memory limit" if limit else " of its memory limit"
                return f"restarted by its nanny{rss}, over {fraction:.0%}{of}"
        if time.monotonic() > deadline:
            return None
        time.sleep(0.1)


__all__ = ["LIMIT_NAME", "install", "memory_kill", "nanny_budget", "workers_available"]
