"""The one home of a resumable job's saved state: its file format, where a render keeps
it, when it is saved while the job runs, and what happens when a save fails.

Every state mcrt persists goes through here: render and adaptive-render
checkpoints (:class:`CheckpointStore`), a reference's cache files
(:mod:`mcrt.analysis.reference_cache`), a study's resume state
(:mod:`mcrt.analysis.study.store`) and the Poisson-disk tables
(:mod:`mcrt.samplers.poisson_tables`).

* :class:`Checkpoint` is the one format: an ``.npz`` holding the key, JSON
  metadata, numpy arrays and a checksum of all of them, written atomically. A
  file that is unreadable, of another format or fails its checksum (or the
  user's own check, ``valid``) is never used: it is reported in one note and set
  aside (renamed ``*.damaged``, :func:`set_aside`), and the work is recomputed.
  A file of another key is not used and stays.
* :class:`Saving` is the one failure policy of state saved while a job runs:
  the first save that fails (full disk, read-only file system, ...) is noted
  once, ``cannot save WHAT (ERROR); WHAT NOW``, and saving stops; the job goes on.
* :class:`CheckpointPacer` says when a running job saves (under 1% of its time,
  or every N seconds); :class:`Checkpointing` is a render's option for it.

The keys are :func:`mcrt.core.job.content_key`; a render's key and paths are
:mod:`mcrt.core.render_job`'s.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import McrtError
from .atomic import atomic_path, remove_stale_temporaries, special_kind

log = logging.getLogger("mcrt")

#: Layout version of checkpoint files; files of another format are not used.
CHECKPOINT_FORMAT = 2


# --------------------------------------------------------------------------- the format


def _checksum(key: str, meta_text: str, arrays: dict[str, np.ndarray]) -> str:
    digest = hashlib.sha256(f"{CHECKPOINT_FORMAT}\0{key}\0{meta_text}".encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


@dataclass
class Checkpoint:
    """Persisted state of a job: JSON-ready ``meta`` and numpy ``arrays``."""

    meta: dict[str, Any] = field(default_factory=dict)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    def save(self, path: Path, key: str, job: str = "") -> None:
        """Write atomically; a kill at any moment leaves the old file or the new one.

        ``job`` (optional) says in words whose checkpoint it is (a command line),
        for the note of a later job that finds it in its way.
        """
        meta_text = json.dumps(self.meta, sort_keys=True)
        header = json.dumps({"format": CHECKPOINT_FORMAT, "key": key, "job": job,
                             "cwd": _cwd() if job else None,
                             "checksum": _checksum(key, meta_text, self.arrays)})
        buffer = io.BytesIO()
        members: dict[str, Any] = {f"a_{name}": a for name, a in self.arrays.items()}
        np.savez(buffer, header=np.array(header), meta=np.array(meta_text), **members)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            f.write(buffer.getvalue())

    @classmethod
    @classmethod
    def load(cls, path: Path, key: str, valid: Callable[[Checkpoint], bool] | None = None,
             invalid: str = "not a valid state") -> Checkpoint | None:
        """The checkpoint at ``path`` if it is intact and belongs to ``key``
        (and passes ``valid``, the user's own check of its content).

        A missing file gives None quietly; a file of another job (another key)
        gives None with a note and stays; a damaged one (or one ``valid``
        rejects: ``invalid`` says why) is set aside with a note.
        A FIFO, socket, device or directory at ``path`` is never opened (a FIFO
        would block for ever): None with a note, and it stays.
        Temporary files of killed writers next to it are removed first.
        """
        remove_stale_temporaries(path.parent)
        kind = special_kind(path)
        if kind is not None:  # never opened (a FIFO would block), renamed or replaced
            log.warning("%s is %s, not a checkpoint: not used", path, kind)
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                meta_text = str(data["meta"])
                arrays = {name[2:]: data[name] for name in data.files if name.startswith("a_")}
        except FileNotFoundError:
            return None
        except IsADirectoryError:
            log.warning("%s is a directory, not a checkpoint: not used", path)
            return None
        except Exception as error:  # truncated, not an npz, bad JSON, bad CRC, ...
            set_aside(path, f"unreadable ({type(error).__name__})")
            return None
        if not isinstance(header, dict) or header.get("format") != CHECKPOINT_FORMAT:
            set_aside(path, "of an unknown format")
            return None
        if header.get("key") != key:
            log.info("%s belongs to another job (other settings, scene files or versions); "
                     "not used", path)
            return None
        if header.get("checksum") != _checksum(key, meta_text, arrays):
            set_aside(path, "damaged (checksum mismatch)")
            return None
        found = cls(meta=json.loads(meta_text), arrays=arrays)
        if valid is not None and not valid(found):
            set_aside(path, invalid)
            return None
        return found


def set_aside(path: Path, why: str) -> None:
    """Rename a damaged file to ``*.damaged`` (never used, never silently deleted)."""
    target = path.with_name(path.name + ".damaged")
    try:
        os.replace(path, target)
        log.warning("%s is %s: moved to %s, the work is done again", path, why, target)
    except OSError:
        log.warning("%s is %s: not used, the work is done again", path, why)


def _cwd() -> str | None:
    try:
        return os.getcwd()
    except OSError:
        return None


def peek(path: Path) -> tuple[dict[str, Any], Any] | None:
    """``(header, meta)`` of the intact-looking checkpoint at ``path`` (its key,
    job, cwd; its metadata), read without the checks; None if there is none,
    it is of another format or cannot be read (:meth:`Checkpoint.load` reports
    those). A FIFO, socket, device or directory is never opened."""
    if special_kind(path) is not None:  # a FIFO would block: Checkpoint.load reports it
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            meta = json.loads(str(data["meta"]))
    except Exception:  # missing, damaged: Checkpoint.load reports those
        return None
    if not isinstance(header, dict) or header.get("format") != CHECKPOINT_FORMAT:
        return None
    return header, meta


def other_job(path: Path, key: str) -> str | None:
    """If ``path`` holds an intact-looking checkpoint of another job than ``key``:
    what it was, in words (its command line and progress). None otherwise."""
    found = peek(path)
    if found is None or found[0].get("key") == key:
        return None
    header, meta = found
    job = str(header.get("job") or "") or "a job with other settings, scene files or versions"
    done = meta.get("done", meta.get("next_pass")) if isinstance(meta, dict) else None
    settings = meta.get("settings") if isinstance(meta, dict) else None
    if isinstance(done, int) and isinstance(settings, list) and len(settings) == 3:
        return f"{job}; {settings[0]} spp, {done} passes done"
    return f"{job}; {done} passes done" if isinstance(done, int) else job


def progress_of(checkpoint: Checkpoint) -> int:
    """How far a checkpoint's job got: its passes done (``done`` of renders and
    references, ``next_pass`` of adaptive renders); -1 if it does not say."""
    meta = checkpoint.meta
    done = meta.get("done", meta.get("next_pass")) if isinstance(meta, dict) else None
    return done if isinstance(done, int) and not isinstance(done, bool) else -1


# --------------------------------------------------------------------------- the failure policy


class Saving:
    """The one failure policy of state saved while a job runs (a render's
    checkpoints, a reference's cache files, a study's resume state, the
    Poisson-disk tables): the first save that fails (full disk, read-only file
    system, permission denied...) is noted once, ``cannot save WHAT (ERROR);
    THEN``, and turns saving off (``on`` False); the job goes on without it.

    ``saving(write)`` runs ``write()`` while saving is on; True if it saved.
    """

    def __init__(self, what: str, then: str, on: bool = True) -> None:
        self.what, self.then, self.on = what, then, on

    def __call__(self, write: Callable[[], object]) -> bool:
        if not self.on:
            return False
        try:
            write()
        except (McrtError, OSError) as error:
            self.on = False
            log.warning("cannot save %s (%s); %s", self.what, error, self.then)
            return False
        return True


# --------------------------------------------------------------------------- a render's store


class CheckpointStore:
    """Where one job keeps its checkpoint: the first of ``paths`` that can be
    written (e.g. next to the output, else in the cache).

    A path holding the checkpoint of another job (another spp, seed, scene...)
    is kept as it is, with a note saying whose it is: this job then uses the
    next path, and the other job can still be resumed by its own command.
    ``job`` (a command line) is recorded with the checkpoints for such notes.
    A checkpoint recorded by this very command line, in this directory, whose
    key is not this job's (a scene file edited since, even in a comment, or
    new versions of mcrt, Mitsuba or Dr.Jit) can no longer be resumed by any
    command: it is replaced, with one note.

    The job keeps one checkpoint: a save to one path removes the job's older
    checkpoints at the others (a full disk next to the output sends the later
    ones to the cache), and :meth:`load` takes the most advanced it finds.
    :meth:`save_periodic` saves under the one failure policy (:class:`Saving`).
    """

    def __init__(self, paths: Iterable[Path], key: str, job: str = "") -> None:
        self.paths = [Path(p) for p in paths]
        self.key = key
        self.job = job
        self.saved: Path | None = None
        self.foreign: set[Path] = set()
        self.failed: set[Path] = set()  # noted once; periodic saves skip them
        self.periodic = Saving("the checkpoint", "checkpoints are off for this run; an "
                               "interruption loses the passes since the last one")

    def load(self) -> Checkpoint | None:
        best: Checkpoint | None = None
        for path in self.paths:
            other = other_job(path, self.key)
            if other is not None and self._unreachable(path):
                log.info("%s is the checkpoint of this same command (%s) made from other "
                         "inputs (a scene file changed since, or the versions of mcrt, "
                         "Mitsuba or Dr.Jit): no command can resume it any more; replaced",
                         path, other)
                continue
            if other is not None:
                self.foreign.add(path)
                mine = next((p for p in self.paths if p not in self.foreign), None)
                where = f"this render keeps its checkpoint in {mine}" if mine else \
                    "this render keeps no checkpoint"
                log.info("%s is the checkpoint of another render (%s): kept, not replaced; "
                         "%s (run the other command to resume it, or delete the file)",
                         path, other, where)
                continue
            found = Checkpoint.load(path, self.key)
            if found is not None and (best is None or progress_of(found) > progress_of(best)):
                best = found
        return best

    def _unreachable(self, path: Path) -> bool:
        """Whether ``path`` holds a checkpoint that this job's own command line
        (run in the same directory) recorded under another key."""
        found = peek(path)
        if found is None or not self.job or found[0].get("job") != self.job:
            return False
        recorded = found[0].get("cwd")
        return recorded is None or recorded == _cwd()

    def save(self, checkpoint: Checkpoint, retry: bool = True) -> Path | None:
        """Save to the first writable path; None if none works. A path that
        fails is noted once and, without ``retry``, not tried again (a read-only
        output directory used to cost a failed write and a note every pass).
        The job's checkpoints at the other paths (older) are removed."""
        for path in self.paths:
            if path in self.foreign or (path in self.failed and not retry):
                continue
            try:
                checkpoint.save(path, self.key, self.job)
            except (McrtError, OSError) as error:
                if path not in self.failed:
                    self.failed.add(path)
                    log.warning("cannot save the checkpoint to %s (%s)", path, error)
                continue
            self.saved = path
            self._remove_older(path)
            return path
        return None

    def _remove_older(self, current: Path) -> None:
        for path in self.paths:
            if path == current or path in self.foreign:
                continue
            found = peek(path)
            if found is not None and found[0].get("key") == self.key:
                with contextlib.suppress(OSError):  # load() still prefers the most advanced one
                    path.unlink()

    def discard(self) -> None:
        """Delete this job's checkpoint (never another job's)."""
        for path in self.paths:
            # Not a FIFO, a directory...: those are not ours to delete.
            if path not in self.foreign and special_kind(path) is None:
                path.unlink(missing_ok=True)

    def save_periodic(self, checkpoint: Checkpoint) -> None:
        """A checkpoint taken while the job runs: after a failure (full disk, ...)
        the job goes on without them, with one note (:class:`Saving`)."""

        def write() -> None:
            if self.save(checkpoint, retry=False) is None:
                raise McrtError("no place could take it")

        self.periodic(write)


# --------------------------------------------------------------------------- periodic saving

#: Share of a job's time its checkpoints may take (:class:`CheckpointPacer`; 2% allowed).
CHECKPOINT_BUDGET = 0.01


#: Speed assumed for a first checkpoint (bytes per second, compression and fsync included).
CHECKPOINT_BYTES_PER_SECOND = 100e6


def expected_save_seconds(state_bytes: int) -> float:
    """What saving a checkpoint of ``state_bytes`` is expected to take."""
    return 0.01 + state_bytes / CHECKPOINT_BYTES_PER_SECOND if state_bytes else 0.0


class CheckpointPacer:
    """When to write a checkpoint during a job: as often as keeps their cost
    below :data:`CHECKPOINT_BUDGET` of the time since the last one, or every
    ``every`` seconds if given (0: after every unit of work).

    ``maybe(save, make)`` calls ``save(make())`` when one is due and times it.
    """

    def __init__(self, every: float | None = None, budget: float = CHECKPOINT_BUDGET,
                 state_bytes: int = 0) -> None:
        self.every, self.budget = every, budget
        self.last = time.perf_counter()
        # Seconds the last checkpoint took; before the first, what one of
        # ``state_bytes`` is expected to take (so a short job writes none).
        self.cost = expected_save_seconds(state_bytes)
        self.spent = 0.0  # seconds all checkpoints took
        self.count = 0

    def due(self) -> bool:
        since = time.perf_counter() - self.last
        if self.every is not None:
            return since >= self.every
        return since * self.budget >= self.cost

    def maybe(self, save: Callable[[Any], Any], make: Callable[[], Any]) -> bool:
        if not self.due():
            return False
        start = time.perf_counter()
        save(make())
        self.last = time.perf_counter()
        self.cost = self.last - start
        self.spent += self.cost
        self.count += 1
        return True


@dataclass(frozen=True)
class Checkpointing:
    """How a render keeps its finished work (one option of :func:`~mcrt.core.render.render_film`
    and :func:`~mcrt.render.adaptive.render_adaptive`): ``resume`` continues from
    the checkpoint of an interrupted, identical render; ``save(checkpoint)`` (e.g.
    :meth:`CheckpointStore.save_periodic`) receives the checkpoint of the finished
    work while it runs, so that even a SIGKILL keeps it: every ``every`` seconds
    (0: after every pass; None: as often as keeps its cost under 2% of the time,
    :class:`CheckpointPacer`)."""

    resume: Checkpoint | None = None
    save: Callable[[Checkpoint], object] | None = None
    every: float | None = None

