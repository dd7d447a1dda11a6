"""Python's cyclic garbage collector, held back while modules are imported.

Importing Mitsuba, Dr.Jit and numpy creates some 10^5 long-lived objects, and
the collector, triggered every 700 new objects, scans them again and again:
about 50 ms of an ``mcrt`` command's start (measured: ``import mcrt.cli.render_cmd``
0.40 s with the collector held back, 0.46 s without; 6 interleaved runs). No
garbage cycles are made while importing, so nothing is lost by waiting.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def collection_held_back(freeze: bool = False) -> Iterator[None]:
    """No cyclic collection inside the block (the collector's previous state is
    restored after it). ``freeze=True`` also moves every object alive at the end
    to the collector's permanent generation (``gc.freeze``), so later
    collections skip them: for a command-line process, never for a library
    import (frozen cycles would never be freed)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if freeze:
            gc.freeze()
        if enabled:
            gc.enable()
