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
