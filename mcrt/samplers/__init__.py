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
``pointset``       a user's point sets from a file (``filename``), randomised
                   per pixel and dimension
=================  ===========================================================

Every sampler name, ours, Mitsuba's and users', lives in one registry
(:mod:`.registry`); ``register()`` makes them available to ``mi.load_dict`` /
``mi.load_file`` for the active variant (``import mcrt`` does it once).
:func:`register_sampler` brings a user's sampler in.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..errors import SamplerError
from . import registry
from .registry import names

if TYPE_CHECKING:  # looked up when asked for (below): a variant switch re-creates it
    from .base import McrtSampler as McrtSampler

#: Mitsuba's built-in samplers that mcrt compares against.
BUILTIN_SAMPLERS: tuple[str, ...] = tuple(registry.MITSUBA_SAMPLERS)

#: Class names this package exports, by module (the classes are re-created
#: after a variant switch, so they are looked up when asked for).
_CLASS_MODULES = {"McrtSampler": "base", "JitteredSampler": "jittered",
                  "UniformGridSampler": "jittered",
                  "PoissonDiskSampler": "poisson_disk", "SobolSampler": "sobol",
                  "ZSobolSampler": "zsobol", "PointSetSampler": "pointset"}


def register() -> None:
    """Register every sampler of the registry with the active Mitsuba variant."""
    registry.register_with_mitsuba()


def standalone_names() -> tuple[str, ...]:
    """The registered samplers that need no parameters (all but ``pointset``)."""
    return tuple(n for n in names() if n != "pointset")


def __getattr__(name: str) -> Any:
    if name == "PLUGINS":  # mcrt's plugin classes by name, for the active variant
        return {n: registry.current_class(n) for n in names("mcrt")}
    if name == "ALL_SAMPLERS":  # every name that renders without parameters
        return standalone_names()
    if name in _CLASS_MODULES:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_CLASS_MODULES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register_sampler(name: str, sampler: type | None = None, *, points=None,
                     file: str | None = None, sets: int | None = None, seed: int = 0,
                     randomize: str = "symmetry", claims=(), origin: str = "") -> str:
    """Bring a sampler into mcrt under ``name``; returns the name.

    Exactly one of:

    * ``sampler``: a ``mi.Sampler`` subclass (usually of :class:`McrtSampler`);
    * ``points``: a function ``fn(count, n, rng)`` returning ``count`` sets of
      ``n`` points in [0, 1)^2 as a numpy array ``(count, n, 2)``; mcrt asks
      for ``sets`` sets (default 256) per sample count, caches them, and serves
      them as the ``pointset`` plugin does;
    * ``file``: a point-set file, as the ``pointset`` plugin's ``filename``.

    ``randomize`` chooses the ``pointset`` randomisation, ``claims`` what the
    points promise (keys of :data:`registry.CLAIMS`, checked by ``mcrt check``).

    Example::

        >>> import mcrt, numpy as np
        >>> mcrt.register_sampler("iid", points=lambda count, n, rng: rng.random((count, n, 2)))
        'iid'
    """
    from .user_points import points_class

    if not isinstance(name, str) or not name:
        raise SamplerError(f"register_sampler: the name must be a non-empty string, got {name!r}")
    if isinstance(claims, str):
        raise SamplerError(f"register_sampler: claims is a collection of names, e.g. "
                           f"claims=({claims!r},), not the string {claims!r}")
    given = [x is not None for x in (sampler, points, file)]
    if sum(given) != 1:
        raise SamplerError("register_sampler: give exactly one of sampler=, points= "
                                    "or file=")
    if sampler is not None:
        return registry.register_class(sampler, name, origin=origin)
    return points_class(name, points=points, file=file, sets=sets, seed=seed,
                        randomize=randomize, claims=frozenset(claims), origin=origin)


__all__ = ["ALL_SAMPLERS", "BUILTIN_SAMPLERS", "PLUGINS", "names",
           "register", "register_sampler", "registry", "standalone_names",
           *_CLASS_MODULES]
