"""What a Python caller hands the renderers, checked before anything renders.

In a notebook the wrong thing is easily passed: a scene's path where a loaded
scene belongs, a ``PlannedScene`` instead of its ``.scene``, a scene or sampler
made before ``mi.set_variant`` switched variants, a float seed. Each check here
turns such a mistake into one line (:class:`~mcrt.errors.ArgumentError`, also a
``ValueError``; :class:`~mcrt.errors.ArgumentTypeError`, also a ``TypeError``)
that names the argument and what it must be, instead of an ``AttributeError``,
a nanobind signature dump or a misleading message from deep inside a render (a
scene of another variant failed as "this scene uses PathIntegrator").
"""

from __future__ import annotations

import os
import sys
from typing import Any

import mitsuba as mi

from ..errors import ArgumentError, ArgumentTypeError, whole_number

#: Seeds are 32-bit (Mitsuba's ``sampler.seed`` takes a UInt32).
SEED_LIMIT = 2 ** 32


def variant_of(obj: Any, base: str) -> str | None:
    """The Mitsuba variant whose class ``base`` (``"Scene"``, ``"Sampler"``) ``obj``
    is an instance of, among the variants loaded in this process; None if none."""
    for variant in mi.variants():
        module = sys.modules.get(f"mitsuba.{variant}")
        cls = getattr(module, base, None) if module is not None else None
        if isinstance(cls, type) and isinstance(obj, cls):
            return variant
    return None


def _other_variant(what: str, variant: str) -> ArgumentTypeError:
    return ArgumentTypeError(
        f"the {what} was made under Mitsuba's {variant} variant, but {mi.variant()} is active "
        f"now: make it again under {mi.variant()} (after mcrt.register()), or switch back "
        f"with mi.set_variant({variant!r})")


def check_scene(scene: Any, who: str) -> mi.Scene:
    """``scene`` if it is a loaded ``mi.Scene`` of the active variant, else a
    one-line error saying what it is and how to get a scene from it."""
    if isinstance(scene, mi.Scene):
        return scene
    variant = variant_of(scene, "Scene")
    if variant is not None:
        raise ArgumentTypeError(f"{who}: {_other_variant('scene', variant)}")
    if isinstance(scene, (str, os.PathLike)):
        got = (f"the path {os.fspath(scene)!r}: load it first, with "
               f"mcrt.render.scene.load_scene(path, params) or plan_scene(path, params).scene")
    elif isinstance(getattr(scene, "scene", None), mi.Scene):
        got = f"a {type(scene).__name__}: pass its .scene"
    elif isinstance(scene, dict):
        got = "a dict: build the scene with mi.load_dict(...) first"
    else:
        got = f"{type(scene).__name__}"
    raise ArgumentTypeError(f"{who}: scene must be a loaded mi.Scene, got {got}")


def check_sampler(sampler: Any, who: str) -> mi.Sampler | str | None:
    """``sampler`` if it is None, a sampler name or a ``mi.Sampler`` of the
    active variant, else a one-line error."""
    if sampler is None or isinstance(sampler, (str, mi.Sampler)):
        return sampler
    variant = variant_of(sampler, "Sampler")
    if variant is not None:
        raise ArgumentTypeError(f"{who}: {_other_variant('sampler', variant)}")
    got = (f"the class {sampler.__name__}: pass an instance (make_sampler(name, spp)) or its "
           f"registered name" if isinstance(sampler, type) else type(sampler).__name__)
    raise ArgumentTypeError(f"{who}: sampler must be a Mitsuba sampler "
                            f"(mcrt.core.sampling.make_sampler(name, spp)) or a sampler name, "
                            f"got {got}")


def check_seed(seed: Any, who: str) -> int:
    """``seed`` as an int in [0, 2^32)."""
    return whole_number(seed, f"{who}: seed", 0, SEED_LIMIT)


def check_spp(spp: Any, who: str) -> int | None:
    """``spp`` as a positive int (None stays None: the sampler's own count)."""
    return None if spp is None else whole_number(spp, f"{who}: spp")


def check_max_lanes(max_lanes: Any, who: str) -> int | None:
    """``max_lanes`` as a positive int (None stays None: no limit but memory's).
    A 0 was taken as no limit (``max_lanes or default``), a negative as a limit
    of one sample per pixel per pass; both are refused."""
    return None if max_lanes is None else whole_number(max_lanes, f"{who}: max_lanes")


def check_sensor(scene: mi.Scene, sensor: Any, who: str) -> int:
    """``sensor`` as an index of one of ``scene``'s sensors."""
    count = len(scene.sensors())
    try:
        return whole_number(sensor, f"{who}: sensor", 0, count)
    except ArgumentError as error:
        raise type(error)(f"{error}: the scene has {count} sensor"
                          f"{'s' if count != 1 else ''}") from None


__all__ = ["SEED_LIMIT", "check_max_lanes", "check_sampler", "check_scene", "check_seed",
           "check_sensor", "check_spp", "variant_of"]
