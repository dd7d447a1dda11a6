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
    """``"$MCRT_CACHE_DIR=ROOT"`` when ``path`` lies under that variable's root
    (so a message about ``path`` can name where it came from), else None."""
    root = os.environ.get("MCRT_CACHE_DIR")
    if not root:
        return None
    if not Path(path).absolute().is_relative_to(Path(root).absolute()):
        return None
    return f"$MCRT_CACHE_DIR={root}"
