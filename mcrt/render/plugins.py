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
from collections.abc import Iterable

import mitsuba as mi

#: Indentation of the rows of a docstring's ``pluginparameters`` table.
ROW = "     "


def register_integrator(plugin: str, module_name: str, class_name: str) -> None:
    """Register ``module_name.class_name`` as Mitsuba integrator ``plugin`` for
    the active variant (re-importing the module if the variant changed)."""
    module = importlib.import_module(module_name)
    if mi.variant() != module._classes_variant:
        module = importlib.reload(module)
    mi.register_integrator(plugin, lambda props, cls=getattr(module, class_name): cls(props))


def parameter_row(name: str, kind: str, text: str) -> str:
    """One row of a plugin's RST parameter table: name, ``|kind|``, wrapped text."""
    body = textwrap.fill(" ".join(text.split()), width=86 - len(ROW),
                         initial_indent=f"{ROW}  - ", subsequent_indent=f"{ROW}    ")
    return f"{ROW}* - {name}\n{ROW}  - |{kind}|\n{body}"


def fill_parameters(template: str, rows: Iterable[str]) -> str:
    """``template`` with its ``{parameters}`` placeholder replaced by the rows."""
    return template.replace("{parameters}", "\n".join(rows))
