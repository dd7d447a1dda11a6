"""Argument types and output checks shared by the subcommands."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..core.atomic import check_free_space, ensure_writable_dir, remove_stale_temporaries
from ..errors import McrtError


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 that fits in 32 bits (seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^32), got {value}")
    return value


def output_stem(out: str | None, default: str) -> Path:
    """``-o OUT`` without a trailing image suffix (``OUT.exr`` and ``OUT.png`` get written)."""
    path = Path(out or default)
    if path.name in ("", ".", ".."):  # "/", ".", "out/..": no file name to add .exr to
        given = f"-o {out}" if out else f"output path {default}"
        raise McrtError(f"{given}: names a directory; give an output path such as "
                        f"{path / 'image'}")
    if path.suffix.lower() in (".exr", ".png"):
        path = path.with_suffix("")
    return path


def check_output_files(*paths: Path) -> None:
    """Fail early if an output path exists but cannot be replaced."""
    for path in paths:
        ensure_writable_dir(path.parent if str(path.parent) else Path("."))
        try:
            if path.exists() and (path.is_dir() or not os.access(path, os.W_OK)):
                raise McrtError(f"cannot overwrite {path}")
        except OSError as error:  # e.g. a file name too long for the file system
            raise McrtError(f"cannot write {path}: {error.strerror}") from None


def checkpoint_interval() -> float | None:
    """Seconds between the checkpoints of a running render: ``$MCRT_CHECKPOINT_SECONDS``
    (0: after every pass), by default paced to cost under 2% of the render time."""
    text = os.environ.get("MCRT_CHECKPOINT_SECONDS", "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise McrtError(f"MCRT_CHECKPOINT_SECONDS must be a number of seconds, got {text!r}")
    if not value >= 0:
        raise McrtError(f"MCRT_CHECKPOINT_SECONDS must be >= 0, got {text!r}")
    return value


#: Bytes the plots, tables and pages of `pattern`, `integrate` and `demo` need
#: at most besides their images (generous: a few PNG plots, a CSV, a page).
PLOTS_BYTES = 16 << 20


def require_space(directory: Path, needed: int, what: str = "the outputs") -> None:
    """Before any work: remove temporaries of killed writers in ``directory``,
    then refuse to start unless ``needed`` bytes are free there (one line)."""
    remove_stale_temporaries(directory)
    check_free_space(directory, needed, what)


def image_bytes(pixels: int, channels: int = 4) -> int:
    """Upper bound of an image file's size: float32 channels, uncompressed."""
    return pixels * channels * 4
