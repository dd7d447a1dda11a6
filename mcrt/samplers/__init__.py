"""Sampler plugins for Mitsuba 3, written in Dr.Jit.

=================  ===========================================================
``uniform_grid``   regular k x k sub-pixel grid (cell centres on the film; other
                   dimensions the same lattice, randomly shifted per pixel)
``jittered``       the same strata with a jitter amount in [0, 1]
``poisson_disk``   per-pixel blue-noise point sets (toroidal min distance
                   >= 0.75 d_hex), 1D dimensions stratified
``sobol``          progressive, padded, Owen-scrambled Sobol' (0,2)-sequences
``zsobol``         Morton-ordered, digit-permuted Sobol': blue-noise error over
                   the screen (needs the film ``width``)
=================  ===========================================================

``register()`` makes them available to ``mi.load_dict`` / ``mi.load_file`` for
the active variant (``import mcrt`` does it once).
"""

from __future__ import annotations

import importlib

import mitsuba as mi

from . import base, jittered, poisson_disk, sobol, zsobol
from .base import McrtSampler
from .jittered import JitteredSampler, UniformGridSampler
from .poisson_disk import PoissonDiskSampler
from .sobol import SobolSampler
from .zsobol import ZSobolSampler

#: Variant whose ``mi.Sampler`` the plugin classes currently derive from.
_classes_variant = mi.variant()

#: mcrt's sampler plugins by Mitsuba plugin name.
PLUGINS: dict[str, type[McrtSampler]] = {
    cls.plugin_name: cls for cls in (UniformGridSampler, JitteredSampler, PoissonDiskSampler,
                                     SobolSampler, ZSobolSampler)
}

#: Mitsuba's built-in samplers that mcrt compares against.
BUILTIN_SAMPLERS: tuple[str, ...] = ("independent", "stratified", "multijitter", "orthogonal",
                                     "ldsampler")

#: Every sampler name the command-line tools accept.
ALL_SAMPLERS: tuple[str, ...] = tuple(PLUGINS) + BUILTIN_SAMPLERS


def _redefine_classes() -> None:
    """Re-import the plugin modules so their classes derive from the active
    variant's ``mi.Sampler`` (a Python class cannot change its C++ base)."""
    global _classes_variant, McrtSampler, JitteredSampler, UniformGridSampler, PoissonDiskSampler
    global SobolSampler, ZSobolSampler
    for module in (base, jittered, poisson_disk, sobol, zsobol):
        importlib.reload(module)
    # Rebinding a class name is what this function is for; mypy forbids it in general.
    McrtSampler = base.McrtSampler  # type: ignore[misc]
    JitteredSampler = jittered.JitteredSampler  # type: ignore[misc]
    UniformGridSampler = jittered.UniformGridSampler  # type: ignore[misc]
    PoissonDiskSampler = poisson_disk.PoissonDiskSampler  # type: ignore[misc]
    SobolSampler = sobol.SobolSampler  # type: ignore[misc]
    ZSobolSampler = zsobol.ZSobolSampler  # type: ignore[misc]
    PLUGINS.clear()
    PLUGINS.update({cls.plugin_name: cls
                    for cls in (UniformGridSampler, JitteredSampler, PoissonDiskSampler,
                                SobolSampler, ZSobolSampler)})
    _classes_variant = mi.variant()


def register() -> None:
    """Register mcrt's sampler plugins with the active Mitsuba variant."""
    if mi.variant() != _classes_variant:
        _redefine_classes()
    for name, cls in PLUGINS.items():
        mi.register_sampler(name, lambda props, cls=cls: cls(props))


__all__ = ["ALL_SAMPLERS", "BUILTIN_SAMPLERS", "PLUGINS", "JitteredSampler", "McrtSampler",
           "PoissonDiskSampler", "SobolSampler", "UniformGridSampler", "ZSobolSampler",
           "register"]
