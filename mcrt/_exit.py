"""Ending a command-line process without tearing the interpreter down.

When a Python process exits normally, CPython destroys every module and the
~10^5 objects that Mitsuba, Dr.Jit and numpy made, and Dr.Jit frees its JIT
state: 35-75 ms of every ``mcrt`` command, depending on how busy the machine
is (``benchmarks/process_timeline.py``: the plain script's exit stage, 36 ms,
against 8 ms for ``mcrt`` with :func:`leave`; 256^2, median of 9 runs). None
of it is needed once a command's files are written: they are flushed and
``fsync``'d by then, and Dr.Jit writes its kernel cache when it compiles a
kernel, not at exit.

:func:`leave` keeps what an exit must do (the ``atexit`` handlers, such as
logging's flush, and flushing stdout and stderr) and then ends the process
with ``os._exit``. Only the console script calls it; ``main(argv)`` called from
Python returns as usual.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading

#: Set by :func:`out_of_memory`: the process ran out of memory.
_out_of_memory = False


def out_of_memory() -> None:
    """The command ended because an allocation failed: :func:`leave` then skips
    the ``atexit`` handlers but logging's flush. Dr.Jit's and Mitsuba's
    clean-up crashed (SIGSEGV, after the one-line error) in a process whose
    allocations had failed, and there is nothing left for them to save."""
    global _out_of_memory
    _out_of_memory = True


def leave(code: int) -> None:
    """End the process now with exit status ``code``, after running the
    ``atexit`` handlers and flushing stdout and stderr.

    Returns (and the caller exits the usual way) when another non-daemon
    thread still runs, which a normal exit would wait for, or when this Python
    has no way to run the ``atexit`` handlers early.
    """
    run_handlers = getattr(atexit, "_run_exitfuncs", None)  # CPython's, since 2.x
    others = [t for t in threading.enumerate()
              if t is not threading.current_thread() and not t.daemon and t.is_alive()]
    if run_handlers is None or others:
        return
    if _out_of_memory:
        if "logging" in sys.modules:
            sys.modules["logging"].shutdown()
    else:
        run_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed pipe or stream: nothing more can be said
            code = code or 1
    os._exit(code)
