"""Where mcrt keeps files it can recompute (Poisson tables, reference renders).

The root is ``$MCRT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mcrt``, else
``~/.cache/mcrt``; each user of the cache gets its own subdirectory
(:func:`cache_dir`). Everything stored there must be safe to delete.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """The root of mcrt's on-disk cache (read from the environment on every call)."""
    root = os.environ.get("MCRT_CACHE_DIR")
    if root:
        return Path(root)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "mcrt"


def cache_dir(name: str) -> Path:
    """Subdirectory ``name`` of :func:`cache_root` (not created here)."""
    return cache_root() / name


def cache_variable(path: str | os.PathLike) -> str | None:
    """Where ``path`` came from when it lies under the cache root, so a message
    about it can say so and how to move it: ``"$MCRT_CACHE_DIR=ROOT"``, or for
    the default root ``"mcrt's cache ROOT; $MCRT_CACHE_DIR moves it"``; else None."""
    root = cache_root()
    if not Path(path).absolute().is_relative_to(root.absolute()):
        return None
    if os.environ.get("MCRT_CACHE_DIR"):
        return f"$MCRT_CACHE_DIR={root}"
    return f"mcrt's cache {root}; $MCRT_CACHE_DIR moves it"
