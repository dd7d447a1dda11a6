"""Write several output files at once.

An image writer spends most of its time in zlib and OpenEXR, which release
Python's lock while they compress, so the EXR and its PNG preview of a render
are written side by side (on two cores, about the time of the slower one).
"""

from __future__ import annotations

import threading
from collections.abc import Callable


def write_all(*writes: Callable[[], object]) -> None:
    """Run every ``write`` (each writes one file, atomically), the first in this
    thread and the others in their own; wait for all of them, then raise the
    first error in the order given (every file that could be written is)."""
    errors: list[BaseException | None] = [None] * len(writes)

    def run(index: int) -> None:
        try:
            writes[index]()
        except BaseException as error:  # re-raised in the caller's thread below
            errors[index] = error

    threads = [threading.Thread(target=run, args=(i,), daemon=True)
               for i in range(1, len(writes))]
    for thread in threads:
        thread.start()
    try:
        if writes:
            run(0)
    finally:
        for thread in threads:
            thread.join()
    for error in errors:
        if error is not None:
            raise error
