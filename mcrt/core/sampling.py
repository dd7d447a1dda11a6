"""The seed route: how every render gets its sampler and its seed.

A render's bits are a function of (scene content, sampler name and parameters,
samples per pixel, seed, variant, plan), whichever way it was asked for: the
scene's own sampler, ``--sampler``, a study cell, the Python API or the
``adaptive`` plugin. So there is exactly one place a seed enters a render: the
engine's ``sampler.seed(seed, lanes)`` (:func:`~mcrt.core.engine.run_passes`).
Samplers are created here *without* a ``seed`` property (Mitsuba's and mcrt's
samplers add that property to the seed they are given, which made
``--sampler X --seed S`` differ from the scene's own ``X`` seeded with ``S``).
"""

from __future__ import annotations

import difflib
import logging
import re
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import mitsuba as mi

from ..errors import ArgumentTypeError, SamplerError, whole_number
from ..samplers import registry
from ..samplers.registry import names

#: Plugin properties that are the render's settings, never sampler parameters,
#: with the option that sets them.
RENDER_SETTINGS = {"type": "--sampler", "sample_count": "--spp", "seed": "--seed"}


def raise_if_interrupted(error: BaseException) -> None:
    """Raise :class:`KeyboardInterrupt` if ``error`` wraps one: a Ctrl-C (or a
    termination signal, :func:`~mcrt.core.engine.termination_as_interrupt`)
    that arrived in Python code Mitsuba or Dr.Jit called. Mitsuba turns it into
    a ``RuntimeError`` whose traceback text ends in ``KeyboardInterrupt`` (a
    plugin's construction), Dr.Jit into one caused by it (a ``dr.while_loop``
    body it traces); a handler of plugin errors would report, or swallow, it as
    the plugin's fault."""
    seen: set[int] = set()
    cause: BaseException | None = error
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            raise KeyboardInterrupt from error
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    lines = str(error).strip().splitlines()
    if lines and lines[-1].strip().startswith("KeyboardInterrupt"):
        raise KeyboardInterrupt from error


def mitsuba_message(error: BaseException) -> str:
    """One line from a Mitsuba exception: no ``[file.cpp:123]`` prefix, and for
    errors raised inside Python plugins, the final ``Type: message`` line. A
    wrapped Ctrl-C is raised again instead (:func:`raise_if_interrupted`)."""
    raise_if_interrupted(error)
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    if not lines:
        return type(error).__name__
    if len(lines) > 1 and "Traceback" in str(error):
        line = lines[-1]
    elif lines[0].endswith(":"):  # a heading followed by a list, e.g. unused parameters
        line = lines[0] + " " + ", ".join(item.lstrip("- ") for item in lines[1:])
    else:
        line = lines[0]
    line = re.sub(r"^\[[\w./-]+:\d+\]\s*", "", line)
    return re.sub(r"^(?:\w+\.)*(?:SamplerError|SceneError|McrtError):\s*", "", line)


def check_sampler_name(name: str) -> str:
    """Return ``name`` if mcrt can render with that sampler, else raise.

    A name mcrt does not know yet first has the installed packages' samplers
    and ``$MCRT_PLUGINS`` loaded (:func:`mcrt.plugins.autoload`, once)."""
    if not isinstance(name, str):
        what = ("a sampler object: pass its name, e.g. sampler_name(sampler)"
                if isinstance(name, mi.Sampler) else f"{name!r} ({type(name).__name__})")
        raise ArgumentTypeError(f"a sampler name (a string such as 'jittered') is needed here, "
                                f"got {what}")
    known = names()
    if name not in known:
        from .. import plugins

        plugins.autoload()
        known = names()
        if name in known:
            return name
        why = plugins.unavailable(name)
        if why:
            raise SamplerError(why)
        raise SamplerError(f"unknown sampler {name!r}{did_you_mean(name, known)}; "
                           f"choose one of: {', '.join(known)} (or load yours with --plugin)")
    return name


def sampler_fingerprint(name: str, params: dict[str, Any] | None = None) -> str:
    """What identifies a user's sampler besides its name and parameters: a digest
    of its code or generator (:attr:`SamplerInfo.fingerprint`) and of a point file
    its ``filename`` parameter names; "" for mcrt's and Mitsuba's samplers (the
    versions in every key cover them). Results keyed with it are not resumed or
    reused after the plugin or the point file changed."""
    from ..samplers import registry
    from ..samplers.point_sources import file_digest

    parts = []
    if name in registry.names():
        parts.append(registry.info(name).fingerprint)
    filename = (params or {}).get("filename")
    if filename:
        parts.append(file_digest(str(filename)))
    return "/".join(p for p in parts if p)


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the choice closest to a mistyped ``name``
    (case and spaces aside), or ``""`` when none is close."""
    choices = list(choices)
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    close = difflib.get_close_matches(key, choices, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def make_sampler(name: str, spp: int, base_seed: int = 0, **params: Any) -> mi.Sampler:
    """Instantiate sampler plugin ``name`` with ``spp`` samples per pixel and
    plugin ``params`` (never a seed: the render gives it, see the module doc;
    ``base_seed`` is the plugin's own ``seed`` property, which a scene may author:
    :func:`base_seed` of a sampler object makes the same sampler again)."""
    check_sampler_name(name)
    for key, option in RENDER_SETTINGS.items():
        if key in params:
            raise SamplerError(f"{name}: the {key} is a setting of the render ({option}), not a "
                               f"sampler parameter")
    spp = whole_number(spp, f"{name}: the samples per pixel")
    own = {"seed": int(base_seed)} if base_seed else {}
    try:
        sampler = mi.load_dict({"type": name, "sample_count": spp, **own, **params})
    except Exception as error:
        message = mitsuba_message(error)
        if "not found" in message and registry.variant_hint():
            message = registry.variant_hint()
        raise SamplerError(f"cannot create sampler {name!r}: {message}") from None
    lost = sorted(set(params) - set(sampler_params(sampler)))
    if lost and registry.info(name).kind == "user":  # its fork() and clone() lose them too
        raise SamplerError(f"{name}: its _parameters() does not return {', '.join(lost)}, so a "
                           f"render elsewhere (a Dask worker, --from) would drop it: return "
                           f"every parameter it reads from props")
    return sampler


def describe(sampler: mi.Sampler) -> str:
    """``str(sampler)``, or "" for a Python ``mi.Sampler`` subclass without a
    ``to_string()``: nanobind's trampoline then raises RuntimeError (``lookup
    failed``) instead of falling back to the base class's description."""
    try:
        return str(sampler)
    except RuntimeError:
        return ""


def base_seed(sampler: mi.Sampler) -> int:
    """The ``seed`` property a sampler object was made with (mcrt's samplers, and
    Mitsuba's that print it); 0 when it cannot be read."""
    own = getattr(sampler, "_base_seed", None)
    if own is not None:
        return int(own)
    found = re.search(r"base_seed = (\d+)", describe(sampler))
    return int(found.group(1)) if found else 0


def bind_film_width(sampler: mi.Sampler, width: int) -> None:
    """Tell a sampler that needs the film size (``zsobol``: its ``width``
    property) the width of the pixel grid it is about to render; other samplers
    are left alone. Called wherever mcrt seeds a sampler for a film."""
    set_width = getattr(sampler, "set_film_width", None)
    if callable(set_width):
        set_width(int(width))


#: Mitsuba's C++ class names of the built-in samplers.
_BUILTIN_CLASSES = {"IndependentSampler": "independent", "StratifiedSampler": "stratified",
                    "MultijitterSampler": "multijitter", "OrthogonalSampler": "orthogonal",
                    "LowDiscrepancySampler": "ldsampler"}


def sampler_name(sampler: mi.Sampler) -> str:
    """Plugin name of a sampler object (ours or Mitsuba's)."""
    plugin = getattr(sampler, "plugin_name", "")
    if plugin:
        return str(plugin)
    cls = sampler.class_name()
    return _BUILTIN_CLASSES.get(cls, cls)


def sampler_params(sampler: mi.Sampler) -> dict[str, Any]:
    """The plugin parameters of a sampler object besides its sample count and
    seed, as ``make_sampler`` takes them (recorded in every output's header)."""
    own = getattr(sampler, "_parameters", None)
    if own is not None:
        return dict(own())
    params: dict[str, Any] = {}
    for line in describe(sampler).splitlines()[1:]:  # "  jitter = 1" (Mitsuba's)
        key, sep, value = line.strip().partition(" = ")
        if sep and key not in _NOT_PARAMETERS:
            params[key] = value.strip()
    if "jitter" in params:  # the one parameter of Mitsuba's samplers: a boolean
        params["jitter"] = params["jitter"] in ("1", "true")
    return params


#: Lines of a Mitsuba sampler's description that are state, not parameters.
_NOT_PARAMETERS = ("sample_count", "base_seed", "seed", "samples_per_wavefront", "wavefront_size")


@contextmanager
def quiet_sampler_warnings() -> Iterator[None]:
    """Silence the "rounding the sample count" warnings of Mitsuba's and mcrt's
    samplers, for tools that create many samplers and report the effective
    counts themselves."""
    level = mi.log_level()
    logger = logging.getLogger("mcrt.samplers")
    old = logger.level
    mi.set_log_level(mi.LogLevel.Error)
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        mi.set_log_level(level)
        logger.setLevel(old)
