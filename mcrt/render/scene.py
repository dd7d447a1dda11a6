"""Loading scenes and samplers with errors a user can act on."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import mitsuba as mi

from ..errors import SamplerError, SceneError
from ..samplers import ALL_SAMPLERS


def mitsuba_message(error: BaseException) -> str:
    """One line from a Mitsuba exception: no ``[file.cpp:123]`` prefix, and for
    errors raised inside Python plugins, the final ``Type: message`` line."""
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


def parse_defines(items: list[str] | None) -> dict[str, str]:
    """``["key=value", ...]`` (the CLI's ``-D``) to a dict, with clear errors."""
    params: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not re.fullmatch(r"[A-Za-z_]\w*", key.strip()):
            raise SceneError(f"-D expects key=value with a parameter name as key, got {item!r}")
        params[key.strip()] = value
    return params


def check_scene_file(path: str | Path) -> Path:
    """``path`` as a Path if it is an existing regular file, else a one-line
    :class:`SceneError` (missing, a directory, a name too long, ...)."""
    path = Path(path)
    try:
        if not path.exists():
            raise SceneError(f"scene file not found: {path}")
        if not path.is_file():
            raise SceneError(f"scene path is not a file: {path}")
    except OSError as error:  # e.g. ENAMETOOLONG, which exists() does not swallow
        raise SceneError(f"cannot read scene {path}: {error.strerror}") from None
    return path


def load_scene(path: str | Path, params: dict[str, str] | None = None) -> mi.Scene:
    """Load a Mitsuba XML scene, substituting ``$key`` parameters from ``params``."""
    path = check_scene_file(path)
    try:
        scene = mi.load_file(str(path), **(params or {}))
    except Exception as error:  # Mitsuba reports parse/plugin errors as RuntimeError
        raise SceneError(f"cannot load scene {path}: {mitsuba_message(error)}") from None
    if not isinstance(scene, mi.Scene):
        raise SceneError(f"{path} does not describe a scene (its root is not <scene>)")
    if not scene.sensors():
        raise SceneError(f"{path} has no sensor to render from")
    return scene


def check_sampler_name(name: str) -> str:
    """Return ``name`` if mcrt can render with that sampler, else raise."""
    if name not in ALL_SAMPLERS:
        raise SamplerError(f"unknown sampler {name!r}; choose one of: {', '.join(ALL_SAMPLERS)}")
    return name


def make_sampler(name: str, spp: int, seed: int = 0, **params) -> mi.Sampler:
    """Instantiate sampler plugin ``name`` with ``spp`` samples per pixel."""
    check_sampler_name(name)
    try:
        return mi.load_dict({"type": name, "sample_count": int(spp), "seed": int(seed), **params})
    except Exception as error:
        raise SamplerError(f"cannot create sampler {name!r}: {mitsuba_message(error)}") from None


#: Mitsuba's C++ class names of the built-in samplers.
_BUILTIN_CLASSES = {"IndependentSampler": "independent", "StratifiedSampler": "stratified",
                    "MultijitterSampler": "multijitter", "OrthogonalSampler": "orthogonal",
                    "LowDiscrepancySampler": "ldsampler"}


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


def sampler_name(sampler: mi.Sampler) -> str:
    """Plugin name of a sampler object (ours or Mitsuba's)."""
    plugin = getattr(sampler, "plugin_name", "")
    if plugin:
        return plugin
    cls = sampler.class_name()
    return _BUILTIN_CLASSES.get(cls, cls)
