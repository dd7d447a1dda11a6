"""mcrt's integrator plugins written in Python: registration and docstrings.

Each plugin module (``distribution``, ``adaptive_integrator``,
``multisample_integrator``) defines its class against the active variant's
``mi.SamplingIntegrator`` and records that variant in ``_classes_variant``;
:func:`register_integrator` re-imports the module after a variant switch (so
the class derives from the new variant's base) and registers it with Mitsuba.
:func:`mcrt.register` is the one place that calls them.

A plugin's RST parameter table (Mitsuba's ``pluginparameters`` format) is made
from its parameter declaration with :func:`parameter_row` and
:func:`fill_parameters`, so the docstring cannot drift from the code.
"""

from __future__ import annotations

import importlib
import textwrap
from collections.abc import Callable, Iterable
from typing import Any

import mitsuba as mi

#: Indentation of the rows of a docstring's ``pluginparameters`` table.
ROW = "     "


def register_integrator(plugin: str, module_name: str, class_name: str) -> None:
    """Register ``module_name.class_name`` as Mitsuba integrator ``plugin`` for
    the active variant (re-importing the module if the variant changed)."""
    module = importlib.import_module(module_name)
    if mi.variant() != module._classes_variant:
        module = importlib.reload(module)
    cls = getattr(module, class_name)
    mi.register_integrator(plugin, lambda props: cls(props))


def parameter_row(name: str, kind: str, text: str) -> str:
    """One row of a plugin's RST parameter table: name, ``|kind|``, wrapped text."""
    body = textwrap.fill(" ".join(text.split()), width=86 - len(ROW),
                         initial_indent=f"{ROW}  - ", subsequent_indent=f"{ROW}    ")
    return f"{ROW}* - {name}\n{ROW}  - |{kind}|\n{body}"


def fill_parameters(template: str, rows: Iterable[str]) -> str:
    """``template`` with its ``{parameters}`` placeholder replaced by the rows."""
    return template.replace("{parameters}", "\n".join(rows))


#: Properties Mitsuba may pass to any sampling integrator (a wrapper ignores them).
IGNORED = ("samples_per_pass", "hide_emitters", "timeout")


def wrapper_properties(plugin: str, props: mi.Properties, declared: Iterable[str],
                       convert: Callable[[str, Any], Any]) -> tuple[mi.SamplingIntegrator,
                                                                    dict[str, Any]]:
    """A wrapping integrator's properties: its one nested sampling integrator
    (default ``path``) and its declared parameters, each through
    ``convert(name, value)``; unknown names and a wrong or doubled nested
    integrator are one-line :class:`~mcrt.errors.McrtError`."""
    from ..errors import McrtError

    names = list(declared)
    nested, values = [], {}
    for name in props.keys():
        value = props[name]
        if isinstance(value, mi.Integrator):
            nested.append(value)
        elif name in names:
            values[name] = convert(name, value)
        elif name not in IGNORED:
            raise McrtError(f"{plugin}: unknown parameter {name!r}; expected one of "
                            f"{', '.join(names)}")
    if len(nested) > 1:
        raise McrtError(f"{plugin}: expected one nested integrator, got {len(nested)}")
    # (parallel=False: a constructor may run on a worker of the scene's own parallel
    # instantiation; a load nested there gains nothing from more threads)
    inner = nested[0] if nested else mi.load_dict({"type": "path"}, parallel=False)
    if not isinstance(inner, mi.SamplingIntegrator):
        raise McrtError(f"{plugin}: the nested integrator must be a sampling integrator "
                        f"(path, direct, ...), got {type(inner).__name__}")
    return inner, values
