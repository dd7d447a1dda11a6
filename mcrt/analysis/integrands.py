"""The integrands of the integration bench (:mod:`.integrate`): mcrt's and a user's own.

An :class:`Integrand` is a function ``f(x, y)`` on the unit square, vectorised (numpy
float64 arrays of one shape in, an array of that shape out), and its integral ``exact``.
mcrt's (:data:`INTEGRANDS`, described in :mod:`.integrate`) have exact values. A user's
comes from :func:`make_integrand`, or gets a name for ``mcrt integrate NAME`` from
:func:`register_integrand` (``mcrt.register_integrand`` in a plugin file, see
:mod:`mcrt.plugins`); the bench takes either, :func:`integrand` resolving a name.

A user's function is tried on a few points inside the square when it is made: an
exception, a result of another shape, values that are not real numbers or not finite are
each a one-line :class:`IntegrandError` naming the integrand. A function of Python numbers
(``math.exp``, ``if x < y``) fails on arrays and is refused, or with ``vectorize=True``
wrapped in ``np.vectorize`` (one Python call per point: ~100x slower). Every evaluation in
the bench is checked the same way (a value that is not finite names its point).

Estimated exact values
======================

Without a known value, ``exact`` is estimated once: the mean of :data:`EXACT_SCRAMBLES`
independent randomisations of a scrambled Sobol' net of ``2^EXACT_LOG2_POINTS`` points
(``scipy.stats.qmc.Sobol``, linear matrix scrambling and a digital shift on 64 bits; its
default 30 bits put every point on the lower corner of a 2^-30 cell, which biased the
estimate of ``exp(-x y)`` by 3e-10, over 3000 of its standard errors), with the standard error
``s = sd / sqrt(16)`` of their spread. Each randomisation is an unbiased estimate, so
``(estimate - I) / s`` is about Student's t on 15 degrees of freedom (at 2^8 points, the
95% interval covered the truth in 98%, 95% and 95% of 1000 repetitions for ``exp(-x y)``,
the disk and the quarter disc).

The bench measures its errors against the estimate, whose own error ``d`` every trial
shares, so the expected MSE is the true one plus ``s^2`` (over ``d``): ``s^2`` is the
*floor* that each MSE has subtracted before the slope fit, as a study subtracts its
reference's noise floor (:func:`~mcrt.analysis.metrics.mse_excess`); an MSE below
:data:`~mcrt.analysis.metrics.RESOLVED_FACTOR` x the floor is beyond what the estimate
resolves: flagged unresolved and left out of the fit. A known exact value has no floor.
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
import os
import traceback
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ArgumentError, McrtError
from ..samplers import registry

log = logging.getLogger(__name__)

#: ``f(x, y)``: float64 arrays of one shape in, an array of that shape out.
Function = Callable[[np.ndarray, np.ndarray], Any]

#: Independent randomisations of the estimate of an unknown exact value.
EXACT_SCRAMBLES = 16
#: Points of each randomisation: ``2^EXACT_LOG2_POINTS`` (about 0.2 s for ``exp(-x y)``).
EXACT_LOG2_POINTS = 20

#: Where a user's function is first tried: points inside the square, none on its edges
#: (where an integrable singularity such as ``1 / sqrt(x)`` may be infinite), shape (2, 3).
_PROBE = (np.array([[0.125, 0.5, 0.875], [0.3, 0.7, 0.45]]),
          np.array([[0.25, 0.625, 0.9], [0.8, 0.15, 0.55]]))


class IntegrandError(ArgumentError):
    """A user's integrand cannot be used: one line naming it."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


@dataclass(frozen=True)
class Integrand:
    """A function on the unit square and its integral (see the module docstring)."""

    name: str
    description: str
    exact: float
    function: Function
    #: The standard error of ``exact`` when it was estimated (0: known), and how it was.
    exact_error: float = 0.0
    exact_method: str = ""

    @property
    def floor(self) -> float:
        """``exact_error^2``: what the estimated exact value's own error adds to an MSE."""
        return self.exact_error ** 2

    def evaluate(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``f(x, y)`` as float64; an :class:`IntegrandError` naming the integrand if
        ``f`` raises or returns another shape or values that are not real numbers."""
        try:
            values = np.asarray(self.function(x, y))
        except MemoryError:
            raise
        except Exception as error:  # noqa: BLE001 - a user's function: any failure, one line
            raise IntegrandError(f"integrand {self.name}: {_raised(error)}") from None
        if values.shape != np.shape(x):
            raise IntegrandError(f"integrand {self.name}: f(x, y) returned shape {values.shape} "
                                 f"for x and y of shape {np.shape(x)}: it must return one value "
                                 f"per point (a constant c: np.full_like(x, c))")
        if values.dtype.kind not in "biuf":
            raise IntegrandError(f"integrand {self.name}: f(x, y) returned {values.dtype} "
                                 f"values, not real numbers")
        return values.astype(np.float64, copy=False)

    def estimates(self, points: np.ndarray) -> np.ndarray:
        """Per-trial estimates ``mean_j f(x_j)`` of points ``(P, N, 2)`` -> ``(P,)``."""
        x = points[..., 0].astype(np.float64)
        y = points[..., 1].astype(np.float64)
        values = self.evaluate(x, y)
        means = np.mean(values, axis=-1)
        if not np.isfinite(means).all():
            raise IntegrandError(self._not_finite(x, y, values))
        return means

    def _not_finite(self, x: np.ndarray, y: np.ndarray, values: np.ndarray) -> str:
        bad = ~np.isfinite(values)
        if not bad.any():
            return (f"integrand {self.name}: the mean of its values overflows float64 "
                    f"(|f| up to {float(np.max(np.abs(values))):.3g})")
        at = tuple(np.argwhere(bad)[0])
        return (f"integrand {self.name}: f({float(x[at])!r}, {float(y[at])!r}) = "
                f"{float(values[at])!r} ({np.count_nonzero(bad)} of {values.size} values are "
                f"not finite); an integrand must be finite on [0, 1)^2")


def _raised(error: BaseException) -> str:
    """``f(x, y) raised Type: message (file, line N)``: the last frame of the user's code."""
    ours = str(Path(__file__).resolve().parent.parent)
    frames = traceback.extract_tb(error.__traceback__)
    frame = next((f for f in reversed(frames) if not f.filename.startswith(ours)
                  and f"{os.sep}numpy{os.sep}" not in f.filename), None)
    where = f" ({frame.filename}, line {frame.lineno})" if frame is not None else ""
    return f"f(x, y) raised {type(error).__name__}: {error}".rstrip(": ") + where


# --------------------------------------------------------------------------- mcrt's integrands


def _quarter_disc(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.where(x * x + y * y <= 1.0, 4.0, 0.0)


DISK_CENTRE = (0.5, 0.5)
DISK_RADIUS = 0.4


def _disk(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    dx, dy = x - DISK_CENTRE[0], y - DISK_CENTRE[1]
    return (dx * dx + dy * dy <= DISK_RADIUS ** 2).astype(np.float64)


GAUSSIAN_SIGMA = 0.2


def _gaussian(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2) / (2.0 * GAUSSIAN_SIGMA ** 2))


def _gaussian_integral(sigma: float) -> float:
    one_d = sigma * math.sqrt(2.0 * math.pi) * math.erf(0.5 / (math.sqrt(2.0) * sigma))
    return one_d * one_d


INTEGRANDS: dict[str, Integrand] = {
    "pi": Integrand("pi", "4 x indicator of the quarter disc x^2 + y^2 <= 1 (estimates pi)",
                    math.pi, _quarter_disc),
    "disk": Integrand("disk", f"indicator of the disc r = {DISK_RADIUS} around {DISK_CENTRE}",
                      math.pi * DISK_RADIUS ** 2, _disk),
    "gaussian": Integrand("gaussian", f"exp(-|x - c|^2 / (2 s^2)), c = (0.5, 0.5), "
                          f"s = {GAUSSIAN_SIGMA}", _gaussian_integral(GAUSSIAN_SIGMA), _gaussian),
}


# --------------------------------------------------------------------------- users' integrands


def estimate_exact(integrand: Integrand, seed: int = 0, scrambles: int = EXACT_SCRAMBLES,
                   log2_points: int = EXACT_LOG2_POINTS) -> tuple[float, float]:
    """The integral of ``integrand``'s function and its standard error, from ``scrambles``
    randomisations of a scrambled Sobol' net of ``2^log2_points`` points (module docstring)."""
    from scipy.stats import qmc

    rng = np.random.default_rng(seed)
    means = np.empty(scrambles)
    below_one = np.nextafter(1.0, 0.0)  # 64-bit points rounded to float64 may reach 1
    for r in range(scrambles):
        points = qmc.Sobol(2, scramble=True, bits=64, seed=rng).random_base2(log2_points)
        blocks = np.minimum(points, below_one).reshape(-1, min(1024, len(points)), 2)
        means[r] = np.mean(integrand.estimates(blocks))
    return float(np.mean(means)), float(np.std(means, ddof=1) / math.sqrt(scrambles))


def make_integrand(function: Function, exact: float | None = None, *, name: str | None = None,
                   description: str = "", vectorize: bool = False, seed: int = 0) -> Integrand:
    """An :class:`Integrand` of a user's ``function`` ``f(x, y)``, checked (see the module
    docstring). ``exact``: its integral over the unit square, or None to estimate it now
    (:func:`estimate_exact` with ``seed``; its standard error in ``exact_error``).
    ``name`` defaults to the function's; ``description`` to its docstring's first line."""
    if name is None:
        name = getattr(function, "__name__", "")
    return _prepare(name, function, exact, description, vectorize, seed)()


def _prepare(name: str, function: Function | Integrand, exact: float | None, description: str,
             vectorize: bool, seed: int) -> Callable[[], Integrand]:
    """Check a user's integrand now; what makes it, estimating an unknown exact value
    on the first call (then cached)."""
    if not (isinstance(name, str) and name.isidentifier()):
        raise IntegrandError(f"integrand name {name!r}: use letters, digits and '_' "
                             f"(a lambda needs name=...)")
    if isinstance(function, Integrand):
        if exact is not None:
            raise IntegrandError(f"integrand {name}: an Integrand states its exact value; "
                                 f"give exact= with a function")
        given = replace(function, name=name, description=description or function.description)
        return lambda: given
    checked = _checked(function, name, vectorize)
    description = description or _describe(function)
    if exact is not None:
        if isinstance(exact, bool) or not isinstance(exact, numbers.Real) \
                or not math.isfinite(exact):
            raise IntegrandError(f"integrand {name}: exact must be a finite number, got "
                                 f"{exact!r}")
        made = Integrand(name, description, float(exact), checked)
        return lambda: made

    @functools.cache
    def estimated() -> Integrand:
        value, error = estimate_exact(Integrand(name, description, math.nan, checked), seed)
        method = (f"estimated: mean of {EXACT_SCRAMBLES} scrambled Sobol' nets of "
                  f"2^{EXACT_LOG2_POINTS} points (seed {seed}), standard error from their spread")
        return Integrand(name, description, value, checked, error, method)
    return estimated


def _checked(function: Any, name: str, vectorize: bool) -> Function:
    """``function`` (wrapped in ``np.vectorize`` with ``vectorize``) once it gives finite
    float values of the right shape on :data:`_PROBE`; else a one-line IntegrandError."""
    if not callable(function):
        raise IntegrandError(f"integrand {name}: {function!r} is not a function f(x, y)")
    if vectorize:
        log.warning("integrand %s: vectorize=True calls f once per point (np.vectorize, "
                    "~100x slower than numpy): the bench evaluates millions of points", name)
        function = np.vectorize(function, otypes=[np.float64])
    probe = Integrand(name, "", 0.0, function)
    try:
        values = probe.evaluate(*(a.copy() for a in _PROBE))
    except IntegrandError as error:
        if not vectorize and _takes_numbers(function):
            raise IntegrandError(f"{error}; on single numbers it works: it is not vectorised. "
                                 f"Write it with numpy (np.exp, np.where, ...) or pass "
                                 f"vectorize=True (np.vectorize, ~100x slower)") from None
        raise
    if not np.isfinite(values).all():
        raise IntegrandError(probe._not_finite(*_PROBE, values))
    return function


def _takes_numbers(function: Callable[..., Any]) -> bool:
    """Whether ``function(0.5, 0.25)`` returns one real number."""
    try:
        value = function(0.5, 0.25)
        return np.ndim(value) == 0 and np.asarray(value).dtype.kind in "biuf"
    except Exception:  # noqa: BLE001 - any failure: it does not
        return False


def _describe(function: Any) -> str:
    """The first line of the function's docstring, else its name and module."""
    lines = [line.strip() for line in (getattr(function, "__doc__", "") or "").splitlines()
             if line.strip()]
    if lines:
        return lines[0]
    return (f"{getattr(function, '__qualname__', type(function).__name__)} "
            f"(from {getattr(function, '__module__', '?')})")


@dataclass(frozen=True)
class _Registered:
    #: The plugin file or entry point that registered it ("": Python code outside one).
    origin: str
    make: Callable[[], Integrand]


#: Users' integrands by name, in registration order.
_REGISTERED: dict[str, _Registered] = {}


def register_integrand(name: str, function: Function | Integrand, exact: float | None = None, *,
                       description: str = "", vectorize: bool = False, seed: int = 0) -> str:
    """Name a user's integrand (a function, as :func:`make_integrand` takes, or an
    :class:`Integrand`) for ``mcrt integrate NAME`` and the bench; returns the name.
    The function is checked now; an unknown exact value is estimated when the integrand
    is first used. A plugin may not take a name another plugin registered; registering
    a name again replaces it otherwise."""
    if name in INTEGRANDS:
        raise IntegrandError(f"integrand name {name!r} is taken by mcrt's {name}")
    origin = registry.default_origin()
    taken = _REGISTERED.get(name)
    if taken is not None and taken.origin and taken.origin != origin:
        raise IntegrandError(f"integrand name {name!r} is taken: {taken.origin} registered "
                             f"it already")
    make = _prepare(name, function, exact, description, vectorize, seed)
    _REGISTERED[name] = _Registered(registry.note_beside("integrand", name, _forget), make)
    return name


def unregister_integrand(name: str) -> None:
    """Remove a user's integrand."""
    if _REGISTERED.pop(name, None) is None:
        raise IntegrandError(f"unregister_integrand: {name!r} is not a user's integrand")


def _forget(origin: str) -> None:
    for name in [n for n, entry in _REGISTERED.items() if entry.origin == origin]:
        del _REGISTERED[name]


def integrand_names() -> tuple[str, ...]:
    """mcrt's integrands, then users' registered ones."""
    return (*INTEGRANDS, *_REGISTERED)


def integrand(spec: str | Integrand) -> Integrand:
    """The integrand ``spec`` names (mcrt's, then the registered ones), or ``spec`` itself
    if it is an :class:`Integrand`; a one-line McrtError otherwise."""
    if isinstance(spec, Integrand):
        if isinstance(spec.exact, bool) or not isinstance(spec.exact, numbers.Real) \
                or not math.isfinite(spec.exact):
            raise IntegrandError(f"integrand {spec.name}: exact is {spec.exact!r}, not a finite "
                                 f"number (make_integrand(f) estimates an unknown one)")
        return spec
    if isinstance(spec, str):
        if spec in INTEGRANDS:
            return INTEGRANDS[spec]
        if spec in _REGISTERED:
            return _REGISTERED[spec].make()
        raise McrtError(f"unknown integrand {spec!r}; choose one of: "
                        f"{', '.join(integrand_names())}")
    if callable(spec):
        raise IntegrandError(f"{spec!r} is a function: give a name or an Integrand, e.g. "
                             f"make_integrand(f, exact=...) (mcrt.analysis.integrands)")
    raise IntegrandError(f"an integrand is a name or an Integrand, not {type(spec).__name__}")
