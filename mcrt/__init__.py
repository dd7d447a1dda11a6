"""mcrt: a distribution ray tracer for studying sampling, built on Mitsuba 3.

Importing the package activates the ``llvm_ad_rgb`` variant when none is active
(after checking that Dr.Jit has a usable libLLVM) and registers mcrt's plugins
(the samplers of :data:`mcrt.samplers.PLUGINS`: ``uniform_grid``, ``jittered``,
``poisson_disk``, ``sobol``, ``zsobol``, ``pointset``; integrators ``distribution``, ``adaptive``
and ``multisample``), so ``mi.load_dict({'type': 'jittered', ...})``
works right away.
Call :func:`register` again after switching variants; :func:`register_sampler`
brings in a user's sampler (docs/extending.md), :func:`register_integrand` a user's
integrand for ``mcrt integrate`` (docs/integrate.md).

The import is kept cheap (about what ``import mitsuba`` and ``set_variant``
cost): numpy, the adaptive renderer and the analysis modules are imported when
first used, not here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ._gc import collection_held_back
from ._platform import ensure_variant, initialise
from .errors import McrtError

if TYPE_CHECKING:
    import mitsuba as mi

from ._version import __version__  # noqa: E402,F401  (re-exported)

with collection_held_back():  # Mitsuba's and Dr.Jit's imports: ~10^5 new objects
    initialise()
    from . import samplers  # noqa: E402  (needs an active variant)
    from .render import distribution  # noqa: E402
    from .samplers import register_sampler  # noqa: E402


def _adaptive_integrator(props: mi.Properties) -> mi.Integrator:
    """Mitsuba's constructor for ``adaptive`` until the integrator is first used.

    The integrator module pulls in numpy and the adaptive renderer, so it is
    imported here, on the first ``{'type': 'adaptive'}``; its own ``register()``
    then replaces this constructor with the class (re-created for the active
    variant if that changed since it was imported).
    """
    from .render import adaptive_integrator

    adaptive_integrator.register()
    integrator: mi.Integrator = adaptive_integrator.AdaptiveIntegrator(props)
    return integrator


def _multisample_integrator(props: mi.Properties) -> mi.Integrator:
    """Mitsuba's constructor for ``multisample`` until it is first used (as
    :func:`_adaptive_integrator`: numpy is imported then, not here)."""
    from .render import multisample_integrator

    multisample_integrator.register()
    integrator: mi.Integrator = multisample_integrator.MultisampleIntegrator(props)
    return integrator


def register_integrand(name: str, function: Any, exact: float | None = None,
                       **options: Any) -> str:
    """Name a user's integrand ``f(x, y)`` for ``mcrt integrate NAME``: see
    :func:`mcrt.analysis.integrands.register_integrand` (imported on the first call, with
    numpy, which ``import mcrt`` does not import)."""
    from .analysis.integrands import register_integrand as register_user_integrand

    return register_user_integrand(name, function, exact, **options)


def register() -> None:
    """Register mcrt's plugins with the active Mitsuba variant."""
    import mitsuba as mi

    ensure_variant()
    samplers.register()
    distribution.register()
    mi.register_integrator("adaptive", _adaptive_integrator)
    mi.register_integrator("multisample", _multisample_integrator)


register()

__all__ = ["McrtError", "register", "register_integrand", "register_sampler", "samplers",
           "__version__"]
