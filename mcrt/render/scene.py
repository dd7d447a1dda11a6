"""Loading scenes and samplers with errors a user can act on.

Every scene mcrt renders is read by :func:`read_scene` (the XML parsed once,
upgraded and resolved as Mitsuba does, into a :class:`SceneDescription` that the
render plan may edit) and built by
:meth:`SceneDescription.instantiate`; :func:`load_scene` does both.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import mitsuba as mi

from ..core.sampling import mitsuba_message
from ..errors import ArgumentTypeError, SceneError
from ..samplers import registry


def parse_defines(items: list[str] | None) -> dict[str, str]:
    """``["key=value", ...]`` (the CLI's ``-D``) to a dict, with clear errors.

    Besides the scene's ``$key`` parameters, :data:`RFILTER_PARAM` (``-D
    mcrt.rfilter=NAME``) replaces the film's reconstruction filter: a study with
    ``filters`` renders so, and its images' recorded commands say so."""
    params: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if key.strip() == RFILTER_PARAM and sep:
            params[RFILTER_PARAM] = value.strip()
            continue
        if not sep or not key.strip() or not re.fullmatch(r"[A-Za-z_]\w*", key.strip()):
            raise SceneError(f"-D expects key=value with a parameter name as key, got {item!r}")
        params[key.strip()] = value
    return params


def check_scene_file(path: str | Path) -> Path:
    """``path`` as a Path if it is an existing regular file, else a one-line
    :class:`SceneError` (missing, a directory, a name too long, ...)."""
    if not isinstance(path, (str, os.PathLike)):
        what = ("a loaded mi.Scene: give the file it was loaded from (mcrt keys its caches "
                "by the file's content)" if isinstance(path, mi.Scene)
                else f"{path!r} ({type(path).__name__})")
        raise ArgumentTypeError(f"a scene file path (str or Path) is needed here, got {what}")
    path = Path(path)
    try:
        if not path.exists():
            raise SceneError(f"scene file not found: {path}")
        if not path.is_file():
            raise SceneError(f"scene path is not a file: {path}")
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as error:  # e.g. ENAMETOOLONG, which exists() does not swallow
        raise SceneError(f"cannot read scene {path}: {error.strerror}") from None
    kind = next((k for magic, k in _IMAGE_MAGIC if head.startswith(magic)), None)
    if kind is not None:
        raise SceneError(f"{path} is {kind} image, not a scene: give a Mitsuba 3 XML scene "
                         f"file (e.g. scenes/cornell_box.xml)")
    return path


#: The first bytes of image files someone may give where a scene belongs.
_IMAGE_MAGIC = ((b"\x89PNG", "a PNG"), (b"\xff\xd8\xff", "a JPEG"),
                (b"\x76\x2f\x31\x01", "an OpenEXR"), (b"#?RADIANCE", "a Radiance HDR"),
                (b"#?RGBE", "a Radiance HDR"), (b"II*\x00", "a TIFF"), (b"MM\x00*", "a TIFF"),
                (b"GIF8", "a GIF"), (b"RIFF", "a RIFF (WebP?)"), (b"BM", "a BMP"))


def scene_parameters(path: str | Path) -> list[str]:
    """The parameters a scene file takes (``<default name=...>`` and ``$name``
    references), sorted; included files are not read."""
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        return []
    names = re.findall(r"<default\s+name\s*=\s*[\"']([A-Za-z_]\w*)", text)
    names += re.findall(r"\$([A-Za-z_]\w*)", text)
    return sorted(set(names))


def _explain(message: str, path: Path) -> str:
    """Mitsuba's message, with the scene's parameters listed when a ``-D`` is unused,
    and a pointer to ``--plugin`` when the scene names a sampler nobody registered."""
    unknown = re.search(r'sampler plugin of type "(\w+)".*Plugin "\1" not found', message)
    if unknown and unknown.group(1) in registry.names() and registry.variant_hint():
        return f"{message}; {registry.variant_hint()}"
    if unknown:
        return (f"{message}; if {unknown.group(1)!r} is your own sampler, load the file that "
                f"registers it with --plugin FILE.py (or $MCRT_PLUGINS; see docs/extending.md)")
    if "unused parameter" not in message:
        return message
    names = scene_parameters(path)
    listed = (f"the scene's parameters are {', '.join(names)}" if names
              else "the scene takes no parameters")
    return f"{message}; {listed}"


def _resolver() -> mi.FileResolver:
    # mi.file_resolver is missing from Mitsuba 3.9's stubs (they only have the
    # deprecated mi.Thread.file_resolver), which makes it an untyped object.
    return cast(Callable[[], mi.FileResolver], mi.file_resolver)()


@contextmanager
def _search_paths(first: list[str]) -> Iterator[mi.FileResolver]:
    """Resolve files (includes, meshes, textures) in the folders ``first``, then
    where the resolver looked before; the resolver is restored after."""
    resolver = _resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    for entry in reversed(first):
        resolver.prepend(entry)
    try:
        yield resolver
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
    #: Where its files are found, in order, as ``mi.load_file`` finds them: the folders
    #: its ``<path value="..."/>`` elements added while it was parsed, then its own.
    search: list[str]

    @property
    def nodes(self) -> mi.parser.SceneNodeList:
        return self.state.nodes

    def instantiate(self) -> mi.Scene:
        """Build the scene the description says now (the description is kept:
        Mitsuba's transforms edit a copy)."""
        try:
            scene = self._build(len(self.nodes) >= PARALLEL_NODES)
        except Exception as error:  # Mitsuba reports plugin errors as RuntimeError
            if not _internal(error):
                raise SceneError(f"cannot load scene {self.path}: "
                                 f"{_explain(mitsuba_message(error), self.path)}") from None
            try:  # (an error of the C++ library itself, not of the scene: once more, serially)
                scene = self._build(False)
            except Exception as again:
                raise SceneError(f"cannot load scene {self.path}: "
                                 f"{_explain(mitsuba_message(again), self.path)}") from None
        if not isinstance(scene, mi.Scene):
            raise _not_a_scene(self.path)
        if not scene.sensors():
            raise SceneError(f"{self.path} has no sensor to render from")
        return scene

    def _build(self, parallel: bool) -> object:
        """Mitsuba's transforms and instantiation of a copy of the state, on
        Mitsuba's threads or not (``parallel``)."""
        state = mi.parser.ParserState(self.state)
        config = _config_like(self.config, parallel)
        with _search_paths(self.search):
            mi.parser.transform_all(config, state)
            return mi.parser.instantiate(config, state)


#: Descriptions of fewer nodes are instantiated on the calling thread: Mitsuba's
#: parallel instantiation gains nothing on a handful of objects, and under it a
#: small scene's sensor failed now and then with a C++ library error
#: (``basic_string::_M_create`` instantiating a radiance meter: three times in
#: full test runs, never when rerun; cause unknown). Larger scenes (many meshes,
#: textures) keep Mitsuba's threads, and such an error is retried serially.
PARALLEL_NODES = 32

#: Messages of the C++ standard library's exceptions: a failure of the loader,
#: never a fault of the scene (which Mitsuba reports in words).
_CPP_INTERNALS = ("basic_string::", "vector::", "std::bad_alloc", "bad_array_new_length")


def _internal(error: BaseException) -> bool:
    return any(text in str(error) for text in _CPP_INTERNALS)


def _config_like(config: mi.parser.ParserConfig, parallel: bool) -> mi.parser.ParserConfig:
    """A copy of ``config`` (each instantiation gets its own) with ``parallel``."""
    copy = mi.parser.ParserConfig(config.variant)
    for name in ("max_include_depth", "merge_equivalent", "merge_meshes",
                 "unused_parameters", "unused_properties"):
        setattr(copy, name, getattr(config, name))
    copy.parallel = parallel
    return copy


def _not_a_scene(path: Path) -> SceneError:
    return SceneError(f"{path} does not describe a scene (its root is not <scene>)")


#: A ``params`` key that is not a scene parameter: the name of a reconstruction
#: filter plugin (``box``, ``gaussian``, ...) that replaces the film's filter
#: (a study's ``filters`` axis sets it; it keys references and caches like any
#: parameter).
RFILTER_PARAM = "mcrt.rfilter"


def scene_params(params: Mapping[str, Any] | None) -> dict[str, Any]:
    """A copy of a caller's scene ``params`` (``{"res": "32"}``), or a one-line
    error for anything else: the ``["res=32"]`` of the command line is turned
    into a dict by :func:`parse_defines`."""
    if params is None:
        return {}
    if not isinstance(params, Mapping):
        hint = (f": parse_defines({params!r}) makes one from key=value strings"
                if isinstance(params, list | tuple) else "")
        raise ArgumentTypeError(f"scene params must be a dict of parameter names to values, "
                                f"e.g. {{'res': 32}}, got {type(params).__name__}{hint}")
    return dict(params)


def read_scene(path: str | Path, params: dict[str, str] | None = None) -> SceneDescription:
    """Parse a Mitsuba XML scene, substituting ``$key`` parameters from ``params``
    (:data:`RFILTER_PARAM` replaces the film's reconstruction filter)."""
    params = scene_params(params)
    rfilter = params.pop(RFILTER_PARAM, None)
    path = check_scene_file(path)
    variant = mi.variant()
    if variant is None:
        raise SceneError("no Mitsuba variant is active (import mcrt to activate one)")
    config = mi.parser.ParserConfig(variant)
    try:
        with _search_paths([str(path.resolve().parent)]) as resolver:
            before = {str(resolver[i]) for i in range(len(resolver))}
            state = mi.parser.parse_file(config, str(path), **(params or {}))
            search = [str(resolver[i]) for i in range(len(resolver))]
    except Exception as error:  # Mitsuba reports parse errors as RuntimeError
        raise SceneError(f"cannot load scene {path}: "
                         f"{_explain(mitsuba_message(error), path)}") from None
    if state.nodes[0].type != mi.ObjectType.Scene:
        raise _not_a_scene(path)
    _upgrade(config, state, path)
    desc = SceneDescription(path, config, state,
                            [entry for entry in search if entry not in before]
                            + [str(path.resolve().parent)])
    if rfilter is not None:
        set_rfilter(desc, rfilter)
    return desc


def set_rfilter(desc: SceneDescription, plugin: str) -> None:
    """Give every film of ``desc`` a default-parameter ``plugin`` filter."""
    films = [i for i, n in enumerate(desc.nodes) if n.type == mi.ObjectType.Film]
    for index in films:
        props = desc.nodes[index].props
        for key in props.keys():
            value = props[key]
            if isinstance(value, mi.Properties.ResolvedReference) and \
                    desc.nodes[value.index()].type == mi.ObjectType.ReconstructionFilter:
                desc.nodes[value.index()].props = mi.Properties(plugin)
                break
        else:
            node = mi.parser.SceneNode()
            node.type = mi.ObjectType.ReconstructionFilter
            node.props = mi.Properties(plugin)
            desc.nodes.append(node)  # may reallocate: look the film up again
            desc.nodes[index].props["rfilter"] = mi.Properties.ResolvedReference(
                len(desc.nodes) - 1)


def _upgrade(config: mi.parser.ParserConfig, state: mi.parser.ParserState, path: Path) -> None:
    """Mitsuba's own first two transforms, so that whoever reads the description
    sees the scene as Mitsuba instantiates it: old-format (``version < 2``) names
    upgraded (``maxDepth`` -> ``max_depth``, ``toWorld`` -> ``to_world``, ...) and
    references resolved to node indices. Both are idempotent, so
    :meth:`SceneDescription.instantiate` may run ``transform_all`` again."""
    try:
        mi.parser.transform_upgrade(config, state)
        mi.parser.transform_resolve(config, state)
    except Exception as error:  # e.g. a reference to a missing id
        raise SceneError(f"cannot load scene {path}: "
                         f"{_explain(mitsuba_message(error), path)}") from None


def load_scene(path: str | Path, params: dict[str, str] | None = None) -> mi.Scene:
    """Load a Mitsuba XML scene, substituting ``$key`` parameters from ``params``
    (what ``mi.load_file`` does, with one-line :class:`SceneError` messages)."""
    return read_scene(path, params).instantiate()
