"""JSON files every parser reads: NaN and infinities written as ``null``.

Python's :mod:`json` writes ``NaN`` and ``Infinity``, which are not JSON:
``jq``, JavaScript's ``JSON.parse`` and most other readers reject the file.
A statistic with no value (a slope of one point, the spectrum of N = 1) is
``null`` instead.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path


def json_safe(value: Any) -> Any:
    """JSON-ready copy: NaN/Inf -> None, numpy scalars -> Python, tuples -> lists,
    paths -> strings (dictionary keys -> strings)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | os.PathLike[str], data: Any, indent: int = 2) -> None:
    """Write ``json_safe(data)`` to ``path`` atomically, with a final newline."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        json.dump(json_safe(data), f, indent=indent, allow_nan=False)
        f.write("\n")


__all__ = ["json_safe", "write_json"]
