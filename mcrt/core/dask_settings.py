"""Dask's process-wide settings that mcrt changes while it uses a client, and restores.

* Dask's loggers are silenced: losing workers is expected and handled, and the
  scheduler's loss is mcrt's one-line error, so neither should print Dask's log
  lines and tracebacks;
* a ``LocalCluster`` in this process (``--cluster local``, or the caller's own)
  keeps the nannies of workers that keep dying. Dask closes, for good, the nanny of a
  worker that is not back ``distributed.deploy.lost-worker-timeout`` (15 s) after
  it was removed, a check meant for batch jobs lost with their node. A nanny restarts
  its worker in under a second, but one whose worker died again just as the 15 s
  were up was closed: a reference on ``LocalCluster(n_workers=1, memory_limit=
  "600MiB")`` whose pass passed the limit every 5 s lost its only worker after the
  8th death and waited 300 s for another (:data:`~mcrt.core.cluster.WORKER_WAIT`),
  then failed saying none came back.
"""

from __future__ import annotations

import logging
from typing import Any

#: Loggers (and their children) silenced while an executor is open, and how.
SILENCED = ("distributed", "tornado")
SILENT = logging.CRITICAL + 1

#: The setting of the nanny check above, and its value while an executor is open.
LOST_WORKER_TIMEOUT = "distributed.deploy.lost-worker-timeout"
KEEP_NANNIES = "1000000s"


class _NoAllExit(logging.Filter):
    """Drops asyncio's "Task exception was never retrieved" about Dask's internal
    ``AllExit`` (a result fetch abandoned after its worker died: nothing to report,
    and logged whenever the garbage collector gets to it, even after ``close``)."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        return type(error).__name__ != "AllExit" or \
            not type(error).__module__.startswith("distributed")


class DaskSettings:
    """The settings above while mcrt uses a client, back as they were when it
    closes. Counted: they come back when the last open executor closes."""

    _open = 0
    _saved: dict[str, int] = {}
    _timeout: list[Any] = []  # the lost-worker timeout before the first executor opened

    def __init__(self) -> None:
        self._active = False
        asyncio_log = logging.getLogger("asyncio")
        if not any(isinstance(f, _NoAllExit) for f in asyncio_log.filters):
            asyncio_log.addFilter(_NoAllExit())  # for good: see _NoAllExit
        self.apply()

    def apply(self) -> None:
        """Silence every Dask logger that exists now (loggers made later inherit)."""
        cls = type(self)
        if not self._active:
            self._active = True
            cls._open += 1
            if cls._open == 1:
                import dask

                cls._timeout[:] = [dask.config.get(LOST_WORKER_TIMEOUT, None)]
                dask.config.set({LOST_WORKER_TIMEOUT: KEEP_NANNIES})
        names = [name for name in list(logging.root.manager.loggerDict)
                 if name.split(".")[0] in SILENCED]
        for name in {*names, *SILENCED}:
            logger = logging.getLogger(name)
            if logger.level != SILENT:
                cls._saved.setdefault(name, logger.level)
                logger.setLevel(SILENT)

    def restore(self) -> None:
        cls = type(self)
        if not self._active:
            return
        self._active = False
        cls._open -= 1
        if cls._open == 0:
            for name, level in cls._saved.items():
                logging.getLogger(name).setLevel(level)
            cls._saved.clear()
            if cls._timeout:
                import dask

                dask.config.set({LOST_WORKER_TIMEOUT: cls._timeout.pop()})
