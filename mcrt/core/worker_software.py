"""Do a cluster's workers run this mcrt? The software check of hand-started workers.

A Dask worker keeps the code it imported: one started before mcrt (or Mitsuba, or
Dr.Jit) was updated runs the old code, and its renders are not this mcrt's bits,
silently. Each worker hashes its mcrt source once, when mcrt's worker setup first
runs there (:func:`~mcrt.core.provenance.source_digest` is cached per process, so a
later command asks the code the worker imported, not the files on its disk now);
before its first job a command compares every worker's :func:`identity` with its
own and refuses, in one line, to run on workers whose software differs
(:func:`mismatch`). Workers that join later are asked when their first result
comes back (:class:`Verified`): a job never keeps a result of other software. A
local cluster's workers start with the command, from its install: they are not
asked.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from ..errors import McrtError
from .provenance import SOFTWARE_KEYS, software

#: What the line says for each key of :data:`~mcrt.core.provenance.SOFTWARE_KEYS`.
_NAMES = {"mcrt_source": "mcrt source", "mitsuba_version": "Mitsuba",
          "drjit_version": "Dr.Jit"}

#: What to do about it.
RESTART = ("restart the workers from this install (a worker keeps the code it imported when "
           "it started)")


def identity() -> dict[str, str]:
    """This process's mcrt source digest and Mitsuba and Dr.Jit versions (run on
    each worker by the client)."""
    now = software()
    return {key: now[key] for key in SOFTWARE_KEYS}


def mismatch(here: dict[str, str], workers: dict[str, dict[str, str]]) -> str | None:
    """The one-line error for the workers (address -> :func:`identity`) whose
    software is not ``here``'s, naming at most three; None when all match."""
    differ = {address: there for address, there in sorted(workers.items()) if there != here}
    if not differ:
        return None
    first, there = next(iter(differ.items()))
    what = ", ".join(f"{_NAMES.get(key, key)} {there.get(key, '?')} where this one has "
                     f"{here[key]}" for key in here if there.get(key) != here[key])
    if len(workers) == 1:
        return (f"the Dask worker at {first} runs other software than this mcrt: {what}; its "
                f"renders would not be this mcrt's bits: {RESTART}")
    named = ", ".join(list(differ)[:3]) + (f" and {len(differ) - 3} more" if len(differ) > 3
                                           else "")
    return (f"{len(differ)} of {len(workers)} Dask workers run other software than this mcrt "
            f"({named}; the first: {what}); their renders would not be this mcrt's bits: "
            f"{RESTART}")

class Verified:
    """The workers whose software was found to be this process's, and the check of
    the others when a result of theirs comes back (a worker that joined a job
    after it started: a restarted one, or one started by hand meanwhile)."""

    def __init__(self, addresses: Iterable[str] = ()) -> None:
        self.addresses = set(addresses)

    def check(self, client: Any, futures: list[Any]) -> None:
        """Raise :class:`~mcrt.errors.McrtError` (:func:`mismatch`'s line) when a
        worker holding one of ``futures``' results runs other software; ask each
        worker once (a scheduler round trip a call while none is new)."""
        holders = {address for where in client.who_has(futures).values() for address in where}
        new = sorted(holders - self.addresses)
        if not new:
            return
        # (a worker gone since cannot answer: its result stays, it is asked no more)
        found = {address: there for address, there in
                 client.run(identity, workers=new, on_error="ignore").items()
                 if isinstance(there, dict)}
        problem = mismatch(identity(), found)
        if problem:
            raise McrtError(problem)
        self.addresses.update(new)


__all__ = ["Verified", "identity", "mismatch"]
