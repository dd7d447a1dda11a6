"""Run a job's tasks on a Dask cluster (``mcrt ... --cluster ADDRESS``).

* ``local`` / ``local:N``: a ``LocalCluster`` of N worker processes on this
  machine (default: one per core), each running one task at a time with its
  share of the cores as Dr.Jit threads;
* ``tcp://HOST:PORT`` (or any address Dask's ``Client`` accepts): an existing
  scheduler, started with ``dask scheduler`` / ``dask worker --nthreads 1``,
  dask-jobqueue (SLURM, PBS, ...) or a Kubernetes operator. Workers need mcrt
  installed, not the client's files: a job's scenes travel as
  :class:`~mcrt.core.scene_files.SceneBundle` (keyed by content, sent to each
  worker once), and workers keep loaded scenes and compiled kernels between tasks.

Tasks are deterministic and their results are folded in task order on the client
(:func:`~mcrt.core.job.run_job`), so a result does not depend on which worker ran what, or
when. While the scheduler lives, any number of workers may die, all of them at once too: the
inputs the tasks share are tasks that carry their value (not scattered data, which dies with
the last worker holding it), so Dask makes them again, and it runs the lost tasks again (same
results); a task or input Dask gives up on (its workers kept dying) is submitted again a few
times, unless the nanny killed its worker for memory (:meth:`DaskExecutor._outcome`); with no
worker left the job waits for one (:data:`WORKER_WAIT`), then fails saying what was lost.
Passes are sized to fit the workers' memory limits (:mod:`mcrt.core.worker_memory`). A
scheduler that cannot be reached, or that goes away, is a one-line
:class:`~mcrt.errors.McrtError` (Dask's own log lines and tracebacks are silenced while mcrt
uses the client); the folded tasks stay checkpointed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from typing import Any, TypeVar

from distributed import Client, Future, KilledWorker, LocalCluster, wait
from distributed.client import ClosedClientError
from distributed.diagnostics.plugin import WorkerPlugin

from ..errors import McrtError
from .dask_settings import SILENT, DaskSettings
from .environ import env_number
from .memory import reuse_freed_memory
from .provenance import source_digest
from .scene_files import SceneSource, describe
from .worker_memory import install as limit_worker_memory
from .worker_memory import memory_kill, workers_available
from .worker_software import Verified, mismatch
from .worker_software import identity as software_identity

log = logging.getLogger("mcrt.cluster")

R = TypeVar("R")

#: Seconds to wait for a scheduler before giving up (``$MCRT_CLUSTER_TIMEOUT``).
CONNECT_TIMEOUT = 10.0

#: Seconds between checks that the scheduler is still there while tasks run.
POLL_SECONDS = 2.0

#: How often Dask retries a task that raised (``Client.submit``'s ``retries``).
RETRIES = 3

#: Times a task is sent again after Dask gave up on it (``KilledWorker``: not for memory
#: kills, see :meth:`DaskExecutor._outcome`) or cancelled it.
RESUBMITS = 3

#: Seconds to wait for a worker when none is left (``$MCRT_CLUSTER_WORKER_WAIT``).
WORKER_WAIT = 300.0

_LOCAL = re.compile(r"^local(?::(\d+))?$")

#: What a task's result raises when the scheduler or the connection to it is gone.
_LOST = (OSError, TimeoutError, CancelledError,  # (CommClosedError is an OSError)
         ClosedClientError)

#: The states of a future that :meth:`DaskExecutor.map` takes in (not pending, not lost).
_DONE = ("finished", "error", "cancelled")

#: Why Dask cancels every future when the scheduler went away.
_SCHEDULER_GONE = ("scheduler-connection-lost",)

class WorkerSetup(WorkerPlugin):
    """Prepares each worker process: Mitsuba's variant (the client's), mcrt's
    plugins, the user's sampler plugins the client loaded (``plugins``: see
    :func:`mcrt.plugins.worker_state`) and the worker's share of Dr.Jit threads
    (local clusters: cores / N; elsewhere ``$MCRT_WORKER_THREADS`` on the
    worker, else all its cores); its memory limit counts as one on renders."""

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
        source_digest()  # (cached: the code this worker imported, see worker_software)
        if self.plugins:  # before any task builds a sampler
            from ..plugins import install_worker_state

            install_worker_state(self.plugins)
        threads = self.threads or int(env_number("MCRT_WORKER_THREADS", 0, integer=True))
        if threads:
            dr.set_thread_count(threads)
        reuse_freed_memory()
        limit_worker_memory(worker)


def placement(indices: list[int], groups: Callable[[int], int],
              workers: list[str]) -> dict[int, str]:
    """The worker each task prefers: the tasks, ordered by group (in the order
    groups first appear) and index, cut into one nearly equal run per worker: as
    few groups per worker as equal shares allow (3 groups of 5 tasks on 2
    workers: 2 each, where tasks taken in turn warm every group on both)."""
    if not workers or not indices:
        return {}
    first: dict[int, int] = {}
    for position, index in enumerate(sorted(indices)):
        first.setdefault(groups(index), position)
    ordered = sorted(indices, key=lambda index: (first[groups(index)], index))
    n = len(workers)
    return {index: workers[position * n // len(ordered)]
            for position, index in enumerate(ordered)}


class DaskExecutor:
    """The executor interface (``map``) over a ``distributed.Client``."""

    def __init__(self, client: Client, cluster: LocalCluster | None = None,
                 address: str = "", variant: str = "", threads: int | None = None,
                 quiet: DaskSettings | None = None) -> None:
        self.client, self.cluster, self.address = client, cluster, address
        self._held: dict[str, Future] = {}  # shared inputs, by content (see _input)
        self._verified: Verified | None = None  # hand-started workers' software, checked
        self._variant, self._threads = variant, threads
        self._plugins: tuple | None = None  # the plugin state the workers have
        self._quiet = quiet or DaskSettings()
        self._workers = 0                   # workers last seen (for messages)
        self._none_since: float | None = None  # when the last worker was seen to go
        self._noted = 0.0                   # when the last "waiting for workers" note went
        if variant:
            try:
                self._setup_workers()
            except BaseException:  # (e.g. workers of other software: let go of them)
                self.close()
                raise

    def _setup_workers(self) -> None:
        """(Re-)register :class:`WorkerSetup` when the user's samplers changed since
        the workers were set up (a study's plugins load after ``--cluster`` connects).
        Workers that join later (a restarted one) run it when they register."""
        from .. import plugins

        key = plugins.state_key()
        if key == self._plugins:
            return
        try:
            self.client.register_plugin(WorkerSetup(self._variant, self._threads,
                                                    plugins.worker_state()))
            # Hand-started workers may run other code (a local cluster's start from ours).
            found = self.client.run(software_identity) if self.cluster is None else {}
        except _LOST as error:
            raise self._lost_scheduler(error) from None
        problem = mismatch(software_identity(), found)
        if problem:
            raise McrtError(problem)
        self._verified = Verified(found) if self.cluster is None else None
        self._plugins = key

    @classmethod
    def connect(cls, address: str) -> DaskExecutor:
        """Start ``local[:N]`` or connect to a scheduler; one-line errors. Dask's
        own log records stay silent while the executor is open (see
        :class:`~mcrt.core.dask_settings.DaskSettings`)."""
        import mitsuba as mi

        variant = mi.variant() or "llvm_ad_rgb"
        local = _LOCAL.match(address)
        if not local and "://" not in address:
            raise McrtError(f"--cluster {address!r}: expected 'local', 'local:N' or a scheduler "
                            f"address such as tcp://HOST:8786")
        if local:
            cores = os.cpu_count() or 1
            workers = int(local.group(1) or cores)
            if workers < 1:
                raise McrtError(f"--cluster {address}: a local cluster needs at least 1 worker")
        quiet = DaskSettings()
        try:
            if local:
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address="127.0.0.1:0",  # this machine only
                                       silence_logs=SILENT, preload=["mcrt.core.local_workers"])
                client = Client(cluster)
                quiet.apply()  # the loggers made while the cluster started
                log.info("local Dask cluster: %d workers, %d Dr.Jit threads each", workers,
                         max(1, cores // workers))
                executor = cls(client, cluster, address, variant, max(1, cores // workers),
                               quiet)
                executor._workers = workers
                return executor
            timeout = env_number("MCRT_CLUSTER_TIMEOUT", CONNECT_TIMEOUT, positive=True)
            try:
                client = Client(address, timeout=timeout)
            except (OSError, TimeoutError, ValueError) as error:
                raise McrtError(f"cannot reach the Dask scheduler at {address} "
                                f"({_first_line(error)})") from None
            executor = cls(client, None, address, variant, None, quiet)
            with contextlib.suppress(*_LOST):
                executor._workers = len(client.nthreads())
            return executor
        except BaseException:
            quiet.restore()
            raise

    def status(self) -> str:
        """``workers B/N busy``: workers running a task, of all workers."""
        if self.client.status != "running":  # (asking would wait for a reconnection)
            return ""
        try:
            processing = self.client.processing()
        except Exception:  # noqa: BLE001 - a progress note must never fail a job
            return ""
        if not processing:
            return "no workers: waiting for some"
        self._workers = len(processing)
        busy = sum(1 for tasks in processing.values() if tasks)
        return f"workers {busy}/{len(processing)} busy"

    def map(self, fn: Callable[..., R], tasks: int, start: int = 0,
            shared: dict[str, Any] | None = None, name: str = "",
            groups: Callable[[int], int] | None = None) -> Iterator[tuple[int, R]]:
        """Submit the tasks, yield their results as they come.

        With ``groups``, each task prefers the worker :func:`placement` gives it
        (a loose restriction: Dask still moves it to an idle worker), so that
        the workers warm up fewer groups each.

        Shared inputs are tasks that carry their value (:meth:`_input`), so Dask
        makes them again wherever they were lost. Worker deaths are Dask's to
        handle (it runs the tasks again); a task Dask gives up on
        (``KilledWorker``) or cancels is submitted again, :data:`RESUBMITS` times
        at most. With no worker left, the job waits :data:`WORKER_WAIT` seconds for
        one (:meth:`_watch`). Only the scheduler's loss ends it at once."""
        if self._variant:
            self._setup_workers()  # plugins loaded since the last job
        run = uuid.uuid4().hex[:8]
        label = name or "job"
        submitted: dict[Future, int] = {}
        again: dict[int, int] = {}  # index: times submitted again

        def submit(indices: list[int]) -> None:
            inputs = {key: self._input(value) for key, value in (shared or {}).items()}
            try:
                where = placement(indices, groups, self._addresses()) if groups else {}
                for index in indices:
                    suffix = f"-again{again[index]}" if index in again else ""
                    prefer = {"workers": [where[index]], "allow_other_workers": True} \
                        if index in where else {}
                    future = self.client.submit(fn, index, **inputs, pure=False,
                                                retries=RETRIES, **prefer,
                                                key=f"mcrt-{label}-{run}-{index}{suffix}")
                    submitted[future] = index
            except _LOST as error:
                raise self._lost_scheduler(error) from None

        try:
            submit(list(range(start, tasks)))
            while submitted:
                redo: list[int] = []
                for future in sorted(self._wait(submitted), key=submitted.__getitem__):
                    if future.status not in _DONE:  # lost since (its worker died): made again
                        continue
                    index = submitted.pop(future)
                    done, result = self._outcome(future, index, label, again,
                                                 len(submitted) + len(redo) + 1)
                    if done:
                        yield index, result
                    else:
                        redo.append(index)
                if redo:
                    submit(redo)
        finally:
            for future in submitted:
                if not future.done():
                    future.cancel()

    def _addresses(self) -> list[str]:
        """The workers' addresses now, sorted."""
        return sorted(self.client.scheduler_info().get("workers", {}))

    def _wait(self, submitted: dict[Future, int]) -> list[Future]:
        """The futures that finished, erred or were cancelled (at least one),
        watching the scheduler and the workers while none did. (A future whose
        result was lost with its worker is ``lost`` until Dask made it again.)"""
        while True:
            try:
                wait(list(submitted), timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:  # nothing finished for a while: is anyone there?
                self._watch(len(submitted))
                continue
            except CancelledError:  # some were cancelled: _outcome says why
                pass
            except _LOST as error:
                raise self._lost_scheduler(error) from None
            except ValueError:  # Dask's `wait` found no client: ours closed itself
                if self.client.status == "running":
                    raise
                raise self._lost_scheduler(ConnectionError("the connection to it was lost")) \
                    from None
            done = [future for future in submitted if future.status in _DONE]
            if done:
                self._workers_back()
                try:  # (workers that joined since: is theirs this software?)
                    if self._verified is not None:
                        self._verified.check(self.client, done)
                except _LOST as error:
                    raise self._lost_scheduler(error) from None
                return done

    def _outcome(self, future: Future, index: int, label: str, again: dict[int, int],
                 pending: int) -> tuple[bool, Any]:
        """``(True, result)`` for a task done; ``(False, None)`` for one to submit
        again (its workers kept dying, or Dask cancelled it while the scheduler
        lives); the task's own error is raised as it is. ``pending``: the job's
        tasks not yet done, for messages.

        A task (or input) whose last worker its nanny restarted for passing the
        worker's memory limit is not submitted again: one line says so. Dask already
        ran it 4 times (``allowed-failures`` + 1), each retry on another worker or a
        freshly restarted one (not a victim of an earlier task's leftovers), and tasks
        are deterministic: a fifth run needs that memory again. Submitting it
        :data:`RESUBMITS` more times cost 12 more restarts (16: 189 s for a ``local:1``
        reference on a 600 MiB worker). Other deaths (SIGKILL, a node lost, a crash)
        need not be the task's doing: those are submitted again."""
        if future.status == "error":
            error = future.exception()
            if not isinstance(error, KilledWorker):
                future.result()  # the task's own error, with its traceback
            deaths = getattr(error, "allowed_failures", 0) + 1
            mine = getattr(error, "task", future.key) == future.key
            why = (f"Dask gave up on it after {deaths} of its workers died running it" if mine
                   else f"Dask gave up on its input after {deaths} of the workers loading it died")
            killed = memory_kill(self.client, getattr(error, "last_worker", None))
            if killed:
                raise McrtError(f"task {index} of job {label} on the Dask cluster at "
                                f"{self.address or 'local'}: {why}, the last one {killed}: it "
                                f"needs more memory than a worker may use; give the workers "
                                f"more (dask worker --memory-limit, fewer workers per machine) "
                                f"or make it smaller (the image, the samples per pass); the "
                                f"work finished so far is kept: run the same command again, "
                                f"with or without --cluster, to resume")
        else:
            while True:
                try:  # (lost with its worker since the status was read: Dask makes it again)
                    return True, future.result(timeout=self._worker_wait() + POLL_SECONDS)
                except TimeoutError:
                    self._watch(pending)
                except CancelledError as error:
                    reason = getattr(error, "reason", "") or "for no reason given"
                    if reason in _SCHEDULER_GONE or self.client.status != "running":
                        raise self._lost_scheduler(error) from None
                    why = f"Dask cancelled it ({reason})"
                    break
                except _LOST as error:
                    raise self._lost_scheduler(error) from None
        count = again[index] = again.get(index, 0) + 1
        if count > RESUBMITS:
            times = f"{count} time{'s' if count > 1 else ''}"
            raise McrtError(f"task {index} of job {label} on the Dask cluster at "
                            f"{self.address or 'local'}: {why} (submitted {times}; does it "
                            f"crash its worker or run out of memory?); the work finished so far "
                            f"is kept: run the same command again, with or without --cluster, "
                            f"to resume")
        log.info("task %d of job %s: %s; submitting it again (%d of %d)", index, label, why,
                 count, RESUBMITS)
        return False, None

    def available_bytes(self) -> int | None:
        """The memory a task can plan to use on the workers now (the least of theirs)."""
        try:
            return workers_available(self.client)
        except _LOST as error:
            raise self._lost_scheduler(error) from None

    def _workers_back(self) -> None:
        """Tasks finish (or workers are there) again after a time without workers."""
        if self._none_since is not None:
            self._none_since = None
            log.info("Dask workers at %s again: the lost tasks run again", self.address or "local")

    @staticmethod
    def _worker_wait() -> float:
        return env_number("MCRT_CLUSTER_WORKER_WAIT", WORKER_WAIT)

    def _watch(self, pending: int) -> None:
        """Nothing finished for a while: the scheduler gone is a
        :class:`McrtError` at once; no workers is a wait for some
        (:data:`WORKER_WAIT` seconds, ``$MCRT_CLUSTER_WORKER_WAIT``), with notes,
        and then a :class:`McrtError` saying what was lost."""
        if self.client.status != "running":
            raise self._lost_scheduler(ConnectionError("the connection to it was lost"))
        try:
            workers = len(self.client.nthreads())
        except _LOST as error:
            raise self._lost_scheduler(error) from None
        now = time.monotonic()
        if workers:
            self._workers = workers
            self._workers_back()
            return
        wait_for = self._worker_wait()
        lost = "the one Dask worker" if self._workers == 1 else \
            f"all {self._workers or 'the'} Dask workers"
        if self._none_since is None:
            self._none_since = self._noted = now
            log.warning("%s at %s died; waiting up to %g s for workers (%d task%s to do)",
                        lost, self.address or "local", wait_for, pending,
                        "s" if pending > 1 else "")
        elif now - self._none_since > wait_for:
            raise McrtError(f"{lost} at {self.address or 'local'} died and none came back "
                            f"within {wait_for:g} s; {pending} task{'s' if pending > 1 else ''} "
                            f"lost; the work finished so far is kept: run the same command "
                            f"again, with or without --cluster, to resume")
        elif now - self._noted >= 60:
            self._noted = now
            log.warning("still no Dask workers at %s after %.0f s (waiting up to %g s)",
                        self.address or "local", now - self._none_since, wait_for)

    def _input(self, value: Any) -> Future:
        """A shared input as a task that returns it: the task carries the value (a
        scene as its files' bundle), so Dask runs it again wherever the input was
        lost (every worker holding it died); each worker gets it once, from a
        worker that has it. Held, by content, until :meth:`close`: a job's next
        tasks may need it again, and so may the next job."""
        if isinstance(value, SceneSource) and value.digest:
            content = f"mcrt-scene-{value.digest}"
        else:
            from dask.base import tokenize

            content = f"mcrt-input-{tokenize(value)}"
        held = self._held.get(content)
        if held is not None and held.status not in ("error", "cancelled"):
            return held
        if isinstance(value, SceneSource):
            value = value.bundle()
            log.debug("sending scene %s to the cluster", describe(value))
        # cancelled (scheduler restarted?) or given up on (its workers died): a new key
        key = content if held is None else f"{content}-{uuid.uuid4().hex[:8]}"
        with warnings.catch_warnings():  # "large graph": carrying the value is the point
            warnings.simplefilter("ignore", UserWarning)
            try:
                future = self.client.submit(_identity, value, key=key, pure=False)
            except _LOST as error:
                raise self._lost_scheduler(error) from None
        self._held[content] = future
        return future

    def _lost_scheduler(self, error: BaseException) -> McrtError:
        """The one-line error of a scheduler gone (or the connection to it)."""
        why = "the connection to it was lost" if isinstance(
            error, (CancelledError, ClosedClientError)) else _first_line(error)
        return McrtError(f"lost the Dask scheduler at {self.address or 'local'} ({why}); the "
                         f"work finished so far is kept: run the same command again, with or "
                         f"without --cluster, to resume")

    def close(self) -> None:
        self._held.clear()
        try:
            self.client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            self._quiet.restore()


def _identity(value: Any) -> Any:
    """A shared input's task: its value, carried in the task itself."""
    return value


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__
