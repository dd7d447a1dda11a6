"""The adaptive renderer's parameters, declared once.

Each field of :class:`AdaptiveSettings` is declared with :func:`param`: its
default, valid range and description. Everything else is derived from these
declarations through :data:`PARAMETERS`:

* :meth:`AdaptiveSettings.check` validates every value against its range;
* the ``adaptive`` integrator plugin parses its properties by each
  parameter's type and generates the parameter table of its docstring
  (:mod:`mcrt.render.adaptive_integrator`);
* ``mcrt render --adaptive`` derives its flags, help texts and defaults
  (:mod:`mcrt.cli._adaptive_args`);
* the parameter table of docs/adaptive.md is compared with them by the tests.
"""

from __future__ import annotations

import math
from dataclasses import Field, dataclass, field, fields
from typing import Any, TypeVar

from ...errors import McrtError

T = TypeVar("T", int, float)


@dataclass(frozen=True)
class Param:
    """One adaptive parameter: name, type, default, valid range, description."""

    name: str
    #: ``int`` or ``float`` (the type of the default).
    kind: type
    default: int | float
    #: Bounds of the valid range; None: unbounded (floats must be finite anyway).
    low: float | None
    high: float | None
    #: Whether ``low`` / ``high`` themselves are excluded (integers: never).
    low_open: bool
    high_open: bool
    #: One line, lower case, no final full stop (command-line help, the table of docs/adaptive.md).
    help: str
    #: More for the plugin's documentation (RST), or "".
    details: str
    #: Why the range is what it is, appended to the rule in error messages, or "".
    reason: str
    #: Whether ``mcrt render`` has a flag for it (``--name-with-dashes``).
    cli: bool

    @property
    def flag(self) -> str:
        """The command-line flag, e.g. ``--dark-floor``."""
        return "--" + self.name.replace("_", "-")

    def rule(self) -> str:
        """The valid range in words, e.g. ``a number >= 0``, ``a positive integer``."""
        low, high = _number(self.low), _number(self.high)
        if self.kind is int:
            if self.low == 1 and self.high is None:
                text = "a positive integer"
            elif self.high is None:
                text = f"an integer >= {low}"
            else:
                text = f"an integer in [{low}, {high}]"
        elif self.high is None:
            text = f"a number {'>' if self.low_open else '>='} {low}"
        else:
            text = (f"a number in {'(' if self.low_open else '['}{low}, "
                    f"{high}{')' if self.high_open else ']'}")
        return f"{text} ({self.reason})" if self.reason else text

    def valid(self, value: Any) -> bool:
        """Whether ``value`` has the parameter's type and lies in its range."""
        if isinstance(value, bool):
            return False
        if self.kind is int:
            if not isinstance(value, int):
                return False
        elif not (isinstance(value, (int, float)) and math.isfinite(value)):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)


def _number(value: float | None) -> str:
    return "" if value is None else f"{value:g}"


def param(default: T, help: str, *, low: float | None = None, high: float | None = None,
          low_open: bool = False, high_open: bool = False, details: str = "",
          reason: str = "", cli: bool = True) -> T:
    """Declare a field of :class:`AdaptiveSettings` (see :class:`Param`)."""
    spec = {"low": low, "high": high, "low_open": low_open, "high_open": high_open,
            "help": help, "details": details, "reason": reason, "cli": cli}
    return field(default=default, metadata={"param": spec})


@dataclass(frozen=True)
class AdaptiveSettings:
    """Parameters of an adaptive render (see :mod:`mcrt.render.adaptive`)."""

    threshold: float = param(
        0.05, "target relative standard error of a pixel's luminance", low=0.0,
        details="A pixel is done when ``z * se_Y <= threshold * max(Y, dark_floor * Ybar)``.")
    confidence: float = param(
        0.95, "confidence of the error bound", low=0.0, high=1.0, low_open=True,
        high_open=True,
        details="``z`` is its two-sided normal quantile (1.96 for 0.95).")
    dark_floor: float = param(
        0.3, "pixels darker than this times the image's mean luminance are judged against "
        "that level", low=0.0,
        details="That mean, ``Ybar``, clips each pixel at the 99th percentile (a small "
                "bright light does not set the level); black pixels thus stop too. 0.3 "
                "lies near the low end of where relMSE (eps = 0.01) measures absolute "
                "error, below 0.1: 0.25-1.4 ``Ybar`` on images whose ``Ybar`` is 0.07-0.4; "
                "0.1 spent samples on shadows that relMSE does not see (docs/adaptive.md).")
    min_spp: int = param(
        16, "samples of every pixel in the first pass", low=2,
        reason="a variance needs two samples",
        details="Rounded up to a count the sampler supports.")
    max_spp: int = param(
        1024, "per-pixel budget, NaN/Inf samples included; never exceeded", low=1,
        details="A nonzero ``spp`` argument of ``mi.render`` overrides it.")
    growth: float = param(
        1.5, "a pass multiplies an active pixel's sample count by about this factor",
        low=1.0, low_open=True,
        details="Batch sizes are rounded to counts the sampler supports.")
    dilation: int = param(
        1, "neighbours within this (Chebyshev) distance of a failing pixel are refined "
        "with it", low=0,
        details="They get its batch size, against false negatives: a feature that all of "
                "a pixel's samples missed is usually hit by a neighbour's.")
    subpixels: int = param(
        4, "sub-pixels per axis of the multi-level reconstruction", low=1, high=16,
        reason="finer grids take minutes to compile: 16 about 14 s, 64 over 12 minutes",
        details="``s``: samples are first averaged in ``s x s`` uniform sub-pixels, which "
                "are then filtered into the pixel with the film's filter.")
    max_lanes: int = param(
        1 << 22, "largest number of lanes traced in one kernel (memory bound)", low=1,
        cli=False)

    def check(self) -> AdaptiveSettings:
        """Raise :class:`McrtError` with a one-line message on invalid values."""
        for p in PARAMETERS:
            value = getattr(self, p.name)
            if not p.valid(value):
                raise _invalid(p.name, p.rule(), value)
        if self.max_spp < self.min_spp:
            raise _invalid("max_spp", f">= min_spp ({self.min_spp})", self.max_spp)
        return self

    @property
    def z(self) -> float:
        """Two-sided normal quantile of :attr:`confidence`."""
        from statistics import NormalDist  # (imported when first needed)

        return NormalDist().inv_cdf(0.5 + 0.5 * self.confidence)


def _invalid(name: str, rule: str, value: Any) -> McrtError:
    return McrtError(f"adaptive: '{name}' must be {rule}, got {value!r}")


def _parameter(f: Field) -> Param:
    default = f.default
    if not isinstance(default, (int, float)) or f.type != type(default).__name__:
        # (annotations are strings: postponed evaluation)
        raise TypeError(f"AdaptiveSettings.{f.name}: annotated {f.type}, default {default!r}")
    return Param(name=f.name, kind=type(default), default=default, **f.metadata["param"])


#: The parameters, in declaration order.
PARAMETERS: tuple[Param, ...] = tuple(_parameter(f) for f in fields(AdaptiveSettings))

#: The parameters by name.
PARAMETERS_BY_NAME: dict[str, Param] = {p.name: p for p in PARAMETERS}


__all__ = ["PARAMETERS", "PARAMETERS_BY_NAME", "AdaptiveSettings", "Param", "param"]
