"""Numbers and switches from ``MCRT_*`` environment variables, checked: a bad
value is a one-line error naming the variable, not a traceback from ``float()``
or a value silently taken for the default."""

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


#: The spellings a switch (:func:`env_switch`) accepts, in any case.
SWITCH_ON = ("1", "on", "true", "yes")
SWITCH_OFF = ("0", "off", "false", "no")


def env_switch(name: str, default: bool) -> bool:
    """``$name`` as on/off (``default`` when unset or empty): ``1``, ``on``,
    ``true``, ``yes`` or ``0``, ``off``, ``false``, ``no``, in any case."""
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    if text.lower() in SWITCH_ON:
        return True
    if text.lower() in SWITCH_OFF:
        return False
    raise McrtError(f"${name} must be 1 or 0 (also on/off, true/false, yes/no), got {text!r}")


__all__ = ["SWITCH_OFF", "SWITCH_ON", "env_number", "env_switch"]
