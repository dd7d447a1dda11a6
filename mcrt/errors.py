"""Exceptions whose message is meant for the user, not a traceback."""

from __future__ import annotations


class McrtError(Exception):
    """An error caused by the user's input or environment.

    The command-line interface prints ``mcrt: error: <message>`` on one line and
    exits with status 2 instead of showing a traceback.
    """


class SetupError(McrtError):
    """The machine lacks something mcrt needs (e.g. a usable libLLVM)."""


class SceneError(McrtError):
    """A scene file is missing, malformed, or names an unknown plugin."""


class SamplerError(McrtError):
    """A sampler was asked for something it cannot do correctly."""


class ArgumentError(McrtError, ValueError):
    """A Python caller passed an argument mcrt cannot use (a ``ValueError`` too)."""


class ArgumentTypeError(ArgumentError, TypeError):
    """A Python caller passed an argument of the wrong type (a ``TypeError`` too)."""


def whole_number(value: object, what: str, low: int = 1, high: int | None = None) -> int:
    """``value`` as an int if it is a whole number in ``[low, high)`` (a Python or
    numpy integer, or a float with no fraction such as ``1e3``), else a one-line
    :class:`ArgumentError` naming ``what``: ``int()`` would silently turn 4.5
    samples per pixel into 4 and a seed of 1.5 into 1."""
    import numbers

    top = "2^32" if high == 2 ** 32 else str(high)
    span = f">= {low}" if high is None else f"in [{low}, {top})"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ArgumentTypeError(f"{what} must be an integer {span}, got {value!r} "
                                f"({type(value).__name__})")
    if isinstance(value, numbers.Integral):
        number = int(value)
    elif float(value).is_integer():
        number = int(float(value))
    else:
        raise ArgumentError(f"{what} must be an integer {span}, got {value!r}")
    if number < low or (high is not None and number >= high):
        raise ArgumentError(f"{what} must be an integer {span}, got {number}")
    return number
