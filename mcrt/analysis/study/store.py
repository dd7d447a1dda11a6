"""The resume state of a study: finished cells saved as soon as they are done.

``mcrt compare`` keeps a :class:`StudyState` in ``<report dir>/.mcrt-resume/``.
Every finished cell is saved atomically, keyed by :func:`study_key` (the
configuration's content, the scenes' content and the software versions); a
run with the same key takes the saved cells instead of rendering them again
(the cells of a group, every sampler at one spp, finish together: the renders
of an interrupted group are rendered again).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ...core.job import Checkpoint, content_key
from ...core.sampling import sampler_fingerprint
from ...core.scene_files import scene_digest
from ...errors import McrtError
from .config import StudyConfig, cell_keys
from .fields import plain
from .summary import CellImages, CellRenders

log = logging.getLogger("mcrt.compare")

#: Directory of the resume state inside a report directory.
STATE_DIR = ".mcrt-resume"

#: Version of the state's layout; a state of another format is ignored.
STATE_FORMAT = 2


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
    return content_key({"kind": "study", "format": STATE_FORMAT, "study": study,
                        "scenes": [scene_digest(s.path, s.params) for s in config.scenes],
                        **({"sampler_code": code} if code else {})})


def reference_fingerprint(mean: np.ndarray, standard_error: np.ndarray) -> str:
    """SHA-256 of a reference's float64 mean and standard error: the cells
    measured against one reference are only resumed against the same bits."""
    digest = hashlib.sha256()
    for array in (mean, standard_error):
        a = np.ascontiguousarray(array, dtype=np.float64)
        digest.update(repr(a.shape).encode() + a.tobytes())
    return digest.hexdigest()[:32]


class StudyState:
    """Finished cells of a study, saved after every cell so that a run can resume.

    Lives in ``<report dir>/.mcrt-resume/``: ``state.npz`` (the reference
    fingerprints and every finished cell with its per-seed values) and one
    ``images_*.npz`` per (scene, sampler) with the report's images and one
    ``renders_*.npz`` per cell with its viewer images, each a
    :class:`~mcrt.core.job.Checkpoint` (key and checksum checked on load; a
    damaged file is set aside and its cells measured again). The images are
    written before the state that refers to them, so a kill at any moment leaves
    a consistent state.
    """

    def __init__(self, directory: str | os.PathLike[str], key: str):
        self.directory = Path(directory)
        self.key = key
        self.cells: dict[tuple[str, str, int], dict[str, Any]] = {}
        self.references: dict[str, str] = {}
        self.seconds = 0.0
        self.runs = 0
        self.writable = True

    @property
    def path(self) -> Path:
        return self.directory / "state.npz"

    @classmethod
    def open(cls, report_dir: str | os.PathLike[str], config: StudyConfig,
             restart: bool = False) -> StudyState:
        """The saved state of ``config`` in ``report_dir``, or an empty one.

        A state that is damaged or of another study (another :func:`study_key`)
        is not used, with a note; ``restart`` deletes any saved state. Nothing is
        written here: the directory is created by the first :meth:`add`.
        """
        state = cls(Path(report_dir) / STATE_DIR, study_key(config))
        if restart:
            state.clear()
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

    def add(self, cell: dict[str, Any], images: CellImages | None, seconds: float,
            renders: CellRenders | None = None) -> None:
        """Record a finished cell (and its images) and save; a write failure
        (disk full, ...) is logged once and turns saving off, the study goes on."""
        key = (cell["scene"], cell["sampler"], cell["spp_requested"])
        self.cells[key] = plain(cell)
        if not self.writable:
            return
        try:
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
        except (McrtError, OSError) as error:
            log.warning("cannot save the resume state (%s); the study goes on, but an "
                        "interruption will lose the cells not saved", error)
            self.writable = False

    def save(self, seconds: float) -> None:
        """Write ``state.npz`` atomically (``seconds``: study time so far, all runs)."""
        Checkpoint({"runs": self.runs + 1, "seconds": seconds, "references": self.references,
                    "cells": list(self.cells.values())}).save(self.path, self.key)

    def clear(self) -> None:
        """Delete the saved state (``--restart``)."""
        shutil.rmtree(self.directory, ignore_errors=True)
