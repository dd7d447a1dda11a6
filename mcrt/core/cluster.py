"""Run a job's tasks on a Dask cluster (``mcrt ... --cluster ADDRESS``).

* ``local`` / ``local:N``: a ``LocalCluster`` of N worker processes on this
  machine (default: one per core), each running one task at a time with its
  share of the cores as Dr.Jit threads;
* ``tcp://HOST:PORT`` (or any address Dask's ``Client`` accepts): an existing
  scheduler, started with ``dask scheduler`` / ``dask worker --nthreads 1``,
  dask-jobqueue (SLURM, PBS, ...) or a Kubernetes operator. Workers need mcrt
  installed, not the client's files: a job's scenes travel as
  :class:`~mcrt.core.scene_files.SceneBundle` (scattered once per worker, keyed
  by content), and workers keep loaded scenes and compiled kernels between tasks.

Tasks are deterministic and their results are folded in task order on the
client (:func:`~mcrt.core.job.run_job`), so a result does not depend on which
worker ran what, or when. A worker that dies has its tasks run again elsewhere
(same result). A scheduler that cannot be reached, or that goes away, is a
one-line :class:`~mcrt.errors.McrtError`; the folded tasks stay checkpointed.
"""

from __future__ import annotations

import logging
import os
import re
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from typing import Any, TypeVar

from distributed import Client, LocalCluster, wait
from distributed.diagnostics.plugin import WorkerPlugin

from ..errors import McrtError
from .scene_files import SceneSource, describe

log = logging.getLogger("mcrt.cluster")

R = TypeVar("R")

#: Seconds to wait for a scheduler before giving up (``$MCRT_CLUSTER_TIMEOUT``).
CONNECT_TIMEOUT = 10.0

#: Seconds between checks that the scheduler is still there while tasks run.
POLL_SECONDS = 2.0

#: How often a task is retried after its worker died (Dask reschedules it).
RETRIES = 3

_LOCAL = re.compile(r"^local(?::(\d+))?$")

#: What a task's result raises when the scheduler or the connection to it is gone.
_LOST = (OSError, TimeoutError, CancelledError)  # (CommClosedError is an OSError)


class WorkerSetup(WorkerPlugin):
    """Prepares each worker process: Mitsuba's variant (the client's), mcrt's
    plugins, the user's sampler plugins the client loaded (``plugins``: see
    :func:`mcrt.plugins.worker_state`) and the worker's share of Dr.Jit threads
    (local clusters: cores / N; elsewhere ``$MCRT_WORKER_THREADS`` on the
    worker, else all its cores)."""

    name = "mcrt-setup"

    def __init__(self, variant: str, threads: int | None,
                 plugins: dict[str, Any] | None = None) -> None:
        self.variant, self.threads, self.plugins = variant, threads, plugins

    def setup(self, worker: Any) -> None:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(self.variant)
        import mcrt

        mcrt.register()
        if self.plugins:  # before any task builds a sampler
            from ..plugins import install_worker_state

            install_worker_state(self.plugins)
        threads = self.threads or int(os.environ.get("MCRT_WORKER_THREADS") or 0)
        if threads:
            dr.set_thread_count(threads)


class DaskExecutor:
    """The executor interface (``map``) over a ``distributed.Client``."""

    def __init__(self, client: Client, cluster: LocalCluster | None = None,
                 address: str = "", variant: str = "", threads: int | None = None) -> None:
        self.client, self.cluster, self.address = client, cluster, address
        self._held: dict[str, Any] = {}  # scattered shared inputs, by content
        self._variant, self._threads = variant, threads
        self._plugins: tuple | None = None  # the plugin state the workers have
        if variant:
            self._setup_workers()

    def _setup_workers(self) -> None:
        """(Re-)register :class:`WorkerSetup` when the user's samplers changed since
        the workers were set up (a study's plugins load after ``--cluster`` connects)."""
        from .. import plugins

        key = plugins.state_key()
        if key == self._plugins:
            return
        try:
            self.client.register_plugin(WorkerSetup(self._variant, self._threads,
                                                    plugins.worker_state()))
        except _LOST as error:
            raise self._lost(error) from None
        self._plugins = key

    @classmethod
    def connect(cls, address: str) -> DaskExecutor:
        """Start ``local[:N]`` or connect to a scheduler; one-line errors."""
        import mitsuba as mi

        variant = mi.variant() or "llvm_ad_rgb"
        local = _LOCAL.match(address)
        if local:
            cores = os.cpu_count() or 1
            workers = int(local.group(1) or cores)
            if workers < 1:
                raise McrtError(f"--cluster {address}: a local cluster needs at least 1 worker")
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address="127.0.0.1:0",  # this machine only
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
            log.info("local Dask cluster: %d workers, %d Dr.Jit threads each", workers,
                     max(1, cores // workers))
            return cls(client, cluster, address, variant, max(1, cores // workers))
        if "://" not in address:
            raise McrtError(f"--cluster {address!r}: expected 'local', 'local:N' or a scheduler "
                            f"address such as tcp://HOST:8786")
        try:
            timeout = float(os.environ.get("MCRT_CLUSTER_TIMEOUT") or CONNECT_TIMEOUT)
            client = Client(address, timeout=timeout)
        except (OSError, TimeoutError, ValueError) as error:
            raise McrtError(f"cannot reach the Dask scheduler at {address} "
                            f"({_first_line(error)})") from None
        return cls(client, None, address, variant, None)

    def status(self) -> str:
        """``workers B/N busy``: workers running a task, of all workers."""
        try:
            processing = self.client.processing()
        except Exception:  # noqa: BLE001 - a progress note must never fail a job
            return ""
        busy = sum(1 for tasks in processing.values() if tasks)
        return f"workers {busy}/{len(processing)} busy"

    def map(self, fn: Callable[..., R], tasks: int, start: int = 0,
            shared: dict[str, Any] | None = None,
            name: str = "") -> Iterator[tuple[int, R]]:
        if self._variant:
            self._setup_workers()  # plugins loaded since the last job
        shared_futures = {key: self._scatter(value) for key, value in (shared or {}).items()}
        run = uuid.uuid4().hex[:8]
        futures = {self.client.submit(fn, index, **shared_futures, pure=False, retries=RETRIES,
                                      key=f"mcrt-{name or 'job'}-{run}-{index}"): index
                   for index in range(start, tasks)}
        pending = set(futures)
        try:
            while pending:
                try:
                    done, _ = wait(list(pending), timeout=POLL_SECONDS,
                                   return_when="FIRST_COMPLETED")
                except TimeoutError:  # nothing finished yet: is the scheduler still there?
                    if self.client.status != "running":
                        raise self._lost(ConnectionError("the scheduler went away")) from None
                    continue
                except _LOST as error:
                    raise self._lost(error) from None
                for future in sorted(done, key=futures.__getitem__):
                    pending.discard(future)
                    try:
                        result = future.result()
                    except _LOST as error:
                        raise self._lost(error) from None
                    yield futures[future], result
        finally:
            for future in futures:
                if not future.done():
                    future.cancel()

    def _scatter(self, value: Any) -> Any:
        """A shared input, on every worker once (a scene goes as its files, once
        per content digest). Scattered data stays held until :meth:`close`: a
        job's next tasks may need it again, and releasing it while another job
        scatters the same content would lose it under them."""
        key = value.digest if isinstance(value, SceneSource) and value.digest else None
        if key is not None and key in self._held:
            return self._held[key]
        if isinstance(value, SceneSource):
            value = value.bundle()
            log.debug("sending scene %s to the workers", describe(value))
        try:
            future = self.client.scatter(value, broadcast=True, hash=True)
        except _LOST as error:
            raise self._lost(error) from None
        self._held[key or future.key] = future
        return future

    def _lost(self, error: BaseException) -> McrtError:
        return McrtError(f"lost the Dask cluster at {self.address or 'local'} "
                         f"({_first_line(error)}); the work finished so far is kept: run the "
                         f"same command again, with or without --cluster, to resume")

    def close(self) -> None:
        self._held.clear()
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__
