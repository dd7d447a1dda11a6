"""What a user's sampler reads on the host while it is traced: part of every replay key.

A replayed render (:mod:`mcrt.core.replay`, :mod:`mcrt.core.pass_replay`,
:mod:`mcrt.render.adaptive.frozen`) launches the kernels recorded when its
sampler was traced, and a Python value the sampler's code read then is baked
into them: ``x * self.scale`` records the scale as a constant. A user's sampler
(registry kind ``user``) may read such values anywhere, and may change them
between renders: an attribute set after construction (``sampler.scale = 0.5``),
a plugin parameter its ``_parameters()`` does not report, a class attribute, a
module global its methods name, a counter it increments as it is traced. So
:func:`sampler_key` keys a recording by the sampler's class (two classes
registered in turn under one name, or made by one factory, are two kinds) and,
for a user's sampler, by a digest of those values: its instance attributes
(besides :class:`~mcrt.samplers.McrtSampler`'s lane state), its classes' data
attributes and the closures and module globals their methods name (one level
of same-module helper functions deep). A value that changed is another
recording; the same bits as tracing (tests/core/test_replay_user_samplers.py).

Dr.Jit arrays enter the digest by value when they hold one value (a literal is
baked in like a Python float) or are not evaluated yet (an expression is
traced into the kernels); evaluated arrays by type and width (a replay reads
them as inputs when ``frozen_inputs()`` returns them, and a recording that
reads one it does not return fails and renders unfrozen). numpy arrays by
their bytes, but :func:`why_not` refuses a user's sampler that holds numpy
arrays and declares no ``frozen_inputs()``: such a sampler converts them while
it is traced, and Dr.Jit aborts the whole process when a recording frees the
array it made (``enqueue_host_func(): this function cannot be recorded``).
What the digest cannot see (a global of another module, a file the sampler
reads) must not change within a process (docs/extending.md).
"""

from __future__ import annotations

import hashlib
import types
from typing import Any

import drjit as dr
import numpy as np

from ..samplers.registry import info, names

#: McrtSampler's own state (the lane layout, the seed key, the pass), which every
#: render sets anew: never part of a key.
LANE_STATE = frozenset({"_base_calls", "_base_seed", "_key", "_dim", "_pass", "_pass_count",
                        "_layout", "_lanes", "_lane_stride", "_lane_span", "_past_limit"})

#: How deep the digest follows containers and plain objects.
_DEPTH = 4

_SKIPPED = (types.ModuleType, type, types.BuiltinFunctionType)


def user_sampler(sampler: Any) -> bool:
    """Whether ``sampler`` is a user's (registered as kind ``user``)."""
    name = getattr(sampler, "plugin_name", "")
    return bool(name) and name in names() and info(name).kind == "user"


def sampler_key(sampler: Any) -> tuple:
    """What a replay key holds of ``sampler`` besides its name, parameters and
    code fingerprint: its class and, for a user's sampler, the digest of the
    host values its traced code reads (see the module docstring)."""
    if not user_sampler(sampler):
        return (type(sampler),)
    digest = hashlib.sha256()
    for part in _state(sampler):
        digest.update(repr(part).encode())
    return (type(sampler), digest.hexdigest()[:24])


def why_not(sampler: Any) -> str | None:
    """Why renders with ``sampler`` cannot be recorded (None: they may be): a
    user's sampler holding numpy arrays without ``frozen_inputs()``."""
    if not user_sampler(sampler):
        return None
    held = [name for name, value in _values(sampler) if _holds_numpy(value, _DEPTH)]
    if held and not tuple(getattr(sampler, "frozen_inputs", tuple)()):
        return (f"{sampler.plugin_name} holds numpy arrays ({', '.join(sorted(held))}) and no "
                f"frozen_inputs(): converting them while recording aborts the process")
    return None


def _user_classes(sampler: Any) -> list[type]:
    """The classes of ``sampler``'s MRO that are the user's (not mcrt's, Mitsuba's)."""
    return [cls for cls in type(sampler).__mro__
            if not cls.__module__.startswith(("mcrt.", "mitsuba", "drjit", "builtins"))]


def _values(sampler: Any) -> list[tuple[str, Any]]:
    """(name, value) of every host value the sampler's code may read while traced."""
    found = [(name, value) for name, value in vars(sampler).items() if name not in LANE_STATE]
    functions: list[Any] = []
    for cls in _user_classes(sampler):
        for name, value in vars(cls).items():
            if isinstance(value, staticmethod | classmethod):
                value = value.__func__
            if isinstance(value, property):
                functions += [f for f in (value.fget, value.fset) if f is not None]
            elif isinstance(value, types.FunctionType):
                functions.append(value)
            elif not (name.startswith("__") or isinstance(value, _SKIPPED)):
                found.append((f"{cls.__qualname__}.{name}", value))
    seen: set[int] = set()
    while functions:
        function = functions.pop()
        if id(function) in seen:
            continue
        seen.add(id(function))
        cells = function.__closure__ or ()
        for name, cell in zip(function.__code__.co_freevars, cells, strict=False):
            try:
                value = cell.cell_contents
            except ValueError:  # an empty cell
                continue
            if isinstance(value, types.FunctionType):
                functions.append(value)
            elif not isinstance(value, _SKIPPED):
                found.append((f"{function.__qualname__}:{name}", value))
        module = function.__globals__
        for name in _names(function.__code__):
            if name not in module:
                continue
            value = module[name]
            if isinstance(value, types.FunctionType):
                if value.__globals__ is module:  # the module's own helpers
                    functions.append(value)
            elif not isinstance(value, _SKIPPED):
                found.append((f"{module.get('__name__')}.{name}", value))
    return found


def _names(code: types.CodeType) -> set[str]:
    """The global (and attribute) names ``code`` and its nested functions use."""
    used = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            used |= _names(const)
    return used


def _state(sampler: Any) -> list[Any]:
    return sorted(((name, _digest(value, _DEPTH)) for name, value in _values(sampler)),
                  key=lambda item: item[0])


def _digest(value: Any, depth: int) -> Any:
    """A comparable summary of ``value`` (see the module docstring)."""
    if value is None or isinstance(value, bool | int | float | complex | str | bytes):
        return value
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(value)
        return ("ndarray", str(data.dtype), data.shape, hashlib.sha256(data.tobytes()).hexdigest())
    if isinstance(value, np.generic):
        return repr(value)
    if dr.is_array_v(value):
        if not dr.is_jit_v(value):
            return repr(value)
        width = dr.width(value)
        if width == 1 or not _evaluated(value):
            return (type(value).__name__, _digest(np.array(value), depth))
        return (type(value).__name__, width)
    if depth <= 0:
        return type(value).__qualname__
    if isinstance(value, list | tuple | set | frozenset):
        items = [_digest(v, depth - 1) for v in value]
        return (type(value).__name__, sorted(items, key=repr) if isinstance(value, set | frozenset)
                else items)
    if isinstance(value, dict):
        return ("dict", sorted(((repr(k), _digest(v, depth - 1)) for k, v in value.items()),
                               key=lambda item: item[0]))
    if isinstance(value, types.FunctionType):
        return ("function", value.__module__, value.__qualname__)
    fields = getattr(value, "__dict__", None)
    if isinstance(fields, dict) and not isinstance(value, _SKIPPED):
        return (type(value).__qualname__, _digest(fields, depth - 1))
    return repr(value)


def _evaluated(value: Any) -> bool:
    """Whether every variable of a Dr.Jit array is evaluated (lives in memory)."""
    if dr.is_tensor_v(value):
        value = value.array
    if dr.depth_v(value) == 1:
        return bool(value.state == dr.VarState.Evaluated)
    return all(_evaluated(value[i]) for i in range(len(value)))


def _holds_numpy(value: Any, depth: int) -> bool:
    if isinstance(value, np.ndarray):
        return True
    if depth <= 0:
        return False
    if isinstance(value, list | tuple | set | frozenset):
        return any(_holds_numpy(v, depth - 1) for v in value)
    if isinstance(value, dict):
        return any(_holds_numpy(v, depth - 1) for v in value.values())
    return False


__all__ = ["LANE_STATE", "sampler_key", "user_sampler", "why_not"]
