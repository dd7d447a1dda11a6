"""Reading and editing the parse state of a scene (:class:`SceneDescription`).

Property values come out of ``mi.Properties`` untyped; the readers here check
what they are, so the rest of the plan works with plain Python values.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ...errors import SceneError
from ..scene import SceneDescription

_T = mi.Properties.Type

#: A property value with a plain Python type.
Scalar = bool | int | float | str
_SCALAR_TYPES = (_T.Float, _T.Integer, _T.Bool, _T.String)


def children(desc: SceneDescription, props: mi.Properties) -> list[tuple[str, int]]:
    """(property name, node index) of every child object of a node."""
    out = []
    for key in props.keys():
        value = props[key]
        if isinstance(value, mi.Properties.ResolvedReference):
            out.append((key, value.index()))
        elif isinstance(value, mi.Properties.Reference) and value.id() in desc.state.id_to_index:
            out.append((key, desc.state.id_to_index[value.id()]))
    return out


def add_node(desc: SceneDescription, kind: mi.ObjectType, props: mi.Properties, parent: int,
             key: str) -> int:
    """Append a node and reference it from node ``parent`` as ``key``.

    Appending may reallocate the node list: every ``desc.nodes[i].props``
    obtained before is then dangling, so the parent is looked up afterwards.
    """
    node = mi.parser.SceneNode()
    node.type = kind
    node.props = props
    desc.nodes.append(node)
    index = len(desc.nodes) - 1
    desc.nodes[parent].props[key] = mi.Properties.ResolvedReference(index)
    return index


def scalar(props: mi.Properties, key: str) -> Scalar:
    """The value of a number, boolean or string property."""
    value = props[key]
    if isinstance(value, (bool, int, float, str)):
        return value
    raise SceneError(f"{props.plugin_name()}: '{key}' must be a number, boolean or string")


def scalars(props: mi.Properties) -> dict[str, Scalar]:
    """Every number, boolean and string property of a node."""
    return {key: scalar(props, key) for key in props.keys() if props.type(key) in _SCALAR_TYPES}


def integer(props: mi.Properties, key: str) -> int:
    return int(scalar(props, key))


def rgb(props: mi.Properties, key: str) -> np.ndarray | None:
    """An rgb or float property as three floats; None if absent or anything else."""
    if key not in props:
        return None
    value = props[key]
    if isinstance(value, (mi.ScalarColor3d, mi.ScalarColor3f)):
        return np.array([float(c) for c in value], dtype=np.float64)
    if isinstance(value, float):
        return np.full(3, value)
    return None


def shapes_by_id(scene: mi.Scene) -> dict[str, mi.Shape]:
    return {s.id(): s for s in scene.shapes()}
