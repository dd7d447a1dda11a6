"""mcrt: a distribution ray tracer for studying sampling, built on Mitsuba 3.

Importing the package activates the ``llvm_ad_rgb`` variant when none is active
(after checking that Dr.Jit has a usable libLLVM) and registers mcrt's plugins
(samplers ``uniform_grid``, ``jittered``, ``poisson_disk``; integrators
``distribution`` and ``adaptive``), so ``mi.load_dict({'type': 'jittered', ...})``
works right away.
Call :func:`register` again after switching variants.
"""

from __future__ import annotations

from ._platform import ensure_variant, initialise
from .errors import McrtError

__version__ = "0.1.0"

initialise()

from . import samplers  # noqa: E402  (needs an active variant)
from .render import adaptive_integrator, distribution  # noqa: E402


def register() -> None:
    """Register mcrt's plugins with the active Mitsuba variant."""
    ensure_variant()
    samplers.register()
    distribution.register()
    adaptive_integrator.register()


register()

__all__ = ["McrtError", "register", "samplers", "__version__"]
