"""A ``local`` cluster's processes and the terminal's signals.

The worker processes of a ``LocalCluster`` and multiprocessing's resource
tracker are children of the mcrt command, in its process group: a Ctrl-C (or a
closed terminal's SIGHUP) reached them too. The client handles it (it writes
the partial results and closes the cluster), but each worker printed its own
``KeyboardInterrupt`` traceback ("Process Dask Worker process (from Nanny):
..."), and a tracker killed by SIGHUP was started again with a warning and a
``KeyError`` traceback for every resource it had not seen. So:

* each worker leaves the command's process group as it starts (a Dask
  preload, :func:`dask_setup`, run by every worker, those that replace dead
  ones included); it still ends with the command, which it watches through a
  pipe, not through signals;
* the resource tracker is started ignoring SIGHUP (:func:`start_resource_tracker`;
  it ignores SIGINT and SIGTERM itself, and ends when the command does).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Any


def dask_setup(worker: Any) -> None:
    """Dask's preload hook, in each local worker process as it starts."""
    with contextlib.suppress(OSError):  # already a group leader: nothing to leave
        os.setsid()  # out of the terminal's process group: its signals go to the command


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker now, ignoring SIGHUP (it keeps
    that disposition: exec leaves ignored signals ignored)."""
    if not hasattr(signal, "SIGHUP") or threading.current_thread() is not threading.main_thread():
        return
    from multiprocessing import resource_tracker

    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(signal.SIGHUP, previous)
