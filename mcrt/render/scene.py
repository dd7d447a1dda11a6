"""Loading scenes and samplers with errors a user can act on.

Every scene mcrt renders is read by :func:`read_scene` (the XML parsed once,
into a :class:`SceneDescription` that the render plan may edit) and built by
:meth:`SceneDescription.instantiate`; :func:`load_scene` does both.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import mitsuba as mi

from ..core.sampling import mitsuba_message
from ..errors import SceneError


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


@contextmanager
def _scene_folder_first(path: Path) -> Iterator[None]:
    """Resolve the files a scene names (includes, meshes, textures) relative to
    its folder first, as ``mi.load_file`` does; the resolver is restored after."""
    # mi.file_resolver is missing from Mitsuba 3.9's stubs (they only have the
    # deprecated mi.Thread.file_resolver), which makes it an untyped object.
    resolver = cast(Callable[[], mi.FileResolver], mi.file_resolver)()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    resolver.prepend(str(path.resolve().parent))
    try:
        yield
    finally:
        resolver.clear()
        for entry in saved:
            resolver.append(entry)


@dataclass
class SceneDescription:
    """A scene file read once: Mitsuba's parse state, which may be edited
    (``nodes``) and instantiated any number of times."""

    path: Path
    config: mi.parser.ParserConfig
    state: mi.parser.ParserState

    @property
    def nodes(self) -> mi.parser.SceneNodeList:
        return self.state.nodes

    def instantiate(self) -> mi.Scene:
        """Build the scene the description says now (the description is kept:
        Mitsuba's transforms edit a copy)."""
        state = mi.parser.ParserState(self.state)
        try:
            with _scene_folder_first(self.path):
                mi.parser.transform_all(self.config, state)
                scene = mi.parser.instantiate(self.config, state)
        except Exception as error:  # Mitsuba reports plugin errors as RuntimeError
            raise SceneError(f"cannot load scene {self.path}: {mitsuba_message(error)}") from None
        if not isinstance(scene, mi.Scene):
            raise _not_a_scene(self.path)
        if not scene.sensors():
            raise SceneError(f"{self.path} has no sensor to render from")
        return scene


def _not_a_scene(path: Path) -> SceneError:
    return SceneError(f"{path} does not describe a scene (its root is not <scene>)")


def read_scene(path: str | Path, params: dict[str, str] | None = None) -> SceneDescription:
    """Parse a Mitsuba XML scene, substituting ``$key`` parameters from ``params``."""
    path = check_scene_file(path)
    variant = mi.variant()
    if variant is None:
        raise SceneError("no Mitsuba variant is active (import mcrt to activate one)")
    config = mi.parser.ParserConfig(variant)
    try:
        with _scene_folder_first(path):
            state = mi.parser.parse_file(config, str(path), **(params or {}))
    except Exception as error:  # Mitsuba reports parse errors as RuntimeError
        raise SceneError(f"cannot load scene {path}: {mitsuba_message(error)}") from None
    if state.nodes[0].type != mi.ObjectType.Scene:
        raise _not_a_scene(path)
    return SceneDescription(path, config, state)


def load_scene(path: str | Path, params: dict[str, str] | None = None) -> mi.Scene:
    """Load a Mitsuba XML scene, substituting ``$key`` parameters from ``params``
    (what ``mi.load_file`` does, with one-line :class:`SceneError` messages)."""
    return read_scene(path, params).instantiate()
