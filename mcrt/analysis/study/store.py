"""The resume state of a study: finished cells saved as soon as they are done.

``mcrt compare`` keeps a :class:`StudyState` in ``<report dir>/.mcrt-resume/``.
Every finished cell is saved atomically, keyed by :func:`study_key` (the
configuration's content, the scenes' content and the software versions); a
run with the same key takes the saved cells instead of rendering them again
(the cells of a group, every sampler at one spp, finish together: the renders
of an interrupted group are rendered again).

Nothing saved is lost to another study, and one process at a time writes a
report directory:

* a saved state of another key (another variant, configuration, scene files or
  versions) is never overwritten or deleted: :meth:`StudyState.open` moves it
  aside to ``.mcrt-resume-<its key>`` with a note naming the command that made
  it, and a later run with that key moves it back and resumes from it;
* :meth:`StudyState.open` takes an exclusive ``flock`` on the report directory,
  held until the state is closed or garbage-collected or the process ends (the
  kernel drops it with the process, so a crash leaves no stale lock); another
  process opening the same directory is refused at once with a one-line error
  naming the directory and the holder (its PID and command line, from
  ``/proc/locks`` where there is one). States opened in one process share the lock.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shlex
import shutil
import time
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from ...core.file_lock import LockBusy, hold_directory, release
from ...core.job import content_key
from ...core.sampling import sampler_fingerprint
from ...core.scene_files import scene_digest
from ...core.state_file import Checkpoint, Saving, peek
from ...errors import McrtError
from .config import StudyConfig, cell_keys
from .fields import Cell, plain
from .summary import CellImages, CellRenders

log = logging.getLogger("mcrt.compare")

#: Directory of the resume state inside a report directory.
STATE_DIR = ".mcrt-resume"

#: Version of the state's layout; a state of another format is ignored.
STATE_FORMAT = 2

#: Hex digits of its key that name a state set aside (``.mcrt-resume-<digits>``).
ASIDE_DIGITS = 16


def study_key(config: StudyConfig) -> str:
    """:func:`~mcrt.core.job.content_key` of everything a study's numbers depend on.

    The parsed configuration (not its bytes: comments, the study's name and
    description do not change a measurement) and the content of every scene file
    (with the files it includes, :func:`~mcrt.core.job.scene_digest`; the baseline
    only changes derived ratios, so it is left out too); the key adds
    the variant and the versions of mcrt, Mitsuba and Dr.Jit. A saved state with
    another key belongs to another study and is never resumed.
    """
    study = config.as_dict()
    for key in ("name", "description", "config_path", "baseline"):
        study.pop(key, None)
    code = {s.label: c for s in config.samplers if (c := sampler_fingerprint(s.name, s.params))}
    ref = config.reference
    ref_code = sampler_fingerprint(ref.sampler, ref.params)  # e.g. its point file's content
    return content_key({"kind": "study", "format": STATE_FORMAT, "study": study,
                        "scenes": [scene_digest(s.path, s.params) for s in config.scenes],
                        **({"sampler_code": code} if code else {}),
                        **({"reference_code": ref_code} if ref_code else {})})


def reference_fingerprint(mean: np.ndarray, standard_error: np.ndarray) -> str:
    """SHA-256 of a reference's float64 mean and standard error: the cells
    measured against one reference are only resumed against the same bits."""
    digest = hashlib.sha256()
    for array in (mean, standard_error):
        a = np.ascontiguousarray(array, dtype=np.float64)
        digest.update(repr(a.shape).encode() + a.tobytes())
    return digest.hexdigest()[:32]


def study_command(config: StudyConfig, report_dir: str | os.PathLike[str]) -> str:
    """The command line that runs ``config`` into ``report_dir`` in this process's
    variant, with the plugin files loaded besides the configuration's own: what a
    set-aside state's note tells to run ("" when the configuration has no file)."""
    import mitsuba as mi

    from ...plugins import command_words, loaded_plugins

    if config.path is None:
        return ""
    variant = mi.variant() or "llvm_ad_rgb"
    words = ["--variant", variant] if variant != "llvm_ad_rgb" else []
    words += command_words(p for p in loaded_plugins() if p not in config.plugins)
    return shlex.join(["mcrt", *words, "compare", str(config.path), "-o", str(report_dir)])


class StudyState:
    """Finished cells of a study, saved after every cell so that a run can resume.

    Lives in ``<report dir>/.mcrt-resume/``: ``state.npz`` (the reference
    fingerprints and every finished cell with its per-seed values) and one
    ``images_*.npz`` per (scene, sampler) with the report's images and one
    ``renders_*.npz`` per cell with its viewer images, each a
    :class:`~mcrt.core.state_file.Checkpoint` (key and checksum checked on load; a
    damaged file is set aside and its cells measured again). The images are
    written before the state that refers to them, so a kill at any moment leaves
    a consistent state. ``state.npz`` records ``command``, the command line that
    resumes it.

    A state from :meth:`open` holds the report directory's lock until
    :meth:`close` (or ``with``, or garbage collection, or the end of the process).
    """

    def __init__(self, directory: str | os.PathLike[str], key: str, command: str = ""):
        self.directory = Path(directory)
        self.key = key
        self.command = command
        self.cells: dict[tuple[str, str, int], Cell] = {}
        self.references: dict[str, str] = {}
        self.seconds = 0.0
        self.runs = 0
        self.saving = Saving("the resume state", "the study goes on, but an interruption will "
                             "lose the cells not saved")
        self._unlock: weakref.finalize | None = None

    @property
    def path(self) -> Path:
        return self.directory / "state.npz"

    @property
    def writable(self) -> bool:
        """Whether saving is still on (a failed write turns it off, :class:`Saving`)."""
        return self.saving.on

    @classmethod
    def open(cls, report_dir: str | os.PathLike[str], config: StudyConfig,
             restart: bool = False, command: str | None = None) -> StudyState:
        """The saved state of ``config`` in ``report_dir``, or an empty one.

        Takes the report directory's lock first (creating the directory): a
        directory another process holds is refused with a one-line
        :class:`~mcrt.errors.McrtError`. A saved state of another study (another
        :func:`study_key`) is moved aside with a note, never overwritten; one of
        this study that an earlier run moved aside is moved back and resumed. A
        damaged state is not used, with a note; ``restart`` deletes this study's
        saved state (never another's). ``command`` (default
        :func:`study_command`) is recorded with every save. No state file is
        written here: the state's directory is created by the first :meth:`add`.
        """
        report = Path(report_dir)
        state = cls(report / STATE_DIR, study_key(config),
                    study_command(config, report) if command is None else command)
        report.mkdir(parents=True, exist_ok=True)
        try:
            held = hold_directory(report, "a second run writing into it would not be refused")
        except LockBusy as busy:
            raise McrtError(f"{report} is in use by another study run ({busy.holder}); one run "
                            f"at a time writes a report directory: wait for it to end, or give "
                            f"this one another -o DIR") from None
        if held is not None:
            state._unlock = weakref.finalize(state, release, held)
        try:
            state._keep_other_study()
            if restart:
                state.clear()
            else:
                state._bring_back()
        except BaseException:
            state.close()
            raise
        found = Checkpoint.load(state.path, state.key)
        if found is None:
            return state
        try:
            keys = set(cell_keys(config))
            for cell in found.meta["cells"]:
                key = (cell["scene"], cell["sampler"], int(cell["spp_requested"]))
                if key in keys:
                    state.cells[key] = cell
            state.references = {str(k): str(v) for k, v in found.meta["references"].items()}
            state.seconds = float(found.meta.get("seconds", 0.0))
            state.runs = int(found.meta.get("runs", 0))
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            log.warning("ignoring the resume state %s (%s)", state.path, error)
            state.cells.clear()
            state.references.clear()
        return state

    def close(self) -> None:
        """Release the report directory's lock (if this state holds it)."""
        if self._unlock is not None:
            self._unlock()

    def __enter__(self) -> StudyState:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _keep_other_study(self) -> None:
        """Move a saved state of another key to ``.mcrt-resume-<its key>`` (a fresh
        name, never over a file), with a note saying how to resume it."""
        saved = _saved(self.path)
        if saved is None or saved["key"] == self.key:
            return
        target = _free_name(self.directory.parent, f"{STATE_DIR}-{saved['key'][:ASIDE_DIGITS]}")
        try:
            os.rename(self.directory, target)
        except OSError as error:
            raise McrtError(f"{self.directory} holds the saved state of another study, which "
                            f"cannot be moved aside ({error.strerror}); move it away yourself "
                            f"or write this study's report to another -o DIR") from None
        if saved["job"] and saved["job"] == self.command:  # this command, other inputs
            how = ("this same command saved it when its inputs were others (the content of "
                   "the configuration or of a scene, plugin or point-set file, or the mcrt, "
                   "Mitsuba or Dr.Jit version): restore them and run it again to resume it")
        elif saved["job"]:
            how = f"to resume it, run: {saved['job']}"
        else:
            how = ("the study that saved it (same configuration, scene files, variant and "
                   "versions) resumes from it")
        log.warning("%s held the saved state of another study (%d cells): kept in %s; %s",
                    self.directory, saved["cells"], target, how)

    def _aside(self) -> list[Path]:
        """This study's states set aside by earlier runs of other studies, newest first."""
        found = [d for d in self.directory.parent.glob(f"{STATE_DIR}-{self.key[:ASIDE_DIGITS]}*")
                 if (s := _saved(d / "state.npz")) is not None and s["key"] == self.key]
        return sorted(found, key=lambda d: (d / "state.npz").stat().st_mtime, reverse=True)

    def _bring_back(self) -> None:
        """Without a state of its own in place, resume the newest one set aside."""
        here = _saved(self.path)
        aside = self._aside() if here is None or here["key"] != self.key else []
        if not aside:
            return
        if self.directory.exists():  # no usable state in it (damaged, or images only): kept
            if any(self.directory.iterdir()):
                os.rename(self.directory, _free_name(self.directory.parent, f"{STATE_DIR}-unused"))
            else:
                self.directory.rmdir()
        os.rename(aside[0], self.directory)
        log.info("resuming from the saved state kept in %s (set aside when another study "
                 "ran in %s)", aside[0], self.directory.parent)

    def _image_path(self, scene: str, label: str) -> Path:
        name = hashlib.sha256(f"{scene}\0{label}".encode()).hexdigest()[:16]
        return self.directory / f"images_{name}.npz"

    def images(self, scene: str, label: str) -> CellImages | None:
        """The saved images of (scene, sampler), or None if missing or damaged."""
        found = Checkpoint.load(self._image_path(scene, label), self.key)
        if found is None or {"render", "error", "std"} - set(found.arrays):
            return None
        return CellImages(render=found.arrays["render"], error=found.arrays["error"],
                          std=found.arrays["std"])

    def _renders_path(self, scene: str, label: str, spp: int) -> Path:
        name = hashlib.sha256(f"{scene}\0{label}\0{spp}".encode()).hexdigest()[:16]
        return self.directory / f"renders_{name}.npz"

    def renders(self, scene: str, label: str, spp: int) -> CellRenders | None:
        """The saved viewer images of a cell, or None if missing or damaged."""
        found = Checkpoint.load(self._renders_path(scene, label, spp), self.key)
        if found is None or {"mean", "first", "variance"} - set(found.arrays):
            return None
        return CellRenders(mean=found.arrays["mean"], first=found.arrays["first"],
                           variance=found.arrays["variance"])

    def check_reference(self, scene: str, fingerprint: str) -> None:
        """Forget the cells of ``scene`` if its reference changed since they were measured."""
        old = self.references.get(scene)
        if old is not None and old != fingerprint:
            stale = [key for key in self.cells if key[0] == scene]
            if stale:
                log.info("the reference of %s changed: %d saved cells are measured again",
                         scene, len(stale))
            for key in stale:
                del self.cells[key]
        self.references[scene] = fingerprint

    def add(self, cell: Cell, images: CellImages | None, seconds: float,
            renders: CellRenders | None = None) -> None:
        """Record a finished cell (and its images) and save, under the one failure
        policy (:class:`~mcrt.core.state_file.Saving`): a write failure (disk full,
        ...) is noted once and turns saving off, the study goes on."""
        key = (cell["scene"], cell["sampler"], cell["spp_requested"])
        self.cells[key] = plain(cell)

        def write() -> None:
            if images is not None:
                Checkpoint({"scene": cell["scene"], "sampler": cell["sampler"]},
                           {"render": images.render, "error": images.error, "std": images.std}
                           ).save(self._image_path(cell["scene"], cell["sampler"]), self.key)
            if renders is not None:
                Checkpoint({"scene": cell["scene"], "sampler": cell["sampler"],
                            "spp": cell["spp_requested"]},
                           {"mean": renders.mean, "first": renders.first,
                            "variance": renders.variance}
                           ).save(self._renders_path(cell["scene"], cell["sampler"],
                                                     cell["spp_requested"]), self.key)
            self.save(seconds)

        self.saving(write)

    def save(self, seconds: float) -> None:
        """Write ``state.npz`` atomically (``seconds``: study time so far, all runs)."""
        Checkpoint({"runs": self.runs + 1, "seconds": seconds, "references": self.references,
                    "cells": list(self.cells.values())}).save(self.path, self.key,
                                                              job=self.command)

    def clear(self) -> None:
        """Delete this study's saved state, and its copies set aside (``--restart``);
        another study's state is moved aside first, never deleted."""
        self._keep_other_study()
        for directory in [self.directory, *self._aside()]:
            shutil.rmtree(directory, ignore_errors=True)


# --------------------------------------------------------------------------- set aside


def _saved(path: Path) -> dict[str, Any] | None:
    """Key, command line and cell count of the intact-looking state file ``path``;
    None if it is missing or unreadable (:meth:`Checkpoint.load` reports those)."""
    found = peek(path)
    if found is None or not isinstance(found[0].get("key"), str):
        return None
    header, meta = found
    cells = meta.get("cells") if isinstance(meta, dict) else None
    return {"key": header["key"], "job": str(header.get("job") or ""),
            "cells": len(cells) if isinstance(cells, list) else 0}


def _free_name(parent: Path, name: str) -> Path:
    """``parent/name``, or with the time (and a count) added if that is taken."""
    target = parent / name
    stamp = time.strftime("%Y%m%d-%H%M%S")
    count = 0
    while target.exists() or target.is_symlink():
        count += 1
        target = parent / f"{name}-{stamp}" if count == 1 else parent / f"{name}-{stamp}-{count}"
    return target
