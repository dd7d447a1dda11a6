"""Numbers from ``MCRT_*`` environment variables, checked: a bad value is a
one-line error naming the variable, not a traceback from ``float()``."""

from __future__ import annotations

import os

from ..errors import McrtError


def env_number(name: str, default: float, *, integer: bool = False,
               positive: bool = False) -> float:
    """``$name`` as a number (``default`` when unset or empty): an integer if
    ``integer``; > 0 if ``positive``, else >= 0."""
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value: float = int(text) if integer else float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 if positive else value >= 0) or value == float("inf"):
        kind = "an integer" if integer else "a number"
        raise McrtError(f"${name} must be {kind} {'> 0' if positive else '>= 0'}, got {text!r}")
    return value


__all__ = ["env_number"]
